"""Data lifecycle on a real server with a real SQLite file: DELETE of jobs (with their
files), plans and datasets; 409 for what an active job uses; the retention policy (oldest
finished first, survives a restart); disk use in /api/health; float32 compressed volumes."""
from __future__ import annotations

import io
import json
import sqlite3
import subprocess
import sys
import time

import h5py
import httpx
import numpy as np
import pytest

from fpscan.service.jobs import lifecycle
from fpscan.service.jobs.store import JobStore
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.waits import HANG_S

pytestmark = needs_recon

N, N_T, DT, PITCH = 8, 32, 2e-8, 1e-4
#: the default depth grid (fpscan.service.recon.depth): rows of the pitch down to c·t_last = 0.93 mm
N_Z = int(1500.0 * (N_T - 1) * DT / PITCH) + 1


def _upload(api) -> str:
    data = np.random.default_rng(3).standard_normal((N_T, N, N))
    buf = io.BytesIO()
    np.save(buf, data)
    r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(PITCH)},
                 files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


def _recon(api, ds: str) -> str:
    r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner"})
    assert r.status_code == 202, r.text
    job = wait_job(api, r.json()["id"])
    assert job["state"] == "succeeded", job
    return job["id"]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fpscan", *args], capture_output=True, text=True,
                          timeout=HANG_S)


def _rows(db, table: str, col: str, value: str) -> int:
    with sqlite3.connect(db) as con:
        return con.execute(f"SELECT COUNT(*) FROM {table} WHERE {col} = ?", (value,)).fetchone()[0]


