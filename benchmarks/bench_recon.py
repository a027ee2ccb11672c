"""Reconstruction speed, as ratios to one complex FFT of the mirrored volume.

For each size (n_t, n_y, n_x) this prints the time of NER (float64, float32),
NEDNER (`reconstruct_points`, ~1600 sensors of an equi-steradian mask), the linear
interpolation mode and the k-Wave-compatible `kspace_plane_recon` ('*nearest', k-Wave's
default, and '*linear'), each divided by the time of one complex FFT of the mirrored
volume (2 n_t, n_y, n_x) and by one of the mirrored volume at fast FFT lengths
(next_fast_len(2 n_t), next_fast_len(n_y), next_fast_len(n_x)), both measured in the same process, and
each process's peak memory above its baseline as a multiple of the input (float64 data).
Every method runs in a fresh process after a small warm-up run (numba compilation).

    .venv/bin/python benchmarks/bench_recon.py [--sizes 512x128x128 1024x226x226] [--repeat 2]
    .venv/bin/python benchmarks/bench_recon.py --sweep          # n = 64..320, n_t = 2 n
    .venv/bin/python benchmarks/bench_recon.py --kwave-2d $FPSCAN_SHARED/data/kwave2d_points.h5
    .venv/bin/python benchmarks/bench_recon.py --cold-start --writer
    .venv/bin/python benchmarks/bench_recon.py --vs-kwave-python   # if k-wave-python is installed

Targets: NER <= 1.0x the fast-length FFT at every sweep size from
n = 128 (float32 <= 0.7x); NEDNER <= 1.5x at 512x128x128, <= 0.9x at 1024x226x226;
k-Wave modes <= 3x and <= 6x the input in peak memory; 2-D NER on the k-Wave tree <= 1.2x;
cold start (imports + compiled code) <= 0.5 s; result writer >= 200 MB/s. The paper:
154 s (226x226 NER), 134 s (1625-sensor NEDNER).

The model-based part (``--methods pair pair-periodic tv``) prints ratios to one
NER (float64) of the same size in the same process instead: ``pair`` is one
`PlanarOperator` forward + adjoint on the sensor grid (free-space model, zero-padded;
``pair-periodic`` without padding; target <= 2.5x), ``tv`` a `reconstruct_tv` of the
equi-steradian mask (1653 points at 226 x 226) with its default stopping rule (float32):
iterations, time / NER, tv's own peak memory above the RSS before it / the input volume
(n_t x n_y x n_x float32; the process's peak is reset after the NER runs, /proc/self/clear_refs;
target <= 10x). ``--tv-iterations N`` caps the iterations (for a quick estimate).
"""
from __future__ import annotations

import argparse
import functools
import multiprocessing as mp
import queue as queue_mod
import resource
import time

import numpy as np

from fpscan.physics.axes import centred_axis

C, DT, PITCH = 1500.0, 8e-9, 60e-6


