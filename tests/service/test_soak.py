"""Soak (issue 14): mixed requests from concurrent clients — status reads, plan previews
with bad parameters, bad and good uploads, bad reconstruction requests — while a scan and
a reconstruction run. No 5xx, no request left unanswered (client-side time-out), the p99
latency of the status reads printed (not asserted: timings go to benchmarks).

By default (CI) the issue's 200 requests from 20 clients; ``FPSCAN_SOAK=full`` runs a
longer soak, 2000 requests from 50 clients (``FPSCAN_SOAK=full .venv/bin/python -m pytest
tests/service/test_soak.py -s``)."""
from __future__ import annotations

import io
import os
import random
import threading
import time

import numpy as np
import pytest

from tests.service.hostile_cases import signature_then_noise, truncated
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.test_scans import make_plan, start_scan, wait_points

driver_sim = pytest.importorskip("driver.simulator")

FULL = os.environ.get("FPSCAN_SOAK") == "full"
CLIENTS, REQUESTS = (50, 2000) if FULL else (20, 200)
ANSWER_S = 60.0
HEALTH_P99_FULL_S = 0.250


def _npy(n: int = 12, n_t: int = 64) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(n).standard_normal((n_t, n, n)).astype(np.float32))
    return buf.getvalue()


def _check_health_latency(latencies: list[float]) -> None:
    """Print /api/health's p50/p99 under the soak; with ``FPSCAN_SOAK=full`` (50 clients)
    hold its p99 to issue 22.3's bound (250 ms)."""
    if not latencies:
        return
    h50, h99 = np.percentile(latencies, 50), np.percentile(latencies, 99)
    print(f"soak: /api/health over {len(latencies)} requests from {CLIENTS} clients: "
          f"p50 {1e3 * h50:.1f} ms, p99 {1e3 * h99:.1f} ms")
    if FULL:
        assert h99 <= HEALTH_P99_FULL_S, f"/api/health p99 {1e3 * h99:.0f} ms under {CLIENTS} clients"


@needs_recon
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_soak_mixed_requests_during_a_scan_and_a_reconstruction(tmp_path):
    from driver.sources import BallSource
    from tests.service.test_scans import phantom

    files = tmp_path / "files"
    files.mkdir()
    bad_files = [truncated(0.5)(files).read_bytes(), signature_then_noise(files).read_bytes()]
    good_file = _npy()
    sim = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=100.0, seed=3).start()
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}, env={"FPSCAN_IMPORT_TIMEOUT_S": "10"}).start()
    try:
        with srv.client() as c:
            plan = make_plan(c)
            scan_id = start_scan(c, plan["id"])
            wait_points(c, scan_id, 20)
            r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                       files={"file": ("d.npy", _npy(32, 256))})
            ds = r.json()["dataset_id"]
            recon = c.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner",
                                                         "params": {"upsample": 2}}).json()["id"]

        def one(c, kind: str):
            if kind == "status":
                return c.get(f"/api/jobs/{scan_id}")
            if kind == "health":
                return c.get("/api/health")
            if kind == "preview":
                return c.post("/api/plans/preview", json={"kind": "equisteradian",
                                                          "lattice": {"n_x": 64, "n_y": 64, "pitch": 6e-5},
                                                          "params": {"depth": random.choice([1e300, -1, 0]),
                                                                     "n_points": 100}})
            if kind == "good-upload":
                return c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                              files={"file": ("g.npy", good_file)})
            if kind == "bad-upload":
                return c.post("/api/datasets", data={"format": "fpscan"},
                              files={"file": ("x.h5", random.choice(bad_files))})
            if kind == "bad-recon":
                return c.post("/api/reconstructions", json={"dataset_id": ds, "params": {"n_z": 1}})
            return c.get("/api/jobs")

        kinds = ["status"] * 5 + ["health", "preview", "bad-upload", "good-upload", "bad-recon", "list"]
        results: list[tuple[str, int, float]] = []
        lock = threading.Lock()
        per_client = REQUESTS // CLIENTS

        def client(seed: int) -> None:
            rnd = random.Random(seed)
            with srv.client(timeout=ANSWER_S) as c:
                for _ in range(per_client):
                    kind = rnd.choice(kinds)
                    t0 = time.perf_counter()
                    try:
                        status = one(c, kind).status_code
                    except Exception as exc:  # a time-out is a hang
                        status = -1
                        print("soak: no answer", kind, type(exc).__name__)
                    with lock:
                        results.append((kind, status, time.perf_counter() - t0))

        t_start = time.perf_counter()
        threads = [threading.Thread(target=client, args=(i,)) for i in range(CLIENTS)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(results) == per_client * CLIENTS
        unanswered = [r for r in results if r[1] == -1]
        server_errors = [r for r in results if r[1] >= 500]
        assert not unanswered and not server_errors, (unanswered, server_errors)
        # a bad request gets its 422, or 429 when too many uploads/plans are in progress at once
        expected = {"bad-upload": (422, 429), "preview": (422, 429), "bad-recon": (422,), "good-upload": (201, 429),
                    "status": (200,), "health": (200,), "list": (200,)}
        wrong = [r for r in results if r[1] not in expected[r[0]]]
        assert not wrong, wrong
        assert any(r[0] == "good-upload" and r[1] == 201 for r in results), "no good upload got through"
        status_lat = sorted(r[2] for r in results if r[0] == "status")
        if status_lat:
            p99 = status_lat[min(len(status_lat) - 1, int(0.99 * len(status_lat)))]
            print(f"soak: {len(results)} requests from {CLIENTS} clients in {time.perf_counter() - t_start:.1f} s, "
                  f"status p99 {1e3 * p99:.1f} ms, "
                  f"median {1e3 * status_lat[len(status_lat) // 2]:.1f} ms, "
                  f"{sum(1 for r in results if r[1] == 429)} answered 429 (busy)")
        _check_health_latency([r[2] for r in results if r[0] == "health"])
        with srv.client() as c:
            assert wait_job(c, recon, timeout=300)["state"] == "succeeded"
            assert wait_job(c, scan_id)["state"] == "succeeded"
    finally:
        srv.stop()
        sim.stop()