def test_delete_retention_and_restart(tmp_path):
    data = tmp_path / "data"
    db = data / "jobs.sqlite"
    srv = Server(data).start()
    try:
        with srv.client() as api:
            ds = _upload(api)
            jobs = [_recon(api, ds) for _ in range(2)]
            folders = [data / "results" / f"{j}.1" for j in jobs]
            assert all(f.is_dir() for f in folders)
            with h5py.File(folders[0] / "volume.h5", "r") as f:  # float32 by default
                assert f["p0"].dtype == np.float32
            disk = api.get("/api/health").json()["disk"]
            assert disk["results_bytes"] > 0 and disk["datasets_bytes"] > 0
            assert disk["free_bytes"] > 0 and disk["total_bytes"] >= disk["results_bytes"]

            # DELETE a job: files, row and events gone; needs the token
            anon = httpx.delete(f"{srv.url}/api/jobs/{jobs[0]}")
            assert anon.status_code == 401
            out = _cli("jobs", "delete", jobs[0], "--server", srv.url, "--token", srv.token)
            assert out.returncode == 0, out.stderr
            assert f"{jobs[0]}: deleted (recon" in out.stdout
            assert not folders[0].exists()
            assert api.get(f"/api/jobs/{jobs[0]}").status_code == 404
            assert _rows(db, "jobs", "id", jobs[0]) == 0 and _rows(db, "events", "job_id", jobs[0]) == 0
            assert api.delete(f"/api/jobs/{jobs[0]}").status_code == 404
            after = api.get("/api/health").json()["disk"]["results_bytes"]
            assert after < disk["results_bytes"]

            # retention: keep the newest result (the one left: nothing to delete yet)
            r = api.put("/api/retention", json={"keep_results": 1})
            assert r.status_code == 200 and r.json()["keep_results"] == 1
            assert folders[1].is_dir()
            assert api.put("/api/retention", json={"keep_results": -1}).status_code == 422

            # short ids (a unique prefix) work wherever a job id does; lists say what a job
            # works on; the job shows the values the reconstruction used
            short = jobs[1][:8]
            job = api.get(f"/api/jobs/{short}").json()
            assert job["id"] == jobs[1]
            assert api.get(f"/api/reconstructions/{short}/volume.h5").status_code == 200
            used = job["params"]["result"]["params_used"]
            assert used["sound_speed"] == 1500.0 and used["dt"] == DT and used["method"] == "ner"
            out = _cli("jobs", "list", "--server", srv.url, "--token", srv.token)
            assert out.returncode == 0 and f"{jobs[1][:12]}  recon  succeeded" in out.stdout
            assert f"ner of dataset {ds[:8]}" in out.stdout, out.stdout
            out = _cli("jobs", "get", short, "--server", srv.url, "--token", srv.token)
            assert out.returncode == 0 and json.loads(out.stdout)["id"] == jobs[1], out.stderr

            # the volume as OME-TIFF over HTTP (short id): shape and voxel sizes in µm
            import tifffile

            r = api.get(f"/api/jobs/{short}/export/ome-tiff")
            assert r.status_code == 200, r.text
            with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
                assert tif.is_ome and tif.series[0].axes == "ZYX" and tif.series[0].shape == (N_Z, N, N)
                pixels = tif.ome_metadata.split("<Pixels ", 1)[1].split(">", 1)[0]
            sizes = {k: float(v.strip('"')) for k, v in (a.split("=", 1) for a in pixels.split())
                     if k in ("PhysicalSizeX", "PhysicalSizeY", "PhysicalSizeZ")}
            assert sizes == pytest.approx({"PhysicalSizeX": PITCH * 1e6, "PhysicalSizeY": PITCH * 1e6,
                                           "PhysicalSizeZ": PITCH * 1e6})

            # an ambiguous prefix: a second job whose id starts with the same 8 characters
            # (a finished scan with no file, written to the database as another process would)
            sibling = jobs[1][:8] + ("1" if jobs[1][8] == "0" else "0") + "f" * 23
            with sqlite3.connect(db) as con:
                con.execute("INSERT INTO jobs (id, kind, state, params, progress, created, finished) "
                            "VALUES (?, 'scan', 'failed', ?, '{}', ?, ?)",
                            (sibling, json.dumps({"plan_id": "p" * 64}), time.time(), time.time()))
            r = api.get(f"/api/jobs/{short}")
            assert r.status_code == 409 and "matches several jobs" in r.json()["detail"], r.text
            assert jobs[1] in r.json()["detail"] and sibling in r.json()["detail"]
            r = api.post("/api/reconstructions", json={"scan_job_id": short, "method": "nedner"})
            assert r.status_code == 409 and "matches several jobs" in r.json()["detail"], r.text
            out = _cli("jobs", "get", short, "--server", srv.url, "--token", srv.token)
            assert out.returncode == 1 and "matches several jobs" in out.stderr, out.stderr
            # a short scan_job_id is resolved: the refusal names the full id
            r = api.post("/api/reconstructions", json={"scan_job_id": sibling[:9], "method": "nedner"})
            assert r.status_code == 409 and f"scan job {sibling} has no scan file yet" in r.json()["detail"], r.text
            out = _cli("jobs", "delete", sibling[:9], "--server", srv.url, "--token", srv.token)
            assert out.returncode == 0 and _rows(db, "jobs", "id", sibling) == 0, out.stderr
            assert api.get(f"/api/jobs/{short}").json()["id"] == jobs[1]

            # a plan for the paused scan below
            r = api.post("/api/plans", json={"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4},
                                             "points": [[0, 0], [1, 1]],
                                             "acquisition": {"n_t": 16, "dt": 1e-8, "prf": 100.0}})
            plan_id = r.json()["id"]
    finally:
        srv.stop()

    # while the server is down: a paused scan (resumable, so active) using the plan, with
    # its scan file, and a queued reconstruction reading that scan
    store = JobStore(db)
    scan, _ = store.create_job("scan", {"plan_id": plan_id, "scanner_id": "fp1",
                                        "scan_path": str(data / "scans" / "held.h5")})
    (data / "scans").mkdir(exist_ok=True)
    (data / "scans" / "held.h5").write_bytes(b"scan bytes")
    (data / "exports").mkdir(exist_ok=True)  # its exports as GET /api/jobs/{id}/export/{format} names them
    exported = [data / "exports" / f"{scan['id']}_ipasc.h5", data / "exports" / f"{scan['id']}.h5"]
    for path in exported:
        path.write_bytes(b"export bytes")
    store.set_state(scan["id"], "paused")
    store.close()

    srv = Server(data).start()
    try:
        with srv.client() as api:
            assert api.get("/api/retention").json()["keep_results"] == 1  # kept by the restart
            newest = _recon(api, ds)  # the older result goes, whole (files and rows)
            deadline = time.monotonic() + HANG_S  # retention runs right after the job's success
            while folders[1].exists() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert not folders[1].exists() and (data / "results" / f"{newest}.1").is_dir()
            assert _rows(db, "jobs", "id", jobs[1]) == 0 and _rows(db, "events", "job_id", jobs[1]) == 0
            assert [j["id"] for j in api.get("/api/jobs", params={"kind": "recon"}).json()] == [newest]

            r = api.delete(f"/api/plans/{plan_id}")
            assert r.status_code == 409 and scan["id"] in r.json()["detail"]
            r = api.delete(f"/api/jobs/{scan['id']}")
            assert r.status_code == 409 and "paused" in r.json()["detail"]
            out = _cli("jobs", "delete", scan["id"], "--server", srv.url, "--token", srv.token)
            assert out.returncode == 1 and "cancel it first" in out.stderr
            assert (data / "scans" / "held.h5").exists() and api.get(f"/api/plans/{plan_id}").status_code == 200

            assert api.post(f"/api/jobs/{scan['id']}/cancel").status_code == 200
            assert api.delete(f"/api/jobs/{scan['id']}").status_code == 200
            assert not (data / "scans" / "held.h5").exists()
            assert not any(p.exists() for p in exported), exported  # its exports went with it
            assert api.delete(f"/api/plans/{plan_id}").status_code == 200
            assert api.get(f"/api/plans/{plan_id}").status_code == 404 and _rows(db, "plans", "id", plan_id) == 0

            r = api.delete(f"/api/datasets/{ds}")
            assert r.status_code == 200 and not (data / "datasets" / ds).exists()
            assert _rows(db, "datasets", "id", ds) == 0
    finally:
        srv.stop()


