"""Slow readers benchmark: the server's memory before, during and after
``--readers`` connections that pipeline ``GET /openapi.json`` with ``SO_RCVBUF`` 1024 and
never read, and a token holder's health latency meanwhile.

The readers come from many loopback addresses (127.0.<i>.<j>: ``--per-address`` each, within
the strangers' per-address budget), are opened as fast as the client can, then left alone.
The server drops each once its response has waited ``--send-timeout`` s without being read
(``FPSCAN_SEND_TIMEOUT_S``). Printed (one JSON object): the server's RSS at its baseline (after
a few requests); for each of ``--rounds`` waves its peak while the readers were open, how long
after the last was opened the server held none, and its RSS then (a second wave that ends at
the first's RSS shows memory reused, not leaked); the ratio of the final RSS to the baseline;
the token holder's health latency (p50/p99/max) throughout.

Run: ``.venv/bin/python benchmarks/bench_slow_readers.py --readers 5000`` (the full check is
20 000; the client needs as many file handles: ``ulimit -n``). Starts its own server
(127.0.0.1, free port) and stops it.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import secrets
import socket
import sys
import tempfile
import time
from pathlib import Path

import httpx
import psutil

from fpscan.clients.processes import start_service

TOKEN = secrets.token_urlsafe(32)  # fpscan serve refuses a guessable token


def _rss(pid: int) -> int:
    return psutil.Process(pid).memory_info().rss


def _held(pid: int, port: int) -> int:
    return sum(1 for c in psutil.Process(pid).net_connections(kind="tcp") if c.laddr and c.laddr.port == port
               and c.status == psutil.CONN_ESTABLISHED)


def _health(url: str, token: str, stop, results) -> None:
    """Poll health every 50 ms until ``stop`` (in its own process: the readers' loop here
    holds no lock it waits for); put the latencies on ``results``."""
    latencies = []
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as c:
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                c.get("/api/health")
            except httpx.TimeoutException:
                pass  # counted at its 60 s
            latencies.append(time.perf_counter() - t0)
            time.sleep(0.05)
    results.put(latencies)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readers", type=int, default=5000)
    ap.add_argument("--per-address", type=int, default=50)
    ap.add_argument("--pipelined", type=int, default=4, help="requests each reader pipelines")
    ap.add_argument("--send-timeout", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=2, help="waves of readers, each after the last was dropped")
    args = ap.parse_args()

    data_dir = Path(tempfile.mkdtemp(prefix="fpscan-bench-readers-")) / "data"
    srv = start_service(data_dir, token=TOKEN, web=False,
                        env={"FPSCAN_SEND_TIMEOUT_S": str(args.send_timeout), "FPSCAN_WARM_UP": "false",
                             "FPSCAN_MAX_CONNECTIONS": str(args.readers + 1000)})
    pid, port = srv.pid, srv.port
    stop = multiprocessing.Event()
    results: multiprocessing.Queue = multiprocessing.Queue()

    readers: list[socket.socket] = []
    request = b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * args.pipelined
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            for _ in range(5):
                c.get("/openapi.json")
        time.sleep(1.0)
        before = _rss(pid)
        watcher = multiprocessing.Process(target=_health, args=(srv.url, TOKEN, stop, results))
        watcher.start()
        rounds = []
        for _ in range(args.rounds):
            t_open = time.monotonic()
            refused = 0
            for k in range(args.readers):
                a, b = divmod(k // args.per_address, 250)
                s = socket.socket()
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
                s.bind((f"127.0.{a + 1}.{b + 1}", 0))
                try:
                    s.connect(("127.0.0.1", port))
                    s.sendall(request)
                except OSError:
                    refused += 1
                    s.close()
                    continue
                readers.append(s)
            t_last = time.monotonic()
            peak = _rss(pid)
            while _held(pid, port) > 1 and time.monotonic() < t_last + 600:
                peak = max(peak, _rss(pid))
                time.sleep(0.5)
            dropped_s = time.monotonic() - t_last
            for s in readers:
                s.close()
            readers = []
            time.sleep(1.0)
            rounds.append({"readers": args.readers - refused, "refused_at_connect": refused,
                           "opened_in_s": round(t_last - t_open, 1),
                           "all_dropped_s_after_the_last_opened": round(dropped_s, 1),
                           "rss_peak_mb": round(peak / 2**20, 1), "rss_after_mb": round(_rss(pid) / 2**20, 1)})
        stop.set()
        latencies = sorted(results.get(timeout=120))
        watcher.join()
        after = _rss(pid)
        print(json.dumps({
            "send_timeout_s": args.send_timeout, "pipelined": args.pipelined, "rounds": rounds,
            "rss_before_mb": round(before / 2**20, 1), "rss_after_mb": round(after / 2**20, 1),
            "rss_after_over_before": round(after / before, 3),
            "health_ms": {"n": len(latencies), "p50": round(1e3 * latencies[len(latencies) // 2], 1),
                          "p99": round(1e3 * latencies[int(0.99 * len(latencies)) - 1], 1),
                          "max": round(1e3 * latencies[-1], 1)},
        }, indent=1))
    finally:
        stop.set()
        for s in readers:
            s.close()
        srv.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
