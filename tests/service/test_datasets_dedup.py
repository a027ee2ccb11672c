"""Datasets never pile up, on a real server with a real SQLite file: the same
file uploaded twice is stored once (files and bytes on disk counted), datasets are listed
(size on disk, content hash, the jobs that read them) and deleted over HTTP, with the
Python client and with ``fpscan datasets``, and retention removes an old dataset no active
job reads while keeping one an active job reads."""
from __future__ import annotations

import hashlib
import io
import subprocess
import sys
import time

import numpy as np
import pytest

from fpscan.clients.http import Client, Conflict, NotFound
from fpscan.service.jobs.store import JobStore
from tests.service.service_servers import Server
from tests.waits import HANG_S

N_T, N, DT, PITCH = 32, 8, 2e-8, 1e-4


def _npy(seed: int) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal((N_T, N, N)).astype(np.float32))
    return buf.getvalue()


def _upload(api, body: bytes, name: str = "d.npy", **form) -> dict:
    r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(PITCH), **form},
                 files={"file": (name, body, "application/octet-stream")})
    assert r.status_code == 201, r.text
    return r.json()


def _on_disk(server) -> tuple[int, int]:
    """(files, bytes) under the server's datasets folder."""
    files = [p for p in (server.data_dir / "datasets").rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def _cli(server, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fpscan", "datasets", *args, "--server", server.url,
                           "--token", server.token], capture_output=True, text=True, timeout=HANG_S)


@pytest.fixture
def dserver(tmp_path):
    srv = Server(tmp_path / "data").start()
    yield srv
    srv.stop()


def test_the_same_file_twice_is_stored_once(dserver):
    body = _npy(1)
    with dserver.client() as api:
        first = _upload(api, body, name="first.npy")
        before = _on_disk(dserver)
        folder = (dserver.data_dir / "datasets").stat().st_mtime_ns
        again = _upload(api, body, name="again.npy")
        after = _on_disk(dserver)
        # staged in incoming/ and discarded there: datasets/ itself is untouched (so
        # /api/health's disk usage needs no new walk), as for a refused upload
        refused = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(PITCH)},
                           files={"file": ("bad.npy", b"\x93NUMPY not an array", "application/octet-stream")})
        assert refused.status_code == 422, refused.text
        assert (dserver.data_dir / "datasets").stat().st_mtime_ns == folder
        assert list((dserver.data_dir / "incoming").iterdir()) == []
        assert not first["deduplicated"] and again["deduplicated"], again
        assert again["dataset_id"] == first["dataset_id"]
        assert first["content_sha256"] == again["content_sha256"] == hashlib.sha256(body).hexdigest()
        assert after == before and before[0] == 1, (before, after)
        # what makes the stored dataset differ makes a new one: another dt
        other = _upload(api, body, dt=repr(2 * DT))
        assert other["dataset_id"] != first["dataset_id"] and not other["deduplicated"]
        assert _on_disk(dserver)[0] == 2
        listed = api.get("/api/datasets").json()
    print(f"dedup: {before[1]} B on disk after one upload, {after[1]} B after the same file again")
    assert [d["dataset_id"] for d in listed] == [first["dataset_id"], other["dataset_id"]]
    d = listed[0]
    assert d["name"] == "first.npy" and d["format"] == "npy" and d["shape"] == [N_T, N, N]
    assert d["size_bytes"] == before[1] and d["content_sha256"] == hashlib.sha256(body).hexdigest()
    assert d["jobs"] == [] and not d["in_use"] and d["created"] <= time.time()
    assert d["last_used"] > d["created"]  # the second upload used it again: retention by age counts from then


