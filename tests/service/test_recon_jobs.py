"""Reconstruction jobs over HTTP on a real uvicorn server: NER and NEDNER from uploaded
datasets against the analytic ball phantom and a direct in-process call; SSE progress
with Last-Event-ID replay; HTTP Range; cancel; the dask LocalCluster executor."""
from __future__ import annotations

import io
import json
import re

import h5py
import httpx
import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_gone, wait_job

pytestmark = needs_recon

N, PITCH, N_T, DT, C = 24, 1e-4, 128, 2e-8, 1500.0


def ball_dataset():
    from fpscan.physics.balls import Ball, ball_alines

    x = (np.arange(N) - (N - 1) / 2) * PITCH
    yy, xx = np.meshgrid(x, x, indexing="ij")
    positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
    balls = [Ball(x=2e-4, y=-1e-4, z=1.2e-3, radius=1.5e-4, amplitude=1.0)]
    alines = ball_alines(positions, balls, DT, N_T, C)          # (n_points, n_t)
    data = alines.T.reshape(N_T, N, N)                           # (n_t, n_y, n_x)
    return data, balls, x


def npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def upload(c: httpx.Client, data) -> str:
    r = c.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(PITCH), "c": repr(C)},
               files={"file": ("d.npy", npy(data), "application/octet-stream")})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


def sse_events(c: httpx.Client, job_id: str, last_event_id: str | None = None, timeout: float = 120.0) -> list[dict]:
    """Read the job's SSE stream to its end; returns [{id, event, data}]."""
    headers = {"Last-Event-ID": last_event_id} if last_event_id is not None else {}
    out, cur = [], {}
    with c.stream("GET", f"/api/jobs/{job_id}/events", headers=headers, timeout=timeout) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("id:"):
                cur["id"] = line[3:].strip()
            elif line.startswith("event:"):
                cur["event"] = line[6:].strip()
            elif line.startswith("data:"):
                cur["data"] = json.loads(line[5:].strip())
            elif line == "" and cur:
                if "data" in cur:
                    out.append(cur)
                cur = {}
    return out


def download_volume(c, job_id):
    r = c.get(f"/api/reconstructions/{job_id}/volume.h5")
    assert r.status_code == 200
    with h5py.File(io.BytesIO(r.content), "r") as f:
        return {k: f[k][...] for k in f if isinstance(f[k], h5py.Dataset)}, dict(f.attrs)


def test_ner_and_nedner_jobs_match_direct_call_and_phantom(shared_server, shared_api):
    api = shared_api
    from fpscan.physics.balls import ball_p0
    from fpscan.service.recon import reconstruct_grid

    data, balls, x = ball_dataset()
    ds = upload(api, data)
    params = {"dtype": "float64", "eps": 1e-9}
    r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner", "params": params})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    events = sse_events(api, job_id)
    states = [e["data"]["state"] for e in events if e["event"] == "state"]
    assert states[0] == "queued" and states[-1] == "succeeded" and "running" in states
    ids = [int(e["id"]) for e in events]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    stages = [e["data"]["stage"] for e in events if e["event"] == "progress"]
    assert stages[:1] == ["starting"]
    assert set(stages) & {"loading", "reconstructing", "writing"}  # the worker's own stage reports
    # reconnecting with Last-Event-ID replays only what came after
    replay = sse_events(api, job_id, last_event_id=str(ids[1]))
    assert [int(e["id"]) for e in replay] == ids[2:]

    job = api.get(f"/api/jobs/{job_id}").json()
    assert job["state"] == "succeeded" and job["progress"]["fraction"] == 1.0
    assert job["timings"]["run_s"] > 0 and "volume" in job["links"]
    vol, attrs = download_volume(api, job_id)
    direct = reconstruct_grid(data, PITCH, DT, C, method="ner", dtype=np.float64, eps=1e-9)
    assert vol["p0"].shape == direct.p0.shape
    np.testing.assert_allclose(vol["p0"], direct.p0, rtol=0, atol=1e-9 * np.abs(direct.p0).max())
    np.testing.assert_allclose(vol["z"], direct.z)
    assert attrs["method"] == "ner"

    # the result correlates with the analytic phantom (limited view keeps it below 1)
    truth = ball_p0(balls, vol["z"], vol["x"], vol["y"], supersample=2)
    cc = np.corrcoef(vol["p0"].max(axis=1).ravel(), truth.max(axis=1).ravel())[0, 1]
    assert cc > 0.6, cc

    # MIPs are PNGs; a depth slice too; HTTP Range on the volume
    for plane in ("xy", "xz", "yz"):
        png = api.get(f"/api/reconstructions/{job_id}/mip/{plane}.png")
        assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    ball_row = round(1.2e-3 / float(vol["z"][1] - vol["z"][0]))  # the ball's depth row (12 of the 0.1 mm pitch)
    assert api.get(f"/api/reconstructions/{job_id}/slice.png", params={"index": ball_row}).status_code == 200
    r = api.get(f"/api/reconstructions/{job_id}/slice.png", params={"index": 10**6})
    assert r.status_code == 422 and "index" in r.json()["detail"]
    r = api.get(f"/api/reconstructions/{job_id}/volume.h5", headers={"Range": "bytes=0-99"})
    assert r.status_code == 206 and len(r.content) == 100
    full = api.get(f"/api/reconstructions/{job_id}/volume.h5").content
    assert r.content == full[:100]
    # HEAD: GET's headers, no body (a download manager's or `curl -I`'s first question)
    head = api.head(f"/api/reconstructions/{job_id}/volume.h5")
    assert head.status_code == 200 and head.content == b"", (head.status_code, head.text)
    assert int(head.headers["content-length"]) == len(full) and head.headers["accept-ranges"] == "bytes"
    # a Range it cannot serve is refused as every other request is: a reason in {"detail"}
    r = api.get(f"/api/reconstructions/{job_id}/volume.h5", headers={"Range": "bytes=oops"})
    assert r.status_code == 400 and "Range" in r.json()["detail"], r.text
    r = api.get(f"/api/reconstructions/{job_id}/volume.h5", headers={"Range": f"bytes={len(full) + 10}-"})
    assert r.status_code == 416 and "no byte inside the file" in r.json()["detail"], r.text
    assert r.headers["content-range"] == f"bytes */{len(full)}"

    # NEDNER on the same (full-lattice) sensors gives the NER image (paper §3.2)
    r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "nedner", "params": params})
    nedner_id = r.json()["id"]
    assert wait_job(api, nedner_id)["state"] == "succeeded"
    vol2, _ = download_volume(api, nedner_id)
    err = np.linalg.norm(vol2["p0"] - vol["p0"]) / np.linalg.norm(vol["p0"])
    assert err < 0.05, err


