"""Load of the lab-network tests, run as scripts so that the load and the
health poller each run in a process of their own (neither's GIL slows the other, and
neither slows the test process):

    python -m tests.service.lab_load health URL TOKEN [PERIOD]
                                                       -> polls every PERIOD s (0.05) until stdin
                                                          closes; prints the latencies (s) as a
                                                          JSON list
    python -m tests.service.lab_load plans URL TOKEN   -> 4 clients make and read plans of
                                                          262 144 points; prints the statuses
    python -m tests.service.lab_load mixed URL TOKEN SPEC -> the soak's clients:
                                                          SPEC is a JSON file (see mixed_load);
                                                          prints [kind, status, latency] rows
    python -m tests.service.lab_load bodies URL TOKEN N DATASET -> 4 clients send the largest
                                                          bodies the API takes, N each (see
                                                          big_bodies); prints the statuses
"""
from __future__ import annotations

import json
import random
import sys
import threading
import time

import httpx

N_BIG = 512  # 512 x 512 = 262 144 points: the largest plan a request may make (plans.MAX_POINTS)


def start(what: str, url: str, token: str | None, *args: str, nice: int = 0, **kw):
    """``python -m tests.service.lab_load WHAT URL TOKEN ARGS...`` as a child process (stdout
    a pipe, run from the repository), ``nice`` levels below the caller; ``kw`` go to
    ``subprocess.Popen`` (``stdin=subprocess.PIPE`` for the health poller)."""
    import os
    import subprocess
    from pathlib import Path

    return subprocess.Popen([sys.executable, "-m", "tests.service.lab_load", what, url, token or "", *args],
                            cwd=Path(__file__).resolve().parents[2], stdout=subprocess.PIPE, text=True,
                            preexec_fn=(lambda: os.nice(nice)) if nice else None, **kw)


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


def largest_recon_bodies(dataset_id: str, limit: int = 64 * 1024) -> list[bytes]:
    """Reconstruction requests of ``limit`` bytes each (``request_json_limit``), the most the
    server reads of such a body, filled with what was slow to check: a dtype of ``"f4,"``
    repeated (NumPy's dtype parser took 4.4 s for 3 MB of it), a unit text as long, nested
    lists, many unknown options."""
    def padded(make) -> bytes:
        n = 1
        while len(json.dumps(make(n * 2)).encode()) <= limit:
            n *= 2
        lo, hi = n, 2 * n
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if len(json.dumps(make(mid)).encode()) <= limit else (lo, mid)
        return json.dumps(make(lo)).encode()

    return [
        padded(lambda n: {"dataset_id": dataset_id, "method": "ner", "params": {"dtype": "f4," * n}}),
        padded(lambda n: {"dataset_id": dataset_id, "method": "tv", "params": {"dz": "1" * n + " um"}}),
        padded(lambda n: {"dataset_id": dataset_id, "method": "ner", "params": {"n_z": [[1, 2]] * n}}),
        padded(lambda n: {"dataset_id": dataset_id, "method": "ner", "params": {f"opt{i}": i for i in range(n)}}),
    ]


def big_bodies(url: str, token: str, per_client: int, dataset_id: str) -> list[int]:
    """Four clients, each on a kept-alive connection of its own, send requests one after
    another: three ``per_client`` of the largest reconstruction bodies
    (:func:`largest_recon_bodies`, 64 KiB), one the largest plan (a point list of 262 144
    points, 3 MB: plan bodies are parsed in the plan worker, seconds each) until they are
    done. Returns every status."""
    bodies = largest_recon_bodies(dataset_id)
    plan = json.dumps(big_plan_body("points")).encode()
    hdr = {"Content-Type": "application/json"}
    statuses: list[int] = []
    lock = threading.Lock()

    done = threading.Event()

    def client(k: int) -> None:
        with _client(url, token) as c:
            for i in range(per_client):
                r = c.post("/api/reconstructions", content=bodies[(k + i) % len(bodies)], headers=hdr)
                with lock:
                    statuses.append(r.status_code)

    def planner() -> None:
        with _client(url, token) as c:
            while True:
                r = c.post("/api/plans/preview", content=plan, headers=hdr)
                with lock:
                    statuses.append(r.status_code)
                if done.is_set():
                    return

    threads = [threading.Thread(target=client, args=(k,)) for k in range(3)]
    plans = threading.Thread(target=planner)
    for t in (*threads, plans):
        t.start()
    for t in threads:
        t.join()
    done.set()
    plans.join()
    return statuses


