"""How NER, NEDNER and tv's operator pair scale with cores, step by step, and how NER's CPU parts
scale with threads beside the memory bandwidth.

Two modes.

``--pinned`` (the table of docs/performance.md, "CPU scaling on the 2-core machine"): each case in
processes pinned with ``taskset`` to 1 core and to 2 cores (``--cores``; numba and OpenMP at that
many threads, pocketfft at the cores of the process's CPU set, `fpscan.physics.fft_engine.workers`,
where the tree has it: an older tree's ``workers=-1`` starts a thread per core of the machine on
the cores it has), so that nothing can use a core it was not given; ``--rounds`` processes each,
the trees and core counts alternating round by round (``--trees LABEL=PATH ...``: each tree's
checkout on ``PYTHONPATH``, e.g. the code before a change beside the code after it), each
process's best of ``--repeat`` calls, and the best of the processes. The cases, at the paper's size
x ``--scale`` (the 226² lattice, 1024 samples of 8 ns, float32; `bench_tv_paper.paper_case`):

- ``ner``: `reconstruct_grid` of random data on the lattice;
- ``nedner``: `reconstruct_points` of the scan's A-lines at the 1653-point equi-steradian mask
  (on the lattice's nodes, with the mask's weights);
- ``pair``: one forward and one preconditioned adjoint of tv's model (``Model.forward`` +
  ``Model.B``, `fpscan.service.recon.tv.problem`: the operator pair an iteration runs) on tv's
  grid for that scan;
- ``fft``: one complex FFT of the mirrored volume at fast lengths (`bench_recon.fft_time`, the
  reference of `bench_recon.py`'s "NER ≤ 0.9 / fast FFT");
- ``tv`` (``--tv-scale``, default 0.5: one core takes minutes at the paper's size): `reconstruct_tv`
  of the scan to its stopping rule, set-up included, once per process (its operator pairs printed),
  after a two-iteration run on the scan at x0.25 (imports and compiled kernels loaded).

Printed: per case and tree, the time on 1 and 2 cores, the speed-up and Amdahl's serial fraction
s = 2 / S − 1 (S the speed-up on 2 cores; S = 1 / (s + (1 − s) / p)); then per case a table of its
steps (`fpscan.physics.step_times`, in the tree that records them): each step's time on 1 and 2
cores, its share of the whole on 1 core, its speed-up and serial fraction, from the call with the
best whole time, and the time outside the steps; the load average (``uptime``) before and after
each round.

    python benchmarks/bench_cpu_scaling.py --pinned [--trees before=/path/to/main after=.] [--rounds 3]
        [--repeat 3] [--scale 1] [--tv-scale 0.5] [--cases ner nedner pair fft tv] [--json FILE]

Without ``--pinned`` (``scripts/gpu-check.sh scaling``, 16 cores): at the paper's NER size, for each
thread count k in ``--threads``, in this process, best of ``--repeat``:

- ``triad``: a = b + s c over three float32 arrays of the temporal fine grid's size, a numba
  ``prange`` loop at k threads: the memory bandwidth the cores share (a STREAM triad);
- ``temporal FFT``: ``scipy.fft.fft`` of the fine temporal grid (n_cols × L complex64), workers=k;
- ``interp``: NER's temporal NUFFT evaluation (`fpscan.physics.nufft.evaluate`, the compiled
  kernel) at k numba threads;
- ``NER``: the whole `reconstruct_grid` float32 at k numba threads (its FFTs on the process's
  cores), for reference.

Each row prints its time and speed-up over one thread.

    python benchmarks/bench_cpu_scaling.py [--threads 1 2 4 8 16] [--repeat 3] [--scale 1]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_gpu import best_of  # best of ``repeat`` calls, in s
from bench_tv_paper import DT, PITCH, C  # the scan's sampling (s, m, m/s)

HERE = Path(__file__).resolve()
CASES = ("ner", "nedner", "pair", "fft", "tv")


@numba.njit(parallel=True, cache=True)
def _triad(a: np.ndarray, b: np.ndarray, c: np.ndarray, s: float) -> None:
    for i in numba.prange(a.size):
        a[i] = b[i] + s * c[i]


def _threads_mode(args: argparse.Namespace) -> None:
    """The in-process rows at each thread count (module doc)."""
    import scipy.fft

    from fpscan.physics import nufft
    from fpscan.physics.fast_lengths import fast_lateral
    from fpscan.service.recon import reconstruct_grid

    cores = numba.config.NUMBA_NUM_THREADS
    threads = args.threads or [k for k in (1, 2, 4, 8, 16, 32) if k <= cores]
    n, n_t = int(round(226 * args.scale)), int(round(1024 * args.scale))
    n_yp, n_xp = fast_lateral(n, n, square=True)
    n_cols = n_yp * (n_xp // 2 + 1)
    grid = nufft.make_grid(n_t, "nufft", 1e-6)
    rng = np.random.default_rng(0)
    U = (rng.standard_normal((n_cols, grid.L)) + 1j * rng.standard_normal((n_cols, grid.L))).astype(np.complex64)
    kx = 2 * np.pi * np.fft.rfftfreq(n_xp, 60e-6)
    ky = 2 * np.pi * np.fft.fftfreq(n_yp, 60e-6)
    klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
    n_kz = n_t + 1
    dz = 1500.0 * 8e-9
    kz = np.pi / ((n_kz - 1) * dz) * np.arange(n_kz)
    qw = np.ones(n_kz)
    groups = nufft.group_columns(klat2)
    size = U.size * 2
    a, b, c = (np.ones(size, np.float32) for _ in range(3))
    data = rng.standard_normal((n_t, n, n)).astype(np.float32)
    rows: dict[str, list[float]] = {"triad": [], "temporal FFT": [], "interp": [], "NER": []}
    for k in threads:
        numba.set_num_threads(k)
        _triad(a, b, c, 0.5)
        rows["triad"].append(best_of(lambda: _triad(a, b, c, 0.5), args.repeat))
        scipy.fft.fft(U[:64], axis=-1, workers=k)  # planned
        rows["temporal FFT"].append(best_of(lambda k=k: scipy.fft.fft(U, axis=-1, workers=k), args.repeat))
        nufft.evaluate(U[:64], grid, klat2[:64], kz, qw, 1500.0, 8e-9, 0.0, inversion=True)
        rows["interp"].append(best_of(lambda: nufft.evaluate(U, grid, klat2, kz, qw, 1500.0, 8e-9, 0.0, inversion=True,
                                                           groups=groups), args.repeat))
        reconstruct_grid(data, 60e-6, 8e-9, 1500.0, dtype=np.float32, device="cpu")
        rows["NER"].append(best_of(lambda: reconstruct_grid(data, 60e-6, 8e-9, 1500.0, dtype=np.float32, device="cpu"),
                                 args.repeat))
    print(f"CPU scaling at NER's size x{args.scale:g} ({n_t} samples, {n_yp}x{n_xp} grid, {n_cols} columns, L = "
          f"{grid.L}), float32; {os.cpu_count()} cores; triad over 3 x {size * 4 / 2**20:.0f} MiB")
    print("| part | " + " | ".join(f"{k} thread{'s' if k > 1 else ''}" for k in threads) + " |")
    print("|---|" + "---|" * len(threads))
    for name, times in rows.items():
        cells = [f"{t * 1e3:.0f} ms ({times[0] / t:.1f}×)" for t in times]
        print(f"| {name} | " + " | ".join(cells) + " |")


# -- --pinned: one child process per tree, core count and round ---------------------------------

def _timed(fn, repeat: int) -> dict:
    """``repeat`` calls of ``fn`` after one warm-up call: the best whole time and the steps of that
    call (`fpscan.physics.step_times`, empty where the tree has none)."""
    try:
        from fpscan.physics.step_times import recording
    except ImportError:  # a tree without step timers: the whole only
        from contextlib import contextmanager

        @contextmanager
        def recording():
            yield {}
    fn()
    best: dict = {"whole": np.inf, "steps": {}}
    for _ in range(repeat):
        with recording() as steps:
            t = time.perf_counter()
            fn()
            whole = time.perf_counter() - t
        if whole < best["whole"]:
            best = {"whole": whole, "steps": dict(steps)}
    return best


def _tv_model(case: dict):
    """tv's model (forward, B) for the scan ``case``, as `reconstruct_tv` makes it (captured from a
    one-iteration run)."""
    from fpscan.service.recon.tv import problem, reconstruct_tv

    models = []
    made = problem.Model.__init__

    def capture(self, *a, **k):
        made(self, *a, **k)
        models.append(self)

    problem.Model.__init__ = capture
    try:
        reconstruct_tv(case["alines"], DT, C, positions=case["positions"], weights=case["weights"], grid=case["grid"],
                       dtype=np.float32, max_iter=1, device="cpu")
    finally:
        problem.Model.__init__ = made
    return models[-1]


def _ner(case: dict, repeat: int) -> dict:
    from fpscan.service.recon import reconstruct_grid

    n, n_t = case["n"], case["n_t"]
    data = np.random.default_rng(2).standard_normal((n_t, n, n)).astype(np.float32)
    return _timed(lambda: reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cpu"), repeat)


def _nedner(case: dict, repeat: int) -> dict:
    from fpscan.service.recon import reconstruct_points

    al = case["alines"].astype(np.float32)
    return _timed(lambda: reconstruct_points(al, case["positions"], DT, C, weights=case["weights"], grid=case["grid"],
                                             dtype=np.float32, device="cpu"), repeat)


def _pair(case: dict, repeat: int) -> dict:
    model = _tv_model(case)
    v = np.random.default_rng(3).standard_normal(model.shape).astype(np.float32)
    return {**_timed(lambda: model.B(model.forward(v)), repeat),
            "grid": [list(model.shape), list(model.op.padded_shape)]}


def _fft(case: dict, repeat: int) -> dict:
    from bench_recon import fft_time

    return {"whole": fft_time(case["n_t"], case["n"], case["n"], repeat, fast=True), "steps": {}}


def _tv(case: dict, repeat: int) -> dict:
    from bench_tv_paper import paper_case

    from fpscan.service.recon.tv import reconstruct_tv

    small = paper_case(0.25)  # the kernels loaded (imports, numba's cache) on another geometry (tv keeps its own)
    reconstruct_tv(small["alines"], DT, C, positions=small["positions"], weights=small["weights"], grid=small["grid"],
                   dtype=np.float32, max_iter=2, device="cpu")
    t = time.perf_counter()
    r = reconstruct_tv(case["alines"], DT, C, positions=case["positions"], weights=case["weights"], grid=case["grid"],
                       dtype=np.float32, device="cpu")
    return {"whole": time.perf_counter() - t, "steps": {}, "pairs": r.params.get("operator_pairs")}


def _child(args: argparse.Namespace) -> None:
    """Measure ``args.cases`` in this (pinned) process, with fpscan from the checkout ``args.tree``
    (first on the path, the one this script sits in taken off it); one JSON line."""
    root = HERE.parents[1]
    sys.path[:] = [args.tree, str(HERE.parent)] + [p for p in sys.path if p and Path(p).resolve() != root]
    import fpscan
    import fpscan.physics  # noqa: F401  (first: its OpenMP wait policy, before numba's threads start)

    assert Path(fpscan.__file__).resolve().is_relative_to(Path(args.tree).resolve()), fpscan.__file__
    from bench_tv_paper import paper_case

    out: dict = {"cores": len(os.sched_getaffinity(0)), "numba_threads": numba.get_num_threads()}
    case = paper_case(args.scale)
    runs = {"ner": _ner, "nedner": _nedner, "pair": _pair, "fft": _fft, "tv": _tv}
    for name in args.cases:
        out[name] = runs[name](paper_case(args.tv_scale) if name == "tv" else case, args.repeat)
    print(json.dumps(out), flush=True)


def _uptime() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _pinned(args: argparse.Namespace) -> dict:
    """The child processes, trees and core counts alternating round by round; the best process."""
    trees = dict(t.split("=", 1) for t in args.trees)
    best: dict = {}
    loads = []
    for r in range(args.rounds):
        before = _uptime()
        for label, path in trees.items():
            for k in args.cores:
                env = {**os.environ, "PYTHONPATH": str(Path(path).resolve()), "NUMBA_NUM_THREADS": str(k),
                       "OMP_NUM_THREADS": str(k)}
                cpus = ",".join(str(c) for c in sorted(os.sched_getaffinity(0))[:k])
                cmd = ["taskset", "-c", cpus, sys.executable, str(HERE), "--child", "--tree", str(Path(path).resolve()),
                       "--repeat", str(args.repeat),
                       "--scale", str(args.scale), "--tv-scale", str(args.tv_scale), "--cases", *args.cases]
                res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=args.timeout)
                if res.returncode != 0:
                    raise RuntimeError(f"{label} at {k} cores failed:\n{res.stderr[-3000:]}")
                got = json.loads(res.stdout.strip().splitlines()[-1])
                for name in args.cases:
                    key = (label, k, name)
                    if key not in best or got[name]["whole"] < best[key]["whole"]:
                        best[key] = got[name]
                print(f"round {r + 1} {label} {k} core(s): "
                      + ", ".join(f"{n} {got[n]['whole']:.3f} s" for n in args.cases), flush=True)
        loads.append((before, _uptime()))
    return {"best": best, "loads": loads, "trees": trees}


def _serial(t1: float, t2: float, p: int) -> float:
    """Amdahl's serial fraction from the times on 1 and p cores."""
    return (p * t2 / t1 - 1) / (p - 1)