def test_running_jobs_inputs_are_protected(tmp_path):
    """The library rules on a real SQLite store: a running reconstruction's dataset and
    scan, and the plan of a running scan, cannot be deleted; retention never takes a scan
    file unless asked, and never one an active job reads."""
    data = tmp_path / "data"
    (data / "datasets" / "d1").mkdir(parents=True)
    (data / "datasets" / "d1" / "dataset.h5").write_bytes(b"x" * 100)
    (data / "scans").mkdir()
    store = JobStore(data / "jobs.sqlite")
    store.put_plan("p1", {"id": "p1"}, {"id": "p1"})
    store.put_dataset("d1", {"layout": "grid", "path": "dataset.h5"})
    scan, _ = store.create_job("scan", {"plan_id": "p1", "scan_path": str(data / "scans" / "s.h5")})
    (data / "scans" / "s.h5").write_bytes(b"y" * 1000)
    store.set_state(scan["id"], "running")
    recon, _ = store.create_job("recon", {"dataset_id": "d1", "scan_job_id": scan["id"]})
    assert store.claim(recon["id"], "me", 60) is not None

    class S:  # the settings the rules read
        data_dir = data
        retention_keep_results = 0
        retention_keep_bytes = 0
        retention_include_scans = True

    for call in (lambda: lifecycle.delete_dataset(store, data, "d1"),
                 lambda: lifecycle.delete_plan(store, "p1"),
                 lambda: lifecycle.delete_job(store, data, scan["id"]),
                 lambda: lifecycle.delete_job(store, data, recon["id"])):
        try:
            call()
        except lifecycle.InUse as exc:
            assert "running" in str(exc)
        else:
            raise AssertionError("deleted something a running job uses")
    assert lifecycle.apply_retention(store, S) == []
    store.set_state(scan["id"], "succeeded")
    assert lifecycle.apply_retention(store, S) == []  # the running reconstruction reads it
    assert (data / "scans" / "s.h5").exists() and (data / "datasets" / "d1").is_dir()
    store.set_state(recon["id"], "failed")
    S.retention_include_scans = False
    assert lifecycle.apply_retention(store, S) == []  # scan files only when asked
    S.retention_include_scans = True
    assert lifecycle.apply_retention(store, S) == [scan["id"]]
    assert not (data / "scans" / "s.h5").exists() and store.get(scan["id"]) is None
    assert lifecycle.delete_dataset(store, data, "d1")["bytes_freed"] == 100
    assert not (data / "datasets" / "d1").exists() and store.get_dataset("d1") is None
    store.close()


