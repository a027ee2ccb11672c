"""Benchmark: sensor-mask generation with weights.

Prints the time to generate the paper's 226 x 226 equi-steradian mask (60 um pitch,
point of interest 3.6 mm above the centre, 1625 points requested) with its weights, its
ratio to the 1 s target, and, measured in the same run, the clipped-Voronoi weights of
the same positions at full accuracy and a complete plan (ordering + content id).

Run: .venv/bin/python benchmarks/bench_plans.py [--repeat 5]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def best_of(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times)), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    from fpscan.service.plans import Lattice, equisteradian_mask, make_plan
    from fpscan.service.plans.mask import default_weights

    lattice = Lattice(226, 226, 60e-6)
    equisteradian_mask(lattice, 3.6e-3, 1625)  # warm-up (imports, caches)
    t_mask, t_mask_med, mask = best_of(lambda: equisteradian_mask(lattice, 3.6e-3, 1625), args.repeat)
    t_vor, t_vor_med, w = best_of(lambda: default_weights(lattice, mask.positions), args.repeat)
    t_plan, t_plan_med, plan = best_of(lambda: make_plan(mask), args.repeat)

    print("equi-steradian mask, 226 x 226 lattice, 60 um pitch, r0 = 3.6 mm, 1625 requested")
    print(f"  points obtained            : {mask.obtained_points}  (paper: 1625)")
    print(f"  outer/inner weight ratio   : {mask.weight_ratio:.3f}  (paper: 9.7)")
    print(f"  mask + r^3 weights         : best {t_mask * 1e3:8.1f} ms   median {t_mask_med * 1e3:8.1f} ms")
    print(f"  ratio to the 1 s target    : {t_mask / 1.0:.3f}")
    print(f"  clipped Voronoi (1024/cell): best {t_vor * 1e3:8.1f} ms   ({t_vor / t_mask:.2f} x the mask)")
    print(f"  full plan (order + id)     : best {t_plan * 1e3:8.1f} ms   ({t_plan / t_mask:.2f} x the mask)")
    print(f"  Voronoi total / r^3 total  : {w.sum() / mask.weights.sum():.6f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
