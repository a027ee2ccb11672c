"""tv against pyproximal's PrimalDual on tv's own problem: J and CC per operator pair, and the
time per iteration of each, from one run.

The problem is `fpscan.tv_problem`'s (tv's operator A, record g, warm start, grid and automatic
λ) for the vessel tree of ``bench_tv_matrix`` (k-Wave, 64 × 96², 60 µm) at ``--mask`` % of its
lattice (equi-steradian) and ``--noise`` (default 11 % and 30 dB below the peak: the quality
gate's row), float32, on the phantom's depth grid (``dz``, ``n_z``), as the gate runs tv.

- **tv**: `reconstruct_tv` with the method's defaults but ``tol`` 0 and ``--iterations``; its
  ``callback`` gives J(x_k) (exact and free: tv computes A x anyway) and the image for its CC.
- **PrimalDual** (Chambolle & Pock 2011; pyproximal): K = [A; ∇] (``problem.gradient``),
  f = positivity (``Box(lower=0)``), g(K p) = ½‖A p − g‖² + λ‖∇p‖₂,₁ (``L2(b=g)``, ``L21``),
  from the warm start, θ = 1, τ μ ‖K‖² = 0.99 (‖K‖² ≤ ‖A‖² + 4 d, ‖A‖ from ``--power`` power
  iterations); the ratio τ / μ tuned over ``--ratios`` on ``--tune-iterations`` iterations (the
  lowest J), then run to ``--iterations``. CC every iteration; J at the rows printed (one more
  forward each, outside the timed iterations).

Operator pairs: 3 before the first iteration (tv's warm start's A, its step's two power
iterations and the noise image: `fpscan.tv_problem` makes them, and both solvers start from
them), then one per iteration of either solver. Time per iteration: the iterations' wall time
less the callbacks', over the iterations after the first.

``--timing ROUNDS`` measures the time per iteration alone, in turns (the load of a shared machine
drifts): ROUNDS rounds of a tv run of ``--block`` iterations at tol 0 (its preconditioned phase,
then its exact phase) and ``--block`` / 3 PrimalDual iterations; per round the medians of the
iterations' wall and CPU times (the process's, all threads), then tv's over PrimalDual's,
medians over the rounds. docs/tv-measurements.md, "What tv minimises", holds the figures.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_tv_primaldual.py [--mask 11] [--noise peak30]
        [--iterations 300] [--ratios 100 300 1000 3000 10000 | --ratio R] [--tune-iterations 30]
        [--skip-tv] [--skip-primaldual] [--json out.json]
    PYTHONPATH=. .venv/bin/python benchmarks/bench_tv_primaldual.py --timing 6 --block 90 --ratio 300
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: the rows printed: operator pairs (3 before the first iteration)
ROWS = (13, 23, 33, 45, 63, 93, 123, 183, 243, 303)
#: operator pairs before the first iteration (module doc)
SETUP_PAIRS = 3


def vessel_scan(percent: int, noise: str, seed: int = 0):
    """The vessel tree's sparse scan as ``bench_tv_matrix`` makes it: (PointDataset, p0, grid options)."""
    from bench_tv_matrix import load_case, make_mask, noisy

    import fpscan
    from fpscan.physics.axes import centred_axis

    case = load_case("vessels")
    data = noisy(case["clean"], noise, seed)
    mask = make_mask(case, percent)
    ix = np.asarray(mask.indices)
    alines = data[:, ix[:, 1], ix[:, 0]].T
    n_y, n_x = data.shape[1:]
    axes = (centred_axis(n_x, case["dx"]), centred_axis(n_y, case["dx"]))
    scan = fpscan.PointDataset(alines=alines, positions=np.asarray(mask.positions, float)[:, :2], dt=case["dt"],
                               sound_speed=case["c"], weights=np.asarray(mask.weights, float), grid=axes)
    return scan, case["p0"], {"dz": case["dz"], "n_z": case["p0"].shape[0]}


class Trace:
    """Per-iteration J, CC and the time outside the callback."""

    def __init__(self, p0: np.ndarray, objective=None, rows=()):
        self.p0, self.objective, self.rows = p0, objective, set(rows)
        self.J: dict[int, float] = {}
        self.cc: list[float] = []
        self.stamps: list[float] = []
        self.cpu: list[float] = []
        self.spent = 0.0
        self.spent_cpu = 0.0

    def __call__(self, k: int, x: np.ndarray, J: float | None = None) -> None:
        from fpscan import correlation_coefficient

        t, c = time.perf_counter(), time.process_time()
        self.stamps.append(t - self.spent)
        self.cpu.append(c - self.spent_cpu)
        image = np.asarray(x).reshape(self.p0.shape)
        self.cc.append(correlation_coefficient(image, self.p0))
        if J is not None:
            self.J[k] = float(J)
        elif self.objective is not None and (SETUP_PAIRS + k) in self.rows:
            self.J[k] = self.objective(image)
        self.spent += time.perf_counter() - t
        self.spent_cpu += time.process_time() - c

    def per_iteration(self) -> float:
        s = self.stamps
        return (s[-1] - s[0]) / (len(s) - 1) if len(s) > 1 else math.nan

    def steps(self, first: int = 2, last: int | None = None, cpu: bool = False) -> list[float]:
        """The wall (or the process's CPU) times of iterations ``first`` .. ``last`` (1-based;
        callbacks excluded), s."""
        d = np.diff(self.cpu if cpu else self.stamps)  # d[i]: iteration i + 2
        return [float(v) for v in d[max(first, 2) - 2: None if last is None else last - 1]]