def _best(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def fft_time(n_t, n_y, n_x, repeat, fast=False):
    import scipy.fft

    n_tt = 2 * n_t
    if fast:  # every axis at a length the FFT likes (226 -> 240, 2 * 452 = 8 * 113 -> 910)
        n_tt = scipy.fft.next_fast_len(n_tt)
        n_y = 1 if n_y == 1 else scipy.fft.next_fast_len(n_y)
        n_x = scipy.fft.next_fast_len(n_x)
    vol = np.zeros((n_tt, n_y, n_x), np.complex128)
    vol[:] = 1.0
    return _best(lambda: scipy.fft.fftn(vol, workers=-1, overwrite_x=True), repeat)


def _rss() -> int:
    """Resident memory now, bytes (Linux)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize()


def _reset_peak() -> None:
    """Reset this process's peak resident memory (VmHWM) to the RSS now (Linux), so that
    `_peak` measures what follows, not an earlier, larger step (the NER runs before tv)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _peak() -> int:
    """Peak resident memory since `_reset_peak`, bytes (VmHWM; elsewhere ru_maxrss)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _run_model(method, n_t, n_y, n_x, repeat, queue, max_iter=None):
    """The operator pair / tv, as ratios to one NER of the same size (same process)."""
    from fpscan.service.recon import PlanarOperator, reconstruct_grid, reconstruct_tv

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
        from fpscan.physics import Ball, ball_alines

        pos, w, kind = _mask_positions(n_y, n_x)
        x = centred_axis(n_x, PITCH)
        y = centred_axis(n_y, PITCH)
        depth = 3.6e-3 * n_x / 226
        al = ball_alines(pos, [Ball(0.0, 0.0, depth, 0.3e-3), Ball(0.8e-3, -0.5e-3, depth * 1.2, 0.2e-3)], DT, n_t, C)
        al = al + rng.standard_normal(al.shape) * float(np.sqrt(np.mean(al**2))) / 10 ** 1.5
        reconstruct_tv(al[:40, :32], DT, C, positions=pos[:40], n_z=8, max_iter=2, dtype=np.float32)  # warm-up
        kw = {} if max_iter is None else {"max_iter": max_iter}
        base = _rss()  # the interpreter, libraries and the NER runs
        _reset_peak()  # tv's own peak, not the NER runs' before it
        t0 = time.perf_counter()
        img = reconstruct_tv(al, DT, C, positions=pos, weights=w, grid=(x, y), dtype=np.float32, **kw)
        t = time.perf_counter() - t0
        note = (f"{len(pos)} sensors ({kind}), {img.params['iterations']} iterations, "
                f"{img.params['stop_reason']}, "
                f"λ = {img.params['lam']:.3g} ({img.params['lam_factor']:.2f} x the noise level), "
                f"(peak - RSS before) / input = "
                f"{(_peak() - base) / (4 * n_t * n_y * n_x):.1f}")
    peak = _peak()
    queue.put((t, t_ner, peak, note))


def _mask_positions(n_y, n_x):
    try:
        from fpscan.service.plans import Lattice, equisteradian_mask

        lat = Lattice(n_x, n_y, PITCH)
        depth = 3.6e-3 * n_x / 226
        m = equisteradian_mask(lat, depth, int(round(1625 * (n_x * n_y) / 226**2)))
        return m.positions, m.weights, "equi-steradian"
    except Exception:  # the plans package is optional for this benchmark
        rng = np.random.default_rng(0)
        k = rng.choice(n_x * n_y, 1600, replace=False)
        x = centred_axis(n_x, PITCH)
        y = centred_axis(n_y, PITCH)
        return np.column_stack([x[k % n_x], y[k // n_x]]), None, "random"


def _run(method, n_t, n_y, n_x, repeat, queue):
    from fpscan.service.recon import kspace_plane_recon, reconstruct_grid, reconstruct_points

    base = _rss()
    rng = np.random.default_rng(1)
    data = rng.standard_normal((n_t, n_y, n_x))
    x = centred_axis(n_x, PITCH)
    y = centred_axis(n_y, PITCH)
    note = ""
    if method == "ner64":
        fn = lambda: reconstruct_grid(data, PITCH, DT, C)
        warm = lambda: reconstruct_grid(data[:32, :16, :16], PITCH, DT, C)
    elif method == "ner32":
        d32 = data.astype(np.float32)
        fn = lambda: reconstruct_grid(d32, PITCH, DT, C, dtype=np.float32)
        warm = lambda: reconstruct_grid(d32[:32, :16, :16], PITCH, DT, C, dtype=np.float32)
    elif method == "linear":
        fn = lambda: reconstruct_grid(data, PITCH, DT, C, method="linear")
        warm = lambda: reconstruct_grid(data[:32, :16, :16], PITCH, DT, C, method="linear")
    elif method == "nedner":
        pos, w, kind = _mask_positions(n_y, n_x)
        al = rng.standard_normal((len(pos), n_t))
        grid = (x, y)
        note = f"{len(pos)} sensors ({kind})"
        fn = lambda: reconstruct_points(al, pos, DT, C, weights=w, grid=grid)
        warm = lambda: reconstruct_points(al[:50, :32], pos[:50], DT, C, grid=grid)
    else:
        interp = "*nearest" if method == "kwave_nearest" else "*linear"
        fn = lambda: kspace_plane_recon(data, PITCH, PITCH, DT, C, interp=interp)
        warm = lambda: kspace_plane_recon(data[:16, :8, :8], PITCH, PITCH, DT, C, interp=interp)
    warm()
    t = _best(fn, repeat)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base
    t_fft = fft_time(n_t, n_y, n_x, repeat)
    t_fast = fft_time(n_t, n_y, n_x, repeat, fast=True)
    queue.put((t, t_fft, t_fast, peak / data.nbytes, note))


LABELS = {"ner64": "ner float64", "ner32": "ner float32", "nedner": "reconstruct_points (NEDNER)",
          "linear": "linear (FFT + interp.)", "kwave_nearest": "kspace_plane_recon ('*nearest')",
          "kwave": "kspace_plane_recon ('*linear')", "pair": "forward + adjoint / NER",
          "pair-periodic": "forward + adjoint (periodic) / NER", "tv": "tv (equi-steradian) / NER"}
MODEL = ("pair", "pair-periodic", "tv")


def _in_process(target, *args, timeout=1800):
    """Run ``target(*args, queue)`` in a fresh spawned process; its result or None."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=target, args=(*args, q))
    p.start()
    try:
        return q.get(timeout=timeout)
    except queue_mod.Empty:
        p.kill()
        return None
    finally:
        p.join(timeout=60)


def _table(sizes, methods, repeat, tv_iterations=None):
    for n_t, n_y, n_x in sizes:
        print(f"\n(n_t, n_y, n_x) = ({n_t}, {n_y}, {n_x}); reference: complex FFT of ({2 * n_t}, {n_y}, {n_x}) "
              "and of the same at fast lengths (every axis)")
        print(f"{'method':34s} {'time s':>8s} {'FFT s':>7s} {'ratio':>6s} {'fast s':>7s} {'ratio':>6s} "
              f"{'peak/in':>8s}  note")
        for m in methods:
            if m in MODEL:
                r = _in_process(functools.partial(_run_model, max_iter=tv_iterations), m, n_t, n_y, n_x, repeat)
                if r is not None:
                    t, t_ner, peak, note = r
                    print(f"{LABELS[m]:34s} {t:8.2f} {t_ner:7.2f} {t / t_ner:6.2f} {'(NER)':>7s} {'':6s} "
                          f"{'':8s}  {note}; peak RSS {peak / 2**30:.2f} GiB", flush=True)
                    continue
            else:
                r = _in_process(_run, m, n_t, n_y, n_x, repeat)
            if r is None:
                print(f"{LABELS[m]:34s} failed", flush=True)
                continue
            t, t_fft, t_fast, peak, note = r
            print(f"{LABELS[m]:34s} {t:8.2f} {t_fft:7.2f} {t / t_fft:6.2f} {t_fast:7.2f} {t / t_fast:6.2f} "
                  f"{peak:8.1f}  {note}", flush=True)


def _kwave2d(path, repeat, queue):
    import scipy.fft

    from fpscan.service.formats import load
    from fpscan.service.recon import reconstruct_grid

    ds = load(path, "kwave-hdf5", key="sensor_data/clean")[1]  # the k-Wave format's reader and spacing rule
    data, dx, dt, c = ds.data.astype(np.float64), ds.dx, ds.dt, ds.c
    reconstruct_grid(data[:64, :64], dx, dt, c)
    t = _best(lambda: reconstruct_grid(data, dx, dt, c), repeat)
    vol = np.ones((2 * data.shape[0], data.shape[1]), np.complex128)
    t_fft = _best(lambda: scipy.fft.fft2(vol, workers=-1, overwrite_x=True), repeat)
    fast = np.ones(tuple(scipy.fft.next_fast_len(n) for n in vol.shape), np.complex128)
    t_fast = _best(lambda: scipy.fft.fft2(fast, workers=-1, overwrite_x=True), repeat)
    queue.put((data.shape, t, t_fft, t_fast))


def _cold_start() -> None:
    """Imports + compiled-code loading + a tiny reconstruction in a fresh interpreter."""
    import subprocess
    import sys

    code = ("import time; t0 = time.perf_counter()\n"
            "import numpy as np\nfrom fpscan.service.recon import reconstruct_grid, reconstruct_points\n"
            "t1 = time.perf_counter()\nreconstruct_grid(np.ones((16, 4, 4)), 1e-4, 1e-8)\n"
            "reconstruct_points(np.ones((5, 16)), np.random.default_rng(0).uniform(-1e-3, 1e-3, (5, 2)), 1e-8)\n"
            "t2 = time.perf_counter()\nprint(t1 - t0, t2 - t1)")
    runs = []
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        runs.append(tuple(float(v) for v in out.stdout.split()))
    imp, first = min(runs, key=sum)
    print(f"\ncold start (best of 3 fresh interpreters): imports {imp:.2f} s, first tiny reconstructions "
          f"(compiled-code loading) {first:.2f} s, total {imp + first:.2f} s (target <= 0.5 s)")


def _writer(repeat) -> None:
    """The result writer (fpscan.service.storage.results) on a noisy and a mostly-zero volume,
    beside fixed HDF5 layouts of the same data (the measurements behind storage_layout)."""
    import tempfile
    from pathlib import Path

    import h5py

    from fpscan.service.storage.results import storage_layout, write_volume

    rng = np.random.default_rng(0)
    n_z, n_y, n_x = 512, 128, 144
    sparse = np.zeros((n_z, n_y, n_x), np.float32)
    sparse[100:140, 40:80, 50:90] = rng.random((40, 40, 40))
    noisy = (sparse + 0.01 * rng.standard_normal(sparse.shape)).astype(np.float32)
    z, y, x = (np.arange(n) * 1e-5 for n in (n_z, n_y, n_x))
    layouts = {"contiguous": {}, "gzip-1+shuffle": dict(chunks=(14, n_y, n_x), compression="gzip",
                                                         compression_opts=1, shuffle=True),
               "gzip-4+shuffle": dict(chunks=True, compression="gzip", compression_opts=4, shuffle=True),
               "lzf+shuffle": dict(chunks=(14, n_y, n_x), compression="lzf", shuffle=True)}
    print(f"\nresult writer ({noisy.nbytes / 1e6:.0f} MB float32 volumes; MB/s and file size / volume)")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "volume.h5"
        for name, p0 in (("noisy", noisy), ("mostly zero", sparse)):
            t = _best(lambda p0=p0: write_volume(path, p0, z, x, y, method="ner", params={"dtype": "float32"},
                                                 input_id="bench"), repeat)
            chosen = storage_layout(p0).get("compression") or "contiguous"
            row = [f"writer ({chosen}) {p0.nbytes / 1e6 / t:6.0f} MB/s {path.stat().st_size / p0.nbytes:5.2f}"]
            for lname, kw in layouts.items():
                def plain(kw=kw, p0=p0):
                    with h5py.File(path, "w") as f:
                        f.create_dataset("p0", data=p0, **kw)
                t = _best(plain, repeat)
                row.append(f"{lname} {p0.nbytes / 1e6 / t:5.0f} MB/s {path.stat().st_size / p0.nbytes:5.2f}")
            print(f"  {name:12s} " + " | ".join(row))
    print("  (target: the writer >= 200 MB/s)")


def _vs_kwave_python(repeat) -> None:
    """k-wave-python's kspacePlaneRecon beside ours on the same data (benchmark-only extra)."""
    import importlib

    fn = None
    why = "not installed (pip install k-wave-python)"
    for mod in ("kwave.reconstruction.kspace_plane_recon", "kwave.kspacePlaneRecon", "kwave.reconstruction"):
        try:
            fn = getattr(importlib.import_module(mod), "kspacePlaneRecon", None)
        except ImportError:
            continue
        except Exception as exc:  # k-wave-python downloads its simulation binaries on import
            why = f"not importable here ({type(exc).__name__}: {exc}; it fetches its binaries on first import)"
            break
        if fn is not None:
            break
    if fn is None:
        print(f"\nk-wave-python is {why}: comparison skipped")
        return
    from fpscan.service.recon import kspace_plane_recon

    data = np.random.default_rng(1).standard_normal((512, 113, 113))
    ours = _best(lambda: kspace_plane_recon(data, PITCH, PITCH, DT, C), repeat)
    theirs = _best(lambda: fn(data, PITCH, PITCH, DT, C), 1)
    print(f"\nk-wave-python kspacePlaneRecon (512x113x113): {theirs:.2f} s; ours {ours:.2f} s "
          f"({theirs / ours:.1f}x faster)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["512x128x128", "1024x226x226"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--methods", nargs="+", default=["ner64", "ner32", "nedner", "linear", "kwave_nearest", "kwave"],
                    help="also: pair, pair-periodic, tv (ratios to one NER)")
    ap.add_argument("--tv-iterations", type=int, default=None, help="cap tv's iterations (default: its rule)")
    ap.add_argument("--sweep", action="store_true", help="NER/NEDNER at n = 64, 128, 226, 256, 320 (n_t = 2 n)")
    ap.add_argument("--kwave-2d", metavar="H5", help="2-D NER on the k-Wave tree (kwave2d_points.h5)")
    ap.add_argument("--cold-start", action="store_true", help="imports + compiled-code loading")
    ap.add_argument("--writer", action="store_true", help="result-file writing speed")
    ap.add_argument("--vs-kwave-python", action="store_true", help="time k-wave-python's kspacePlaneRecon too")
    args = ap.parse_args()
    extras = args.sweep or args.kwave_2d or args.cold_start or args.writer or args.vs_kwave_python
    if not extras or "--sizes" in " ".join(__import__("sys").argv):
        _table([tuple(int(v) for v in size.split("x")) for size in args.sizes], args.methods, args.repeat,
               args.tv_iterations)
    if args.sweep:
        _table([(2 * n, n, n) for n in (64, 128, 226, 256, 320)], ["ner64", "ner32", "nedner"], args.repeat)
    if args.kwave_2d:
        r = _in_process(_kwave2d, args.kwave_2d, args.repeat)
        if r is not None:
            shape, t, t_fft, t_fast = r
            print(f"\n2-D NER on the k-Wave tree {shape}: {t:.2f} s, mirrored 2-D FFT {t_fft:.3f} s, "
                  f"ratio {t / t_fft:.2f}; at fast lengths {t_fast:.3f} s, ratio {t / t_fast:.2f} (target <= 1.5)")
    if args.cold_start:
        _cold_start()
    if args.writer:
        _writer(args.repeat)
    if args.vs_kwave_python:
        _vs_kwave_python(args.repeat)


if __name__ == "__main__":
    main()
