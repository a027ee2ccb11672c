"""Soak: mixed requests from concurrent clients — status reads, plan previews
with bad parameters, bad and good uploads, bad reconstruction requests — while a scan and
a reconstruction run. No 5xx, no request left unanswered (client-side time-out), the p99
latency of the status reads printed (not asserted: timings go to benchmarks).

By default (CI) 200 requests from 20 clients; ``FPSCAN_SOAK=full`` runs a
longer soak, 2000 requests from 50 clients (``FPSCAN_SOAK=full .venv/bin/python -m pytest
tests/service/test_soak.py -s``)."""
from __future__ import annotations

import io
import json
import os
import subprocess
import time

import numpy as np
import pytest

from tests.service import lab_load
from tests.service.hostile_cases import signature_then_noise, truncated
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.test_scans import make_plan, start_scan, wait_points

driver_sim = pytest.importorskip("fpscan.driver.simulator")

FULL = os.environ.get("FPSCAN_SOAK") == "full"
CLIENTS, REQUESTS = (50, 2000) if FULL else (20, 200)
ANSWER_S = 60.0
HEALTH_P99_FULL_S = 0.250


def _npy(n: int = 12, n_t: int = 64) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(n).standard_normal((n_t, n, n)).astype(np.float32))
    return buf.getvalue()


def _check_health_latency(latencies: list[float]) -> None:
    """Print /api/health's p50/p99 as its poller saw it under the soak (a failed poll is
    ``inf``); with ``FPSCAN_SOAK=full`` (50 clients) hold its p99 to a bound
    (250 ms)."""
    assert latencies, "the health poller made no poll"
    assert np.isfinite(latencies).all(), "a health poll failed"
    h50, h99 = np.percentile(latencies, 50), np.percentile(latencies, 99)
    print(f"soak: /api/health polled {len(latencies)} times under {CLIENTS} clients: "
          f"p50 {1e3 * h50:.1f} ms, p99 {1e3 * h99:.1f} ms")
    if FULL:
        assert h99 <= HEALTH_P99_FULL_S, f"/api/health p99 {1e3 * h99:.0f} ms under {CLIENTS} clients"


def _serial_if_full(test):
    """Alone (``serial``) only where the soak holds a time bound: the full soak's health p99.
    The default soak asserts answers and status codes, no time, and runs in the parallel part."""
    return pytest.mark.serial(test) if FULL else test


@_serial_if_full
@needs_recon
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_soak_mixed_requests_during_a_scan_and_a_reconstruction(tmp_path):
    from fpscan.driver.sources import BallSource
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

        # the clients run in a process of their own, one nice level below the server (as the
        # lab-network tests' load): on this 2-core machine their own CPU use is not what is
        # measured; /api/health is polled every 20 ms by a third process (lab_load health)
        (files / "good.npy").write_bytes(good_file)
        bad_paths = []
        for i, data in enumerate(bad_files):
            (files / f"bad{i}.h5").write_bytes(data)
            bad_paths.append(str(files / f"bad{i}.h5"))
        kinds = ["status"] * 5 + ["health", "preview", "bad-upload", "good-upload", "bad-recon", "list"]
        per_client = REQUESTS // CLIENTS
        spec = {"scan_id": scan_id, "dataset_id": ds, "good": str(files / "good.npy"), "bad": bad_paths,
                "kinds": kinds, "clients": CLIENTS, "per_client": per_client, "answer_s": ANSWER_S}
        (files / "spec.json").write_text(json.dumps(spec))
        t_start = time.perf_counter()
        health = lab_load.start("health", srv.url, srv.token, "0.02", stdin=subprocess.PIPE)
        load = lab_load.start("mixed", srv.url, srv.token, str(files / "spec.json"), nice=5)
        out, _ = load.communicate(timeout=540)
        probe = json.loads(health.communicate("", timeout=60)[0])
        assert load.returncode == 0, out
        results = [tuple(r) for r in json.loads(out)]
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
        clients_health = [r[2] for r in results if r[0] == "health"]
        if clients_health:
            print(f"soak: the clients' own /api/health: p50 {1e3 * np.percentile(clients_health, 50):.1f} ms, "
                  f"p99 {1e3 * np.percentile(clients_health, 99):.1f} ms")
        _check_health_latency(probe)
        with srv.client() as c:
            assert wait_job(c, recon, timeout=300)["state"] == "succeeded"
            assert wait_job(c, scan_id)["state"] == "succeeded"
    finally:
        srv.stop()
        sim.stop()
