"""Scan jobs end to end over HTTP only: a real simulated FP scanner on a pty, a real
uvicorn server in a subprocess, a real SQLite file. Full scan with SSE progress and a
changing live preview → NEDNER reconstruction correlating with the phantom; pause/resume;
abort; SIGKILL of the server mid-scan and mid-reconstruction, then restart."""
from __future__ import annotations

import io
import json
import threading
import time

import h5py
import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_gone, wait_job
from tests.waits import HANG_S

driver_sim = pytest.importorskip("fpscan.driver.simulator")

pytestmark = [needs_recon, pytest.mark.long(65)]

N, PITCH, N_T, DT = 20, 1e-4, 128, 2e-8


def phantom():
    from fpscan.physics import Ball

    return [Ball(x=3e-4, y=-2e-4, z=1.0e-3, radius=1.5e-4, amplitude=1.0),
            Ball(x=-4e-4, y=3e-4, z=1.6e-3, radius=1.5e-4, amplitude=0.8)]


@pytest.fixture
def sim(tmp_path):
    from fpscan.driver.sources import BallSource

    s = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=3,
                                    record=tmp_path / "truth.h5").start()
    yield s
    s.stop()


@pytest.fixture
def scan_server(tmp_path, sim):
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}).start()
    yield srv
    srv.stop()


def make_plan(c, *, n=N, prf=100.0) -> dict:
    pts = []
    for iy in range(n):  # serpentine over the lattice
        row = [[ix, iy] for ix in range(n)]
        pts += row if iy % 2 == 0 else row[::-1]
    r = c.post("/api/plans", json={"lattice": {"n_x": n, "n_y": n, "pitch": PITCH}, "points": pts,
                                   "acquisition": {"n_t": N_T, "dt": DT, "prf": prf}})
    assert r.status_code == 201, r.text
    return r.json()


def start_scan(c, plan_id) -> str:
    r = c.post("/api/scans", json={"plan_id": plan_id, "scanner_id": "sim"})
    assert r.status_code == 202, r.text
    return r.json()["id"]


def wait_points(c, job_id, at_least, timeout=HANG_S) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = c.get(f"/api/jobs/{job_id}").json()
        if (job["progress"].get("points_done") or 0) >= at_least:
            return job
        time.sleep(0.05)
    raise AssertionError(f"scan {job_id} did not reach {at_least} points: {job}")


def check_scan_file(c, job_id, sim, tmp_path, n_points):
    """Every point complete, none lost; each A-line is exactly what the device sent."""
    from fpscan.driver.scanfile import read_scan

    r = c.get(f"/api/scans/{job_id}/file")
    assert r.status_code == 200
    head = c.head(f"/api/scans/{job_id}/file")  # the same file's headers, no body
    assert head.status_code == 200 and int(head.headers["content-length"]) == len(r.content) and not head.content
    path = tmp_path / f"{job_id}.h5"
    path.write_bytes(r.content)
    scan = read_scan(path)
    assert scan.completed.all() and scan.n_points == n_points
    assert np.array_equal(scan.meta["point_index"], np.arange(n_points))
    sim.write_record(tmp_path / "truth.h5")
    with h5py.File(tmp_path / "truth.h5", "r") as f:
        truth = f[f"plans/{scan.plan_id}/samples"][...]
    assert np.array_equal(scan.alines_all, truth)
    return scan


