"""Honest progress: a reconstruction job's progress events rise through the reconstruct
stage with the reconstruction's own per-chunk fractions (not one jump from 20 % to 90 %),
read from the Server-Sent Events of a real server; and the worker's progress file loses
no stage, however short (its reader on a real file, lines written by the worker's writer)."""
from __future__ import annotations

import io

import numpy as np

from tests.service.service_servers import Server, needs_recon
from tests.service.test_recon_jobs import sse_events

pytestmark = needs_recon


def test_progress_events_strictly_increase_through_reconstruction(tmp_path):
    n, n_t = 64, 1024  # NEDNER over 4096 points: several chunks, each reported
    data = np.random.default_rng(1).standard_normal((n_t, n, n)).astype(np.float32)
    buf = io.BytesIO()
    np.save(buf, data)
    srv = Server(tmp_path / "data").start()
    try:
        with srv.client() as api:
            r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                         files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
            assert r.status_code == 201, r.text
            r = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "nedner",
                                                       "params": {"eps": 1e-6, "dtype": "float64"}})
            assert r.status_code == 202, r.text
            events = sse_events(api, r.json()["id"], timeout=300)
    finally:
        srv.stop()
    assert [e["data"]["state"] for e in events if e["event"] == "state"][-1] == "succeeded"
    progress = [e["data"] for e in events if e["event"] == "progress"]
    fractions = [p["fraction"] for p in progress if p.get("stage") == "reconstructing"]
    assert len(fractions) >= 3, progress  # real fractions in between, not one jump
    assert all(b > a for a, b in zip(fractions, fractions[1:])), fractions
    assert fractions[0] >= 0.2 and fractions[-1] <= 0.9
    assert any(0.25 < f < 0.85 for f in fractions), fractions
    everything = [p["fraction"] for p in progress]
    assert all(b >= a for a, b in zip(everything, everything[1:])), everything  # never backwards


def test_the_progress_file_keeps_every_stage_in_order_and_waits_for_a_torn_line(tmp_path):
    from fpscan.service.jobs.work import ProgressLog, progress_file

    path = tmp_path / ".job.1.progress"
    log = ProgressLog(path, most=4)
    assert log.new() == []  # no file yet: nothing, no error
    write = progress_file(str(path))
    write(0.1, "loading")
    write(0.1, "loading")  # a repeat is not written again
    write(0.3, "iteration 1/3")
    lines = log.new()
    # each line says when, on the worker's clock (a line's elapsed_s + eta_s is the end it predicts)
    assert [line.pop("elapsed_s") >= 0 for line in lines] == [True, True]
    assert lines == [{"stage": "loading", "fraction": 0.1}, {"stage": "iteration 1/3", "fraction": 0.3}]
    assert path.read_text().count("loading") == 1
    with open(path, "ab") as f:  # a line the worker is still writing, then a line that is not JSON
        f.write(b'{"stage": "iteration 2/3", "fra')
    assert log.new() == []
    with open(path, "ab") as f:
        f.write(b'ction": 0.5}\nnot json\n')
    assert log.new() == [{"stage": "iteration 2/3", "fraction": 0.5}]
    for k in range(3, 13):  # a burst between two reads: thinned to `most`, evenly, the newest kept
        write(0.5 + k / 100, f"iteration {k}/12")
    burst = log.new()
    assert len(burst) == 4 and burst[-1]["stage"] == "iteration 12/12", burst
    ks = [int(b["stage"].split()[1].split("/")[0]) for b in burst]
    assert ks == sorted(ks) and len(set(ks)) == 4 and ks[0] <= 6, ks
    assert log.new() == []