def test_cancel_queued_and_running(shared_api):
    api = shared_api
    data, _, _ = ball_dataset()
    ds = upload(api, data)
    first = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner"}).json()["id"]
    second = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "linear"}).json()["id"]
    r = api.post(f"/api/jobs/{second}/cancel")
    assert r.status_code == 200
    assert wait_job(api, second)["state"] == "cancelled"
    r = api.post(f"/api/jobs/{first}/cancel")
    assert r.status_code in (200, 409)  # 409: it had already finished
    final = wait_job(api, first)
    assert final["state"] in ("cancelled", "succeeded")
    if final["state"] == "cancelled":
        assert api.get(f"/api/reconstructions/{first}/volume.h5").status_code == 409
    assert api.post(f"/api/jobs/{second}/cancel").status_code == 409


def test_dask_localcluster_gives_the_local_pool_result(tmp_path, shared_api):
    from distributed import LocalCluster

    data, _, _ = ball_dataset()
    body = {"method": "ner", "params": {"dtype": "float64"}}
    jid = shared_api.post("/api/reconstructions", json={**body, "dataset_id": upload(shared_api, data)}).json()["id"]
    assert wait_job(shared_api, jid)["state"] == "succeeded"
    local = download_volume(shared_api, jid)[0]["p0"]
    # a scheduler with one in-process (thread) worker; the server connects to its address
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
                      dashboard_address=None) as cluster:
        srv = Server(tmp_path / "dask", env={"FPSCAN_DASK_SCHEDULER": cluster.scheduler_address}).start()
        try:
            with srv.client() as c:
                assert c.get("/api/health").json()["executor"] == "dask"
                jid = c.post("/api/reconstructions", json={**body, "dataset_id": upload(c, data)}).json()["id"]
                assert wait_job(c, jid)["state"] == "succeeded"
                remote = download_volume(c, jid)[0]["p0"]
                workers = srv.workers()
        finally:
            srv.stop()
        assert wait_gone(workers) == []  # a stopped server leaves no worker behind
    np.testing.assert_array_equal(remote, local)


