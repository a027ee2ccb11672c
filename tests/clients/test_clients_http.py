"""The Python client (sync and async) against a real `fpscan serve` on 127.0.0.1.

Oracles: the raw HTTP answer of the same request (httpx, no client code) for error
details; the plan's own lattice arithmetic for positions; Pillow/h5py for downloads."""
from __future__ import annotations

import asyncio

import httpx
import numpy as np
import pytest

from fpscan.clients.http import (
    ApiError,
    AsyncClient,
    AuthError,
    Client,
    NotFound,
    ServerUnavailable,
    field_of,
)
from tests.clients.clients_servers import free_port, has_command
from tests.waits import HANG_S

TOKEN = "client-test-token"

pytestmark = pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available yet")


@pytest.fixture()
def api(server):
    with Client(server, token=TOKEN) as c:
        yield c


def _points_body(n=8, pitch=1e-4, points=((0, 0), (3, 1), (7, 7), (4, 5), (1, 6))):
    return {"lattice": {"n_x": n, "n_y": n, "pitch": pitch}, "points": [list(p) for p in points],
            "acquisition": {"n_t": 64, "dt": 2e-8, "prf": 0}}


def test_health(api):
    from importlib.metadata import version

    health = api.health()
    assert health["status"] == "ok"
    assert health["version"] == version("fpscan")


def test_server_down_raises_server_unavailable():
    url = f"http://127.0.0.1:{free_port()}"
    with Client(url, token=TOKEN, timeout=5) as c:
        with pytest.raises(ServerUnavailable) as err:
            c.health()
    assert url in str(err.value)

    async def main():
        async with AsyncClient(url, timeout=5) as c:
            await c.list_jobs()

    with pytest.raises(ServerUnavailable):
        asyncio.run(main())


@pytest.mark.parametrize("token", ["wrong-token", None])
def test_bad_or_missing_token_raises_auth_error_with_server_detail(server, token):
    raw = httpx.post(server + "/api/plans", json=_points_body(),
                     headers={"Authorization": f"Bearer {token}"} if token else {})
    assert raw.status_code in (401, 403)
    with Client(server, token=token or "") as c:  # "": no token, whatever the environment says
        with pytest.raises(AuthError) as err:
            c.create_plan(_points_body())
    assert err.value.status_code == raw.status_code
    assert err.value.detail == raw.json()["detail"]
    assert raw.json()["detail"] in str(err.value)
    if raw.status_code == 401:  # how to give the token, after the server's reason
        assert "token=" in str(err.value) and "FPSCAN_TOKEN" in str(err.value), str(err.value)


def test_unknown_job_raises_not_found_with_detail(api, server):
    raw = httpx.get(server + "/api/jobs/no-such-job", headers={"Authorization": f"Bearer {TOKEN}"})
    with pytest.raises(NotFound) as err:
        api.get_job("no-such-job")
    assert err.value.status_code == 404
    assert err.value.detail == raw.json()["detail"]
    with pytest.raises(NotFound):
        api.wait("no-such-job", timeout=10)


def test_invalid_plan_is_a_422_naming_the_field(api):
    body = _points_body()
    body["lattice"]["pitch"] = -1.0
    with pytest.raises(ApiError) as err:
        api.create_plan(body)
    assert err.value.status_code == 422
    assert "pitch" in str(err.value)
    body = _points_body(points=((0, 0), (0, 0)))
    with pytest.raises(ApiError) as err:
        api.create_plan(body)
    assert err.value.status_code == 422 and "duplicate" in str(err.value)


def test_plan_round_trip_and_preview_png(api, tmp_path):
    from PIL import Image

    from fpscan.clients.http.models import Plan

    body = _points_body()
    plan = api.create_plan(body)
    assert isinstance(plan, Plan)
    assert plan.n_points == len(body["points"])
    again = api.get_plan(plan.id)
    assert again == plan
    assert plan.id in [p.id for p in api.list_plans()]
    full = api.get_plan_json(plan.id)
    assert full["id"] == plan.id
    # positions follow the lattice convention x_i = (i - (n-1)/2) * pitch
    n, pitch = body["lattice"]["n_x"], body["lattice"]["pitch"]
    expect = [[(i - (n - 1) / 2) * pitch, (j - (n - 1) / 2) * pitch] for i, j in body["points"]]
    np.testing.assert_allclose(full["points"]["positions"], expect, rtol=0, atol=1e-15)
    png = api.download_plan_preview(plan.id, tmp_path / "sub" / "mask.png")
    with Image.open(png) as im:
        assert im.format == "PNG"
        a = np.asarray(im.convert("L"))
    assert (a > 0).any() and (a == 0).any()
    assert not list(tmp_path.glob("sub/*.part"))
    preview = api.preview_plan(body)
    assert field_of(preview, "points") == len(body["points"])


