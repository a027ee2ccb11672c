"""The automatic λ's calibration: tv's CC with the true p0 over a λ sweep on
the calibration cases, and the rule λ = a · s · max(1, (D₀ / knee)^p) that loses least in the
worst case (`fpscan.service.recon.tv`, module doc: s the image's noise level, D₀ the warm start's
discrepancy).

Cases (`bench_tv_solver.make_case`: 24 × 40 × 40 voxels of 50 µm, or 64 × 96 pixels in 2-D, exact
grid data with seeded white noise, float32, tv's default stopping rule):

- ``fit`` — the 30 cases the rule was fitted on: 3-D balls and vessel trees on equi-steradian
  masks of 53, 85 and 165 of the 1600 lattice points, and of 53 at a 100 µm lateral pitch;
  2-D lines of 24 of 96 sensors; 20, 30 and 40 dB; noise seed 0;
- ``unseen`` — 20 cases the fit never saw: masks of 53, 101 and 228 points and 2-D lines of 16
  and 32 sensors at 22 and 38 dB, masks of 84 and 164 points at 100 µm and 30 dB; seed 11.

Per case: s, D₀, the automatic λ's factor λ / s and iterations, and the CC at λ × 2^(k/2),
k = −6 … 6 (the automatic λ at k = 0), one JSON line each (``--out`` keeps them). Then, over
the cases: each candidate rule's λ is placed in the sweep (CC interpolated linearly in k) and
its loss against the sweep's best read off; printed are the present rule's worst and mean loss,
its worst cases, and the ten candidates (a on a 0.025 grid, knee, p) of least worst-case loss
on ``fit``, with their loss on ``unseen``. ``--from`` reads earlier JSON lines instead of
solving (a fit of measured sweeps takes seconds; the sweeps take about 15 minutes on 2 cores).

    .venv/bin/python benchmarks/bench_tv_lambda.py --out /tmp/lam.jsonl
    .venv/bin/python benchmarks/bench_tv_lambda.py --from /tmp/lam.jsonl
"""
from __future__ import annotations

import argparse
import json
import time
from multiprocessing import Pool

import numpy as np
from bench_tv_solver import DT, C, make_case

K = tuple(range(-6, 7))  # the sweep: λ × 2^(k/2)
AS = tuple(np.round(np.arange(0.2, 1.2001, 0.025), 3))
KNEES = (3.0, 5.0, 7.0, 9.5, 12.0, 15.0, 20.0, 30.0)
POWERS = (-0.75, -0.5, -0.375, -0.25, -0.125, 0.0, 0.125, 0.25, 0.375, 0.5)


def cases() -> list[tuple]:
    """(set, kind, dims, snr_db, points, seed, lateral) of every case."""
    out = []
    for kind in ("balls", "vessels"):
        for snr in (20.0, 30.0, 40.0):
            out.append(("fit", kind, 2, snr, 24, 0, 1.0))
            out += [("fit", kind, 3, snr, points, 0, 1.0) for points in (53, 85, 165)]
            out.append(("fit", kind, 3, snr, 53, 0, 2.0))
        for snr, sensors in ((22.0, 16), (38.0, 32)):
            out.append(("unseen", kind, 2, snr, sensors, 11, 1.0))
            out += [("unseen", kind, 3, snr, points, 11, 1.0) for points in (53, 101, 228)]
        out += [("unseen", kind, 3, 30.0, points, 11, 2.0) for points in (84, 164)]
    return out


def sweep(case: tuple) -> dict:
    """One case's sweep (module doc)."""
    from fpscan.service.metrics import correlation_coefficient
    from fpscan.service.recon.tv import reconstruct_tv

    which, kind, dims, snr, points, seed, lateral = case
    p0, alines, pos, kw = make_case(kind, dims, snr, points, seed, lateral=lateral)
    t = time.perf_counter()
    auto = reconstruct_tv(alines, DT, C, positions=pos, dtype=np.float32, **kw)
    p = auto.params
    ccs, its = {}, {}
    for k in K:
        r = auto if k == 0 else reconstruct_tv(alines, DT, C, positions=pos, dtype=np.float32,
                                               lam=p["lam"] * 2 ** (k / 2), **kw)
        ccs[k], its[k] = correlation_coefficient(r.p0, p0), r.params["iterations"]
    return dict(case=list(case), s=p["image_noise"], D0=p["warm_discrepancy"], lam=p["lam"],
                factor=p["lam_factor"], iterations=p["iterations"], converged=p["converged"],
                ccs={str(k): v for k, v in ccs.items()}, sweep_iterations={str(k): v for k, v in its.items()},
                wall_s=time.perf_counter() - t)


