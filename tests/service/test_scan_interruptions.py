"""A service scan that loses its device or its disk: the job becomes
``paused`` (stage ``interrupted``, with the reason), never ``failed`` with its points
stranded nor ``running`` forever; ``/resume`` completes it, and every A-line in the scan
file is bit for bit what a device sent. Real simulators on ptys, a real server, a real
tmpfs (skipped where mounting is not permitted)."""
from __future__ import annotations

import os
import time

import h5py
import httpx
import numpy as np
import pytest

from tests.rss import MB, RssWatch, resident
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.small_disks import fill, tmpfs
from tests.service.test_scans import N, make_plan, phantom, start_scan, wait_points
from tests.waits import HANG_S

driver_sim = pytest.importorskip("fpscan.driver.simulator")

pytestmark = [needs_recon, pytest.mark.long(95)]


def new_sim(seed: int = 3):
    from fpscan.driver.sources import BallSource

    return driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=seed).start()


def truth(sims, folder, plan_id: str) -> np.ndarray:
    """What the devices sent, per (wavelength, point): each simulator's record where it
    sent the A-line."""
    out = None
    for i, sim in enumerate(sims):
        path = folder / f"truth{i}.h5"
        sim.write_record(path)
        with h5py.File(path, "r") as f:
            g = f[f"plans/{plan_id}"]
            samples, sent = g["samples"][...], g["sent"][...].astype(bool)
        out = np.zeros_like(samples) if out is None else out
        out[sent] = samples[sent]
    return out


def check_file(c, job_id, expected: np.ndarray, folder) -> None:
    from fpscan.driver.scanfile import read_scan

    path = folder / f"{job_id}.h5"
    path.write_bytes(c.get(f"/api/scans/{job_id}/file").content)
    scan = read_scan(path)
    assert scan.completed.all()
    assert np.array_equal(scan.meta["point_index"], np.arange(scan.n_points))
    assert np.array_equal(scan.alines_all, expected)  # (n_wavelengths, n_points, n_t)


def wait_state(c, job_id, state: str, timeout: float = HANG_S) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = c.get(f"/api/jobs/{job_id}").json()
        if job["state"] == state:
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} not {state} after {timeout} s: {job}")


@pytest.mark.timeout(300)
def test_device_lost_mid_scan_then_resume_on_a_new_simulator(tmp_path):
    link = tmp_path / "fp-device"  # the configured device path; a new simulator takes it over
    sim1 = new_sim()
    link.symlink_to(sim1.path)
    srv = Server(tmp_path / "srv", devices={"sim": str(link)}).start()
    sims = [sim1]
    try:
        with srv.client() as c:
            plan = make_plan(c)
            jid = start_scan(c, plan["id"])
            wait_points(c, jid, 60)
            sim1.stop()  # the device is gone mid-scan
            job = wait_state(c, jid, "paused")
            assert job["progress"]["stage"] == "interrupted"
            assert "device" in job["progress"]["reason"]
            done_before = job["progress"]["points_done"]
            assert 60 <= done_before < N * N
            sim2 = new_sim()
            sims.append(sim2)
            link.unlink()
            link.symlink_to(sim2.path)
            assert c.post(f"/api/scans/{jid}/resume").status_code == 200
            final = wait_job(c, jid)
            assert final["state"] == "succeeded", final
            check_file(c, jid, truth(sims, tmp_path, plan["id"]), tmp_path)
    finally:
        srv.stop()
        for s in sims:
            s.stop()