def test_list_and_delete_over_http_client_and_cli(dserver):
    with dserver.client() as api:
        a = _upload(api, _npy(2), name="a.npy")["dataset_id"]
        b = _upload(api, _npy(3), name="b.npy")["dataset_id"]
        c = _upload(api, _npy(4), name="c.npy")["dataset_id"]
        # a reconstruction of b: the list names the job
        r = api.post("/api/reconstructions", json={"dataset_id": b, "method": "ner"})
        assert r.status_code == 202, r.text
        job = r.json()["id"]
        listed = {d["dataset_id"]: d for d in api.get("/api/datasets").json()}
        assert listed[b]["jobs"] == [job]

        assert api.delete(f"/api/datasets/{a}").status_code == 200
        assert not (dserver.data_dir / "datasets" / a).exists()
        assert api.delete(f"/api/datasets/{a}").status_code == 404

    with Client(dserver.url, token=dserver.token) as client:
        rows = client.list_datasets()
        assert {d["dataset_id"] for d in rows} == {b, c}
        size_c = next(d["size_bytes"] for d in rows if d["dataset_id"] == c)
        gone = client.delete_dataset(c)
        assert gone["bytes_freed"] == size_c and not (dserver.data_dir / "datasets" / c).exists()
        with pytest.raises(NotFound):
            client.delete_dataset(c)

    out = _cli(dserver, "list")
    assert out.returncode == 0, out.stderr
    assert b[:12] in out.stdout and "b.npy" in out.stdout and "1 dataset," in out.stdout, out.stdout
    out = _cli(dserver, "delete", "f" * 32)  # unknown: refused input
    assert out.returncode == 2 and "no dataset" in out.stderr, (out.returncode, out.stderr)
    out = _cli(dserver, "delete", b)
    assert out.returncode in (0, 1), out.stderr  # 1 (409: state) while the reconstruction of b still runs
    if out.returncode == 1:
        assert "409" in out.stderr and job in out.stderr, out.stderr
    else:
        assert not (dserver.data_dir / "datasets" / b).exists()


def test_retention_removes_old_unreferenced_datasets_and_keeps_one_an_active_job_reads(dserver):
    with dserver.client() as api:
        old = _upload(api, _npy(5), name="old.npy")["dataset_id"]
        held = _upload(api, _npy(6), name="held.npy")["dataset_id"]
        # an active (paused) reconstruction reads `held`: written to the database as another
        # server process would
        store = JobStore(dserver.data_dir / "jobs.sqlite")
        try:
            job, _ = store.create_job("recon", {"dataset_id": held, "method": "ner",
                                                "input_id": f"dataset:{held}"})
            store.set_state(job["id"], "paused")
        finally:
            store.close()
        sizes = {d["dataset_id"]: d["size_bytes"] for d in api.get("/api/datasets").json()}
        total = sum(sizes.values())
        listed = {d["dataset_id"]: d for d in api.get("/api/datasets").json()}
        assert listed[held]["in_use"] and listed[held]["jobs"] == [job["id"]]
        r = api.delete(f"/api/datasets/{held}")
        assert r.status_code == 409 and job["id"] in r.json()["detail"], r.text
        out = _cli(dserver, "delete", held)
        assert out.returncode == 1 and "409" in out.stderr, out.stderr  # the server's state, not the input
        with Client(dserver.url, token=dserver.token) as client, pytest.raises(Conflict):
            client.delete_dataset(held)

        # retention by age: everything is older than 0 s; the one an active job reads stays
        r = api.put("/api/retention", json={"datasets_max_age_s": 0})
        assert r.status_code == 200 and r.json()["datasets_max_age_s"] == 0, r.text
        left = [d["dataset_id"] for d in api.get("/api/datasets").json()]
        assert left == [held], left
        assert not (dserver.data_dir / "datasets" / old).exists()
        assert (dserver.data_dir / "datasets" / held).is_dir()
        print(f"retention by age: {total} B of datasets -> {sizes[held]} B (kept the one a paused job reads)")

        # once the job is over, the dataset goes too
        assert api.post(f"/api/jobs/{job['id']}/cancel").status_code == 200
        assert api.put("/api/retention", json={"datasets_max_age_s": 0}).status_code == 200
        assert api.get("/api/datasets").json() == []
        assert api.put("/api/retention", json={"datasets_max_age_s": -1}).status_code == 422

        # retention by bytes (applied after each new upload): the oldest go until the rest fit;
        # the newest upload is kept
        assert api.put("/api/retention", json={"datasets_keep_bytes": 0}).status_code == 200
        first = _upload(api, _npy(7))["dataset_id"]
        second = _upload(api, _npy(8))["dataset_id"]
        assert [d["dataset_id"] for d in api.get("/api/datasets").json()] == [second]
        assert not (dserver.data_dir / "datasets" / first).exists()