def test_scan_preview_sse_then_nedner_matches_phantom(scan_server, sim, tmp_path):
    from fpscan.physics.balls import ball_p0

    with scan_server.client() as c:
        scanners = c.get("/api/scanners").json()
        assert scanners[0]["id"] == "sim" and scanners[0]["status"] == "idle"
        plan = make_plan(c)
        job_id = start_scan(c, plan["id"])
        events = []

        def read_sse():
            with scan_server.client(timeout=120) as c2:
                with c2.stream("GET", f"/api/jobs/{job_id}/events") as r:
                    for line in r.iter_lines():
                        if line.startswith("data:"):
                            events.append(json.loads(line[5:]))

        t = threading.Thread(target=read_sse, daemon=True)
        t.start()
        previews = {}

        def new_previews() -> dict:
            """Keep every preview version seen (points used, xy PNG); the preview's state."""
            info = c.get(f"/api/scans/{job_id}/preview").json()
            if info["version"] and info["version"] not in previews:
                png = c.get(f"/api/scans/{job_id}/preview/xy.png")
                if png.status_code == 200:
                    previews[info["version"]] = (info["points_used"], png.content)
            return info

        # a preview of part of the points, whatever the machine's speed: the scan is held
        # (paused) after a few points until the preview of those shows, then resumed
        wait_points(c, job_id, 2)
        assert c.post(f"/api/scans/{job_id}/pause").status_code == 200
        deadline = time.monotonic() + HANG_S
        while not any(used < N * N for used, _ in previews.values()):
            assert time.monotonic() < deadline, f"no preview of the paused scan after {HANG_S} s"
            new_previews()
            time.sleep(0.2)
        assert c.post(f"/api/scans/{job_id}/resume").status_code == 200
        while c.get(f"/api/jobs/{job_id}").json()["state"] not in ("succeeded", "failed", "cancelled"):
            assert time.monotonic() < deadline, f"scan {job_id} not finished after {HANG_S} s"
            new_previews()
            time.sleep(0.2)
        job = wait_job(c, job_id)
        assert job["state"] == "succeeded", job
        assert job["progress"]["faults_recovered"] == 0, job  # none injected: none counted
        new_previews()  # the last refresh, with every point, lands before the job ends
        t.join(timeout=HANG_S)
        # SSE carried the progress of the acquisition up to the last point
        done = [e["points_done"] for e in events if "points_done" in e and e.get("points_done") is not None]
        assert done and done == sorted(done) and done[-1] == N * N
        assert any(e.get("state") == "succeeded" for e in events)
        # the live preview changed while the scan ran: a preview of part of the points, then
        # one of all of them; more points each version, and a different picture
        assert len(previews) >= 2, previews.keys()
        versions = sorted(previews)
        used = [previews[v][0] for v in versions]
        assert used == sorted(used) and used[0] < used[-1] == N * N, used
        assert previews[versions[0]][1] != previews[versions[-1]][1]

        check_scan_file(c, job_id, sim, tmp_path, N * N)

        r = c.post("/api/reconstructions", json={"scan_job_id": job_id, "method": "nedner",
                                                 "params": {"dtype": "float64"}})
        assert r.status_code == 202, r.text
        rid = r.json()["id"]
        assert wait_job(c, rid)["state"] == "succeeded"
        vol = c.get(f"/api/reconstructions/{rid}/volume.h5").content
        with h5py.File(io.BytesIO(vol), "r") as f:
            p0, z, x, y = f["p0"][...], f["z"][...], f["x"][...], f["y"][...]
        truth = ball_p0(phantom(), z, x, y, supersample=2)
        cc = np.corrcoef(p0.max(axis=0).ravel(), truth.max(axis=0).ravel())[0, 1]
        assert cc > 0.6, cc
        assert c.get(f"/api/reconstructions/{rid}/mip/xy.png").content[:4] == b"\x89PNG"

        # IPASC round trip: export → import → reconstruct gives the same image; so does
        # uploading the scan file itself
        ipasc = c.get(f"/api/jobs/{job_id}/export/ipasc")
        assert ipasc.status_code == 200
        with h5py.File(io.BytesIO(ipasc.content), "r") as f:
            assert f["binary_time_series_data"].shape[:2] == (N * N, N_T)
            assert "meta_data" in f and "meta_data_device" in f
        scan_file = c.get(f"/api/scans/{job_id}/file").content
        for fmt, content in (("ipasc", ipasc.content), ("fpscan", scan_file)):
            r = c.post("/api/datasets", data={"format": fmt},
                       files={"file": (f"x.{fmt}", content, "application/octet-stream")})
            assert r.status_code == 201, r.text
            r = c.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "nedner",
                                                     "params": {"dtype": "float64"}})
            rid2 = r.json()["id"]
            assert wait_job(c, rid2)["state"] == "succeeded"
            with h5py.File(io.BytesIO(c.get(f"/api/reconstructions/{rid2}/volume.h5").content), "r") as f:
                again = f["p0"][...]
            np.testing.assert_allclose(again, p0, rtol=0, atol=1e-9 * np.abs(p0).max(), err_msg=fmt)


