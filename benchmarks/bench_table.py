"""One table: what a reconstruction costs through each door -- the library, the
job worker's own function, an HTTP job (submit -> succeeded) and the command line -- cold and warm,
per method and size, as ratios measured in one run, with the machine's load average beside every row.

Columns, per method and lateral size (n_t fixed by ``--n-t``; float32; one synthetic dataset
per size, content irrelevant to timing):

- ``lib cold``: a fresh interpreter's import of the pipeline + its first reconstruction
  (numba's on-disk cache as it is); ``lib``: a warm ``fpscan.service.pipeline.reconstruct`` in that
  process (median of ``--repeat``);
- ``worker``: ``fpscan.service.jobs.work.run_reconstruction`` in the same process (what a pool worker
  runs: load the canonical dataset file, reconstruct, write the result folder), over ``lib``;
- ``write``: ``fpscan.service.storage.results.write_result`` (volume.h5 + MIP PNGs) of that
  reconstruction in the same process, over ``lib`` (target <= 0.3);
- ``http``: one job over HTTP, submit to ``succeeded`` (the end of the job's events stream, as
  ``fpscan.clients.http.Client.wait`` waits), with ``--fetch`` then its ``volume.h5`` fetched
  (``fpscan.clients.http.Client.download_volume``, to a file), on a server whose
  worker is warm, over ``lib`` (target <= 1.3; with ``--fetch`` <= 1.2); the library call and the
  job alternate (lib, http, lib, http, ...: ``--repeat`` rounds, medians), so both see the same load;
- ``fetch``: with ``--fetch``, the download's part of ``http``;
- ``job load`` / ``job recon`` / ``job write``: the job's own timings (``params.result.timings``: the
  worker reading its input, reconstructing, writing the result folder);
- ``cli``: ``fpscan recon FILE.npy`` wall time (a fresh process: imports, reconstruction, writing);
- ``load``: 1-minute load average when the row was measured;
- ``second job``: with ``--second-job`` every row is measured twice, the second time while
  another client keeps one more job running (the first method at the largest size, back to
  back; the server then has 2 workers): the "under a second job's load" case.

Then: start-up to a healthy ``/api/health`` (target <= 3 s), and the first job after start-up
(the first method at the first size, submitted as soon as the server is healthy: it waits for
the worker's warm-up) over ``lib`` (target <= 2).

    .venv/bin/python benchmarks/bench_table.py                   # 128, 226, 256 at n_t 256
    .venv/bin/python benchmarks/bench_table.py --sizes 128 --n-t 256 --methods ner --no-cli   # quick
    .venv/bin/python benchmarks/bench_table.py --second-job     # also under a second job's load
    .venv/bin/python benchmarks/bench_table.py --sizes 192 --n-t 512 --methods ner --no-cli --fetch --repeat 5

Starts its own server (127.0.0.1, free port) and stops it. The child processes (library, server,
CLI) run with bytecode caching on (``PYTHONDONTWRITEBYTECODE`` removed), as an installed package
has it. Prints the table (markdown) and, with ``--json``, the raw numbers.
"""
from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DT, DX, C = 8e-9, 6e-5, 1500.0
TOKEN = secrets.token_urlsafe(32)  # fpscan serve refuses a guessable token


def dataset(n_t: int, n: int) -> np.ndarray:
    """A synthetic ``(n_t, n, n)`` float32 A-line volume (a few sources and noise)."""
    rng = np.random.default_rng(n)
    t = np.arange(n_t, dtype=np.float32)[:, None, None]
    return (np.sin(0.05 * t) * np.ones((1, n, n), np.float32)
            + 0.1 * rng.standard_normal((n_t, n, n)).astype(np.float32)).astype(np.float32)


