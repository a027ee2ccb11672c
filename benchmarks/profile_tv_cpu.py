"""Where tv's time goes on the CPU: cProfile of one tv run on the paper's scan (bench_tv_paper's
case, ``--scale``), float32, every core, the 25 functions with the most time of their own — to find
what keeps tv from scaling with cores (bench_gpu.py's one-core rows).

    python benchmarks/profile_tv_cpu.py [--scale 0.5] [--top 25]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_tv_paper import DT, C, paper_case


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args(argv)
    from fpscan.service.recon.tv import reconstruct_tv

    case = paper_case(args.scale)
    kw = dict(positions=case["positions"], weights=case["weights"], grid=case["grid"], dtype=np.float32,
              device="cpu")
    reconstruct_tv(case["alines"][:40, :32], DT, C, positions=case["positions"][:40], n_z=8, max_iter=2,
                   dtype=np.float32, device="cpu")  # compiled kernels
    profile = cProfile.Profile()
    t = time.perf_counter()
    profile.enable()
    rec = reconstruct_tv(case["alines"], DT, C, **kw)
    profile.disable()
    wall = time.perf_counter() - t
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats("tottime").print_stats(args.top)
    print(f"tv at x{args.scale:g}: {wall:.2f} s, {rec.params['operator_pairs']:.1f} pairs, image {rec.p0.shape}")
    print("\n".join(line for line in out.getvalue().splitlines() if line.strip())[:6000])


if __name__ == "__main__":
    main()