def test_async_client_matches_sync(api, server):
    body = _points_body(points=((1, 1), (2, 2), (6, 3)))

    async def main():
        async with AsyncClient(server, token=TOKEN) as c:
            plan = await c.create_plan(body)
            got = await c.get_plan(plan.id)
            jobs = await c.list_jobs()
            return plan, got, jobs

    plan, got, jobs = asyncio.run(main())
    assert plan == got == api.get_plan(plan.id)
    assert [j.id for j in jobs] == [j.id for j in api.list_jobs()]


def test_download_error_leaves_no_file(api, tmp_path):
    dest = tmp_path / "vol.h5"
    with pytest.raises(NotFound):
        api.download_volume("no-such-job", dest)
    assert not dest.exists() and not list(tmp_path.iterdir())


def test_bad_arguments_are_value_errors(api, tmp_path):
    with pytest.raises(ValueError):
        api.start_reconstruction(method="ner")
    with pytest.raises(ValueError):
        api.start_reconstruction(scan_job_id="a", dataset_id="b")
    with pytest.raises(ValueError):
        api.download_mip("x", "zz", tmp_path / "m.png")
    with pytest.raises(ValueError):
        api.upload_dataset(tmp_path / "missing.npy", "npy")
    with pytest.raises(ValueError):
        Client("ftp://example")


def _grid_data():
    """A small 3-D dataset (n_t, n_y, n_x) from the exact ball model on a 16x16 grid."""
    phys = pytest.importorskip("fpscan.physics")
    n, dx, dt, n_t = 16, 1e-4, 4e-8, 96
    x = (np.arange(n) - (n - 1) / 2) * dx
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    alines = phys.ball_alines(pos, [phys.Ball(0.0, 0.0, 1.2e-3, 2e-4, 1.0)], dt, n_t, 1500.0)
    return alines.T.reshape(n_t, n, n).astype(np.float32), dx, dt


def test_reconstruction_job_with_progress_and_downloads(api, tmp_path):
    recon = pytest.importorskip("fpscan.service.recon")
    if not hasattr(recon, "reconstruct_grid"):
        pytest.skip("fpscan.service.recon.reconstruct_grid not available yet")
    import h5py
    from PIL import Image

    data, dx, dt = _grid_data()
    np.save(tmp_path / "data.npy", data)
    dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=dt, dx=dx)
    key = "recon-key-1"
    job_id = api.start_reconstruction(dataset_id=dataset_id, method="ner",
                                      params={"dtype": "float64"}, idempotency_key=key)
    assert api.start_reconstruction(dataset_id=dataset_id, method="ner", params={"dtype": "float64"},
                                    idempotency_key=key) == job_id
    seen = []
    job = api.wait(job_id, on_progress=seen.append, timeout=HANG_S)
    assert job.state == "succeeded"
    assert seen and all(isinstance(p, dict) for p in seen)
    # the finished job's event stream replays everything, and resumes after Last-Event-ID
    events = list(api.events(job_id))
    ids = [int(e[2]) for e in events]
    assert ids == sorted(ids) and len(ids) >= 2
    assert events[-1][1].get("state") == "succeeded"
    assert list(api.events(job_id, last_event_id=events[0][2])) == events[1:]
    vol = api.download_volume(job_id, tmp_path / "volume.h5")
    with h5py.File(vol, "r") as f:
        p0 = f["p0"][...]
    expect = recon.reconstruct_grid(data.astype(np.float64), dx, dt, 1500.0, method="ner").p0
    np.testing.assert_allclose(p0, expect, rtol=0, atol=1e-6 * np.abs(expect).max())
    for plane in ("xy", "xz", "yz"):
        with Image.open(api.download_mip(job_id, plane, tmp_path / f"{plane}.png")) as im:
            assert im.format == "PNG"