def test_pause_resume_and_abort(scan_server, sim, tmp_path):
    with scan_server.client() as c:
        plan = make_plan(c)
        job_id = start_scan(c, plan["id"])
        wait_points(c, job_id, 40)
        r = c.post(f"/api/scans/{job_id}/pause")
        assert r.status_code == 200 and r.json()["state"] == "paused"
        # the device has stopped and every A-line it sent has landed (not a fixed wait)
        deadline = time.monotonic() + HANG_S
        while not (sim.state == "PAUSED" and c.get(f"/api/jobs/{job_id}").json()["progress"]["points_done"]
                   == sim.stats["alines"]):
            assert time.monotonic() < deadline, f"paused scan still receiving after {HANG_S} s"
            time.sleep(0.05)
        before = c.get(f"/api/jobs/{job_id}").json()["progress"]["points_done"]
        time.sleep(1.0)
        after = c.get(f"/api/jobs/{job_id}").json()
        assert after["state"] == "paused" and after["progress"]["points_done"] == before < N * N
        r = c.post(f"/api/scans/{job_id}/resume")
        assert r.status_code == 200 and r.json()["state"] == "running"
        assert wait_job(c, job_id)["state"] == "succeeded"
        check_scan_file(c, job_id, sim, tmp_path, N * N)
        assert c.post(f"/api/scans/{job_id}/pause").status_code == 409  # already finished

        # abort keeps what was acquired and frees the scanner; Idempotency-Key: same job
        job2 = c.post("/api/scans", json={"plan_id": plan["id"], "scanner_id": "sim"},
                      headers={"Idempotency-Key": "scan-abc"}).json()["id"]
        same = c.post("/api/scans", json={"plan_id": plan["id"], "scanner_id": "sim"},
                      headers={"Idempotency-Key": "scan-abc"}).json()["id"]
        assert same == job2
        wait_points(c, job2, 20)
        assert c.post(f"/api/scans/{job2}/abort").status_code == 200
        final = wait_job(c, job2)
        assert final["state"] == "cancelled"
        assert 20 <= final["progress"]["points_done"] < N * N
        deadline = time.monotonic() + HANG_S
        while c.get("/api/scanners").json()[0]["status"] != "idle" and time.monotonic() < deadline:
            time.sleep(0.1)
        assert c.get("/api/scanners").json()[0]["status"] == "idle"
        # a retry answered after its plan is deleted: the same job, not a 404 for the plan
        assert c.delete(f"/api/plans/{plan['id']}").status_code == 200
        again = c.post("/api/scans", json={"plan_id": plan["id"], "scanner_id": "sim"},
                       headers={"Idempotency-Key": "scan-abc"})
        assert again.status_code == 202 and again.json()["id"] == job2, again.text
        r = c.post("/api/scans", json={"plan_id": plan["id"], "scanner_id": "sim", "preview_wavelength": 1},
                   headers={"Idempotency-Key": "scan-abc"})  # another request under the key
        assert r.status_code == 404 and plan["id"] in r.json()["detail"], r.text


def test_sigkill_mid_scan_and_mid_recon_then_restart(tmp_path):
    """With link faults injected too (corrupted and dropped bytes, a device reset)."""
    from fpscan.driver.faults import FaultSpec
    from fpscan.driver.sources import BallSource

    sim = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=5,
                                      faults=FaultSpec.parse("corrupt=0.0005,drop=0.0005,reset=300")).start()
    srv = Server(tmp_path / "crash", devices={"sim": sim.path}).start()
    try:
        with srv.client() as c:
            plan = make_plan(c)
            scan_id = start_scan(c, plan["id"])
            wait_points(c, scan_id, 60)
        srv.kill()
        srv.start()
        with srv.client() as c:
            job = c.get(f"/api/jobs/{scan_id}").json()
            assert job["state"] == "paused" and job["progress"]["stage"] == "interrupted"
            assert c.post(f"/api/scans/{scan_id}/resume").status_code == 200
            wait_points(c, scan_id, job["progress"]["points_done"] + 60)
        # killed again; this time the server resumes interrupted scans by itself
        srv.kill()
        srv.extra_env["FPSCAN_RESUME_SCANS"] = "true"
        srv.start()
        with srv.client() as c:
            done = wait_job(c, scan_id)
            assert done["state"] == "succeeded", done
            assert done["progress"]["faults_recovered"] > 0  # the link faults were met and recovered
            check_scan_file(c, scan_id, sim, tmp_path, N * N)

            # a reconstruction killed while running is re-queued and finishes
            # tv for a fixed 150 iterations (tol 0: seconds here) is caught running on any machine; a
            # NEDNER of this scan takes milliseconds once the worker is warm
            r = c.post("/api/reconstructions", json={"scan_job_id": scan_id, "method": "tv",
                                                     "params": {"iterations": 150, "tol": 0}})
            rid = r.json()["id"]
            assert wait_job(c, rid, states=("running", "succeeded"))["state"] == "running"
        workers = srv.workers()
        assert workers  # the reconstruction and preview worker processes
        srv.kill()
        assert wait_gone(workers) == []  # no worker outlives a crashed server
        srv.start()
        with srv.client() as c:
            job = wait_job(c, rid)
            assert job["state"] == "succeeded", job
            assert job["attempts"] == 2  # interrupted once, then finished
            assert c.get(f"/api/reconstructions/{rid}/volume.h5").status_code == 200
            assert len(c.get("/api/jobs").json()) == 2
    finally:
        srv.stop()
        sim.stop()