def _encoded(url: str, token: str, spec: dict) -> dict[str, list[bytes]]:
    """Every request of the soak as the bytes on the wire (HTTP/1.1, keep-alive), by kind:
    encoded once with httpx, so that sending one costs the load process next to nothing."""
    from pathlib import Path

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    good = Path(spec["good"]).read_bytes()
    bad = [Path(f).read_bytes() for f in spec["bad"]]

    def raw(method: str, path: str, **kw) -> bytes:
        req = httpx.Request(method, url + path, headers=headers, **kw)
        body = req.read()
        host = httpx.URL(url).netloc.decode()
        lines = [f"{method} {req.url.raw_path.decode()} HTTP/1.1", f"Host: {host}"]
        lines += [f"{k}: {v}" for k, v in req.headers.items() if k.lower() != "host"]
        if "content-length" not in req.headers:
            lines.append(f"Content-Length: {len(body)}")
        return ("\r\n".join(lines) + "\r\n\r\n").encode() + body

    preview = [raw("POST", "/api/plans/preview", json={
        "kind": "equisteradian", "lattice": {"n_x": 64, "n_y": 64, "pitch": 6e-5},
        "params": {"depth": depth, "n_points": 100}}) for depth in (1e300, -1, 0)]
    return {
        "status": [raw("GET", f"/api/jobs/{spec['scan_id']}")],
        "health": [raw("GET", "/api/health")],
        "preview": preview,
        "good-upload": [raw("POST", "/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                            files={"file": ("g.npy", good)})],
        "bad-upload": [raw("POST", "/api/datasets", data={"format": "fpscan"}, files={"file": ("x.h5", b)})
                       for b in bad],
        "bad-recon": [raw("POST", "/api/reconstructions",
                          json={"dataset_id": spec["dataset_id"], "params": {"n_z": 1}})],
        "list": [raw("GET", "/api/jobs")],
    }


async def _exchange(reader, writer, request: bytes) -> tuple[int, bool]:
    """Send one request and read its whole response: (status, the server keeps the
    connection)."""
    writer.write(request)
    await writer.drain()
    status = int((await reader.readline()).split()[1])
    length, chunked, keep = 0, False, True
    while (line := await reader.readline()) not in (b"\r\n", b""):
        name, _, value = line.decode("latin-1").partition(":")
        name, value = name.strip().lower(), value.strip().lower()
        if name == "content-length":
            length = int(value)
        elif name == "transfer-encoding" and "chunked" in value:
            chunked = True
        elif name == "connection" and value == "close":
            keep = False
    if chunked:
        while (size := int((await reader.readline()).split(b";")[0], 16)) > 0:
            await reader.readexactly(size + 2)
        await reader.readline()
    else:
        await reader.readexactly(length)
    return status, keep


def mixed_load(url: str, token: str, spec: dict) -> list[tuple[str, int, float]]:
    """The soak's clients: ``spec["clients"]`` concurrent clients, each on a keep-alive
    connection of its own, sending ``spec["per_client"]`` requests one after another,
    drawn from ``spec["kinds"]`` (job status of ``spec["scan_id"]``, health, plan previews
    with bad depths, uploads of ``spec["good"]`` and of the files ``spec["bad"]``,
    reconstruction requests with bad options on ``spec["dataset_id"]``, the job list), each
    answered within ``spec["answer_s"]`` or counted as never answered; with
    ``spec["pause_s"]`` each client waits about that long (0.5-1.5 times) after an answer,
    as a person's client does between requests. The clients are
    coroutines in one thread that send requests encoded once (:func:`_encoded`): like
    clients on other machines they take next to none of the server's cores (50 httpx
    clients in this process took a whole core from the server on a 2-core machine).
    Returns one ``(kind, status, latency_s)`` per request; status -1 is a request never
    answered."""
    import asyncio

    wire = _encoded(url, token, spec)
    target = httpx.URL(url)
    results: list[tuple[str, int, float]] = []

    async def client(seed: int) -> None:
        rnd = random.Random(seed)
        conn = None
        for _ in range(spec["per_client"]):
            kind = rnd.choice(spec["kinds"])
            t0 = time.perf_counter()
            try:
                if conn is None:
                    conn = await asyncio.open_connection(target.host, target.port)
                status, keep = await asyncio.wait_for(_exchange(*conn, rnd.choice(wire[kind])), spec["answer_s"])
                if not keep:
                    conn[1].close()
                    conn = None
            except Exception as exc:  # a time-out is a hang
                status = -1
                print("soak: no answer", kind, type(exc).__name__, file=sys.stderr)
                if conn is not None:
                    conn[1].close()
                conn = None
            results.append((kind, status, time.perf_counter() - t0))
            if spec.get("pause_s"):
                await asyncio.sleep(spec["pause_s"] * rnd.uniform(0.5, 1.5))
        if conn is not None:
            conn[1].close()

    async def main() -> None:
        await asyncio.gather(*(client(i) for i in range(spec["clients"])))

    asyncio.run(main())
    return results


if __name__ == "__main__":
    what, url, token = sys.argv[1:4]
    if what == "mixed":
        with open(sys.argv[4]) as f:
            print(json.dumps(mixed_load(url, token, json.load(f))))
    elif what == "bodies":
        print(json.dumps(big_bodies(url, token, int(sys.argv[4]), sys.argv[5])))
    elif what == "health":
        stop = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        period = float(sys.argv[4]) if len(sys.argv) > 4 else 0.05
        print(json.dumps(poll_health(url, token, stop, period)))
    else:
        print(json.dumps(plan_load(url, token)))