def _library_child(method_paths: list[str]) -> None:
    """In a fresh interpreter: the cold time (imports + first call) of the first dataset, then
    one line of JSON per command read from stdin (``METHOD PATH``): a warm library call, the
    worker's ``run_reconstruction`` and ``write_result`` of the same data, each timed."""
    t0 = time.perf_counter()
    from fpscan.service.jobs.work import run_reconstruction
    from fpscan.service.pipeline import reconstruct
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.storage.loader import write_dataset
    from fpscan.service.storage.results import write_result

    method, path = method_paths
    ds = GridDataset(data=np.load(path), dx=DX, dt=DT, sound_speed=C, dy=DX)
    rec = reconstruct(ds, method, dtype="float32")
    print(json.dumps({"cold_s": time.perf_counter() - t0}), flush=True)
    canonical: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        write_result(os.path.join(tmp, "warm"), rec, input_id="bench")  # the writer's imports and fonts
        for line in sys.stdin:
            method, path = line.split()
            ds = GridDataset(data=np.load(path), dx=DX, dt=DT, sound_speed=C, dy=DX)
            if path not in canonical:
                canonical[path] = os.path.join(tmp, f"ds{len(canonical)}.h5")
                write_dataset(canonical[path], ds)
            t = time.perf_counter()
            rec = reconstruct(ds, method, dtype="float32")
            lib = time.perf_counter() - t
            t = time.perf_counter()
            write_result(os.path.join(tmp, "lib-result"), rec, input_id="bench")
            write = time.perf_counter() - t
            del rec  # the worker's call starts with the memory a pool worker has between jobs
            spec = {"input": {"kind": "dataset", "path": canonical[path]},
                    "params": {"method": method, "dtype": "float32"}, "out_dir": os.path.join(tmp, "job-result"),
                    "input_id": "bench"}
            t = time.perf_counter()
            summary = run_reconstruction(spec)
            worker = time.perf_counter() - t
            print(json.dumps({"lib_s": lib, "write_s": write, "worker_s": worker,
                              "worker_timings": summary["timings"]}), flush=True)


