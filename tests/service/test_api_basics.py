"""The HTTP API against a real uvicorn server on 127.0.0.1 with a real SQLite file:
health, plans, auth, bad input, uploads, idempotency, SSE replay."""
from __future__ import annotations

import hashlib
import io
import json
import sqlite3

import numpy as np
import pytest

from tests.service.service_servers import TOKEN, Server, wait_job

LATTICE = {"n_x": 8, "n_y": 8, "pitch": 1e-4}
POINTS = [[0, 0], [3, 4], [7, 7], [5, 1]]


def test_health_and_openapi(shared_api):
    api = shared_api
    h = api.get("/api/health")
    assert h.status_code == 200 and h.json()["status"] == "ok"
    schema = api.get("/openapi.json").json()
    for path in ("/api/plans", "/api/scans", "/api/reconstructions", "/api/jobs/{job_id}/events",
                 "/api/datasets", "/api/scans/{job_id}/preview/{plane}.png"):
        assert path in schema["paths"], path


def test_plan_from_points_has_content_hash_id(api, server):
    r = api.post("/api/plans", json={"lattice": LATTICE, "points": POINTS,
                                     "acquisition": {"n_t": 64, "dt": 1e-8, "prf": 100.0}})
    assert r.status_code == 201, r.text
    plan = r.json()
    assert r.headers["location"] == f"/api/plans/{plan['id']}"
    assert plan["n_points"] == 4
    assert plan["expected_scan_time_s"] == pytest.approx(4 / 100.0)
    full = api.get(f"/api/plans/{plan['id']}/plan.json").json()
    body = {k: v for k, v in full.items() if k != "id"}
    assert hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest() == plan["id"]
    # positions follow the centred lattice convention x_i = (i - (n-1)/2) * pitch
    pos = np.array(full["points"]["positions"])
    assert np.allclose(pos[1], [(3 - 3.5) * 1e-4, (4 - 3.5) * 1e-4])
    # the same request gives the same plan id; the plan is listed; its preview is a PNG
    again = api.post("/api/plans", json={"lattice": LATTICE, "points": POINTS,
                                         "acquisition": {"n_t": 64, "dt": 1e-8, "prf": 100.0}}).json()
    assert again["id"] == plan["id"]
    assert [p["id"] for p in api.get("/api/plans").json()] == [plan["id"]]
    png = api.get(f"/api/plans/{plan['id']}/preview.png")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    # the database on disk is real SQLite in WAL mode and holds the plan
    db = sqlite3.connect(server.data_dir / "jobs.sqlite")
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("SELECT COUNT(*) FROM plans").fetchone()[0] == 1
    db.close()


