"""Spectral benchmarks: autofocus cost and unmixing throughput.

1. Sound-speed autofocus (``c="auto"``) on the k-Wave 3-D reference data
   (``$FPSCAN_SHARED/data/kwave3d_balls_yarn.h5``, 96 × 96 sensors, 751 samples) and on a
   simulated ball phantom (128 × 128 sensors, 1024 samples, c = 1480 m/s): the search
   time as a ratio to ONE reconstruction of the same data with the same method (target
   ≤ 4×), and the c found.
2. Unmixing (closed-form NNLS, :func:`fpscan.service.recon.unmix.unmix`) of a 226 × 226 × 512
   two-wavelength float32 volume: time per voxel, and the speed-up over calling
   ``scipy.optimize.nnls`` voxel by voxel (measured on 20 000 voxels).

Prints ratios and per-voxel times only; no assertions.

    .venv/bin/python benchmarks/bench_spectral.py [--skip-kwave] [--side 128]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from fpscan.physics.axes import centred_axis

#: the k-Wave reference files: $FPSCAN_SHARED/data, by default the shared folder beside the checkout
SHARED = Path(os.environ.get("FPSCAN_SHARED", Path(__file__).resolve().parents[1].parent / "shared")) / "data"


def _timed(f, *args, **kwargs):
    t = time.perf_counter()
    out = f(*args, **kwargs)
    return out, time.perf_counter() - t


def bench_autofocus(name: str, ds, c_true: float) -> None:
    from fpscan.service import pipeline

    method = pipeline.default_method(ds)
    pipeline.reconstruct(ds, method, sound_speed=1500.0)  # warm-up (compilation, FFT plans)
    _, t_one = _timed(pipeline.reconstruct, ds, method, sound_speed=1500.0)
    rec, t_auto = _timed(pipeline.reconstruct, ds, method, c="auto")
    af = rec.params["autofocus"]
    print(f"autofocus {name}: one reconstruction {t_one:.2f} s; c='auto' total {t_auto:.2f} s "
          f"(search {af['time_s']:.2f} s = {af['time_s'] / t_one:.2f}x one reconstruction, "
          f"search + final = {t_auto / t_one:.2f}x); c = {af['c']:.2f} m/s "
          f"(truth {c_true:g}, error {100 * (af['c'] - c_true) / c_true:+.3f} %), "
          f"{af['evaluations']} evaluations at decimation {af['decimation']}")


def bench_unmix() -> None:
    from scipy.optimize import nnls

    from fpscan.physics import spectra
    from fpscan.service.recon.unmix import endmember_matrix, unmix

    w = [750e-9, 850e-9]
    shape = (512, 226, 226)
    rng = np.random.default_rng(0)
    so2 = rng.uniform(0, 1, shape[1:]).astype(np.float32)
    mua = spectra.absorption(w, so2, 1.0).astype(np.float32)  # (2, 226, 226)
    vol = np.empty((2, *shape), dtype=np.float32)
    vol[:] = mua[:, None]
    vol += 0.01 * rng.standard_normal(vol.shape, dtype=np.float32)
    n = int(np.prod(shape))
    _, t = _timed(unmix, vol, w)
    A = endmember_matrix(w)
    Y = vol.reshape(2, -1)[:, :20000].astype(np.float64)
    _, t_ref = _timed(lambda: [nnls(A, Y[:, j]) for j in range(Y.shape[1])])
    print(f"unmix 226x226x512 x 2 wavelengths: {t:.2f} s = {1e9 * t / n:.1f} ns/voxel; "
          f"scipy.optimize.nnls per voxel: {1e9 * t_ref / Y.shape[1]:.0f} ns/voxel "
          f"({t_ref / Y.shape[1] / (t / n):.0f}x slower)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-kwave", action="store_true")
    ap.add_argument("--side", type=int, default=128, help="simulated sensor grid side")
    args = ap.parse_args()

    from fpscan.physics import Ball, ball_alines
    from fpscan.service.storage.loader import GridDataset, load_dataset

    path = SHARED / "kwave3d_balls_yarn.h5"
    if not args.skip_kwave and path.is_file():
        bench_autofocus("k-Wave 3-D 96x96x751", load_dataset(path), 1500.0)
    n, dx, dt, n_t = args.side, 60e-6, 10e-9, 1024
    x = centred_axis(n, dx)
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    rng = np.random.default_rng(1)
    balls = [Ball(float(bx), float(by), float(bz), float(r)) for bx, by, bz, r in
             zip(rng.uniform(-2e-3, 2e-3, 8), rng.uniform(-2e-3, 2e-3, 8), rng.uniform(1.5e-3, 6e-3, 8),
                 rng.uniform(80e-6, 200e-6, 8), strict=True)]
    data = ball_alines(pos, balls, dt, n_t, 1480.0).T.reshape(n_t, n, n).astype(np.float32)
    data += 0.01 * np.abs(data).max() * rng.standard_normal(data.shape, dtype=np.float32)
    bench_autofocus(f"simulated balls {n}x{n}x{n_t}", GridDataset(data, dx, dt, 1500.0, dy=dx), 1480.0)
    bench_unmix()


if __name__ == "__main__":
    main()
