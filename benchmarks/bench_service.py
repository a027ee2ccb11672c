"""Service benchmark: status-endpoint latency under load, live-preview refresh.

1. 50 concurrent clients poll ``GET /api/jobs/{id}``, each every ``--interval`` s, for
   ``--seconds``, first with the server idle, then while a ``--size``² × ``--n-t`` NER
   reconstruction runs in the local process pool (same run, same server): requests/s and
   p50/p99 latency of both, and their ratio; then the same back to back (no pause: the
   saturation throughput). Target: p99 < 50 ms while a 226×226 reconstruction runs. Before
   the 50 clients, ``GET /api/health`` alone, every 20 ms from one client, while that
   reconstruction runs (target: p99 < 100 ms during a paper-size reconstruction).
2. A ~``--points``-point equi-steradian scan of the simulated scanner (unthrottled, on a
   pty) through the server; the live preview's refresh time (NEDNER of the points so far
   + MIP PNGs, reported by ``GET /api/scans/{id}/preview``). Target < 2 s for ~1600 points.

Run: ``.venv/bin/python benchmarks/bench_service.py`` (``--quick`` for a small smoke run).
Prints one JSON object. Starts its own server (127.0.0.1, free port) and simulator, and
stops them.
"""
from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import secrets
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from fpscan.clients.processes import start_service

TOKEN = secrets.token_urlsafe(32)  # fpscan serve refuses a guessable token


async def _poll_async(url: str, job_id: str, clients: int, seconds: float, interval: float,
                      offset: int, total: int) -> tuple[list[float], int]:
    latencies: list[float] = []
    errors = 0
    stop = time.monotonic() + seconds

    async def one(client: httpx.AsyncClient, k: int):
        nonlocal errors
        await client.get(f"/api/jobs/{job_id}")  # untimed: opens this client's connection
        await asyncio.sleep(interval * (offset + k) / total)  # spread the clients over the interval
        while time.monotonic() < stop:
            t0 = time.perf_counter()
            r = await client.get(f"/api/jobs/{job_id}")
            dt = time.perf_counter() - t0
            latencies.append(dt)
            if r.status_code != 200:
                errors += 1
            if interval > dt:
                await asyncio.sleep(interval - dt)

    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    # every API route needs the token when one is configured (reads too)
    async with httpx.AsyncClient(base_url=url, limits=limits, timeout=30,
                                 headers={"Authorization": f"Bearer {TOKEN}"}) as client:
        await asyncio.gather(*(one(client, k) for k in range(clients)))
    return latencies, errors


def _poll_process(args) -> tuple[list[float], int]:
    return asyncio.run(_poll_async(*args))