@pytest.mark.parametrize("body, reason", [
    (b'{"lattice": ', "malformed JSON"),
    (b'{"lattice": {"n_x": "eight", "pitch": 1e-4}, "points": [[0, 0]]}', "lattice.n_x"),
    (b'{"lattice": {"n_x": NaN, "pitch": 1e-4}, "points": [[0, 0]]}', "finite"),
    (b'{"lattice": {"n_x": 1000000000, "pitch": 1e-4}, "points": [[0, 0]]}', "lattice.n_x"),
    (b'{"lattice": {"n_x": 8, "pitch": 1e-4}, "points": [[9, 0]]}', "lattice"),
    (b'{"lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4}, "points": [[1, 1], [1, 1]]}', "duplicates"),
    (b'{"lattice": {"n_x": 8, "pitch": 1e-4}}', "mask kind"),
    (b'{"lattice": {"n_x": 8, "pitch": 1e-4}, "points": [[0, 0]], "surprise": 1}', "surprise"),
    (b'{"lattice": {"n_x": 8, "pitch": 1e-4}, "points": [[0, 0], [2, 0]], "order": "banana"}', "banana"),
    (b'[1, 2, 3]', "body"),
])
def test_bad_plan_input_gets_422_with_reason(shared_api, body, reason):
    api = shared_api
    r = api.post("/api/plans", content=body, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert reason in r.json()["detail"]


def test_token_guards_every_api_route_on_loopback_too(shared_server):
    server = shared_server
    import httpx

    body = {"lattice": LATTICE, "points": POINTS}
    with httpx.Client(base_url=server.url, timeout=10) as anon:
        r = anon.post("/api/plans", json=body)
        assert r.status_code == 401 and "token" in r.json()["detail"]
        r = anon.post("/api/plans", json=body, headers={"Authorization": "Bearer wrong"})
        assert r.status_code == 401 and "invalid" in r.json()["detail"]
        r = anon.post("/api/jobs/abc/cancel")
        assert r.status_code == 401
        # reads need the token too, on a loopback bind as well
        assert anon.get("/api/jobs").status_code == 401
        assert anon.get("/api/jobs", headers={"Authorization": f"Bearer {TOKEN}"}).status_code == 200
        assert anon.get("/api/auth").json() == {"token_required": True, "authenticated": False}
        r = anon.post("/api/plans", json=body, headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 201


def test_unknown_ids_and_path_tricks(shared_api):
    api = shared_api
    assert api.get("/api/jobs/0123456789abcdef").status_code == 404
    assert "no job" in api.get("/api/jobs/0123456789abcdef").json()["detail"]
    assert api.get("/api/plans/nope").status_code == 404
    for trick in ("/api/jobs/..%2F..%2Fetc%2Fpasswd", "/api/reconstructions/..%2Fjobs.sqlite/volume.h5",
                  "/api/scans/%2Fetc%2Fpasswd/file", "/api/plans/a.b/preview.png"):
        r = api.get(trick)
        assert r.status_code in (404, 422), (trick, r.status_code)
        assert "root:" not in r.text and "SQLite" not in r.text
    r = api.get("/api/reconstructions/abc/mip/zz.png")
    assert r.status_code == 422 and "plane" in r.json()["detail"]
    r = api.post("/api/reconstructions", json={"dataset_id": "0123abcd", "method": "ner"})
    assert r.status_code == 404 and "no dataset" in r.json()["detail"]
    r = api.post("/api/reconstructions", json={"method": "ner"})
    assert r.status_code == 422 and "exactly one" in r.json()["detail"]
    r = api.post("/api/scans", json={"plan_id": "missing", "scanner_id": "sim"})
    assert r.status_code in (404, 409)


def _npy_bytes(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def test_dataset_upload_validation(shared_api, shared_server):
    api, server = shared_api, shared_server
    good = np.zeros((32, 8, 8), dtype=np.float32)
    r = api.post("/api/datasets", data={"format": "npy", "dt": "1e-8", "dx": "1e-4"},
                 files={"file": ("../../../etc/evil.npy", _npy_bytes(good), "application/octet-stream")})
    assert r.status_code == 201, r.text
    ds = r.json()
    assert ds["shape"] == [32, 8, 8] and ds["layout"] == "grid"
    # the client's file name never reaches the file system
    assert not (server.data_dir.parent / "etc").exists()
    assert list((server.data_dir / "datasets" / ds["dataset_id"]).iterdir())[0].name == "dataset.h5"
    cases = [
        ({"format": "npy", "dt": "1e-8"}, _npy_bytes(good), "dx"),
        ({"format": "npy", "dt": "nan", "dx": "1e-4"}, _npy_bytes(good), "dt"),
        ({"format": "npy", "dt": "-1", "dx": "1e-4"}, _npy_bytes(good), "dt"),
        ({"format": "npy", "dt": "1e-8", "dx": "1e-4"}, _npy_bytes(np.array([1.0, np.nan, 2.0]).reshape(3, 1)), "shape"),
        ({"format": "npy", "dt": "1e-8", "dx": "1e-4"}, _npy_bytes(np.full((4, 4), np.nan)), "NaN"),
        ({"format": "npy", "dt": "1e-8", "dx": "1e-4"}, _npy_bytes(np.array([{"a": 1}], dtype=object)), "pickle"),
        ({"format": "npy", "dt": "1e-8", "dx": "1e-4"}, b"not a numpy file", "NumPy"),
        ({"format": "kwave-hdf5", "dt": "1e-8", "dx": "1e-4"}, b"not hdf5", "HDF5"),
        ({"format": "tiff", "dt": "1e-8", "dx": "1e-4"}, _npy_bytes(good), "format"),
    ]
    for data, content, reason in cases:
        r = api.post("/api/datasets", data=data, files={"file": ("x", content, "application/octet-stream")})
        assert r.status_code == 422, (data, r.text)
        assert reason in r.json()["detail"], (reason, r.json())
        assert str(server.data_dir) not in r.text and "upload.bin" not in r.text  # no internals


def test_upload_limit_gives_413(tmp_path):
    srv = Server(tmp_path / "small", env={"FPSCAN_UPLOAD_LIMIT": "20000"}).start()
    try:
        with srv.client() as c:
            big = np.zeros((100, 10, 10), dtype=np.float64)  # 80 kB
            r = c.post("/api/datasets", data={"format": "npy", "dt": "1e-8", "dx": "1e-4"},
                       files={"file": ("big.npy", _npy_bytes(big), "application/octet-stream")})
            assert r.status_code == 413 and "limit" in r.json()["detail"]
            small = np.zeros((16, 4, 4), dtype=np.float32)
            r = c.post("/api/datasets", data={"format": "npy", "dt": "1e-8", "dx": "1e-4"},
                       files={"file": ("s.npy", _npy_bytes(small), "application/octet-stream")})
            assert r.status_code == 201
    finally:
        srv.stop()


def test_idempotency_key_and_memory_admission(tmp_path):
    srv = Server(tmp_path / "mem", env={"FPSCAN_MEMORY_LIMIT": str(64 * 2**20)}).start()
    try:
        with srv.client() as c:
            a = np.zeros((64, 8, 8), dtype=np.float32)
            ds = c.post("/api/datasets", data={"format": "npy", "dt": "1e-8", "dx": "1e-4"},
                        files={"file": ("a.npy", _npy_bytes(a), "application/octet-stream")}).json()["dataset_id"]
            body = {"dataset_id": ds, "method": "ner", "params": {"eps": 1e-6}}
            r1 = c.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "k-1"})
            r2 = c.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "k-1"})
            assert r1.status_code == 202 and r2.status_code == 202
            assert r1.json()["id"] == r2.json()["id"]
            assert r1.headers["location"] == f"/api/jobs/{r1.json()['id']}"
            r3 = c.post("/api/reconstructions", json={**body, "params": {"eps": 1e-5}}, headers={"Idempotency-Key": "k-1"})
            assert r3.status_code == 409 and "Idempotency-Key" in r3.json()["detail"]
            r4 = c.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "k-2"})
            assert r4.json()["id"] != r1.json()["id"]
            assert len(c.get("/api/jobs", params={"kind": "recon"}).json()) == 2
            # a retry answered after its input is gone: the same job, not a 404 for the dataset
            for r in (r1, r4):
                assert wait_job(c, r.json()["id"])["state"] == "succeeded"
            assert c.delete(f"/api/datasets/{ds}").status_code == 200
            again = c.post("/api/reconstructions", content=json.dumps(body, indent=2),  # spaced otherwise
                           headers={"Idempotency-Key": "k-1", "Content-Type": "application/json"})
            assert again.status_code == 202 and again.json()["id"] == r1.json()["id"], again.text
            assert again.headers["location"] == r1.headers["location"]
            assert "request_digest" not in again.json()["params"]  # the server's own bookkeeping
            # another request under that key, or the same under an unused key, meets the input's 404
            r = c.post("/api/reconstructions", json={**body, "params": {"eps": 1e-5}}, headers={"Idempotency-Key": "k-1"})
            assert r.status_code == 404 and ds in r.json()["detail"], r.text
            r = c.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "k-3"})
            assert r.status_code == 404 and ds in r.json()["detail"], r.text
            # a reconstruction that can never fit in 64 MiB is refused up front with the reason
            big = np.zeros((4096, 64, 64), dtype=np.float32)
            ds_big = c.post("/api/datasets", data={"format": "npy", "dt": "1e-8", "dx": "1e-4"},
                            files={"file": ("b.npy", _npy_bytes(big), "application/octet-stream")}).json()["dataset_id"]
            r = c.post("/api/reconstructions", json={"dataset_id": ds_big, "method": "ner"})
            assert r.status_code == 422 and "memory limit" in r.json()["detail"]
    finally:
        srv.stop()
