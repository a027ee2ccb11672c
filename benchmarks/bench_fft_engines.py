"""FFT engines behind ``scipy.fft``'s backend interface at fpscan's lengths.

For each engine that imports here — pocketfft (scipy's own, the default), pyFFTW
(``pyfftw.interfaces.scipy_fft``) and mkl_fft (``mkl_fft.interfaces.scipy_fft``) — this prints
the best of ``--repeat`` wall times of the transforms the reconstructions run at the paper's
size (1024 samples on a 226 x 226 lattice; the model-based operator's working grid 1025 x 450
x 450), each engine in turn in one process, every transform on every core (``workers=-1``):

- ``y c2c 450`` / ``x r2c 450``: the operator's lateral transforms of one block of rows;
- ``y c2c 226 (k-Wave)``: k-Wave's transform along y at the lattice's own length 226 = 2·113
  (no fast length: k-Wave's k grid is the scan's);
- ``y c2c 240`` / ``x r2c 240``: NER's lateral transforms (226 padded to 240);
- ``t c2c 2048``: the temporal NUFFT's fine grid (L = 2048 for 1024 samples), one chunk;
- ``z dct1 1025``: the depth DCT-I (pocketfft and pyFFTW only: mkl_fft has no DCT);

and each engine's time over pocketfft's. An engine is adopted only where it is faster and
installs from the registries (an optional extra, pocketfft the fallback).

    .venv/bin/python benchmarks/bench_fft_engines.py [--repeat 5] [--scale 0.5]

``--scale`` shrinks the leading (batch) dimension of every case, not the lengths. Install the
engines into a scratch environment to measure them (``pip install pyfftw mkl_fft``); they are
not fpscan's dependencies.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.fft


def _cases(scale: float):
    rng = np.random.default_rng(0)

    def c(shape, dtype=np.complex64):
        a = rng.standard_normal(shape).astype(np.float32)
        return (a + 1j * a[::-1]).astype(dtype)

    def r(shape, dtype=np.float32):
        return rng.standard_normal(shape).astype(dtype)

    b = lambda n: max(1, int(n * scale))
    return [
        ("y c2c 450 (operator, complex64)", lambda: c((b(128), 450, 226)), lambda a: scipy.fft.fft(a, axis=1, workers=-1)),
        ("x r2c 450 (operator, float32)", lambda: r((b(128), 226, 450)), lambda a: scipy.fft.rfft(a, axis=2, workers=-1)),
        ("y c2c 226 (k-Wave, complex128)", lambda: c((b(1024), 226, 114), np.complex128),
         lambda a: scipy.fft.fft(a, axis=1, workers=-1)),
        ("y c2c 240 (NER, complex64)", lambda: c((b(1024), 240, 121)), lambda a: scipy.fft.fft(a, axis=1, workers=-1)),
        ("x r2c 240 (NER, float32)", lambda: r((b(1024), 226, 240)), lambda a: scipy.fft.rfft(a, axis=2, workers=-1)),
        ("t c2c 2048 (fine grid, complex64)", lambda: c((b(2048), 2048)), lambda a: scipy.fft.fft(a, axis=1, workers=-1)),
        ("z dct1 1025 (depth, float32 pairs)", lambda: r((b(4096), 1025)),
         lambda a: scipy.fft.dct(a, type=1, axis=1, workers=-1)),
    ]


def _engines(planner: str = "FFTW_MEASURE"):
    out = [("pocketfft", None)]
    try:
        import pyfftw
        import pyfftw.interfaces.scipy_fft as pyfftw_backend

        pyfftw.interfaces.cache.enable()
        pyfftw.interfaces.cache.set_keepalive_time(60)
        pyfftw.config.PLANNER_EFFORT = planner
        out.append(("pyfftw", pyfftw_backend))
    except ImportError:
        pass
    try:
        import mkl_fft.interfaces.scipy_fft as mkl_backend

        out.append(("mkl_fft", mkl_backend))
    except ImportError:
        pass
    return out


def _best(fn, arr, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn(arr)
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scale", type=float, default=1.0, help="shrink the batch dimension of every case")
    ap.add_argument("--planner", default="FFTW_MEASURE", help="pyFFTW's planner effort (FFTW_ESTIMATE, FFTW_MEASURE, ...)")
    args = ap.parse_args(argv)
    engines = _engines(args.planner)
    print("engines: " + ", ".join(name for name, _ in engines) + f"; best of {args.repeat}; pyFFTW {args.planner}")
    for label, make, fn in _cases(args.scale):
        arr = make()
        times = {}
        for name, backend in engines:
            try:
                if backend is None:
                    fn(arr)  # warm-up (plans)
                    times[name] = _best(fn, arr, args.repeat)
                else:
                    with scipy.fft.set_backend(backend, only=True):
                        fn(arr)
                        times[name] = _best(fn, arr, args.repeat)
            except Exception as exc:  # an engine without this transform (mkl_fft: no DCT)
                times[name] = exc
        ref = times["pocketfft"]
        cells = []
        for name, t in times.items():
            if isinstance(t, Exception):
                cells.append(f"{name} -")
            else:
                cells.append(f"{name} {t:7.4f} s ({t / ref:4.2f})")
        print(f"{label:36s} " + "  ".join(cells), flush=True)


if __name__ == "__main__":
    main()
