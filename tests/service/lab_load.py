"""Load of the lab-network tests (issue 22.3), run as scripts so that the load and the
health poller each run in a process of their own (neither's GIL slows the other, and
neither slows the test process):

    python -m tests.service.lab_load health URL TOKEN  -> polls until stdin closes; prints the
                                                          latencies (s) as a JSON list
    python -m tests.service.lab_load plans URL TOKEN   -> 4 clients make and read plans of
                                                          262 144 points; prints the statuses
    python -m tests.service.lab_load mixed URL TOKEN SPEC -> the soak's clients (issue 14):
                                                          SPEC is a JSON file (see mixed_load);
                                                          prints [kind, status, latency] rows
"""
from __future__ import annotations

import json
import random
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


def _mixed_request(c: httpx.Client, kind: str, spec: dict, files: dict[str, bytes]):
    if kind == "status":
        return c.get(f"/api/jobs/{spec['scan_id']}")
    if kind == "health":
        return c.get("/api/health")
    if kind == "preview":
        return c.post("/api/plans/preview", json={"kind": "equisteradian",
                                                  "lattice": {"n_x": 64, "n_y": 64, "pitch": 6e-5},
                                                  "params": {"depth": random.choice([1e300, -1, 0]),
                                                             "n_points": 100}})
    if kind == "good-upload":
        return c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                      files={"file": ("g.npy", files["good"])})
    if kind == "bad-upload":
        return c.post("/api/datasets", data={"format": "fpscan"},
                      files={"file": ("x.h5", random.choice(files["bad"]))})
    if kind == "bad-recon":
        return c.post("/api/reconstructions", json={"dataset_id": spec["dataset_id"], "params": {"n_z": 1}})
    return c.get("/api/jobs")


def mixed_load(url: str, token: str, spec: dict) -> list[tuple[str, int, float]]:
    """The soak's clients: ``spec["clients"]`` threads, each sending ``spec["per_client"]``
    requests drawn from ``spec["kinds"]`` (job status of ``spec["scan_id"]``, health,
    plan previews with bad depths, uploads of ``spec["good"]`` and of the files
    ``spec["bad"]``, reconstruction requests with bad options on ``spec["dataset_id"]``,
    the job list), each with a client time-out of ``spec["answer_s"]``. Returns one
    ``(kind, status, latency_s)`` per request; status -1 is a request never answered."""
    from pathlib import Path

    files = {"good": Path(spec["good"]).read_bytes(), "bad": [Path(f).read_bytes() for f in spec["bad"]]}
    results: list[tuple[str, int, float]] = []
    lock = threading.Lock()

    def client(seed: int) -> None:
        rnd = random.Random(seed)
        with _client(url, token, timeout=spec["answer_s"]) as c:
            for _ in range(spec["per_client"]):
                kind = rnd.choice(spec["kinds"])
                t0 = time.perf_counter()
                try:
                    status = _mixed_request(c, kind, spec, files).status_code
                except Exception as exc:  # a time-out is a hang
                    status = -1
                    print("soak: no answer", kind, type(exc).__name__, file=sys.stderr)
                with lock:
                    results.append((kind, status, time.perf_counter() - t0))

    threads = [threading.Thread(target=client, args=(i,)) for i in range(spec["clients"])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


if __name__ == "__main__":
    what, url, token = sys.argv[1:4]
    if what == "mixed":
        with open(sys.argv[4]) as f:
            print(json.dumps(mixed_load(url, token, json.load(f))))
    elif what == "health":
        stop = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        print(json.dumps(poll_health(url, token, stop)))
    else:
        print(json.dumps(plan_load(url, token)))