def test_async_wait_with_coroutine_callback(api, server, tmp_path):
    recon = pytest.importorskip("fpscan.service.recon")
    if not hasattr(recon, "reconstruct_grid"):
        pytest.skip("fpscan.service.recon.reconstruct_grid not available yet")
    import h5py

    data, dx, dt = _grid_data()
    np.save(tmp_path / "a.npy", data)

    async def main():
        seen = []

        async def on_progress(p):
            seen.append(p)

        async with AsyncClient(server, token=TOKEN) as c:
            ds = await c.upload_dataset(tmp_path / "a.npy", "npy", dt=dt, dx=dx)
            job_id = await c.start_reconstruction(dataset_id=ds, method="nedner", params={"n_z": 32})
            job = await c.wait(job_id, on_progress=on_progress, timeout=HANG_S)
            path = await c.download_volume(job_id, tmp_path / "a.h5")
            return job, path, seen

    job, path, seen = asyncio.run(main())
    assert job.state == "succeeded" and seen
    with h5py.File(path, "r") as f:
        assert f["p0"].shape == (32, 16, 16)
    # the same job seen through the blocking client
    assert api.get_job(job.id).state == "succeeded"


def test_interrupted_download_resumes_with_range(api, server, tmp_path):
    """A `.part` left by a cut-off download is completed with a Range request (only the
    rest is fetched), and thrown away when the file changed (If-Range mismatch)."""
    recon = pytest.importorskip("fpscan.service.recon")
    if not hasattr(recon, "reconstruct_grid"):
        pytest.skip("fpscan.service.recon.reconstruct_grid not available yet")
    data, dx, dt = _grid_data()
    np.save(tmp_path / "r.npy", data)
    dataset_id = api.upload_dataset(tmp_path / "r.npy", "npy", dt=dt, dx=dx)
    job_id = api.start_reconstruction(dataset_id=dataset_id, method="ner", params={"n_z": 32})
    api.wait(job_id, timeout=HANG_S)
    full = httpx.get(f"{server}/api/reconstructions/{job_id}/volume.h5",
                     headers={"Authorization": f"Bearer {TOKEN}"})
    assert full.status_code == 200
    validator = full.headers.get("etag") or full.headers.get("last-modified")
    assert validator
    whole = full.content
    k = len(whole) // 2
    dest = tmp_path / "volume.h5"
    part, meta = tmp_path / "volume.h5.part", tmp_path / "volume.h5.part.etag"
    # a cut-off download: marked bytes where the first half was (after the HDF5 signature, which a
    # downloaded volume must begin with), with the file's validator
    marker = whole[:8] + bytes(b ^ 0xFF for b in whole[8:k])
    part.write_bytes(marker)
    meta.write_text(validator)
    api.download_volume(job_id, dest)
    assert dest.read_bytes() == marker + whole[k:]  # only the rest was fetched
    assert not part.exists() and not meta.exists()
    # a stale validator: the server sends the whole file, which replaces the part
    part.write_bytes(marker)
    meta.write_text('"stale"')
    api.download_volume(job_id, dest)
    assert dest.read_bytes() == whole


CLIENT_METHODS = {
    ("get", "/api/health"): "health",
    ("get", "/api/auth"): "auth",
    ("post", "/api/plans"): "create_plan",
    ("get", "/api/plans"): "list_plans",
    ("get", "/api/plans/kinds"): "mask_kinds",
    ("post", "/api/plans/preview"): "preview_plan",
    ("get", "/api/plans/{plan_id}"): "get_plan",
    ("get", "/api/plans/{plan_id}/plan.json"): "get_plan_json",
    ("get", "/api/plans/{plan_id}/preview.png"): "download_plan_preview",
    ("get", "/api/scanners"): "scanners",
    ("post", "/api/scans"): "start_scan",
    ("post", "/api/scans/{job_id}/pause"): "pause_scan",
    ("post", "/api/scans/{job_id}/resume"): "resume_scan",
    ("post", "/api/scans/{job_id}/abort"): "abort_scan",
    ("get", "/api/scans/{job_id}/file"): "download_scan",
    ("get", "/api/scans/{job_id}/preview"): "scan_preview",
    ("get", "/api/scans/{job_id}/preview/{plane}.png"): "download_scan_preview",
    ("post", "/api/datasets"): "upload_dataset",
    ("get", "/api/datasets"): "list_datasets",
    ("get", "/api/datasets/formats"): "dataset_formats",
    ("post", "/api/reconstructions"): "start_reconstruction",
    ("get", "/api/reconstructions/methods"): "methods",
    ("get", "/api/reconstructions/{job_id}/volume.h5"): "download_volume",
    ("get", "/api/reconstructions/{job_id}/mip/{plane}.png"): "download_mip",
    ("get", "/api/reconstructions/{job_id}/slice.png"): "download_slice",
    ("get", "/api/jobs"): "list_jobs",
    ("get", "/api/jobs/{job_id}"): "get_job",
    ("post", "/api/jobs/{job_id}/cancel"): "cancel_job",
    ("get", "/api/jobs/{job_id}/events"): "events",
    ("delete", "/api/jobs/{job_id}"): "delete_job",
    ("delete", "/api/plans/{plan_id}"): "delete_plan",
    ("delete", "/api/datasets/{dataset_id}"): "delete_dataset",
    ("get", "/api/retention"): "retention",
    ("put", "/api/retention"): "retention",
    ("get", "/api/reconstructions/{job_id}/unmix.h5"): "download_unmix",
    ("get", "/api/reconstructions/{job_id}/so2.png"): "download_so2",
    ("get", "/api/formats"): "formats",
    ("get", "/api/jobs/{job_id}/export/{format}"): "export",
}


