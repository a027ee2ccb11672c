"""Cost of the model-based operator pair against one NER of the same image.

For each size n_t x n_y x n_x (image n_z = n_t rows at dz = c·dt, pitch 60 µm, dt 8 ns,
c 1500 m/s: the FP scanner's and the paper's sampling) and each working dtype this
prints the median of ``--repeat`` runs of

- NER: `reconstruct_grid` of data on the n_y x n_x sensor grid;
- pair: one `PlanarOperator.forward` + `adjoint` on the same grid (free space: the
  zero-padded working grid `padded_shape`, also printed);
- NEDNER and the pair at points, with ``--points N``: N sensors drawn at random on the
  lattice, `reconstruct_points` vs the operator with those positions;

and the ratio pair / NER (target <= 2.5), of wall times and of CPU times (all threads: the
figure to trust on a machine other jobs share). Operator construction (its plans) and the first
application (numba compilation) are outside the timing; so is NER's warm-up.

    .venv/bin/python benchmarks/bench_tv_operator.py                       # 128x128x128 and 256x226x226
    .venv/bin/python benchmarks/bench_tv_operator.py --sizes 64x64x64 --repeat 3
    .venv/bin/python benchmarks/bench_tv_operator.py --sizes 128x128x128 --points 1653

The padding the free-space model needs grows with the record's reach c·t_last in pitches
(here n_t · 12 µm / 60 µm = n_t / 5 pitches on each side's gap), so the ratio depends on
n_t / n_x: the 226² case runs with 256 samples (a quarter of the paper's 1024) to fit
a 2-core, few-GiB machine; ``--sizes 1024x226x226`` runs the paper's.

Measured (2-core machine shared with other jobs, load 5-6: wall times scatter by ±30 %,
CPU-time ratios are steadier), pair / NER as CPU-time ratio (wall in brackets):

    size           dtype     working grid      before (complex128, old padding)  after
    128x128x128    float32   129 x 160 x 160   4.50 (9.2)                        3.0-3.5 (2.9-3.2)
    128x128x128    float64   129 x 160 x 160   3.69 (3.9)                        3.0-3.4 (3.1-4.9)
    256x226x226    float32   257 x 288 x 288   8.08 (9.9)                        2.55 (2.78)
    256x226x226    float64   257 x 288 x 288   5.54 (4.7)                        2.18 (1.84)
    128x128x128 at 1653 random lattice sensors, pair / NEDNER: float32 2.19 -> 1.00, float64 2.23 -> 1.49

Then (2026-11-23 afternoon, idle; the previous tree f0bb686 and this one alternating, median of
3, float32 at 256x226x226): the grid pair 2.13 -> 1.74 s (NER 0.66 -> 0.46 s: the compiled
temporal interpolation and the in-place inverse lateral FFT made NER faster too, so pair/NER
reads 3.22 -> 3.81); the pair at 1653 lattice sensors 3.55 -> 1.58 s, pair/NEDNER 3.72 -> 1.97
(sensors on grid nodes take exact lateral DFTs instead of NUFFTs, and the temporal step
gathers and scatters its columns in place).

Then (2026-11-24, `--sizes 512x128x128 --points 533 --repeat 3`, two runs each, alternating): the
adjoint's k-space in private instead of shared anonymous pages (docs/history/measurements.md, "the operator's adjoint
releases its memory for real") took the
float32 pair from 0.95-1.02 to 0.84-0.90 s and the float64 one from 1.56-1.64 to 1.26-1.35 s.

At 128 x 128² the padded lateral area alone is 1.56x NER's (160² half spectrum against
128²), so two transforms cost at least ~3.1 NERs at NER's own cost per element; the
exact free-space model cannot pad less (`fpscan.service.recon.operator`, Padding). At the
paper's 1024 samples the reach is 205 pitches and the working grid 450 x 450: expect
about 7x.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

C, DT, PITCH = 1500.0, 8e-9, 60e-6


def _median(fn, repeat: int) -> tuple[float, float]:
    """Median wall and CPU (all threads) seconds of ``repeat`` calls."""
    wall, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return float(np.median(wall)), float(np.median(cpu))


def _row(label: str, ref: str, t_ref, t_pair) -> str:
    return (f"{label}  {ref} {t_ref[0]:7.3f} s  pair {t_pair[0]:7.3f} s  pair/{ref} {t_pair[0] / t_ref[0]:5.2f}"
            f"  (CPU time: {t_pair[1] / t_ref[1]:5.2f})")


def bench(n_t: int, n_y: int, n_x: int, dtype, repeat: int, n_points: int | None) -> list[str]:
    from fpscan.service.recon.operator import PlanarOperator
    from fpscan.service.recon.planar import reconstruct_grid, reconstruct_points

    rng = np.random.default_rng(0)
    data = rng.standard_normal((n_t, n_y, n_x)).astype(dtype)
    reconstruct_grid(data, PITCH, DT, C, dtype=dtype)  # warm-up
    t_ner = _median(lambda: reconstruct_grid(data, PITCH, DT, C, dtype=dtype), repeat)
    op = PlanarOperator((n_t, n_y, n_x), PITCH, C * DT, DT, n_t, C, dtype=dtype)
    x = rng.standard_normal(op.ishape).astype(dtype)
    op.adjoint(op.forward(x))  # warm-up (compiled kernels for this dtype)
    t_pair = _median(lambda: op.adjoint(op.forward(x)), repeat)
    name = np.dtype(dtype).name
    rows = [_row(f"{n_t}x{n_y}x{n_x} {name:8s} grid   padded {op.padded_shape}", "NER", t_ner, t_pair)]
    if n_points:
        ax = (np.arange(n_x) - (n_x - 1) / 2) * PITCH
        ay = (np.arange(n_y) - (n_y - 1) / 2) * PITCH
        idx = rng.choice(n_x * n_y, n_points, replace=False)
        pos = np.stack([ax[idx % n_x], ay[idx // n_x]], 1)
        alines = rng.standard_normal((n_points, n_t)).astype(dtype)
        kw = dict(grid=(ax, ay), dtype=dtype)
        reconstruct_points(alines, pos, DT, C, **kw)
        t_ned = _median(lambda: reconstruct_points(alines, pos, DT, C, **kw), repeat)
        op = PlanarOperator((n_t, n_y, n_x), PITCH, C * DT, DT, n_t, C, positions=pos, dtype=dtype)
        op.adjoint(op.forward(x))
        t_pair = _median(lambda: op.adjoint(op.forward(x)), repeat)
        rows.append(_row(f"{n_t}x{n_y}x{n_x} {name:8s} points padded {op.padded_shape}", "NEDNER", t_ned, t_pair)
                    + f"  {n_points} sensors")
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["128x128x128", "256x226x226"],
                    help="n_t x n_y x n_x (the image has n_z = n_t rows)")
    ap.add_argument("--dtypes", nargs="+", default=["float32", "float64"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--points", type=int, default=None, help="also time N random lattice sensors")
    args = ap.parse_args(argv)
    print(f"pitch {PITCH * 1e6:g} µm, dt {DT * 1e9:g} ns, c {C:g} m/s, dz = c·dt; median of {args.repeat}")
    for size in args.sizes:
        n_t, n_y, n_x = (int(v) for v in size.split("x"))
        for name in args.dtypes:
            for row in bench(n_t, n_y, n_x, np.dtype(name), args.repeat, args.points):
                print(row, flush=True)


if __name__ == "__main__":
    main()