class Library:
    """The library child process (:func:`_library_child`): ``call(method, path)`` -> timings."""

    def __init__(self, method: str, path: Path):
        self.proc = subprocess.Popen([sys.executable, __file__, "--library-child", method, str(path)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.cold_s = self._answer()["cold_s"]

    def _answer(self) -> dict:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the library child exited {self.proc.wait()}")
        return json.loads(line)

    def call(self, method: str, path: Path) -> dict:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{method} {path}\n")
        self.proc.stdin.flush()
        return self._answer()

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def cli(method: str, path: Path, out: Path) -> float:
    from fpscan.clients.processes import fpscan_argv

    argv = fpscan_argv("recon", str(path), "--format", "npy", "--dt", str(DT), "--dx", str(DX), "--c", str(C),
                       "--method", method, "--dtype", "float32", "--out", str(out), "--quiet")
    t = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True)
    return time.perf_counter() - t


def _upload(c, path: Path) -> str:
    r = c.post("/api/datasets", data={"format": "npy", "dt": str(DT), "dx": str(DX), "sound_speed": str(C)},
               files={"file": (path.name, path.read_bytes(), "application/octet-stream")})
    r.raise_for_status()
    return r.json()["dataset_id"]


def job(c, ds: str, method: str, fetch: Path | None = None) -> tuple[float, dict]:
    """Submit a job and wait for it: (submit -> succeeded seconds, the job); with ``fetch`` (a file
    path) then download its ``volume.h5`` there as the HTTP client does, inside the time (the
    download's own seconds in the job's ``"fetch_s"``)."""
    t = time.perf_counter()
    r = c.post("/api/reconstructions", json={"dataset_id": ds, "method": method, "params": {"dtype": "float32"}})
    r.raise_for_status()
    jid = r.json()["id"]
    # as a client waits (fpscan.clients.http.Client.wait): the job's events stream, which ends
    # after the job's final state
    with c.stream("GET", f"/api/jobs/{jid}/events") as events:
        for _ in events.iter_lines():
            pass
    j = c.get(f"/api/jobs/{jid}").json()
    if j["state"] != "succeeded":
        raise RuntimeError(f"job {jid} {j['state']}: {j.get('error')}")
    if fetch is not None:
        f0 = time.perf_counter()
        _client(str(c.base_url)).download_volume(jid, fetch)
        j["fetch_s"] = time.perf_counter() - f0
        dt = time.perf_counter() - t
        fetch.unlink()
        return dt, j
    return time.perf_counter() - t, j


_CLIENTS: dict = {}


def _client(url: str):
    """One `fpscan.clients.http.Client` per server, kept (its connection too) across jobs."""
    if url not in _CLIENTS:
        from fpscan.clients.http import Client

        _CLIENTS[url] = Client(url, token=TOKEN)
    return _CLIENTS[url]


def _parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 226, 256], help="lateral sizes n (n x n)")
    ap.add_argument("--n-t", type=int, default=256)
    ap.add_argument("--methods", nargs="+", default=["ner", "nedner", "kwave"])
    ap.add_argument("--repeat", type=int, default=3, help="rounds of (library call, HTTP job); medians")
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line column")
    ap.add_argument("--fetch", action="store_true",
                    help="the http column includes fetching the result's volume.h5 with the HTTP client")
    ap.add_argument("--second-job", action="store_true",
                    help="measure every row again while another client keeps a second job running "
                         "(server with 2 workers)")
    ap.add_argument("--json", action="store_true", help="also print the raw numbers as JSON")
    ap.add_argument("--library-child", nargs=2, help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def main() -> int:
    args = _parse_args()
    if args.library_child:
        _library_child(args.library_child)
        return 0

    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # the children cache bytecode, as an install does
    load_start = os.getloadavg()
    rows: dict[tuple[str, int, bool], dict] = {}
    extra: dict = {}
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        paths = _write_datasets(tmp, args.sizes, args.n_t)
        lib = Library(args.methods[0], paths[0])
        try:
            _measure(args, tmp, paths, lib, rows, extra)
        finally:
            lib.close()
        if not args.no_cli:
            for m in args.methods:
                for n, p in zip(args.sizes, paths):
                    rows[(m, n, False)]["cli_s"] = cli(m, p, tmp / f"cli-{m}-{n}")
    _print_table(args, rows, extra, load_start, os.getloadavg())
    return 0


def _write_datasets(tmp: Path, sizes: list[int], n_t: int) -> list[Path]:
    """One ``.npy`` dataset per lateral size in ``tmp``."""
    paths = []
    for n in sizes:
        p = tmp / f"d{n}.npy"
        np.save(p, dataset(n_t, n))
        paths.append(p)
    return paths


def _median(values: list[float]) -> float:
    return float(np.median(values))


def _measure(args: argparse.Namespace, tmp: Path, paths: list[Path], lib: Library, rows: dict,
             extra: dict) -> None:
    """Start a server; time start-up and the first job after it; then per method and size
    ``--repeat`` rounds of (library call + worker function + writer, HTTP job)."""
    import httpx

    from fpscan.clients.processes import start_service

    extra["lib_cold_s"] = lib.cold_s
    # references for the start-up: a bare interpreter, numpy, and the web framework every FastAPI
    # server imports (fresh interpreters, measured just before the server starts)
    for name, code in (("python_pass_s", "pass"), ("import_numpy_s", "import numpy"),
                       ("import_fastapi_s", "import fastapi, uvicorn")):
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        extra[name] = time.perf_counter() - t
    t = time.perf_counter()
    env = {"FPSCAN_LOG_LEVEL": "warning", **({"FPSCAN_WORKERS": "2"} if args.second_job else {})}
    srv = start_service(tmp / "data", token=TOKEN, web=False, env=env,
                        log_path=tmp / "server.log")
    extra["startup_to_healthy_s"] = time.perf_counter() - t
    extra["startup_load"] = os.getloadavg()[0]
    try:
        with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600) as c:
            ids = {}
            for n, p in zip(args.sizes, paths):
                ids[n] = _upload(c, p)
                if n == args.sizes[0]:  # the first job, right after start-up (worker still warming)
                    extra["first_job_s"], first = job(c, ids[n], args.methods[0])
                    extra["first_job_timings"] = {**first["params"]["result"]["timings"],
                                                  "queued_s": first["timings"]["queued_s"],
                                                  "run_s": first["timings"]["run_s"]}
                    extra["first_job_load"] = os.getloadavg()[0]
            for second in (False, True) if args.second_job else (False,):
                background = _SecondJob(srv.url, ids[args.sizes[-1]], args.methods[0]) if second else None
                try:
                    for m in args.methods:
                        for n, p in zip(args.sizes, paths):
                            rows[(m, n, second)] = _rounds(args, lib, c, m, n, p, ids[n])
                finally:
                    if background is not None:
                        extra["second_jobs_done"] = background.stop()
    finally:
        srv.stop(timeout=20)
    m0, n0 = args.methods[0], args.sizes[0]
    extra["first_job_over_lib"] = extra["first_job_s"] / rows[(m0, n0, False)]["lib_s"]