@pytest.mark.timeout(300)
def test_a_scanner_that_skips_ahead_pauses_the_scan_in_bounded_memory(tmp_path):
    """One A-line frame with a good CRC, run id and boot id but a data sequence number 2³¹
    ahead of its run: the job pauses (stage ``interrupted``) with the device fault as its
    reason, ``/api/health`` answers throughout and names the fault, the server's resident size
    stays within 50 MB of what it was after a first complete scan (everything a scan loads is
    loaded then), the scan file holds every A-line sent before, and ``/resume`` completes the
    scan bit for bit. The server's peak resident size is watched meanwhile (``tests.rss.RssWatch``)
    and the server killed at +50 MB: one that books every "missing" sequence number would take the machine's memory."""
    from fpscan.driver.faults import FaultSpec
    from fpscan.driver.scanfile import read_scan
    from fpscan.driver.sources import BallSource

    skip_at = 40
    skip_to = 2**31 + 25 + skip_at  # 2³¹ ahead: the first scan's 25 A-lines took seqs 0 … 24
    sim = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=3,
                                      faults=FaultSpec.parse(f"seq={skip_at}:{skip_to}")).start()
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}).start()
    watch = None
    try:
        with srv.client() as c:
            first = make_plan(c, n=5)  # 25 A-lines: the skip (at A-line 40) is not reached
            assert wait_job(c, start_scan(c, first["id"]))["state"] == "succeeded"
            plan = make_plan(c)
            watch = RssWatch(srv.service.pid, limit=50 * MB, what="the server").start()
            jid = start_scan(c, plan["id"])
            deadline = time.monotonic() + HANG_S
            while True:
                try:
                    assert c.get("/api/health", timeout=10).status_code == 200
                    job = c.get(f"/api/jobs/{jid}").json()
                except httpx.HTTPError:
                    watch.check()
                    raise
                watch.check()
                if job["state"] == "paused":
                    break
                assert job["state"] in ("queued", "running") and time.monotonic() < deadline, job
                time.sleep(0.05)
            progress = job["progress"]
            assert progress["stage"] == "interrupted", job
            assert progress["reason"].startswith("device fault: "), job
            assert f"sequence number {skip_to} is outside run" in progress["reason"], job
            health = c.get("/api/health").json()
            assert any("device fault" in p for p in health["problems"]), health
            rss = resident(srv.service.pid)
            print(f"server RSS: {watch.base / MB:.1f} MB before the scan, peak {watch.peak / MB:.1f} MB, "
                  f"{rss / MB:.1f} MB after the device fault")
            assert rss - watch.base < 50 * MB
            held = tmp_path / "paused.h5"
            held.write_bytes(c.get(f"/api/scans/{jid}/file").content)
            assert np.array_equal(read_scan(held).completed, np.arange(N * N) < skip_at)
            assert c.post(f"/api/scans/{jid}/resume").status_code == 200
            final = wait_job(c, jid)
            assert final["state"] == "succeeded", final
            assert c.get("/api/health").json()["problems"] == []
            check_file(c, jid, truth([sim], tmp_path, plan["id"]), tmp_path)
    finally:
        if watch is not None:
            watch.stop()
        srv.stop()
        sim.stop()


def _wait_paused(c, jid: str) -> dict:
    """The job once it is ``paused``; it must stay ``queued`` or ``running`` until then (a
    ``failed`` job is not resumable) and ``/api/health`` must answer meanwhile."""
    deadline = time.monotonic() + HANG_S
    while True:
        assert c.get("/api/health", timeout=10).status_code == 200
        job = c.get(f"/api/jobs/{jid}").json()
        if job["state"] == "paused":
            return job
        assert job["state"] in ("queued", "running") and time.monotonic() < deadline, job
        time.sleep(0.05)


