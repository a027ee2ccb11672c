"""One table (issue 20.4): what a reconstruction costs through each door -- the library, an HTTP
job (submit -> succeeded) and the command line -- cold and warm, per method and size, with the
machine's load average beside every row.

Columns, per method and lateral size (n_t fixed by ``--n-t``; float32; one synthetic dataset
per size, content irrelevant to timing):

- ``lib cold``: a fresh interpreter's import of the pipeline + its first reconstruction
  (numba's on-disk cache as it is); ``lib warm``: the next call in that process;
- ``http``: one job over HTTP, submit to ``succeeded`` (polled every 20 ms), on a server whose
  worker is warm; ``http/lib``: that over ``lib warm`` (target <= 1.3);
- ``write/recon``: the job's own timings (``params.result.timings``): writing the result folder
  (volume.h5 + MIP PNGs) over the reconstruction (target <= 0.3);
- ``cli``: ``fpscan recon FILE.npy`` wall time (a fresh process: imports, reconstruction, writing);
- ``load``: 1-minute load average when the row was measured.

Then: start-up to a healthy ``/api/health``, and the first job after start-up (NER at the first
size, submitted as soon as the server is healthy: it waits for the worker's warm-up) over
``lib warm`` (target <= 2).

    .venv/bin/python benchmarks/bench_table.py                   # 128, 226, 256 at n_t 256
    .venv/bin/python benchmarks/bench_table.py --sizes 128 --n-t 128 --methods ner   # quick

Starts its own server (127.0.0.1, free port) and stops it. Prints the table (markdown) and,
with ``--json``, the raw numbers.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DT, DX, C = 8e-9, 6e-5, 1500.0
TOKEN = "bench-token"


def dataset(n_t: int, n: int) -> np.ndarray:
    """A synthetic ``(n_t, n, n)`` float32 A-line volume (a few sources and noise)."""
    rng = np.random.default_rng(n)
    t = np.arange(n_t, dtype=np.float32)[:, None, None]
    return (np.sin(0.05 * t) * np.ones((1, n, n), np.float32)
            + 0.1 * rng.standard_normal((n_t, n, n)).astype(np.float32)).astype(np.float32)


def _library_child(method: str, paths: list[str]) -> None:
    """In a fresh interpreter: cold (imports + first call) and warm times of each file."""
    t0 = time.perf_counter()
    from service.pipeline import reconstruct
    from service.recon.dataset import GridDataset

    out = []
    for k, path in enumerate(paths):
        ds = GridDataset(data=np.load(path), dx=DX, dt=DT, c=C, dy=DX)
        t1 = time.perf_counter()
        reconstruct(ds, method, dtype="float32")
        first = time.perf_counter() - (t0 if k == 0 else t1)
        t2 = time.perf_counter()
        reconstruct(ds, method, dtype="float32")
        out.append({"cold_s": first if k == 0 else None, "warm_s": time.perf_counter() - t2})
    print(json.dumps(out))


def library(method: str, paths: list[Path]) -> list[dict]:
    r = subprocess.run([sys.executable, __file__, "--library-child", method, *map(str, paths)],
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def cli(method: str, path: Path, out: Path) -> float:
    from clients.processes import fpscan_argv

    argv = fpscan_argv("recon", str(path), "--format", "npy", "--dt", str(DT), "--dx", str(DX), "--c", str(C),
                       "--method", method, "--dtype", "float32", "--out", str(out), "--quiet")
    t = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True)
    return time.perf_counter() - t


def _upload(c, path: Path) -> str:
    r = c.post("/api/datasets", data={"format": "npy", "dt": str(DT), "dx": str(DX), "c": str(C)},
               files={"file": (path.name, path.read_bytes(), "application/octet-stream")})
    r.raise_for_status()
    return r.json()["dataset_id"]


def job(c, ds: str, method: str) -> tuple[float, dict]:
    """Submit a job and wait for it: (submit -> succeeded seconds, the job)."""
    t = time.perf_counter()
    r = c.post("/api/reconstructions", json={"dataset_id": ds, "method": method, "params": {"dtype": "float32"}})
    r.raise_for_status()
    jid = r.json()["id"]
    while True:
        j = c.get(f"/api/jobs/{jid}").json()
        if j["state"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.02)
    dt = time.perf_counter() - t
    if j["state"] != "succeeded":
        raise RuntimeError(f"job {jid} {j['state']}: {j.get('error')}")
    return dt, j


def _parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 226, 256], help="lateral sizes n (n x n)")
    ap.add_argument("--n-t", type=int, default=256)
    ap.add_argument("--methods", nargs="+", default=["ner", "nedner", "kwave"])
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line column")
    ap.add_argument("--json", action="store_true", help="also print the raw numbers as JSON")
    ap.add_argument("--library-child", nargs="+", help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def main() -> int:
    args = _parse_args()
    if args.library_child:
        _library_child(args.library_child[0], args.library_child[1:])
        return 0

    load_start = os.getloadavg()
    rows: dict[tuple[str, int], dict] = {}
    extra: dict = {}
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        paths = _write_datasets(tmp, args.sizes, args.n_t)
        for m in args.methods:
            for n, lib in zip(args.sizes, library(m, paths)):
                rows[(m, n)] = {"lib_cold_s": lib["cold_s"], "lib_warm_s": lib["warm_s"]}
        _measure_http(args, tmp, paths, rows, extra)
        if not args.no_cli:
            for m in args.methods:
                for n, p in zip(args.sizes, paths):
                    rows[(m, n)]["cli_s"] = cli(m, p, tmp / f"cli-{m}-{n}")
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


def _measure_http(args: argparse.Namespace, tmp: Path, paths: list[Path], rows: dict, extra: dict) -> None:
    """Start a server; time start-up, the first job after it and one job per method and size."""
    import httpx

    from clients.processes import start_service

    t = time.perf_counter()
    srv = start_service(tmp / "data", token=TOKEN, web=False, env={"FPSCAN_LOG_LEVEL": "warning"},
                        log_path=tmp / "server.log")
    extra["startup_to_healthy_s"] = time.perf_counter() - t
    try:
        with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600) as c:
            ids = {}
            for n, p in zip(args.sizes, paths):
                ids[n] = _upload(c, p)
                if n == args.sizes[0]:  # the first job, right after start-up (worker still warming)
                    first, _ = job(c, ids[n], args.methods[0])
                    extra["first_job_s"] = first
                    extra["first_job_over_lib"] = first / rows[(args.methods[0], n)]["lib_warm_s"]
            for m in args.methods:
                for n in args.sizes:
                    dt, j = job(c, ids[n], m)
                    tm = j["params"]["result"]["timings"]
                    rows[(m, n)].update(http_s=dt, recon_s=tm["reconstruct_s"], write_s=tm["write_s"],
                                        load=os.getloadavg()[0])
    finally:
        srv.stop(timeout=20)


def _print_table(args: argparse.Namespace, rows: dict, extra: dict, load_start, load_end) -> None:
    """The markdown table, the start-up lines and (``--json``) the raw numbers."""

    def f(v, fmt="{:.2f}"):
        return "–" if v is None else fmt.format(v)

    print(f"\nfpscan bench_table: n_t = {args.n_t}, float32; load average at start "
          f"{load_start[0]:.2f} {load_start[1]:.2f} {load_start[2]:.2f}, at end "
          f"{load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f} on {os.cpu_count()} CPUs\n")
    print("| method | size | lib cold s | lib warm s | http s | http/lib | recon s (job) | write s (job) "
          "| write/recon | cli s | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for (m, n), r in rows.items():
        print(f"| {m} | {args.n_t}×{n}² | {f(r['lib_cold_s'])} | {f(r['lib_warm_s'])} | {f(r.get('http_s'))} "
              f"| {f(r.get('http_s', 0) / r['lib_warm_s'])} | {f(r.get('recon_s'))} | {f(r.get('write_s'))} "
              f"| {f(r.get('write_s', 0) / max(r.get('recon_s', 1), 1e-9))} | {f(r.get('cli_s'))} "
              f"| {f(r.get('load'))} |")
    m0, n0 = args.methods[0], args.sizes[0]
    print(f"\nstart-up to healthy: {extra['startup_to_healthy_s']:.2f} s (target <= 3 s); first job after "
          f"start-up ({m0}, {args.n_t}×{n0}²): {extra['first_job_s']:.2f} s = {extra['first_job_over_lib']:.2f}× "
          f"lib warm (target <= 2)")
    if args.json:
        print(json.dumps({"rows": [{"method": m, "n": n, **r} for (m, n), r in rows.items()], **extra,
                          "n_t": args.n_t, "load_start": load_start, "load_end": load_end}, indent=1))

if __name__ == "__main__":
    sys.exit(main())
