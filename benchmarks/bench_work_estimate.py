"""The work admission's estimates against measured run times, as ratios.

For each method and size, the library call (``fpscan.service.pipeline.reconstruct``, the worker's
call) is timed (best of ``--repeat``, after one warm-up call) and divided by the method's work
estimate (``fpscan.service.jobs.admission.estimate_work``: seconds on the reference 2 cores). A ratio
of 1 is an exact estimate; above 1 the estimate is short, below 1 generous. tv runs a fixed
number of iterations (``tol = 0``) on a 15 % mask, so its estimate (which counts the
iterations asked for) is compared like for like. The load average is printed beside: the
estimates' rates were measured at load 4-6 on the reference machine (AMD EPYC Zen 4, 2 cores).

    .venv/bin/python benchmarks/bench_work_estimate.py [--repeat 2] [--tv-iterations 6]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from fpscan.service.jobs.admission import estimate_work, input_shape
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon.dataset import GridDataset

CASES = [  # (method, (n_t, n_y, n_x), options)
    ("ner", (256, 64, 64), {}), ("ner", (512, 128, 128), {}), ("ner", (256, 128, 128), {"upsample": 2}),
    ("ner", (512, 128, 128), {"dtype": "float64"}), ("nedner", (256, 128, 128), {}),
    ("nedner", (512, 128, 128), {}), ("linear", (512, 128, 128), {}), ("nearest", (512, 128, 128), {}),
    ("cubic", (256, 64, 64), {}), ("kwave", (512, 128, 128), {}), ("kwave", (1024, 96, 96), {}),
    ("ner", (256, 64, 64), {"sound_speed": "auto"}), ("tv", (256, 32, 32), {}), ("tv", (256, 64, 64), {}),
    ("tv", (384, 64, 64), {}),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--tv-iterations", type=int, default=6)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'method':8s} {'size':>14s} {'options':24s} {'measured s':>10s} {'estimate s':>10s} {'ratio':>6s}")
    for method, (n_t, n_y, n_x), options in CASES:
        data = rng.standard_normal((n_t, n_y, n_x)).astype(np.float32)
        ds = GridDataset(data, dx=1e-4, dt=1e-4 / 1500 / 2, sound_speed=1500.0, dy=1e-4)
        opts = dict(options)
        if method == "tv":
            points = ds.to_points()
            keep = rng.random(points.alines.shape[0]) < 0.15
            from dataclasses import replace

            ds = replace(points, alines=points.alines[keep], positions=points.positions[keep], weights=None)
            opts.update(max_iter=args.tv_iterations, tol=0.0)
        estimate = estimate_work(input_shape(ds), {"method": method, **opts})
        reconstruct(ds, method, **opts)  # warm: kernels compiled, pages faulted
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            reconstruct(ds, method, **opts)
            best = min(best, time.perf_counter() - t0)
        shown = ", ".join(f"{k}={v}" for k, v in options.items()) or "-"
        print(f"{method:8s} {f'{n_t}x{n_y}x{n_x}':>14s} {shown:24s} {best:10.3f} {estimate:10.3f} "
              f"{best / estimate:6.2f}", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