def run_tv(scan, pb, p0, grid_opts, iterations: int) -> Trace:
    from fpscan.service.recon.methods.tv import Options, problem_arguments
    from fpscan.service.recon.tv.reconstruct import reconstruct_tv

    trace = Trace(p0)
    args = problem_arguments(scan, scan.sound_speed, Options(dtype="float32", **grid_opts))
    rec = reconstruct_tv(**args, max_iter=iterations, tol=0.0, device="cpu", callback=trace)
    assert rec.params["lam"] == pb.lam, (rec.params["lam"], pb.lam)
    trace.final = rec.p0  # type: ignore[attr-defined]
    trace.exact_from = rec.params["exact_from"]  # type: ignore[attr-defined]
    return trace


def operator_norm(A, steps: int) -> float:
    x = np.random.default_rng(0).standard_normal(A.shape[1]).astype(A.dtype)
    s = 0.0
    for _ in range(steps):
        y = A.rmatvec(A.matvec(x))
        s = float(np.linalg.norm(y))
        x = (y / s).astype(A.dtype)
    return math.sqrt(s)


def run_primaldual(pb, p0, ratio: float, iterations: int, norm_k: float, rows=()) -> Trace:
    import pylops
    import pyproximal
    from pyproximal.optimization.primaldual import PrimalDual

    K = pylops.VStack([pb.operator, pb.gradient])
    n_data = pb.data.size
    g = pyproximal.VStack([pyproximal.L2(b=pb.data.ravel().astype(pb.operator.dtype)),
                           pyproximal.L21(ndim=len(pb.operator.dims), sigma=pb.lam)],
                          nn=[n_data, K.shape[0] - n_data])
    f = pyproximal.Box(lower=0.0) if pb.positivity else pyproximal.Box()
    tau = math.sqrt(0.99 * ratio) / norm_k
    mu = math.sqrt(0.99 / ratio) / norm_k
    trace = Trace(p0, pb.objective, rows)
    count = [0]

    def callback(x):
        count[0] += 1
        trace(count[0], x)

    x = PrimalDual(f, g, K, x0=pb.warm_start.ravel().copy(), tau=tau, mu=mu, theta=1.0, niter=iterations,
                   callback=callback)
    trace.final = x.reshape(p0.shape)  # type: ignore[attr-defined]
    if iterations not in trace.J:
        trace.J[iterations] = pb.objective(trace.final)
    return trace


def print_rows(out: dict, pd: Trace | None, iterations: int) -> None:
    """The table: J and CC per operator pair (`ROWS`), and the times per iteration."""
    print("\n| pairs | iterations | tv J | tv CC | PrimalDual J | PrimalDual CC |\n|---|---|---|---|---|---|")
    for pairs in ROWS:
        k = pairs - SETUP_PAIRS
        if k > iterations:
            break
        tv_j = f"{out['tv']['J'][k]:.6g}" if "tv" in out else ""
        tv_cc = f"{out['tv']['cc'][k - 1]:.4f}" if "tv" in out else ""
        pd_j = f"{pd.J[k]:.6g}" if pd is not None and k in pd.J else ""
        pd_cc = f"{pd.cc[k - 1]:.4f}" if pd is not None else ""
        print(f"| {pairs} | {k} | {tv_j} | {tv_cc} | {pd_j} | {pd_cc} |")
    if "tv" in out and pd is not None:
        print(f"\ntime per iteration: tv {out['tv']['per_iteration']:.3f} s, PrimalDual {pd.per_iteration():.3f} s "
              f"(tv / PrimalDual = {out['tv']['per_iteration'] / pd.per_iteration():.3f})")