def test_retention_by_bytes_alone(tmp_path):
    """``keep_bytes`` without ``keep_results``: the oldest finished results go until the
    rest fit; a finished scan's file stays unless scans are included."""
    data = tmp_path / "data"
    (data / "results").mkdir(parents=True)
    (data / "scans").mkdir()
    store = JobStore(data / "jobs.sqlite")
    jobs = []
    for _ in range(3):  # finished in this order, 1000 bytes of results each
        job, _ = store.create_job("recon", {"dataset_id": "d"})
        (data / "results" / f"{job['id']}.1").mkdir()
        (data / "results" / f"{job['id']}.1" / "volume.h5").write_bytes(b"v" * 1000)
        store.set_state(job["id"], "succeeded")
        jobs.append(job["id"])
        time.sleep(0.01)
    scan, _ = store.create_job("scan", {"plan_id": "p", "scan_path": str(data / "scans" / "s.h5")})
    (data / "scans" / "s.h5").write_bytes(b"s" * 5000)
    store.set_state(scan["id"], "succeeded")

    class S:  # the settings the rules read
        data_dir = data
        retention_keep_results = None
        retention_keep_bytes = None
        retention_include_scans = False

    assert lifecycle.apply_retention(store, S) == []  # no policy: nothing goes
    lifecycle.set_retention(store, {"keep_bytes": 2500})
    assert lifecycle.apply_retention(store, S) == [jobs[0]]  # 3000 -> 2000 bytes
    assert not (data / "results" / f"{jobs[0]}.1").exists() and store.get(jobs[0]) is None
    assert all((data / "results" / f"{j}.1").is_dir() for j in jobs[1:])
    lifecycle.set_retention(store, {"keep_bytes": 0})
    assert lifecycle.apply_retention(store, S) == jobs[1:]
    assert (data / "scans" / "s.h5").exists() and store.get(scan["id"]) is not None
    lifecycle.set_retention(store, {"keep_bytes": 0, "include_scans": True})
    assert lifecycle.apply_retention(store, S) == [scan["id"]] and not (data / "scans" / "s.h5").exists()
    store.close()


def test_a_report_whose_rollback_failed_raises_its_own_error_and_ends_at_full_sync(tmp_path):
    """A report (``update_progress``: committed with ``synchronous=NORMAL``) that fails and whose
    ROLLBACK fails too: the report's own error is raised (today's main raised SQLite's "Safety
    level may not be changed inside a transaction" instead, so a full disk was no longer
    recognised as one), the connection is out of the transaction and back at
    ``synchronous=FULL``, and the next commit is durable and stored. The failures are SQLite's
    own: an authorizer (``sqlite3_set_authorizer``) on the store's real connection refuses the
    progress UPDATE and then the first ROLLBACK."""
    store = JobStore(tmp_path / "jobs.sqlite", reserve_bytes=0)
    try:
        job, _ = store.create_job("recon", {"method": "ner"})
        refused = {"update": 1, "rollback": 1}

        def authorizer(action: int, arg1, arg2, _db, _trigger) -> int:
            if action == sqlite3.SQLITE_UPDATE and arg1 == "jobs" and arg2 == "progress" and refused["update"]:
                refused["update"] -= 1
                return sqlite3.SQLITE_DENY
            if action == sqlite3.SQLITE_TRANSACTION and arg1 == "ROLLBACK" and refused["rollback"]:
                refused["rollback"] -= 1
                return sqlite3.SQLITE_DENY
            return sqlite3.SQLITE_OK

        store._db.set_authorizer(authorizer)
        with pytest.raises(sqlite3.DatabaseError, match="not authorized"):
            store.update_progress(job["id"], {"note": "x"})
        assert refused == {"update": 0, "rollback": 0}  # both failed as meant
        store._db.set_authorizer(None)
        assert not store._db.in_transaction
        assert store._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
        assert store.set_state(job["id"], "cancelled")
        assert store.get(job["id"])["state"] == "cancelled" and "note" not in store.get(job["id"])["progress"]
    finally:
        store.close()


def test_an_older_database_gains_the_datasets_store_times_from_their_wall_times(tmp_path):
    """A database of an earlier release (datasets with their wall times only): each dataset's
    store time of use becomes its latest use's wall time (the meta's ``last_used``, else its
    upload's), the best there is, as the jobs' were; a dataset stored afterwards comes after
    them on the store's time, and retention ages them by it."""
    from types import SimpleNamespace

    db = tmp_path / "jobs.sqlite"
    with sqlite3.connect(db) as con:  # the datasets table as earlier releases made it
        con.execute("CREATE TABLE datasets (id TEXT PRIMARY KEY, meta TEXT NOT NULL, created REAL NOT NULL)")
        con.execute("INSERT INTO datasets VALUES ('used', ?, 1000.0)", (json.dumps({"last_used": 5000.0}),))
        con.execute("INSERT INTO datasets VALUES ('idle', '{}', 2000.0)")
    store = JobStore(db)
    try:
        assert {r["id"]: r["used_mono"] for r in store.list_datasets()} == {"used": 5000.0, "idle": 2000.0}
        store.put_dataset("new", {})
        assert store.list_datasets()[-1]["used_mono"] > 5000.0
        settings = SimpleNamespace(data_dir=tmp_path / "data")
        policy = {"datasets_max_age_s": 2500.0, "datasets_keep_bytes": None}
        assert lifecycle.apply_dataset_retention(store, settings, policy, now=5500.0) == ["idle"]
    finally:
        store.close()