def test_kwave_hdf5_upload_2d_ner_matches_kwave_and_direct_call(shared_api, shared_data):
    """Real k-Wave data (shared/data/kwave2d_points.h5) uploaded as kwave-hdf5: the 2-D NER
    job equals the direct call and agrees with k-Wave's own kspaceLineRecon output."""
    from fpscan.service.recon import reconstruct_grid

    path = shared_data / "kwave2d_points.h5"
    r = shared_api.post("/api/datasets", data={"format": "kwave-hdf5"},
                        files={"file": ("kwave2d_points.h5", path.read_bytes(), "application/x-hdf5")})
    assert r.status_code == 201, r.text
    ds = r.json()
    assert ds["layout"] == "grid" and ds["shape"] == [3519, 1024] and ds["dt"] == pytest.approx(1e-8)
    r = shared_api.post("/api/reconstructions", json={"dataset_id": ds["dataset_id"], "method": "ner",
                                                      "params": {"dtype": "float64", "n_z": 854, "dz": 1.5e-5}})
    jid = r.json()["id"]
    assert wait_job(shared_api, jid)["state"] == "succeeded"
    vol, attrs = download_volume(shared_api, jid)
    assert "y" not in vol and vol["p0"].shape == (854, 1024)
    with h5py.File(path, "r") as f:
        data = f["sensor_data/clean"][...]
        kwave = f["recon/clean/recon_starlinear_poscond0"][...]
    # k-Wave's rows: 854 of c·dt = 15 µm (the default would be the pitch, 50 µm)
    direct = reconstruct_grid(data, 5e-5, 1e-8, 1500.0, method="ner", dtype=np.float64, n_z=854, dz=1.5e-5)
    np.testing.assert_allclose(vol["p0"], direct.p0, rtol=0, atol=1e-9 * np.abs(direct.p0).max())
    cc = np.corrcoef(vol["p0"].ravel(), kwave.ravel())[0, 1]
    assert cc > 0.9, cc
    assert shared_api.get(f"/api/reconstructions/{jid}/mip/xz.png").status_code == 200
    r = shared_api.get(f"/api/reconstructions/{jid}/mip/xy.png")
    assert r.status_code == 404 and "2-D" in r.json()["detail"]


def test_tv_job_progress_names_the_iteration_and_bad_options_are_422(shared_api):
    """Model-based ``tv`` over HTTP: the job's SSE progress shows the solver's iterations
    ("iteration k/N"), and bad options are 422 naming them. (Its volume equals the local
    and worker ones: tests/service/test_pipeline_parity.py.)"""
    from fpscan.physics.balls import Ball, ball_alines

    # small: the server reads every line of the worker's progress file, also after the
    # worker has returned, so a solve that ends between two of its reads shows its iterations
    n, n_t, max_iter = 12, 48, 20
    x = (np.arange(n) - (n - 1) / 2) * PITCH
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    alines = ball_alines(pos, [Ball(x=1e-4, y=0.0, z=0.5e-3, radius=1.5e-4, amplitude=1.0)], DT, n_t, C)
    data = alines.T.reshape(n_t, n, n).astype(np.float32)
    api = shared_api
    ds = upload(api, data)
    for bad, name in (({"lam": -1.0}, "lam"), ({"max_iter": 0}, "max_iter"), ({"lam": "a lot"}, "lam")):
        r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "tv", "params": bad})
        assert r.status_code == 422 and name in r.text, r.text
    params = {"dtype": "float64", "lam": 0.0, "max_iter": max_iter, "n_z": 12}  # 1.1 mm of the pitch (0.1 mm)
    r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "tv", "params": params})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    events = sse_events(api, job_id)
    assert [e["data"]["state"] for e in events if e["event"] == "state"][-1] == "succeeded", events[-1]
    stages = [e["data"]["stage"] for e in events if e["event"] == "progress"]
    its = [s for s in stages if s.startswith("iteration ")]
    assert its and all(re.fullmatch(rf"iteration \d+/{max_iter}", s) for s in its), stages
    # the events carry the stopping rule's tolerance and the ETA to it, bounded by the limit
    from fpscan.service.recon.methods.tv import DEFAULT_TOL

    fields = [e["data"] for e in events if e["event"] == "progress" and e["data"].get("iteration")]
    assert fields and all(f["stop_tol"] == DEFAULT_TOL and isinstance(f["stop_armed"], bool) for f in fields), fields
    timed = [f for f in fields if f.get("eta_s") is not None]
    assert timed and all(f["eta_max_s"] >= f["eta_s"] >= 0 and f["eta_basis"] for f in timed), [
        {k: f.get(k) for k in ("iteration", "eta_s", "eta_max_s", "eta_basis", "stop_value")} for f in timed]
    vol, attrs = download_volume(api, job_id)
    assert attrs["method"] == "tv"
    assert vol["p0"].shape == (12, n, n) and vol["p0"].min() >= 0  # positivity: on by default for tv
    # the solver's answer, not the warm start: closer to the data than NEDNER's image
    used = json.loads(attrs["params"])
    assert used["warm_start"] == "nedner" and used["iterations"] <= max_iter and 0 < used["residual"] < 1


#: a reconstruction job's phases in the order a person sees them (the test's own oracle of
#: "forward": each stage's phase is the first whose words start it)
PHASES = (("starting",), ("loading",), ("reconstructing",), ("warm start",), ("norm estimate",), ("iteration ",),
          ("converged after ", "stopped after "), ("writing",), ("done",))


