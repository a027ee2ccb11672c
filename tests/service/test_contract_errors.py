"""Small API contract errors on a real server: one-line reasons without
pydantic URLs, empty Idempotency-Key, chunked oversized bodies, options that can never
work refused up front, the memory limit refused before queueing, OpenAPI stating what
the server enforces, and ``redact`` replacing whole path prefixes only."""
from __future__ import annotations

import io

import numpy as np
import pytest

from fpscan.service.settings import Settings
from tests.service.service_servers import Server


@pytest.fixture(scope="module")
def small_server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("contract") / "data",
                 env={"FPSCAN_UPLOAD_LIMIT": str(2**20), "FPSCAN_MEMORY_LIMIT": str(256 * 2**20)}).start()
    yield srv
    srv.stop()


def _dataset(api, n=16, n_t=64) -> str:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(0).standard_normal((n_t, n, n)).astype(np.float32))
    r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                 files={"file": ("d.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


@pytest.mark.timeout(300)
def test_contract_errors(small_server):
    with small_server.client() as api:
        ds = _dataset(api)
        cases = [
            ({"dataset_id": ds, "method": "ner", "params": {"n_z": 1}}, {}, 422, "n_z"),
            ({"dataset_id": ds, "method": "ner", "params": {"dz": 5e-324}}, {}, 422, "dz"),
            # dz valid alone but far below c·dt: the depth rows it implies are counted
            ({"dataset_id": ds, "method": "ner", "params": {"dz": 1e-8}}, {}, 422, "dz"),
            ({"dataset_id": ds, "scan_job_id": "a" * 32, "method": "ner"}, {}, 422, "exactly one"),
            ({"method": "ner"}, {}, 422, "exactly one"),
            ({"dataset_id": ds, "method": "ner"}, {"Idempotency-Key": ""}, 422, "Idempotency-Key"),
            # needs more than the 256 MiB limit: refused before it is queued
            ({"dataset_id": ds, "method": "ner", "params": {"upsample": 8, "n_z": 65536}}, {}, 422, "memory limit"),
        ]
        for body, headers, status, fragment in cases:
            r = api.post("/api/reconstructions", json=body, headers=headers)
            assert r.status_code == status, (body, r.text)
            detail = r.json()["detail"]
            assert fragment in detail and "http" not in detail and "\n" not in detail, (body, detail)
        assert api.get("/api/jobs").status_code == 200
        assert not [j for j in api.get("/api/jobs").json() if j.get("kind") == "recon"]

        # a chunked body over the upload limit: 413, not 400
        def chunks():  # a well-formed multipart start, then more than the limit of file bytes
            yield (b'--zzz\r\nContent-Disposition: form-data; name="file"; filename="a.npy"\r\n'
                   b"Content-Type: application/octet-stream\r\n\r\n")
            for _ in range(80):
                yield b"x" * 65536
        r = api.post("/api/datasets", content=chunks(),
                     headers={"Content-Type": "multipart/form-data; boundary=zzz"})
        assert r.status_code == 413, r.text

        schema = api.get("/openapi.json").json()
        assert {} not in schema["paths"]["/api/health"]["get"]["security"]  # a token is set: reads need it
        assert {} not in schema["paths"]["/api/plans/preview"]["post"]["security"]
        # exactly one input: a scan job, a dataset, or one dataset per wavelength (unmixing)
        branches = schema["components"]["schemas"]["ReconRequestNer"]["oneOf"]  # each method's variant says it
        assert sorted(b["required"][0] for b in branches) == ["dataset_id", "dataset_ids", "scan_job_id"]
        assert all("not" in b for b in branches)
        # the point list's exclusive fields, as the server enforces them
        for name, pair in (("PointsParams", {"points", "indices"}), ("PlanCreate_points", {"points", "params"})):
            assert {tuple(b["required"]) for b in schema["components"]["schemas"][name]["oneOf"]} == \
                {(f,) for f in pair}, name
        both = {"kind": "points", "lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4}, "points": [[0, 0]],
                "params": {"indices": [[1, 1]]}}
        r = api.post("/api/plans/preview", json=both)
        assert r.status_code == 422 and "either as points or as params" in r.json()["detail"], r.text


def test_redact_replaces_whole_path_prefixes_only(tmp_path):
    s = Settings(data_dir="data")
    assert s.redact("fpscan dataset data/x.h5 in /srv/data/y") == "fpscan dataset <data>/x.h5 in /srv/data/y"
    root = tmp_path / "d"
    s = Settings(data_dir=root)
    assert s.redact(f"{root}/a.h5 {root}d/b {root}") == f"<data>/a.h5 {root}d/b <data>"