def _print_pinned(args: argparse.Namespace, r: dict) -> None:
    best, trees = r["best"], list(r["trees"])
    lo, hi = min(args.cores), max(args.cores)
    print(f"\nbench_cpu_scaling --pinned: the paper's scan x{args.scale:g} (tv x{args.tv_scale:g}), float32; "
          f"{len(os.sched_getaffinity(0))} cores; best of {args.rounds} processes per tree and core count "
          f"(each the best of {args.repeat} calls), alternating; load average (1, 5, 15 min) per round: "
          + "; ".join(f"{a[0]:.2f} {a[1]:.2f} {a[2]:.2f} -> {b[0]:.2f} {b[1]:.2f} {b[2]:.2f}" for a, b in r["loads"]))
    print(f"\n| case | tree | {lo} core | {hi} cores | speed-up | serial fraction |")
    print("|---|---|---|---|---|---|")
    for name in args.cases:
        for label in trees:
            t1, t2 = best[(label, lo, name)]["whole"], best[(label, hi, name)]["whole"]
            pairs = best[(label, hi, name)].get("pairs")
            print(f"| {name}{f' ({pairs:g} pairs)' if pairs else ''} | {label} | {t1:.3f} s | {t2:.3f} s | {t1 / t2:.2f}× "
                  f"| {_serial(t1, t2, hi / lo):.3f} |")
    if "ner" in args.cases and "fft" in args.cases:
        for label in trees:
            print(f"NER / fast FFT at {hi} cores, {label}: "
                  f"{best[(label, hi, 'ner')]['whole'] / best[(label, hi, 'fft')]['whole']:.2f}")
    for name in ("ner", "nedner", "pair"):
        if name in args.cases:
            _print_steps(name, best, trees, lo, hi)