def poll(url: str, job_id: str, clients: int, seconds: float, interval: float, processes: int = 4) -> dict:
    """``clients`` concurrent pollers of the job status for ``seconds``, each asking once
    every ``interval`` s (0 = back to back: the saturation throughput), spread over
    ``processes`` client processes so that the client side is not the bottleneck."""
    from concurrent.futures import ProcessPoolExecutor

    per = [clients // processes + (1 if i < clients % processes else 0) for i in range(processes)]
    offsets = [sum(per[:i]) for i in range(processes)]
    # the load generator shares this machine with the server: it runs one nice level
    # below, so that it measures the server rather than competing with it for the CPU
    with ProcessPoolExecutor(processes, initializer=os.nice, initargs=(5,)) as pool:
        parts = list(pool.map(_poll_process, [(url, job_id, n, seconds, interval, o, clients)
                                               for n, o in zip(per, offsets) if n]))
    lat = np.array([x for p in parts for x in p[0]])
    errors = sum(p[1] for p in parts)
    if not len(lat):  # a loaded machine: the client processes started after the window closed
        return {"requests": 0, "errors": errors, "requests_per_s": 0.0, "p50_ms": None, "p99_ms": None}
    return {"requests": len(lat), "errors": errors, "requests_per_s": len(lat) / seconds,
            "p50_ms": float(np.percentile(lat, 50) * 1e3), "p99_ms": float(np.percentile(lat, 99) * 1e3)}


def _health_process(url: str, seconds: float, interval: float) -> list[float]:
    latencies = []
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as c:
        c.get("/api/health")  # untimed: opens the connection
        stop = time.monotonic() + seconds
        while time.monotonic() < stop:
            t0 = time.perf_counter()
            c.get("/api/health").raise_for_status()
            dt = time.perf_counter() - t0
            latencies.append(dt)
            time.sleep(max(0.0, interval - dt))
    return latencies


def health_poll(url: str, seconds: float, interval: float = 0.02) -> dict:
    """``GET /api/health`` every ``interval`` s for ``seconds`` from one client in a process
    of its own (target: p99 < 100 ms while a paper-size reconstruction runs)."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as pool:
        lat = np.array(pool.submit(_health_process, url, seconds, interval).result())
    return {"requests": len(lat), "p50_ms": float(np.percentile(lat, 50) * 1e3),
            "p99_ms": float(np.percentile(lat, 99) * 1e3), "max_ms": float(lat.max() * 1e3)}


def npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def status_benchmark(url: str, size: int, n_t: int, clients: int, seconds: float, interval: float) -> dict:
    headers = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=url, headers=headers, timeout=600) as c:
        t = np.arange(n_t, dtype=np.float32)[:, None, None]
        data = np.sin(0.05 * t) * np.ones((1, size, size), dtype=np.float32)  # content is irrelevant to timing
        ds = c.post("/api/datasets", data={"format": "npy", "dt": "8e-9", "dx": "6e-5"},
                    files={"file": ("d.npy", npy_bytes(data), "application/octet-stream")}).json()["dataset_id"]
        # a warm-up job, so both measurements see a started worker process
        warm = c.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner",
                                                   "params": {"dtype": "float32", "n_z": 8}}).json()["id"]
        while c.get(f"/api/jobs/{warm}").json()["state"] not in ("succeeded", "failed"):
            time.sleep(0.2)
        poll(url, warm, clients, 1.0, interval)  # untimed warm-up of the server and the clients
        idle = poll(url, warm, clients, seconds, interval)
        idle_saturated = poll(url, warm, clients, seconds / 2, 0.0)
        # three reconstructions queued back to back keep the worker busy for the whole measurement
        body = {"dataset_id": ds, "method": "ner", "params": {"dtype": "float32"}}
        jobs = [c.post("/api/reconstructions", json=body).json()["id"] for _ in range(3)]
        while c.get(f"/api/jobs/{jobs[0]}").json()["state"] == "queued":
            time.sleep(0.05)
        health = health_poll(url, seconds)  # health alone while the reconstruction runs
        busy = poll(url, jobs[0], clients, seconds, interval)
        busy_saturated = poll(url, jobs[0], clients, seconds / 2, 0.0)
        states = [c.get(f"/api/jobs/{j}").json()["state"] for j in jobs]
        for j in jobs:
            c.post(f"/api/jobs/{j}/cancel")
        # the running one stops when its step returns (cooperative cancel): wait for it
        while any(c.get(f"/api/jobs/{j}").json()["state"] in ("queued", "running") for j in jobs):
            time.sleep(0.2)
        first = c.get(f"/api/jobs/{jobs[0]}").json()
    return {"size": [n_t, size, size], "clients": clients, "seconds": seconds, "poll_interval_s": interval,
            "idle": idle, "health_during_recon": health, "during_recon": busy,
            "saturated_idle": idle_saturated, "saturated_during_recon": busy_saturated,
            "recon_running_at_end_of_poll": "running" in states,
            "recon_run_s": first["timings"]["run_s"], "recon_state": first["state"],
            "p99_ratio_busy_over_idle": (busy["p99_ms"] / idle["p99_ms"]) if busy["p99_ms"] and idle["p99_ms"]
            else None}


def preview_benchmark(url: str, n_points: int, lattice: int, n_t: int) -> dict:
    headers = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=url, headers=headers, timeout=600) as c:
        r = c.post("/api/plans", json={"kind": "equisteradian",
                                       "lattice": {"n_x": lattice, "n_y": lattice, "pitch": 6e-5},
                                       "params": {"depth": 3.6e-3 * lattice / 226, "n_points": n_points},
                                       "acquisition": {"n_t": n_t, "dt": 8e-9, "prf": 0}})
        r.raise_for_status()
        plan = r.json()
        job = c.post("/api/scans", json={"plan_id": plan["id"], "scanner_id": "sim"}).json()["id"]
        refreshes = []
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            info = c.get(f"/api/scans/{job}/preview").json()
            if info["version"] and (not refreshes or refreshes[-1]["version"] != info["version"]):
                refreshes.append(info)
            state = c.get(f"/api/jobs/{job}").json()["state"]
            if state in ("succeeded", "failed", "cancelled") and refreshes and \
                    refreshes[-1]["points_used"] == plan["n_points"]:
                break
            time.sleep(0.1)
        final = c.get(f"/api/jobs/{job}").json()
    times = [r["refresh_s"] for r in refreshes]
    return {"points": plan["n_points"], "lattice": lattice, "n_t": n_t, "scan_state": final["state"],
            "refreshes": len(refreshes), "refresh_s_last": times[-1] if times else None,
            "refresh_s_median": statistics.median(times) if times else None,
            "points_used": [r["points_used"] for r in refreshes]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=226)
    ap.add_argument("--n-t", type=int, default=1024)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--interval", type=float, default=0.5, help="each client's polling period, s")
    ap.add_argument("--points", type=int, default=1600)
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.size, args.n_t, args.seconds, args.points = 64, 256, 2.0, 200

    from fpscan.driver.simulator import SimulatedScanner

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        sim = SimulatedScanner(prf=0.0).start()
        srv = start_service(Path(tmp) / "data", token=TOKEN, devices={"sim": sim.path}, web=False,
                            env={"FPSCAN_PREVIEW_INTERVAL_S": "1.0", "FPSCAN_LOG_LEVEL": "warning"},
                            log_path=Path(tmp) / "server.log")
        url = srv.url
        try:
            out["status_endpoint"] = status_benchmark(url, args.size, args.n_t, args.clients, args.seconds,
                                                      args.interval)
            out["live_preview"] = preview_benchmark(url, args.points, args.size, args.n_t)
        finally:
            srv.stop(timeout=20)
            sim.stop()
    s = out["status_endpoint"]
    out["targets"] = {"status_p99_ms_during_recon": s["during_recon"]["p99_ms"], "status_p99_target_ms": 50,
                      "preview_refresh_s": out["live_preview"]["refresh_s_last"], "preview_target_s": 2.0}
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
