"""Reconstruction speed, as ratios to one complex FFT of the mirrored volume.

For each size (n_t, n_y, n_x) this prints the time of NER (float64, float32),
NEDNER (`reconstruct_points`, ~1600 sensors of an equi-steradian mask), the linear
interpolation mode and `kspace_plane_recon`, each divided by the time of one complex FFT
of the mirrored volume (2 n_t, n_y, n_x) measured in the same process, and each
process's peak resident memory. Every method runs in a fresh process (so the peak
memory is its own) after a small warm-up run (numba compilation).

    .venv/bin/python benchmarks/bench_recon.py [--sizes 512x128x128 1024x226x226] [--repeat 2]

Targets (DESIGN §8): NER <= 1.5x (float64), <= 1.0x (float32); NEDNER <= 1.5x; NER no
slower than linear. The paper: 154 s (226x226 NER), 134 s (1625-sensor NEDNER).

The model-based part (issue 11, ``--methods pair pair-periodic tv``) prints ratios to one
NER (float64) of the same size in the same process instead: ``pair`` is one
`PlanarOperator` forward + adjoint on the sensor grid (free-space model, zero-padded;
``pair-periodic`` without padding; target <= 2.5x), ``tv`` a `reconstruct_tv` of the
equi-steradian mask (1653 points at 226 x 226) with its default stopping rule (float32):
iterations, time / NER, peak memory / the input volume (n_t x n_y x n_x float32;
target <= 4x). ``--tv-iterations N`` caps the iterations (for a quick estimate).
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import queue as queue_mod
import resource
import time

import numpy as np

C, DT, PITCH = 1500.0, 8e-9, 60e-6


def _best(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _fft_time(n_t, n_y, n_x, repeat):
    import scipy.fft

    vol = np.zeros((2 * n_t, n_y, n_x), np.complex128)
    vol[:] = 1.0
    return _best(lambda: scipy.fft.fftn(vol, workers=-1, overwrite_x=True), repeat)


def _run_model(method, n_t, n_y, n_x, repeat, queue, max_iter=None):
    """The operator pair / tv, as ratios to one NER of the same size (same process)."""
    from service.recon import PlanarOperator, reconstruct_grid, reconstruct_tv

    rng = np.random.default_rng(1)
    data = rng.standard_normal((n_t, n_y, n_x))
    reconstruct_grid(data[:32, :16, :16], PITCH, DT, C)  # numba warm-up
    t_ner = _best(lambda: reconstruct_grid(data, PITCH, DT, C), repeat)
    note = ""
    if method.startswith("pair"):
        op = PlanarOperator((n_t, n_y, n_x), PITCH, C * DT, DT, n_t, C, periodic=method == "pair-periodic")
        small = PlanarOperator((16, 8, 8), PITCH, C * DT, DT, 16, C)
        small.adjoint(small.forward(np.ones(small.ishape)))
        p0 = rng.standard_normal(op.ishape)
        t = _best(lambda: op.adjoint(op.forward(p0)), repeat)
        note = f"padded grid {op.padded_shape}"
    else:
        from driver.physics import Ball, ball_alines

        pos, w, kind = _mask_positions(n_y, n_x)
        x = (np.arange(n_x) - (n_x - 1) / 2) * PITCH
        y = (np.arange(n_y) - (n_y - 1) / 2) * PITCH
        depth = 3.6e-3 * n_x / 226
        al = ball_alines(pos, [Ball(0.0, 0.0, depth, 0.3e-3), Ball(0.8e-3, -0.5e-3, depth * 1.2, 0.2e-3)], DT, n_t, C)
        al = al + rng.standard_normal(al.shape) * float(np.sqrt(np.mean(al**2))) / 10 ** 1.5
        reconstruct_tv(al[:40, :32], DT, C, positions=pos[:40], n_z=8, max_iter=2, dtype=np.float32)  # warm-up
        kw = {} if max_iter is None else {"max_iter": max_iter}
        import psutil

        base = psutil.Process().memory_info().rss  # the interpreter, libraries and the NER runs
        t0 = time.perf_counter()
        img = reconstruct_tv(al, DT, C, positions=pos, weights=w, grid=(x, y), dtype=np.float32, **kw)
        t = time.perf_counter() - t0
        note = (f"{len(pos)} sensors ({kind}), {img.params['iterations']} iterations, "
                f"λ = {img.params['lam']:.3g}, (peak - RSS before) / input = "
                f"{(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base) / (4 * n_t * n_y * n_x):.1f}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    queue.put((t, t_ner, peak, note))


def _mask_positions(n_y, n_x):
    try:
        from service.plans import Lattice, equisteradian_mask

        lat = Lattice(n_x, n_y, PITCH)
        depth = 3.6e-3 * n_x / 226
        m = equisteradian_mask(lat, depth, int(round(1625 * (n_x * n_y) / 226**2)))
        return m.positions, m.weights, "equi-steradian"
    except Exception:  # the plans package is optional for this benchmark
        rng = np.random.default_rng(0)
        k = rng.choice(n_x * n_y, 1600, replace=False)
        x = (np.arange(n_x) - (n_x - 1) / 2) * PITCH
        y = (np.arange(n_y) - (n_y - 1) / 2) * PITCH
        return np.column_stack([x[k % n_x], y[k // n_x]]), None, "random"


def _run(method, n_t, n_y, n_x, repeat, queue):
    from service.recon import kspace_plane_recon, reconstruct_grid, reconstruct_points

    rng = np.random.default_rng(1)
    data = rng.standard_normal((n_t, n_y, n_x))
    x = (np.arange(n_x) - (n_x - 1) / 2) * PITCH
    y = (np.arange(n_y) - (n_y - 1) / 2) * PITCH
    note = ""
    if method == "ner64":
        fn = lambda: reconstruct_grid(data, PITCH, DT, C)  # noqa: E731
        warm = lambda: reconstruct_grid(data[:32, :16, :16], PITCH, DT, C)  # noqa: E731
    elif method == "ner32":
        d32 = data.astype(np.float32)
        fn = lambda: reconstruct_grid(d32, PITCH, DT, C, dtype=np.float32)  # noqa: E731
        warm = lambda: reconstruct_grid(d32[:32, :16, :16], PITCH, DT, C, dtype=np.float32)  # noqa: E731
    elif method == "linear":
        fn = lambda: reconstruct_grid(data, PITCH, DT, C, method="linear")  # noqa: E731
        warm = lambda: reconstruct_grid(data[:32, :16, :16], PITCH, DT, C, method="linear")  # noqa: E731
    elif method == "nedner":
        pos, w, kind = _mask_positions(n_y, n_x)
        al = rng.standard_normal((len(pos), n_t))
        grid = (x, y)
        note = f"{len(pos)} sensors ({kind})"
        fn = lambda: reconstruct_points(al, pos, DT, C, weights=w, grid=grid)  # noqa: E731
        warm = lambda: reconstruct_points(al[:50, :32], pos[:50], DT, C, grid=grid)  # noqa: E731
    else:
        fn = lambda: kspace_plane_recon(data, PITCH, PITCH, DT, C, interp="*linear")  # noqa: E731
        warm = lambda: None  # noqa: E731
    warm()
    t_fft = _fft_time(n_t, n_y, n_x, repeat)
    t = _best(fn, repeat if method != "kwave" else 1)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    queue.put((t, t_fft, peak, note))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["512x128x128", "1024x226x226"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--methods", nargs="+", default=["ner64", "ner32", "nedner", "linear", "kwave"],
                    help="also: pair, pair-periodic, tv (ratios to one NER)")
    ap.add_argument("--tv-iterations", type=int, default=None, help="cap tv's iterations (default: its rule)")
    args = ap.parse_args()
    ctx = mp.get_context("spawn")
    labels = {"ner64": "ner float64", "ner32": "ner float32", "nedner": "reconstruct_points (NEDNER)",
              "linear": "linear (FFT + interp.)", "kwave": "kspace_plane_recon ('*linear')",
              "pair": "forward + adjoint / NER", "pair-periodic": "forward + adjoint (periodic) / NER",
              "tv": "tv (equi-steradian) / NER"}
    for size in args.sizes:
        n_t, n_y, n_x = (int(v) for v in size.split("x"))
        print(f"\n(n_t, n_y, n_x) = ({n_t}, {n_y}, {n_x}); reference: complex FFT of ({2 * n_t}, {n_y}, {n_x})")
        print(f"{'method':34s} {'time s':>8s} {'ref s':>7s} {'ratio':>6s} {'peak GiB':>9s}  "
              "note (ref: the FFT; one NER for the '/ NER' rows)")
        for m in args.methods:
            q = ctx.Queue()
            if m in ("pair", "pair-periodic", "tv"):
                p = ctx.Process(target=_run_model, args=(m, n_t, n_y, n_x, args.repeat, q, args.tv_iterations))
            else:
                p = ctx.Process(target=_run, args=(m, n_t, n_y, n_x, args.repeat, q))
            p.start()
            try:
                t, t_fft, peak, note = q.get(timeout=1800)
            except queue_mod.Empty:
                p.kill()
                print(f"{labels[m]:34s} failed (exit code {p.exitcode})", flush=True)
                continue
            finally:
                p.join(timeout=60)
            print(f"{labels[m]:34s} {t:8.2f} {t_fft:7.2f} {t / t_fft:6.2f} {peak / 2**30:9.2f}  {note}", flush=True)


if __name__ == "__main__":
    main()