def _rounds(args: argparse.Namespace, lib: Library, c, m: str, n: int, p: Path, ds: str) -> dict:
    """``--repeat`` rounds of (library call + worker function + writer, HTTP job): medians."""
    got: dict[str, list] = {}
    for i in range(max(1, args.repeat)):
        r = lib.call(m, p)
        dt, j = job(c, ds, m, fetch=p.with_name(f"fetched-{m}-{n}-{i}.h5") if args.fetch else None)
        tm = j["params"]["result"]["timings"]
        for key, v in (("lib_s", r["lib_s"]), ("worker_s", r["worker_s"]), ("write_s", r["write_s"]),
                       ("http_s", dt), ("fetch_s", j.get("fetch_s")), ("job_load_s", tm["load_s"]),
                       ("job_recon_s", tm["reconstruct_s"]), ("job_write_s", tm["write_s"]),
                       ("load", os.getloadavg()[0])):
            got.setdefault(key, []).append(v)
    row = {k: None if None in v else _median(v) for k, v in got.items()}
    row["http_over_lib"] = _median([h / v for h, v in zip(got["http_s"], got["lib_s"])])
    return row


class _SecondJob:
    """``--second-job``: another client keeps one more job running on the server (the first
    method at the largest size, back to back, on the server's second worker) while the rows
    are measured: the library call and the HTTP job both share the machine with it."""

    def __init__(self, url: str, dataset_id: str, method: str) -> None:
        import threading

        import httpx

        self._client = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600)
        self._stop = threading.Event()
        self.done = 0
        self._thread = threading.Thread(target=self._loop, args=(dataset_id, method), daemon=True)
        self._thread.start()

    def _loop(self, dataset_id: str, method: str) -> None:
        while not self._stop.is_set():
            job(self._client, dataset_id, method)
            self.done += 1

    def stop(self) -> int:
        """Stop after the job in flight; returns how many jobs it ran."""
        self._stop.set()
        self._thread.join()
        self._client.close()
        return self.done


def _print_table(args: argparse.Namespace, rows: dict, extra: dict, load_start, load_end) -> None:
    """The markdown table, the start-up lines and (``--json``) the raw numbers."""

    def f(v, fmt="{:.2f}"):
        return "–" if v is None else fmt.format(v)

    print(f"\nfpscan bench_table: n_t = {args.n_t}, float32, {args.repeat} rounds; load average at start "
          f"{load_start[0]:.2f} {load_start[1]:.2f} {load_start[2]:.2f}, at end "
          f"{load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f} on {os.cpu_count()} CPUs\n")
    print("| method | size | second job | lib s | worker s (/lib) | write s (/lib) | http s (/lib) | fetch s "
          "| job load s | job recon s | job write s (/recon) | cli s | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (m, n, second), r in rows.items():
        lib = r["lib_s"]
        print(f"| {m} | {args.n_t}×{n}² | {'yes' if second else 'no'} | {f(lib)} | {f(r['worker_s'])} ({f(r['worker_s'] / lib)}) "
              f"| {f(r['write_s'])} ({f(r['write_s'] / lib)}) | {f(r['http_s'])} ({f(r['http_over_lib'])}) "
              f"| {f(r['fetch_s'])} | {f(r['job_load_s'])} "
              f"| {f(r['job_recon_s'])} | {f(r['job_write_s'])} ({f(r['job_write_s'] / max(r['job_recon_s'], 1e-9))}) "
              f"| {f(r.get('cli_s'))} | {f(r['load'])} |")
    m0, n0 = args.methods[0], args.sizes[0]
    print(f"\nlibrary cold (fresh interpreter: imports + first {m0} at {args.n_t}×{n0}²): {extra['lib_cold_s']:.2f} s")
    print(f"start-up to healthy: {extra['startup_to_healthy_s']:.2f} s (target <= 3 s; load "
          f"{extra['startup_load']:.2f}) = {extra['startup_to_healthy_s'] / extra['import_fastapi_s']:.2f}× a fresh "
          f"`import fastapi, uvicorn` ({extra['import_fastapi_s']:.2f} s; `import numpy` "
          f"{extra['import_numpy_s']:.2f} s, `pass` {extra['python_pass_s']:.2f} s)")
    print(f"first job after start-up ({m0}, {args.n_t}×{n0}²): "
          f"{extra['first_job_s']:.2f} s = {extra['first_job_over_lib']:.2f}× lib (target <= 2; load "
          f"{extra['first_job_load']:.2f}); its parts: "
          + ", ".join(f"{k} {v:.2f}" for k, v in extra["first_job_timings"].items()))
    if args.json:
        print(json.dumps({"rows": [{"method": m, "n": n, "second_job": sj, **r} for (m, n, sj), r in rows.items()],
                          **extra,
                          "n_t": args.n_t, "load_start": load_start, "load_end": load_end}, indent=1))

if __name__ == "__main__":
    sys.exit(main())