def _step_time(x: dict, s: str) -> float | None:
    """A step's seconds in a measurement ``x`` (``"whole"``; ``"outside the steps"``)."""
    if s == "whole":
        return x["whole"]
    if s == "outside the steps":
        return x["whole"] - sum(x["steps"].values()) if x["steps"] else None
    return x["steps"].get(s)


def _print_steps(name: str, best: dict, trees: list[str], lo: int, hi: int) -> None:
    """The table of a case's steps on ``lo`` and ``hi`` cores per tree, and each step's share of
    the whole on ``lo`` cores in the last tree."""
    heads = " | ".join(f"{label} {lo} | {label} {hi} | {label} × (s)" for label in trees)
    print(f"\n{name}: steps (share = of the whole on {lo} core, {trees[-1]})\n\n| step | {heads} | share |")
    print("|---|" + "---|---|---|" * len(trees) + "---|")
    steps: list[str] = []
    for label in trees:
        steps += [s for s in best[(label, lo, name)]["steps"] if s not in steps]
    for s in steps + ["outside the steps", "whole"]:
        cells = []
        for label in trees:
            t1, t2 = _step_time(best[(label, lo, name)], s), _step_time(best[(label, hi, name)], s)
            cells.append("– | – | –" if t1 is None or t2 is None else
                         f"{t1 * 1e3:.0f} ms | {t2 * 1e3:.0f} ms | {t1 / t2:.2f} ({_serial(t1, t2, hi / lo):.2f})")
        last = best[(trees[-1], lo, name)]
        t1 = _step_time(last, s)
        share = "–" if t1 is None else f"{t1 / last['whole'] * 100:.0f} %"
        print(f"| {s} | " + " | ".join(cells) + f" | {share} |")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=None)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--pinned", action="store_true", help="pinned processes at --cores, per step (module doc)")
    parser.add_argument("--trees", nargs="+", default=[f"this={HERE.parents[1]}"], help="LABEL=PATH of each checkout")
    parser.add_argument("--cores", type=int, nargs=2, default=[1, 2])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cases", nargs="+", default=["ner", "nedner", "pair", "fft"], choices=CASES)
    parser.add_argument("--tv-scale", type=float, default=0.5)
    parser.add_argument("--timeout", type=float, default=1800.0, help="s per child process")
    parser.add_argument("--json", default=None, help="also write the raw numbers there")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tree", default=str(HERE.parents[1]), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args)
        return
    if not args.pinned:
        _threads_mode(args)
        return
    r = _pinned(args)
    _print_pinned(args, r)
    if args.json:
        Path(args.json).write_text(json.dumps({"loads": r["loads"], "trees": r["trees"],
                                               "best": {" ".join(map(str, k)): v for k, v in r["best"].items()}},
                                              indent=1))


if __name__ == "__main__":
    main()
