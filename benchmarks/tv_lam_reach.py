"""tv's λ against how far its proximal step reaches: ρ = λ / (L max x₀) per row of the quality gate.

Each of tv's iterations takes a proximal step of λ TV / L (`fpscan.service.recon.tv.fista`), so ρ is
that step's weight relative to the warm start's peak x₀ (NER's image on tv's grid, Pa): how far TV
can reshape the image per iteration. Printed beside it: ρ of the noise-level rule's λ alone (below
tv's reach floor, 3e-4, where that floor set λ), λ / s (the automatic λ's factor of the image's
noise level s) and D₀ (the warm start's discrepancy in noise norms), the rule's inputs
(`fpscan.service.recon.tv.lam`). The set-up only (`fpscan.tv_problem`: the warm start and the
gain estimate), no solve: seconds per row.

docs/results.md ("tv's quality gate", the automatic λ) sets ρ beside the best λ of each row's sweep
(`bench_tv_matrix.py --sweep`).

    .venv/bin/python benchmarks/tv_lam_reach.py vessels:4:rms30 paper:11:peak30 family-05 ...

A row is ``case:mask:noise`` (a case of `bench_tv_matrix`), a family member's name (its own mask
and noise), or ``solver-KIND:POINTS:SNR``, a 3-D case of `bench_tv_solver` (fpscan's own phantoms on
24 × 40² voxels of 50 µm: KIND vessels or balls, POINTS sensors of the 1600, SNR dB below the RMS).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_tv_matrix as matrix


def described(problem, case: str, mask: int, noise: str, seed: int) -> dict:
    """ρ, λ, L · max x₀, λ / s and D₀ of a row's `TvProblem` (module doc), and ρ of the noise-level
    rule's λ alone (``rho_noise``: below the reach floor where it set λ, ``floored``;
    `fpscan.service.recon.tv.lam.REACH_FLOOR`)."""
    p = problem.params
    unit = p["reach_unit"]  # L · max x₀
    return dict(case=case, mask=mask, noise=noise, seed=seed, lam=problem.lam, reach_unit=unit,
                rho=p["prox_reach"], rho_noise=p["lam_noise_level"] / unit, floored=p["lam_floored"],
                lam_factor=p["lam_factor"], warm_discrepancy=p["warm_discrepancy"])


def reach(name: str, percent: int, noise: str, seed: int = 0) -> dict:
    """`described` of one row of `bench_tv_matrix` (module doc)."""
    from fpscan import tv_problem

    case = matrix.load_case(name)
    _, scan = matrix.sparse_scan(case, matrix.make_mask(case, percent), noise, seed, {})
    grid_opts = {} if case["p0"] is None else {"dz": case["dz"], "n_z": case["p0"].shape[0]}
    return described(tv_problem(scan, dtype="float32", **grid_opts), name, percent, noise, seed)


def solver_reach(kind: str, points: int, snr_db: float, seed: int = 0) -> dict:
    """`described` of a 3-D case of `bench_tv_solver` (module doc)."""
    import bench_tv_solver as solver

    from fpscan.service.recon.tv.reconstruct import tv_problem

    _, alines, positions, options = solver.make_case(kind, 3, snr_db, points, seed)
    problem = tv_problem(alines, solver.DT, solver.C, positions=positions, **options)
    return described(problem, f"solver-{kind}", points, f"rms{snr_db:g}", seed)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="case:mask:noise or a family member (family-05)")
    ap.add_argument("--seed", type=int, default=0, help="the noise's seed")
    ap.add_argument("--json", action="store_true", help="one JSON line per row instead of the table")
    args = ap.parse_args(argv)
    if not args.json:
        print("| row | ρ = λ / (L max x₀) | ρ of the noise-level λ | λ / s | D₀ |\n|---|---|---|---|---|")
    for spec in args.rows:
        if spec.startswith("solver-"):
            kind, points, snr = spec.removeprefix("solver-").split(":")
            r = solver_reach(kind, int(points), float(snr), args.seed)
            name, percent, noise = r["case"], r["mask"], r["noise"]
            print(json.dumps(r) if args.json else
                  f"| {name}, {percent} points, {noise} | {r['rho']:.2e} | {r['rho_noise']:.2e} | {r['lam_factor']:.2f} | "
                  f"{r['warm_discrepancy']:.1f} |", flush=True)
            continue
        if spec.startswith("family"):
            family = matrix._family()
            percent, noise = family.member_scan(*family.member(spec))
            name = spec
        else:
            name, mask, noise = spec.split(":")
            percent = int(mask)
        r = reach(name, percent, noise, args.seed)
        print(json.dumps(r) if args.json else
              f"| {name}, {percent} %, {noise} | {r['rho']:.2e} | {r['rho_noise']:.2e} | {r['lam_factor']:.2f} | "
              f"{r['warm_discrepancy']:.1f} |",
              flush=True)


if __name__ == "__main__":
    main()
