"""How NER's CPU parts scale with cores (beside bench_gpu.py's one-core rows): the memory bandwidth's own
scaling beside them, to tell a serial part from a bandwidth floor.

At the paper's NER size (bench_gpu's: 1024 samples on the 240² transform grid, float32), for each
thread count k in ``--threads``, best of ``--repeat``:

- ``triad``: a = b + s c over three float32 arrays of the temporal fine grid's size, a numba
  ``prange`` loop at k threads: the memory bandwidth the cores share (a STREAM triad);
- ``temporal FFT``: ``scipy.fft.fft`` of the fine temporal grid (n_cols × L complex64), workers=k;
- ``interp``: NER's temporal NUFFT evaluation (`fpscan.physics.nufft.evaluate`, the compiled
  kernel) at k numba threads;
- ``NER``: the whole `reconstruct_grid` float32 at k numba threads (its FFTs always ask for every
  core: ``workers=-1``), for reference.

Each row prints its time and speed-up over one thread.

    python benchmarks/bench_cpu_scaling.py [--threads 1 2 4 8 16] [--repeat 3] [--scale 1]
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_gpu import best_of  # best of ``repeat`` calls, in s


@numba.njit(parallel=True, cache=True)
def _triad(a: np.ndarray, b: np.ndarray, c: np.ndarray, s: float) -> None:
    for i in numba.prange(a.size):
        a[i] = b[i] + s * c[i]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=None)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--scale", type=float, default=1.0)
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    main()