def losses(rows: list[dict], a: float, knee: float, power: float) -> np.ndarray:
    """Each case's CC lost at λ = a s max(1, (D₀ / knee)^power) against its sweep's best (1 where
    that λ falls outside the sweep)."""
    out = []
    for r in rows:
        lam = a * r["s"] * max(1.0, (r["D0"] / knee) ** power)
        k = 2 * np.log2(lam / r["lam"])
        cc = np.array([r["ccs"][str(j)] for j in K])
        out.append(float(cc.max() - np.interp(k, K, cc)) if K[0] <= k <= K[-1] else 1.0)
    return np.array(out)


def present_rule() -> tuple[float, float, float]:
    """(a, knee, p) of tv's automatic λ as it stands."""
    from fpscan.service.recon.tv import lam

    return (lam.LAM_SCALE, lam.LAM_KNEE, lam.LAM_POWER)


def report(rows: list[dict]) -> None:
    fit = [r for r in rows if r["case"][0] == "fit"]
    unseen = [r for r in rows if r["case"][0] == "unseen"]
    a, knee, power = present_rule()
    for name, part in (("fit", fit), ("unseen", unseen)):
        if not part:
            continue
        loss = losses(part, a, knee, power)
        its = [r["iterations"] for r in part]
        print(f"{name}: {len(part)} cases, the present rule (a {a}, knee {knee}, p {power}) loses at most "
              f"{loss.max():.4f} CC (mean {loss.mean():.4f}); iterations {min(its)}-{max(its)}, "
              f"converged {sum(r['converged'] for r in part)} of {len(part)}")
        for r, l in sorted(zip(part, loss), key=lambda t: -t[1])[:5]:
            best = max(r["ccs"], key=lambda j: r["ccs"][j])
            print(f"    {r['case'][1:]}: D0 {r['D0']:.1f}, lost {l:.4f}, best at x{2 ** (int(best) / 2):.2f}")
    if not fit:
        return
    found = sorted((float(loss.max()), float(loss.mean()), a, knee, p)
                   for a in AS for knee in KNEES for p in POWERS for loss in (losses(fit, a, knee, p),))
    print("the ten rules of least worst-case loss on fit (worst, mean; on unseen):")
    for worst, mean, a, knee, p in found[:10]:
        seen = losses(unseen, a, knee, p) if unseen else np.zeros(1)
        print(f"    a {a:.3f} knee {knee:g} p {p:g}: {worst:.4f}, {mean:.4f}; {seen.max():.4f}, {seen.mean():.4f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="also write the sweeps here, one JSON line per case")
    ap.add_argument("--from", dest="source", help="read the sweeps from here instead of solving")
    ap.add_argument("--sets", nargs="+", default=["fit", "unseen"], choices=["fit", "unseen"])
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args(argv)
    if args.source:
        with open(args.source) as f:
            rows = [json.loads(line) for line in f if line.strip()]
    else:
        todo = sorted((c for c in cases() if c[0] in args.sets), key=lambda c: (c[2] != 3, c[4]))  # slow ones first
        rows = []
        out = open(args.out, "w") if args.out else None
        try:
            with Pool(args.processes) as pool:
                for row in pool.imap_unordered(sweep, todo):
                    rows.append(row)
                    if out:
                        print(json.dumps(row), file=out, flush=True)
                    print(f"{row['case']}: factor {row['factor']:.2f}, D0 {row['D0']:.1f}, "
                          f"{row['iterations']} iterations, {row['wall_s']:.0f} s", flush=True)
        finally:
            if out:
                out.close()
    report(rows)


if __name__ == "__main__":
    main()
