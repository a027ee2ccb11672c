"""The model-based solver against one NEDNER of the same data.

For vessel (`fpscan.experiments.phantoms.vessel_phantom`) and ball phantoms, 2-D (a line of
``n_x`` sensors, 24 of them used, equiangular about the image's centre) and 3-D (a lattice,
an equi-steradian mask of about 10 %), exact grid data (`forward_grid`, pitch = dz = 50 µm,
dt = pitch / c) with seeded white noise ``--snr`` dB below the signal, this prints per case:

- NEDNER wall time (the warm start) and tv's at its defaults, and their ratio;
- tv's iterations, operator pairs (the power iterations included), whether the default rule
  converged, the stop reason, the residual against the noise share;
- CC with the true p0 of NEDNER and tv, and their least-squares amplitudes (argmin_a
  ‖img − a p0‖), with ``--debias`` also tv's after the least-squares refit;
- the automatic λ over the image's noise level and the warm start's discrepancy D₀ that
  sets it (`fpscan.service.recon.tv`, module doc);
- with ``--sweep``, tv's CC at λ ×1/8 … ×8 of the automatic one, the best factor and the CC
  lost at the automatic λ (target ≤ 0.01; docs/results.md's table);
- with ``--rule``, what the stopping rule's threshold buys: a 300-iteration
  solve at the automatic λ (and its distance to a 1000-iteration one), then for each ``tol``
  in `RULE_TOLS` (5e-3 is the default) the iterations and pairs to the rule, the relative
  distance ‖x − x₃₀₀‖ / ‖x₃₀₀‖ and the CC with the true p0, all at that λ.

    .venv/bin/python benchmarks/bench_tv_solver.py                   # 64x96 (2-D), 24x40x40 (3-D), 30 dB
    .venv/bin/python benchmarks/bench_tv_solver.py --snr 20 30 40 --debias
    .venv/bin/python benchmarks/bench_tv_solver.py --dims 3 --points 48 80 160 --snr 20 30 40 --sweep
    .venv/bin/python benchmarks/bench_tv_solver.py --rule --points 160 53     # the rule's threshold
    .venv/bin/python benchmarks/bench_tv_solver.py --dims 3 --kinds blobs vessels-flipped --points 48 160 \
        --snr 20 30 40 --seed 7 --poi 10 --sweep    # cases the automatic λ's calibration never saw

Small sizes only: the solver's iteration counts are the point; `bench_tv_operator.py` times
the operator pair at large sizes. Times exclude compilation (one run of each first).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

C, PITCH = 1500.0, 50e-6
DT = PITCH / C


SWEEP = (1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0, 8.0)
RULE_TOLS = (5e-3, 2e-3, 1e-3, 5e-4, 2e-4)  # the stopping rule's thresholds of --rule (5e-3: tv's default)


def _blobs(shape, seed: int) -> np.ndarray:
    """Five Gaussian blobs (σ 1-3 voxels, amplitudes 0.4-1) at seeded places: smooth
    sources, unlike the balls' sharp edges and the vessels' tubes (a phantom the automatic λ
    was not calibrated on)."""
    rng = np.random.default_rng(seed)
    grids = np.meshgrid(*[np.arange(n, dtype=float) for n in shape], indexing="ij")
    p0 = np.zeros(shape)
    for _ in range(5):
        centre = [rng.uniform(0.25 * n, 0.75 * n) for n in shape]
        width = rng.uniform(1.0, 3.0)
        r2 = sum((g - c) ** 2 for g, c in zip(grids, centre))
        p0 += rng.uniform(0.4, 1.0) * np.exp(-r2 / (2 * width**2))
    return p0


def make_case(kind: str, dims: int, snr_db: float, points: int = 160, seed: int = 0, poi: float = 12.0,
          lateral: float = 1.0):
    """Phantom, A-lines, sensor positions and tv's keywords of one case: ``points`` sensors of
    the 3-D mask (2-D: of the line; 0: 24), lateral pitch ``lateral`` × 50 µm (depth 50 µm)."""
    from fpscan.experiments.phantoms import vessel_phantom
    from fpscan.physics import Ball, ball_p0
    from fpscan.physics.forward import forward_grid
    from fpscan.service.plans import Lattice, equiangular_mask, equisteradian_mask

    if dims == 2:
        n_z, n = 64, 96
        shape: tuple[int, ...] = (n_z, n)
    else:
        n_z, n = 24, 40
        shape = (n_z, n, n)
    px = PITCH * lateral
    x = (np.arange(n) - (n - 1) / 2) * px
    z = np.arange(n_z) * PITCH
    if kind == "vessels":
        p0 = vessel_phantom(shape)
    elif kind == "vessels-flipped":  # the tree mirrored laterally, two voxels deeper
        p0 = np.roll(vessel_phantom(shape)[(slice(None),) + (slice(None, None, -1),) * (dims - 1)], 2, axis=0)
    elif kind == "blobs":
        p0 = _blobs(shape, 47 + seed)
    elif dims == 2:
        p0 = ball_p0([Ball(-12 * PITCH, 0, 30 * PITCH, 8 * PITCH), Ball(14 * PITCH, 0, 22 * PITCH, 5 * PITCH, 0.7),
                      Ball(2 * PITCH, 0, 45 * PITCH, 4 * PITCH, 0.5)], z, x, supersample=2)
    else:
        p0 = ball_p0([Ball(0.0, 0.0, 12 * PITCH, 4 * px), Ball(7 * px, -5 * px, 16 * PITCH, 3 * px, 0.7),
                      Ball(-8 * px, 4 * px, 9 * PITCH, 2.5 * px, 0.5)], z, x, x, supersample=2)
    n_t = int(np.hypot(n_z, lateral * (n if dims == 2 else n / np.sqrt(2)))) + 8
    clean = forward_grid(p0, px, PITCH, DT, n_t, C)
    rng = np.random.default_rng(seed)
    g = clean + rng.standard_normal(clean.shape) * float(np.sqrt(np.mean(clean**2))) / 10 ** (snr_db / 20)
    if dims == 2:
        mask = equiangular_mask(Lattice(n, 1, px), n_z * PITCH / 2, points or 24)
        idx = np.asarray(mask.indices)[:, 0]
        alines, pos, grid = g[:, idx].T, np.asarray(mask.positions, float)[:, :1], (x,)
    else:
        mask = equisteradian_mask(Lattice(n, n, px), poi * PITCH, points)
        ix, iy = np.asarray(mask.indices).T
        alines, pos, grid = g[:, iy, ix].T, np.asarray(mask.positions, float)[:, :2], (x, x)
    kw = dict(weights=np.asarray(mask.weights, float), grid=grid, n_z=n_z, dz=PITCH)
    return p0, alines, pos, kw


def run(kind: str, dims: int, snr_db: float, debias: bool, points: int = 160, sweep: bool = False, seed: int = 0,
        poi: float = 12.0, rule: bool = False) -> str:
    from fpscan.service.metrics import correlation_coefficient
    from fpscan.service.recon import reconstruct_points
    from fpscan.service.recon.tv import reconstruct_tv

    p0, alines, pos, kw = make_case(kind, dims, snr_db, points, seed, poi)
    amp = lambda img: float(np.vdot(img, p0) / np.vdot(p0, p0))
    reconstruct_tv(alines, DT, C, positions=pos, max_iter=2, **kw)  # compile
    t = time.perf_counter()
    ned = reconstruct_points(alines, pos, DT, C, **kw).p0
    t_ned = time.perf_counter() - t
    t = time.perf_counter()
    tv = reconstruct_tv(alines, DT, C, positions=pos, **kw)
    t_tv = time.perf_counter() - t
    p = tv.params
    where = "" if dims == 2 else f" {len(alines)} points"
    row = (f"{dims}-D {kind:7s}{where} {snr_db:4.0f} dB  NEDNER {t_ned:6.3f} s  tv {t_tv:6.2f} s  tv/NEDNER {t_tv / t_ned:6.0f}"
           f"  λ {p['lam_factor']:.2f} x the noise level"
           f" (warm start's discrepancy {p['warm_discrepancy']:.1f})"
           f"  iterations {p['iterations']:3d}  pairs {p['operator_pairs']:5.1f}  converged {p['converged']!s:5s}"
           f" ({p['stop_reason']})  residual {p['residual']:.3f} (noise {p['noise_share']:.3f})"
           f"  CC NEDNER {correlation_coefficient(ned, p0):.4f} tv {correlation_coefficient(tv.p0, p0):.4f}"
           f"  amplitude NEDNER {amp(ned):.3f} tv {amp(tv.p0):.3f}")
    if debias:
        refit = reconstruct_tv(alines, DT, C, positions=pos, debias=True, **kw)
        row += f" debiased {amp(refit.p0):.3f} (CC {correlation_coefficient(refit.p0, p0):.4f})"
    if sweep:
        ccs = {f: correlation_coefficient(tv.p0 if f == 1.0 else
                                          reconstruct_tv(alines, DT, C, positions=pos, lam=f * p["lam"], **kw).p0, p0)
               for f in SWEEP}
        best = max(ccs, key=lambda f: ccs[f])
        row += (f"  λ sweep {' '.join(f'x{f:g} {cc:.4f}' for f, cc in ccs.items())}: best x{best:g},"
                f" lost at the automatic λ {ccs[best] - ccs[1.0]:.4f}")
    if rule:
        def solve(**opts):
            return reconstruct_tv(alines, DT, C, positions=pos, lam=p["lam"], **kw, **opts)

        long = solve(max_iter=300, tol=0.0).p0
        longer = solve(max_iter=1000, tol=0.0).p0
        size = float(np.linalg.norm(long))
        row += (f"\n    300 iterations: CC {correlation_coefficient(long, p0):.4f},"
                f" {np.linalg.norm(long - longer) / np.linalg.norm(longer):.4f} from 1000 iterations")
        for tol in RULE_TOLS:
            r = solve(tol=tol, max_iter=300)
            q = r.params
            row += (f"\n    tol {tol:g}: iterations {q['iterations']:3d} pairs {q['operator_pairs']:5.1f}"
                    f" ({q['stop_reason']})  distance to the 300-iteration image {np.linalg.norm(r.p0 - long) / size:.4f}"
                    f"  CC {correlation_coefficient(r.p0, p0):.4f}")
    return row


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--snr", type=float, nargs="+", default=[30.0], help="noise levels, dB below the signal")
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3], choices=[2, 3])
    ap.add_argument("--kinds", nargs="+", default=["vessels", "balls"],
                    choices=["vessels", "balls", "vessels-flipped", "blobs"],
                    help="phantoms; vessels-flipped and blobs were not in the automatic λ's calibration")
    ap.add_argument("--seed", type=int, default=0, help="noise seed (and the blobs' places)")
    ap.add_argument("--poi", type=float, default=12.0, help="3-D: the mask's point of interest, depth in pitches")
    ap.add_argument("--debias", action="store_true", help="also the least-squares refit's amplitude")
    ap.add_argument("--points", type=int, nargs="+", default=[160],
                    help="3-D: sensors of the equi-steradian mask, of the 1600 lattice points")
    ap.add_argument("--sweep", action="store_true", help="also the λ sweep x1/8 .. x8 of the automatic λ")
    ap.add_argument("--rule", action="store_true",
                    help="also the stopping rule's thresholds against a 300-iteration solve (slow)")
    args = ap.parse_args(argv)
    for dims in args.dims:
        for kind in args.kinds:
            for snr in args.snr:
                for points in (args.points if dims == 3 else [0]):
                    print(run(kind, dims, snr, args.debias, points, args.sweep, args.seed, args.poi, args.rule),
                          flush=True)


if __name__ == "__main__":
    main()