def test_client_covers_every_api_route(server):
    """Every operation of the live OpenAPI schema under /api has a method on both
    clients (a new route fails this test until the client offers it)."""
    spec = httpx.get(server + "/openapi.json").json()
    ops = {(m, path) for path, item in spec["paths"].items() if path.startswith("/api/")
           for m in item if m in ("get", "post", "put", "patch", "delete")}
    assert ops == set(CLIENT_METHODS), ops ^ set(CLIENT_METHODS)
    for name in CLIENT_METHODS.values():
        assert callable(getattr(Client, name)) and callable(getattr(AsyncClient, name))
        assert getattr(Client, name).__doc__


def test_slice_png(api, tmp_path):
    recon = pytest.importorskip("fpscan.service.recon")
    if not hasattr(recon, "reconstruct_grid"):
        pytest.skip("fpscan.service.recon.reconstruct_grid not available yet")
    from PIL import Image

    data, dx, dt = _grid_data()
    np.save(tmp_path / "s.npy", data)
    job_id = api.start_reconstruction(dataset_id=api.upload_dataset(tmp_path / "s.npy", "npy", dt=dt, dx=dx),
                                      method="ner", params={"n_z": 32})
    api.wait(job_id, timeout=HANG_S)
    with Image.open(api.download_slice(job_id, 10, tmp_path / "slice.png")) as im:
        assert im.format == "PNG"
    with pytest.raises(ApiError) as err:
        api.download_slice(job_id, 32, tmp_path / "bad.png")
    assert err.value.status_code == 422 and "index" in str(err.value)


# What a client machine with only the base install (httpx, httpx-sse, pydantic, rich) sees:
# every package of the optional extras fails to import (ModuleNotFoundError, as when absent).
# The fpscan packages themselves (clients, service, driver) are installed with the base.
BLOCKER = r'''
import importlib.abc, sys
BLOCKED = {"numpy", "scipy", "h5py", "pint", "fastapi", "starlette", "uvicorn", "sse_starlette",
           "multipart", "pydantic_settings", "dask", "distributed", "finufft", "numba", "matplotlib",
           "PIL", "tifffile", "pylops", "pyproximal", "threadpoolctl", "serial", "cobs", "psutil"}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, Block())
'''

CLIENT_ONLY = BLOCKER + r'''
import json
from fpscan.clients.http import Client
from fpscan.clients.http import models
url, token, body = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
with Client(url, token=token) as api:
    plan = api.create_plan(body)
    again = api.get_plan(plan.id)
    jobs = api.list_jobs()
assert isinstance(plan, models.Plan) and again == plan, (type(plan), plan)
print(json.dumps({"id": plan.id, "n_points": plan.n_points, "jobs": len(jobs)}))
'''

CLI = BLOCKER + r'''
from fpscan.clients.cli import main
sys.exit(main(sys.argv[1:]))
'''


def _client_only(*args, script=CLI, env=None):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=env)