@pytest.mark.timeout(300)
def test_a_field_out_of_range_and_a_scanner_that_keeps_resetting_pause_the_scan(tmp_path):
    """Two device faults in one scan, each pausing it (stage ``interrupted``, reason
    ``device fault: …``), never failing it: an A-line whose ``dc_level`` is 0 (out of its range,
    docs/protocol.md §5: the scan file would refuse it), then, after ``/resume``, a scanner that
    resets every time it comes to A-line 60, nine times (the host recovers from 8). Each time the
    scan file holds what the device sent before, ``/api/health`` names the fault, and the last
    ``/resume`` (the device now sound) completes the scan bit for bit."""
    from fpscan.driver.faults import FaultSpec
    from fpscan.driver.scanfile import read_scan
    from fpscan.driver.sources import BallSource

    bad_at, reset_at = 40, 60
    sim = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=3,
                                      faults=FaultSpec.parse(f"field={bad_at}:dc_level:0,reset={reset_at}:9")).start()
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}).start()
    try:
        with srv.client() as c:
            plan = make_plan(c)
            jid = start_scan(c, plan["id"])
            reasons = ["dc_level = 0.0 V is out of its range (finite and > 0)",
                       "the scanner reset 9 times during this scan; the host recovers from 8"]
            for i, says in enumerate(reasons):
                job = _wait_paused(c, jid)
                progress = job["progress"]
                assert progress["stage"] == "interrupted", job
                assert progress["reason"].startswith("device fault: ") and says in progress["reason"], job
                health = c.get("/api/health").json()
                assert any("device fault" in p for p in health["problems"]), health
                held = tmp_path / f"paused{i}.h5"
                held.write_bytes(c.get(f"/api/scans/{jid}/file").content)
                done = read_scan(held).completed
                n_done = int(done.sum())  # the A-lines sent before the fault: a prefix of the plan
                assert np.array_equal(done, np.arange(N * N) < n_done)
                assert n_done == bad_at if i == 0 else bad_at < n_done <= reset_at, (i, n_done)
                assert c.post(f"/api/scans/{jid}/resume").status_code == 200
            final = wait_job(c, jid)
            assert final["state"] == "succeeded", final
            assert c.get("/api/health").json()["problems"] == []
            assert sim.stats["resets"] == 9
            check_file(c, jid, truth([sim], tmp_path, plan["id"]), tmp_path)
    finally:
        srv.stop()
        sim.stop()