def timing(scan, pb, p0, grid_opts, norm_k: float, args) -> None:
    """Time per iteration of each, in turns (the load of a shared machine drifts): ``args.timing``
    rounds of a tv run of ``args.block`` iterations (tol 0: its preconditioned phase, then its exact
    phase) and ``args.block`` // 3 iterations of PrimalDual. Per round the medians of the
    iterations' wall and CPU (the process's, all threads) times, tv's per phase; then the medians
    over the rounds of tv's over PrimalDual's."""
    ratios: dict[str, list[float]] = {"wall": [], "wall exact": [], "cpu": [], "cpu exact": []}
    for r in range(args.timing):
        tv = run_tv(scan, pb, p0, grid_opts, args.block)
        pd = run_primaldual(pb, p0, args.ratio or 1000.0, max(args.block // 3, 3), norm_k)
        switch = tv.exact_from or args.block + 1
        line = []
        for cpu in (False, True):
            pre = float(np.median(tv.steps(2, switch - 1, cpu)))
            exact = float(np.median(tv.steps(switch + 1, None, cpu))) if switch < args.block else math.nan
            other = float(np.median(pd.steps(cpu=cpu)))
            kind = "cpu" if cpu else "wall"
            ratios[kind].append(pre / other)
            ratios[kind + " exact"].append(exact / other)
            line.append(f"{kind}: tv {pre:.3f} s, its exact phase {exact:.3f} s, PrimalDual {other:.3f} s")
        print(f"  round {r + 1} (exact phase from {tv.exact_from}): " + "; ".join(line), flush=True)
    print("tv / PrimalDual, time per iteration (medians over the rounds): " + ", ".join(
        f"{k} {float(np.median(v)):.3f}" for k, v in ratios.items()))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mask", type=int, default=11)
    parser.add_argument("--noise", default="peak30")
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--ratios", type=float, nargs="+", default=[100.0, 300.0, 1000.0, 3000.0, 10000.0])
    parser.add_argument("--tune-iterations", type=int, default=30)
    parser.add_argument("--power", type=int, default=12)
    parser.add_argument("--skip-tv", action="store_true")
    parser.add_argument("--skip-primaldual", action="store_true")
    parser.add_argument("--ratio", type=float, help="PrimalDual's τ/μ (no tuning)")
    parser.add_argument("--timing", type=int, default=0, metavar="ROUNDS",
                        help="time per iteration only: ROUNDS rounds of --block iterations of each, in turn")
    parser.add_argument("--block", type=int, default=60)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    import fpscan

    scan, p0, grid_opts = vessel_scan(args.mask, args.noise)
    t = time.perf_counter()
    pb = fpscan.tv_problem(scan, dtype="float32", **grid_opts)
    print(f"problem: {time.perf_counter() - t:.1f} s, image {pb.operator.dims}, data {pb.data.shape}, "
          f"λ = {pb.lam:.6g}, J(warm) = {pb.objective(pb.warm_start):.6g}, "
          f"CC(warm) = {fpscan.correlation_coefficient(pb.warm_start, p0):.4f}", flush=True)
    out: dict = dict(mask=args.mask, noise=args.noise, lam=pb.lam, iterations=args.iterations)
    if not args.skip_tv and not args.timing:
        tv = run_tv(scan, pb, p0, grid_opts, args.iterations)
        out["tv"] = dict(J=tv.J, cc=tv.cc, per_iteration=tv.per_iteration())
        print(f"tv: {tv.per_iteration():.3f} s per iteration, J({args.iterations}) = {tv.J[args.iterations]:.6g} "
              f"(problem's objective: {pb.objective(tv.final):.6g})", flush=True)
    norm_a = operator_norm(pb.operator, args.power)
    norm_k = math.sqrt(norm_a ** 2 + 4 * len(pb.operator.dims))
    print(f"‖A‖ ≈ {norm_a:.6g}, ‖K‖ ≤ {norm_k:.6g}", flush=True)
    if args.timing:
        timing(scan, pb, p0, grid_opts, norm_k, args)
        return
    if args.skip_primaldual:
        print_rows(out, None, args.iterations)
        if args.json:
            args.json.write_text(json.dumps(out, default=float))
        return
    tuning = {}
    for ratio in [] if args.ratio else args.ratios:
        tr = run_primaldual(pb, p0, ratio, args.tune_iterations, norm_k)
        tuning[ratio] = tr.J[args.tune_iterations]
        print(f"  PrimalDual τ/μ = {ratio:g}: J({args.tune_iterations}) = {tuning[ratio]:.6g}, "
              f"CC {tr.cc[-1]:.4f}, {tr.per_iteration():.3f} s per iteration", flush=True)
    best = args.ratio or min(tuning, key=tuning.get)
    pd = run_primaldual(pb, p0, best, args.iterations, norm_k, ROWS)
    out["primaldual"] = dict(ratio=best, tuning=tuning, J=pd.J, cc=pd.cc, per_iteration=pd.per_iteration())
    print(f"PrimalDual τ/μ = {best:g}: {pd.per_iteration():.3f} s per iteration", flush=True)
    print_rows(out, pd, args.iterations)
    if args.json:
        args.json.write_text(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