def test_client_runs_without_the_server_stack(server, tmp_path):
    """On the base install (every package of the extras refuses to import): the HTTP client
    creates and reads a plan (its own models, ``fpscan.clients.http.models``); ``fpscan --version``,
    ``--help`` (every command's too) and ``fpscan jobs list --server`` work; an unreachable
    server and a command that needs the driver extra are one-line reasons (exit 1, exit 2),
    never an ImportError."""
    import json
    import os

    body = _points_body()
    out = _client_only(server, TOKEN, json.dumps(body), script=CLIENT_ONLY)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n_points"] == len(body["points"])
    with Client(server, token=TOKEN) as api:  # the same plan, seen by the full client
        assert api.get_plan(got["id"]).n_points == len(body["points"])
        n_jobs = len(api.list_jobs())

    version = _client_only("--version")
    assert version.returncode == 0 and version.stdout.startswith("fpscan "), version.stderr[-3000:]
    helps = _client_only("--help")
    assert helps.returncode == 0 and "recon" in helps.stdout and "plan" in helps.stdout, helps.stderr[-3000:]
    for command in ("plan", "recon", "unmix", "scan", "export", "jobs", "serve", "sim", "demo", "evaluate"):
        res = _client_only(command, "--help")
        assert res.returncode == 0 and res.stdout.startswith("usage: fpscan " + command), (command, res.stderr)

    env = {**os.environ, "FPSCAN_TOKEN": TOKEN}
    listed = _client_only("jobs", "list", "--server", server, "--json", env=env)
    assert listed.returncode == 0, listed.stderr[-3000:]
    assert len(json.loads(listed.stdout)) == n_jobs

    down = _client_only("jobs", "list", "--server", f"http://127.0.0.1:{free_port()}", env=env)
    assert down.returncode == 1 and down.stderr.count("\n") == 1, down.stderr
    assert down.stderr.startswith("fpscan jobs: error: cannot reach"), down.stderr

    for argv in (["plan", "full", "--out", tmp_path / "p.json"], ["serve"],
                 ["recon", __file__]):
        res = _client_only(*argv)
        extra = "server" if argv[0] == "serve" else "driver"
        assert res.returncode == 2 and res.stderr.count("\n") == 1, (argv, res.stderr)
        assert f"fpscan[{extra}]" in res.stderr and "Traceback" not in res.stderr, (argv, res.stderr)


def test_client_models_mirror_the_servers_schema(server):
    """The client's own response models (``fpscan.clients.http.models``) have exactly the fields
    of the server's response schemas of the same name in the live OpenAPI document."""
    from fpscan.clients.http.models import MODELS

    schemas = httpx.get(server + "/openapi.json").json()["components"]["schemas"]
    for name, model in MODELS.items():
        assert name in schemas, f"the server has no {name} schema"
        assert set(model.model_fields) == set(schemas[name]["properties"]), name


def test_jobs_list_a_page_at_a_time(api, server, tmp_path, capsys):
    """``GET /api/jobs`` pages: ``limit`` jobs, a ``Link: rel="next"`` header where more follow, and
    ``before=<the page's last id>`` the next page, until every job is listed once, in order (the
    listing stopped at its limit, 200, with no way on); the client and ``fpscan jobs list`` follow it."""
    from fpscan.clients.cli import main

    data, dx, dt = _grid_data()
    np.save(tmp_path / "p.npy", data[:, :8, :8])
    dataset_id = api.upload_dataset(tmp_path / "p.npy", "npy", dt=dt, dx=dx)
    for n_z in (16, 17, 18, 19, 20):  # five jobs (different options: not one idempotent job)
        api.start_reconstruction(dataset_id=dataset_id, method="ner", params={"n_z": n_z})
    every = [j.id for j in api.list_jobs(limit=1000)]
    assert len(every) >= 5
    paged, before = [], None
    while True:
        page = api.list_jobs(limit=2, before=before)
        paged += [j.id for j in page]
        if len(page) < 2:
            break
        before = page[-1].id
    assert paged == every
    raw = httpx.get(f"{server}/api/jobs", params={"limit": 2}, headers={"Authorization": f"Bearer {TOKEN}"},
                    timeout=HANG_S)
    assert raw.headers["link"] == f'</api/jobs?limit=2&before={every[1]}>; rel="next"', raw.headers
    last = httpx.get(f"{server}/api/jobs", params={"limit": 1000}, headers={"Authorization": f"Bearer {TOKEN}"},
                     timeout=HANG_S)
    assert "link" not in last.headers
    with pytest.raises(NotFound, match="no job nonexistent-job to list the jobs before"):
        api.list_jobs(before="nonexistent-job")
    base = ["jobs", "list", "--server", server, "--token", TOKEN, "--ids"]
    assert main(base + ["--limit", "2"]) == 0
    out = capsys.readouterr()
    assert out.out.split() == every[:2] and "the 2 newest shown; more with --all or --limit" in out.err
    assert main(base + ["--limit", "2", "--all"]) == 0
    out = capsys.readouterr()
    assert out.out.split() == every and not out.err