def phase(stage: str) -> int:
    for i, starts in enumerate(PHASES):
        if stage.startswith(starts):
            return i
    raise AssertionError(f"a stage no phase names: {stage!r}")


def test_tv_job_progress_only_moves_forward_and_says_when_the_rule_can_stop(shared_api):
    """A tv job (λ continuation on: faint noise) over a real server, followed on its event stream,
    and those events as ``fpscan jobs wait`` prints them: the stage's phase and the fraction never go back
    (the pipeline's closing "reconstructing" no longer follows tv's "converged after k iterations");
    while λ falls the stage says "λ continuation k/K" with K the result's continuation iterations,
    and the rule's first possible stop, K + 3, is in every iteration's event; every event's bound on
    the iterations left holds; a figure under 5 s is never shown 5 s or more after the first such
    figure of its stretch (the worker's clock, ``elapsed_s``)."""
    from fpscan.clients.cli.common import ProgressBar
    from fpscan.physics.balls import Ball, ball_alines
    from fpscan.service.recon.tv.stopping import typical_stop
    from tests.waits import HANG_S

    n, n_t, max_iter = 20, 160, 40
    x = (np.arange(n) - (n - 1) / 2) * PITCH
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    balls = [Ball(x=2e-4, y=-1e-4, z=1.0e-3, radius=1.5e-4, amplitude=1.0),
             Ball(x=-3e-4, y=2e-4, z=1.6e-3, radius=1e-4, amplitude=0.6)]
    data = ball_alines(pos, balls, DT, n_t, C).T.reshape(n_t, n, n)
    data = data + np.random.default_rng(0).standard_normal(data.shape) * np.abs(data).max() / 100  # 40 dB below the peak
    ds = upload(shared_api, data.astype(np.float32))
    r = shared_api.post("/api/reconstructions", json={"dataset_id": ds, "method": "tv",
                                                      "params": {"n_z": 32, "max_iter": max_iter}})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    events = sse_events(shared_api, job_id, timeout=HANG_S)
    assert [e["data"]["state"] for e in events if e["event"] == "state"][-1] == "succeeded", events[-3:]
    progress = [e["data"] for e in events if e["event"] == "progress"]
    stages = [p["stage"] for p in progress]
    phases = [phase(s) for s in stages]
    assert phases == sorted(phases), stages
    fractions = [p["fraction"] for p in progress]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0, fractions
    used = wait_job(shared_api, job_id)["params"]["result"]["params_used"]
    K, last = used["continuation_iterations"], used["iterations"]
    assert K > 0 and used["stop_armed_at"] == K + 3 and last >= K + 3, used
    its = [p for p in progress if p.get("iteration")]
    assert its, stages
    for p in its:
        k = p["iteration"]
        continuing = re.fullmatch(rf"iteration {k}/{max_iter} \(λ continuation {k}/{K}\)", p["stage"])
        assert bool(continuing) == (k <= K) and (k > K or re.fullmatch(rf"iteration {k}/{max_iter}", p["stage"])
                                                  is None), p
        assert p["stop_armed_at"] == K + 3 and p["stop_armed"] == (k >= K + 3), p
        # what its ETA takes while far (later where the reach floor set λ)
        assert p["stop_typical_at"] == typical_stop(used["tol"], K + 3, used["lam_floored"]) >= K + 3, p
        if p.get("iterations_left_max") is not None:  # the bound holds
            assert last <= k + p["iterations_left_max"], (last, p)
    low_since = None
    for p in progress:
        shown = p.get("eta_s")
        if shown is not None and shown < 5:
            low_since = p["elapsed_s"] if low_since is None else low_since
            assert p["elapsed_s"] - low_since < 5, p
        else:
            low_since = None
    # the CLI's lines of these events (`fpscan jobs wait`'s progress bar, off a terminal, a line
    # each): phases and percentages only forward, the waiting phase named
    bar = ProgressBar(f"job {job_id[:8]}", stream=io.StringIO(), period=0)
    with bar:
        for p in progress:
            bar(p)
    err = bar.stream.getvalue()
    lines = [m for m in (re.match(rf"^job {job_id[:8]}: (?P<stage>.+?)  (?P<pct>\d+)%", line)
                         for line in err.splitlines()) if m]
    assert [phase(m["stage"]) for m in lines] == sorted(phase(m["stage"]) for m in lines), err
    assert [int(m["pct"]) for m in lines] == sorted(int(m["pct"]) for m in lines), err
    assert any(re.search(rf"\(λ continuation \d+/{K}\)$", m["stage"]) for m in lines), err
    assert f"once λ has settled, from iteration {K + 3})" in err, err
