"""The speed of sound is ``sound_speed`` in what the server stores and returns (a job's
options, its input's shape, its result and the values used), over a real server with a
real SQLite file; ``c`` stays accepted as input (deprecated), and a job an older server stored
with ``c`` reads back as ``sound_speed`` (and, still queued, runs with its value)."""
from __future__ import annotations

import doctest
import io
import json
import sqlite3

import numpy as np

import fpscan.service.names
from fpscan.service.jobs.store import JobStore
from fpscan.service.names import OLD_NAMES, current_names
from tests.json_keys import all_keys
from tests.service.service_servers import Server, needs_recon, wait_job

pytestmark = needs_recon

DT, DX = 2e-8, 1e-4


def _npy() -> bytes:
    a = np.zeros((48, 6, 6))
    a[20, 3, 3] = 1.0
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _stored(srv: Server, job_id: str) -> dict:
    with sqlite3.connect(srv.data_dir / "jobs.sqlite") as db:
        return json.loads(db.execute("SELECT params FROM jobs WHERE id = ?", (job_id,)).fetchone()[0])


def older_names(obj: object) -> object:
    """``obj`` as an older server wrote it: today's speed-of-sound keys under their old names."""
    back = {new: old for old, new in OLD_NAMES.items()}
    if isinstance(obj, dict):
        return {back.get(k, k): older_names(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [older_names(v) for v in obj]
    return obj


def test_names_module_examples_and_round_trip():
    assert doctest.testmod(fpscan.service.names).failed == 0
    tree = {"params": {"c": "auto", "c_range": [1450.0, 1600.0], "dz": 3e-5},
            "result": {"c": 1490.0, "autofocus": {"c": 1490.0, "c_values": [1450.0, 1490.0]}}}
    assert older_names(current_names(tree)) == tree
    assert "c" not in all_keys(current_names(tree)) and "dz" in all_keys(current_names(tree))
    assert current_names(tree)["result"]["autofocus"]["sound_speed_values"] == [1450.0, 1490.0]


def test_jobs_store_and_return_sound_speed_and_read_older_jobs(tmp_path):
    srv = Server(tmp_path / "data").start()
    try:
        with srv.client() as api:
            r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(DX),
                                                "sound_speed": "1500"}, files={"file": ("d.npy", _npy())})
            assert r.status_code == 201, r.text
            ds = r.json()["dataset_id"]
            ids = []
            # the whole depth grid given (dz alone reaches c·t_last: rows, and the estimates stored with the job,
            # would follow each speed; the older server's row below copies the first job's)
            for name, value in (("sound_speed", 1490.0), ("c", 1510.0)):  # c: the accepted alias
                r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner",
                                                           "params": {name: value, "dz": 1e-4, "n_z": 15}})
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
            for job_id, value in zip(ids, (1490.0, 1510.0), strict=True):
                job = wait_job(api, job_id)
                assert job["state"] == "succeeded", job
                p = job["params"]
                assert p["params"]["sound_speed"] == value and p["shape"]["sound_speed"] == 1500.0, p
                assert p["result"]["sound_speed"] == value == p["result"]["params_used"]["sound_speed"], p
                assert "c" not in all_keys(p) and "c_range" not in all_keys(p), p
                stored = _stored(srv, job_id)  # what the server wrote into SQLite
                assert stored["params"]["sound_speed"] == value and "c" not in all_keys(stored), stored
            listed = {j["id"]: j for j in api.get("/api/jobs", params={"kind": "recon"}).json()}
            assert {listed[i]["params"]["params"]["sound_speed"] for i in ids} == {1490.0, 1510.0}
            assert not any("c" in all_keys(j["params"]) for j in listed.values())
            first = _stored(srv, ids[0])
    finally:
        srv.stop()

    # an older server's rows: the finished job rewritten with c, and a queued job with c = 1480
    store = JobStore(srv.data_dir / "jobs.sqlite")
    try:
        old = older_names(first)
        assert old["params"]["c"] == 1490.0 and old["result"]["params_used"]["c"] == 1490.0
        store._db.execute("UPDATE jobs SET params = ? WHERE id = ?", (json.dumps(old), ids[0]))
        queued = {k: v for k, v in old.items() if k != "result"}
        queued["params"] = {**queued["params"], "c": 1480.0}
        older, _ = store.create_job("recon", queued, idempotency_key="older-server")
        assert '"c": 1480.0' in store._db.execute("SELECT params FROM jobs WHERE id = ?",
                                                  (older["id"],)).fetchone()[0]
    finally:
        store.close()

    srv = Server(srv.data_dir).start()
    try:
        with srv.client() as api:
            p = api.get(f"/api/jobs/{ids[0]}").json()["params"]
            assert p["params"]["sound_speed"] == 1490.0 == p["result"]["params_used"]["sound_speed"], p
            assert "c" not in all_keys(p), p
            job = wait_job(api, older["id"])
            assert job["state"] == "succeeded", job
            # the older job ran with its own c (not the dataset's 1500): read as sound_speed
            assert job["params"]["result"]["params_used"]["sound_speed"] == 1480.0, job["params"]
            assert job["params"]["params"]["sound_speed"] == 1480.0 and "c" not in all_keys(job["params"])
            # the same request again under the older job's key is that job, not a conflict
            r = api.post("/api/reconstructions", headers={"Idempotency-Key": "older-server"},
                         json={"dataset_id": first["dataset_id"], "method": "ner",
                               "params": {"sound_speed": 1480.0, "dz": 1e-4, "n_z": 15}})
            assert r.status_code in (200, 202) and r.json()["id"] == older["id"], r.text
    finally:
        srv.stop()