def _upload_npy(c) -> str:
    import io

    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(0).standard_normal((64, 8, 8)).astype(np.float32))
    r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
               files={"file": ("d.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


@pytest.fixture
def small_disk(tmp_path):
    with tmpfs(tmp_path / "tmpfs", "4m") as folder:
        yield folder


@pytest.mark.timeout(300)
def test_full_disk_mid_scan_pauses_with_the_reason_then_resumes(tmp_path, small_disk):
    sim = new_sim()
    # the job database lives elsewhere: the scan file's disk is the one that fills
    srv = Server(small_disk / "data", devices={"sim": sim.path},
                 env={"FPSCAN_DB_PATH": str(tmp_path / "jobs.sqlite"),
                      "FPSCAN_DISK_RESERVE_BYTES": "0"}).start()  # a 4 MiB disk: keep no reserve
    try:
        with srv.client() as c:
            plan = make_plan(c)
            ds = _upload_npy(c)
            jid = start_scan(c, plan["id"])
            wait_points(c, jid, 40)
            fill(small_disk)
            job = wait_state(c, jid, "paused")
            assert job["progress"]["stage"] == "interrupted"
            assert "disk full" in job["progress"]["reason"]
            assert job["progress"]["points_done"] < N * N
            health = c.get("/api/health").json()
            assert any("disk full" in p for p in health["problems"]), health
            # a reconstruction asked for meanwhile is refused at the door (its result does not
            # fit), and leaves no temporary files behind
            r = c.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner"})
            assert r.status_code == 507 and "no room for the result" in r.json()["detail"], r.text
            results = small_disk / "data" / "results"
            assert not [p.name for p in results.iterdir()] if results.exists() else True
            # resumed while still full: refused up front by the space check, paused again. The
            # resume re-queues it at once (its answer says "queued", or "paused" when the
            # space check was quicker still): then the wait is for the pause, not a fixed time
            r = c.post(f"/api/scans/{jid}/resume")
            assert r.status_code == 200 and r.json()["state"] in ("queued", "paused"), r.text
            job = wait_state(c, jid, "paused")
            assert "disk" in job["progress"]["reason"]
            os.unlink(small_disk / "filler.bin")  # the scan resumes by itself once its file fits
            final = wait_job(c, jid)
            assert final["state"] == "succeeded", final
            assert c.get("/api/health").json()["problems"] == []
            check_file(c, jid, truth([sim], tmp_path, plan["id"]), tmp_path)
    finally:
        srv.stop()
        sim.stop()


@pytest.mark.timeout(300)
def test_full_disk_under_the_job_store_too(tmp_path, small_disk):
    """The job database on the full disk as well (the default layout): requests that must
    write answer 503 with the reason (not 500), an upload leaves nothing behind,
    /api/health names the problem on one line; once space is freed the job, paused with the
    reason, resumes by itself and completes bit-identically, the reason cleared."""
    import io

    sim = new_sim()
    srv = Server(small_disk / "data", devices={"sim": sim.path},
                 env={"FPSCAN_DISK_RESERVE_BYTES": "0"})  # a 4 MiB disk: keep no reserve
    srv.log = tmp_path / "server.log"  # not on the disk that fills
    srv.start()
    try:
        with srv.client() as c:
            plan = make_plan(c)
            jid = start_scan(c, plan["id"])
            wait_points(c, jid, 40)
            fill(small_disk)
            deadline = time.monotonic() + HANG_S
            while not (problems := c.get("/api/health").json()["problems"]) and time.monotonic() < deadline:
                time.sleep(0.2)
            assert problems and all("disk full" in p and "\n" not in p for p in problems), problems
            r = c.post("/api/plans", json={"kind": "full", "lattice": {"n_x": 3, "n_y": 3, "pitch": 1e-4}})
            assert r.status_code == 503 and "disk is full" in r.json()["detail"], r.text
            buf = io.BytesIO()
            np.save(buf, np.zeros((64, 4, 4), np.float32))
            r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                       files={"file": ("d.npy", buf.getvalue())})
            # refused before a byte is written: the free-disk admission (507) or the full store (503)
            assert (r.status_code, "disk" in r.json()["detail"]) in ((503, True), (507, True)), r.text
            assert not list((small_disk / "data" / "datasets").glob("*"))
            os.unlink(small_disk / "filler.bin")
            # with the space freed the scan, paused by the full disk, resumes by itself
            # and health no longer says the disk (or database) is full
            final = wait_job(c, jid)
            assert final["state"] == "succeeded" and final["progress"]["reason"] is None, final
            assert c.get("/api/health").json()["problems"] == []
            events = c.get(f"/api/jobs/{jid}/events").text  # the stream ends after the final state
            assert '"state": "paused"' in events, events[-2000:]
            check_file(c, jid, truth([sim], tmp_path, plan["id"]), tmp_path)
    finally:
        srv.stop()
        sim.stop()


def test_a_resume_clears_a_cancel_asked_while_the_scan_was_stuck(tmp_path):
    """A cancel asked while a scan was stuck ``running`` (it could not stop then) must not
    end the resumed run ``cancelled`` after it acquired every point (real SQLite store,
    real ScanManager controls; nothing is started)."""
    from fpscan.service.jobs.scan_manager import ScanManager
    from fpscan.service.jobs.store import JobStore
    from fpscan.service.settings import Settings

    settings = Settings(data_dir=tmp_path / "data")
    store = JobStore(tmp_path / "jobs.sqlite")
    try:
        job, _ = store.create_job("scan", {"plan_id": "p" * 64, "scanner_id": "sim"})
        store.claim(job["id"], "old-server", lease_s=60)
        store.request_cancel(job["id"])  # running: only flagged
        assert store.get(job["id"])["cancel_requested"]
        assert store.recover("new-server", max_attempts=3)["paused"] == [job["id"]]
        ScanManager(store, settings).resume(job["id"])
        after = store.get(job["id"])
        assert after["state"] == "queued" and not after["cancel_requested"]
    finally:
        store.close()
