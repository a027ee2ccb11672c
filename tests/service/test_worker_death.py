"""SIGTERM and SIGKILL of the server during a reconstruction: after a restart
on the same data folder every job succeeds (a shutdown re-queues its job, and does not
count as an attempt); start-up removes the crash debris of the killed run.

Trials per signal: 5 by default, 10 kills in all (``FPSCAN_KILL_TRIALS=10`` runs
10 per signal). A trial is a small tv job (24 x 24 x 128 A-line samples, about 1.4 s of
iterations on one core of the 2-core machine): its length comes from the iterations, not from
a fresh worker's first-call costs, so it is caught mid-run on a fast machine too (a 32 x 32 x
256 NER takes 7 ms once the worker is warm, and a fast CI machine finished one between two
polls). Most of a trial is the restart and the new worker's imports (5-8 s on the 2-core
machine)."""
from __future__ import annotations

import io
import os
import signal
import time

import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_gone, wait_job
from tests.waits import HANG_S

pytestmark = pytest.mark.long(90)

TRIALS = int(os.environ.get("FPSCAN_KILL_TRIALS", "5"))
N, N_T = 24, 128
#: tv iterates (1.4 s here) whatever the worker has run before; the default options
METHOD, JOB_PARAMS = "tv", {}


def upload(api) -> str:
    rng = np.random.default_rng(0)
    buf = io.BytesIO()
    np.save(buf, rng.standard_normal((N_T, N, N)).astype(np.float32))
    r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                 files={"file": ("d.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


def wait_running(api, jid: str, timeout: float = HANG_S) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = api.get(f"/api/jobs/{jid}").json()
        if job["state"] != "queued" and (job["state"] != "running"
                                         or job["progress"].get("stage") not in (None, "starting", "loading")):
            return job
        time.sleep(0.05)
    raise AssertionError(f"job {jid} never ran: {job}")


@needs_recon
@pytest.mark.timeout(600)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_killed_server_finishes_every_reconstruction_after_restart(tmp_path, sig):
    data = tmp_path / "data"
    srv = Server(data, env={"FPSCAN_MAX_ATTEMPTS": "3"}).start()
    hit = 0
    try:
        with srv.client() as api:
            ds = upload(api)
        jobs = []
        for _ in range(TRIALS):
            with srv.client() as api:
                jid = api.post("/api/reconstructions",
                               json={"dataset_id": ds, "method": METHOD, "params": JOB_PARAMS}).json()["id"]
                jobs.append(jid)
                if wait_running(api, jid)["state"] == "running":
                    hit += 1
            srv.proc.send_signal(sig)
            srv.proc.wait(timeout=60)
            srv.start()
        with srv.client() as api:
            finished = [wait_job(api, jid, timeout=300) for jid in jobs]
            assert [j["state"] for j in finished] == ["succeeded"] * TRIALS, finished
            for jid in jobs:
                assert api.get(f"/api/reconstructions/{jid}/volume.h5").status_code == 200
        print(f"{sig.name}: {hit} of {TRIALS} trials caught the reconstruction running")
        assert hit >= max(1, TRIALS // 2), "too few trials caught a reconstruction running"
        # after the restarts no temporary result folder or progress file is left
        debris = [p.name for p in (data / "results").iterdir() if ".tmp-" in p.name or p.name.endswith(".progress")]
        assert not debris, debris
    finally:
        srv.stop()


#: the reconstruction workers' priority increment in these tests (``FPSCAN_WORKER_NICE``; the
#: default is 0): it tells them apart from the plan (+8) and preview (+5) workers
RECON_NICE = 10


def recon_workers(srv: Server) -> list:
    """The server's reconstruction pool workers: the spawned processes at nice
    ``RECON_NICE`` (``Settings.worker_nice``; preview workers run at +5, the plan worker at +8)."""
    return [p for p in srv.workers() if "spawn_main" in " ".join(p.cmdline()) and p.nice() >= RECON_NICE]


@needs_recon
@pytest.mark.timeout(300)
def test_a_killed_worker_process_requeues_its_reconstruction(tmp_path):
    """SIGKILL of the reconstruction worker alone (the server stays up), mid-reconstruction:
    the job is re-queued as a new attempt, runs in a new worker and succeeds; the server
    kept answering."""
    srv = Server(tmp_path / "data", env={"FPSCAN_MAX_ATTEMPTS": "3", "FPSCAN_WORKER_NICE": str(RECON_NICE)}).start()
    try:
        with srv.client() as api:
            ds = upload(api)
            jid = api.post("/api/reconstructions",
                           json={"dataset_id": ds, "method": METHOD, "params": JOB_PARAMS}).json()["id"]
            job = wait_running(api, jid)
            assert job["state"] == "running", job  # caught mid-reconstruction (else the test proves nothing)
            workers = recon_workers(srv)
            assert len(workers) == 1, workers
            killed_at = time.time()  # the second attempt starts after it (the first before)
            workers[0].kill()
            assert not wait_gone(workers)
            assert api.get("/api/health").status_code == 200
            done = wait_job(api, jid)
            assert done["state"] == "succeeded" and done["attempts"] == 2, done
            assert api.get(f"/api/reconstructions/{jid}/volume.h5").status_code == 200
            # the second attempt's timing starts anew; the first is recorded
            timings = done["timings"]
            assert timings["started"] > killed_at > job["timings"]["started"], (timings, killed_at)
            assert timings["run_s"] == pytest.approx(timings["finished"] - timings["started"])
            [first] = timings["earlier_attempts"]
            assert first["attempt"] == 1 and first["started"] == job["timings"]["started"], first
            assert first["started"] < first["ended"] <= timings["started"], (first, timings)
            assert first["reason"] == "the worker process died" and first["run_s"] > 0, first
            assert recon_workers(srv) and recon_workers(srv)[0].pid != workers[0].pid
        assert srv.proc.poll() is None  # the server itself never stopped
    finally:
        srv.stop()


def test_start_up_removes_only_the_crash_debris_older_than_the_process(tmp_path):
    from fpscan.service.jobs.queue import remove_debris

    data = tmp_path / "data"
    results, datasets = data / "results", data / "datasets"
    (results / "job1.1.tmp-123-456").mkdir(parents=True)
    (results / "job1.1.tmp-123-456" / "volume.h5").write_bytes(b"x" * 100)
    (results / ".job1.1.progress").write_text("{}")
    (results / "job2.1").mkdir()                     # a finished result: kept
    (datasets / "partial").mkdir(parents=True)
    (datasets / "partial" / "upload.bin").write_bytes(b"y")
    (data / "incoming" / "staged").mkdir(parents=True)   # an upload staged before a crash
    (data / "incoming" / "staged" / "upload.bin").write_bytes(b"w")
    (datasets / "done").mkdir()
    (datasets / "done" / "dataset.h5").write_bytes(b"z")  # a stored dataset: kept
    old = time.time() - 3600
    for p in [results / "job1.1.tmp-123-456", results / ".job1.1.progress", datasets / "partial",
              data / "incoming" / "staged"]:
        os.utime(p, (old, old))
    (results / "job3.1.tmp-9-9").mkdir()             # being written by this process: kept
    removed = remove_debris(data, time.time() - 60)
    assert sorted(removed) == [".job1.1.progress", "job1.1.tmp-123-456", "partial", "staged"]
    assert list((data / "incoming").iterdir()) == []
    assert sorted(p.name for p in results.iterdir()) == ["job2.1", "job3.1.tmp-9-9"]
    assert sorted(p.name for p in datasets.iterdir()) == ["done"]
    # a dataset moved into place whose record never committed (the server stopped between the two:
    # an upload never acknowledged) goes too, given the ids the store holds; a stored one stays
    (datasets / "unrecorded").mkdir()
    (datasets / "unrecorded" / "dataset.h5").write_bytes(b"u")
    os.utime(datasets / "unrecorded", (old, old))
    os.utime(datasets / "done", (old, old))
    assert remove_debris(data, time.time() - 60, known_datasets={"done"}) == ["unrecorded"]
    assert sorted(p.name for p in datasets.iterdir()) == ["done"]
