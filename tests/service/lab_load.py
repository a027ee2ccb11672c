"""Load of the lab-network tests (issue 22.3), run as scripts so that the load and the
health poller each run in a process of their own (neither's GIL slows the other, and
neither slows the test process):

    python -m tests.service.lab_load health URL TOKEN  -> polls until stdin closes; prints the
                                                          latencies (s) as a JSON list
    python -m tests.service.lab_load plans URL TOKEN   -> 4 clients make and read plans of
                                                          262 144 points; prints the statuses
"""
from __future__ import annotations

import json
import sys
import threading
import time

import httpx

N_BIG = 512  # 512 x 512 = 262 144 points: the largest plan a request may make (plans.MAX_POINTS)


def big_plan_body(kind: str) -> dict:
    """A plan request of 262 144 points: a full 512 x 512 grid, or a point list of every
    lattice point (a 3 MB body)."""
    lattice = {"n_x": N_BIG, "n_y": N_BIG, "pitch": 6e-5}
    if kind == "full":
        return {"kind": "full", "lattice": lattice, "params": {}}
    if kind == "points":
        return {"kind": "points", "lattice": lattice,
                "points": [[i, j] for j in range(N_BIG) for i in range(N_BIG)]}
    raise ValueError(kind)


def _client(url: str, token: str, timeout: float = 300) -> httpx.Client:
    return httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"} if token else {},
                        timeout=timeout)


def poll_health(url: str, token: str, stop: threading.Event, period: float = 0.05) -> list[float]:
    """``GET /api/health`` every ``period`` s until ``stop``; the latencies (s), a failed
    poll as ``inf``."""
    out: list[float] = []
    with _client(url, token, timeout=30) as c:
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                ok = c.get("/api/health").status_code == 200
            except httpx.HTTPError:
                ok = False
            out.append(time.perf_counter() - t0 if ok else float("inf"))
            stop.wait(period)
    return out


def plan_load(url: str, token: str) -> dict:
    """Four clients with the largest plans: one makes the full 512 x 512 grid, then a
    second client makes the point list of the same 262 144 points (a 3 MB body) while
    three read the first plan (its summary and its 16 MB plan.json) until it is done.
    Returns ``{"create": [statuses], "read": [statuses]}``."""
    body = {k: json.dumps(big_plan_body(k)) for k in ("full", "points")}
    hdr = {"Content-Type": "application/json"}
    out: dict[str, list[int]] = {"create": [], "read": []}
    with _client(url, token) as c:
        r = c.post("/api/plans", content=body["full"], headers=hdr)
        out["create"].append(r.status_code)
        plan_id = r.json()["id"]
    done = threading.Event()

    def create() -> None:
        with _client(url, token) as c:
            out["create"].append(c.post("/api/plans", content=body["points"], headers=hdr).status_code)
        done.set()

    def read() -> None:
        with _client(url, token) as c:
            while not done.wait(0.25):  # a client that re-reads the plan, not a flood
                out["read"].append(c.get(f"/api/plans/{plan_id}").status_code)
                with c.stream("GET", f"/api/plans/{plan_id}/plan.json") as r:
                    for _ in r.iter_bytes():
                        pass
                    out["read"].append(r.status_code)

    threads = [threading.Thread(target=create)] + [threading.Thread(target=read) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


if __name__ == "__main__":
    what, url, token = sys.argv[1:4]
    if what == "health":
        stop = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        print(json.dumps(poll_health(url, token, stop)))
    else:
        print(json.dumps(plan_load(url, token)))
