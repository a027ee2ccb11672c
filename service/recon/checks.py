"""Input validation and the peak-memory estimate shared by the reconstructions."""
from __future__ import annotations

import os

import numpy as np

from driver.physics.fast_lengths import fast_dct1_rows, fast_lateral
from driver.units import RefusedInput

__all__ = [
    "positive", "finite_array", "EPS_RANGE", "UPSAMPLE_RANGE", "N_Z_RANGE", "DZ_RANGE", "LAM_RANGE",
    "ITERATIONS_RANGE", "TIME_LIMIT_MAX", "OptionError", "check_eps", "check_upsample", "check_n_z",
    "check_dz", "check_lam", "check_iterations", "check_time_limit", "check_dtype", "available_memory",
    "estimate_peak_memory", "padded_lateral", "tv_memory", "check_memory",
]


def positive(name: str, value) -> float:
    """``value`` as float; ValueError unless finite and > 0."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def finite_array(name: str, a, ndims: tuple[int, ...]) -> np.ndarray:
    """``a`` as an ndarray with ndim in ``ndims``; ValueError on NaN/inf, wrong ndim,
    empty or non-numeric input."""
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim not in ndims:
        raise ValueError(f"{name} must have {' or '.join(map(str, ndims))} dimensions, got shape {arr.shape}")
    if arr.size == 0 or 0 in arr.shape:
        raise ValueError(f"{name} is empty (shape {arr.shape})")
    # one summing pass without a temporary (NaN/inf propagate into the sum); only a sum
    # that overflowed from finite values needs the element-wise check
    with np.errstate(all="ignore"):
        total = arr.sum(dtype=np.float64)
    if not np.isfinite(total) and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


# -- the reconstruction options' rules: one owner each ----------------------------------
# The kernels (``planar``, ``tv``) apply these; ``service.pipeline.check_options`` applies
# the same functions at every door (library, CLI, HTTP) before a job is queued, and the
# HTTP schema states the same bounds (``service.api.models.ReconParams``).

# the ranges: service.recon.limits (import-free, read by the methods' option models too)
from service.recon.limits import (  # noqa: E402
    DZ_RANGE,
    EPS_RANGE,
    ITERATIONS_RANGE,
    LAM_RANGE,
    N_Z_RANGE,
    TIME_LIMIT_MAX,
    UPSAMPLE_RANGE,
)


class OptionError(RefusedInput):
    """A reconstruction option refused by its rule (a value outside its range, or an option
    the chosen method does not take): the caller's input, a usage error (CLI exit 2,
    HTTP 422)."""


def _number(name: str, value, what: str) -> float:
    if isinstance(value, bool):
        raise OptionError(f"{name} must be {what}, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be {what}, got {value!r}") from None


def _integer(name: str, value, lo: int, hi: int) -> int:
    what = f"an integer in {lo}..{hi}"
    v = _number(name, value, what)
    if not np.isfinite(v) or int(v) != v or not lo <= v <= hi:
        raise OptionError(f"{name} must be {what}, got {value!r}")
    return int(v)


def check_eps(eps) -> float:
    """NUFFT tolerance in ``EPS_RANGE`` ([1e-14, 1e-1]) or OptionError (a ValueError)."""
    e = _number("eps", eps, "a number")
    if not (EPS_RANGE[0] <= e <= EPS_RANGE[1]):
        raise OptionError(f"eps must be in [1e-14, 1e-1], got {eps!r}")
    return e


def check_upsample(upsample) -> int:
    """Lateral upsampling factor: an integer in ``UPSAMPLE_RANGE`` (1..8) or OptionError."""
    return _integer("upsample", upsample, *UPSAMPLE_RANGE)


def check_n_z(n_z) -> int:
    """Output depth samples: an integer in ``N_Z_RANGE`` (2..65536) or OptionError."""
    return _integer("n_z", n_z, *N_Z_RANGE)


def check_dz(dz) -> float:
    """Output depth spacing in m within ``DZ_RANGE`` ([1 nm, 0.1 m]) or OptionError."""
    v = _number("dz", dz, "a depth spacing in m")
    if not np.isfinite(v) or not DZ_RANGE[0] <= v <= DZ_RANGE[1]:
        raise OptionError(f"dz must be in [1e-09, 0.1] m, got {dz!r}")
    return v


def check_lam(lam) -> float:
    """TV weight λ: a finite number in ``LAM_RANGE`` ([0, 1e30]) or OptionError."""
    v = _number("lam (the TV weight λ)", lam, "a number >= 0")
    if not np.isfinite(v) or not LAM_RANGE[0] <= v <= LAM_RANGE[1]:
        raise OptionError(f"lam (the TV weight λ) must be in [0, 1e+30], got {lam!r}")
    return v


def check_iterations(iterations) -> int:
    """Most iterations of the model-based solver: an integer in ``ITERATIONS_RANGE``
    (1..100000) or OptionError."""
    return _integer("iterations", iterations, *ITERATIONS_RANGE)


def check_time_limit(seconds) -> float:
    """Wall-time limit of the model-based solver in s: in (0, ``TIME_LIMIT_MAX``] (a week)
    or OptionError."""
    v = _number("time_limit", seconds, "a number of seconds")
    if not np.isfinite(v) or not 0 < v <= TIME_LIMIT_MAX:
        raise OptionError(f"time_limit must be in (0, {TIME_LIMIT_MAX:g}] s, got {seconds!r}")
    return v


def check_dtype(dtype) -> np.dtype:
    """float32 or float64 or ValueError."""
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise OptionError(f"dtype must be float32 or float64, got {dtype!r}") from None
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise OptionError(f"dtype must be float32 or float64, got {dt}")
    return dt


def available_memory() -> int:
    """Bytes of memory available now (Linux MemAvailable; else physical pages free)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def estimate_peak_memory(
    n_t: int,
    n_x: int,
    n_y: int = 1,
    *,
    n_z: int | None = None,
    upsample: int = 1,
    dtype=np.float64,
    method: str = "ner",
    n_points: int | None = None,
    dx: float | None = None,
    dt: float | None = None,
    c: float | None = None,
    dz: float | None = None,
    square: bool | None = None,
) -> int:
    """Estimated peak memory in bytes of a planar reconstruction.

    Parameters: ``n_t`` samples; ``n_x``, ``n_y`` lateral grid (``n_y = 1`` in 2-D; the
    planar methods zero-pad it to the fast transform lengths of
    ``driver.physics.fast_lengths.fast_lateral``, e.g. 226 -> 240, and the estimate counts
    those; ``square``: dy = dx, which may give both axes one length; None: unknown, the
    larger of the two);
    ``n_z`` output depth samples (default n_t); ``upsample`` lateral factor; ``dtype``
    float32/float64; ``method`` "ner"/"linear"/"nearest"/"cubic"/"nedner"/"kwave";
    ``n_points`` sensors for NEDNER (its weighted A-lines, the full-plane type-1 spectrum
    and, for weights not given, the Voronoi raster of ``driver.physics.weights``).
    ``method="tv"`` gives `tv_memory` on the free-space operator's padded grid
    (`driver.physics.forward`'s padding rule) when the pitch ``dx`` (m), ``dt`` (s) and
    ``c`` (m/s) are given (``dz`` default c·dt), else on a conservative one (dx = c·dt).

    The planar methods (`service.recon.planar`) are counted phase by phase, the arrays
    alive in each (b: the real itemsize, complex 2b): the lateral spectrum A (n_t x
    n_y x (n_x/2+1); NEDNER's type-1 output is the full plane n_t x n_y x n_x, of which A is
    a view), alive to the end; the temporal fine grid U (columns x L), the evaluated
    spectrum F and its transposed k-space image K (depth rows x columns); K zero-padded
    for ``upsample`` u (u² times larger); the inverse lateral FFT's complex intermediate
    (as large as the padded K) and the output (depth rows x n_y u x n_x u); the cropped
    copy when the transform grid was padded. The peak is the largest phase, plus the
    input (measured within ±25 % for ner/nedner at upsample 1-8,
    tests/service/test_memory_admission.py).
    """
    b = np.dtype(dtype).itemsize
    cb = 2 * b
    n_z = n_t if n_z is None else n_z
    n_in = n_t * n_y * n_x  # the input, as given
    n_y0, n_x0 = n_y, n_x
    if method not in ("tv", "kwave"):  # the transform sizes the planar methods use
        n_y, n_x = padded_lateral(n_y, n_x, square)
        n_z = fast_dct1_rows(max(int(n_z), 2))  # the depth rows the transform works on
    cols = n_y * (n_x // 2 + 1)
    spectrum = n_t * cols * cb
    if method in ("ner", "nedner"):
        from driver.physics.nufft import make_grid

        fine = cols * make_grid(n_t, "nufft", 1e-6).L * cb
    else:
        fine = cols * (2 * n_t - 1) * cb
    kimage = n_z * cols * cb
    u_y = upsample if n_y > 1 else 1
    padded = n_z * n_y * u_y * (n_x * upsample // 2 + 1) * cb if upsample > 1 else kimage
    out = n_z * n_y * u_y * n_x * upsample * b
    crop = n_z * n_y0 * u_y * n_x0 * upsample * b if (n_y0, n_x0) != (n_y, n_x) else 0
    a_alive = spectrum
    front = 0
    if method == "nedner":  # type-1 NUFFT: the full plane, A a view of it; weighted A-lines (float64 + complex)
        a_alive = n_t * n_y * n_x * cb
        front = a_alive + (n_points or 0) * n_t * (8 + cb)
        # the Voronoi raster of weights not given (driver.physics.weights: ~1024 samples per cell within
        # 2^20, ~80 bytes each; measured 82 MiB (tracemalloc) from 500 to 3000 sensors since its
        # steps free their arrays as they end, 98 MiB before)
        front = max(front, 80 * min(1024 * max(n_points or 0, 768), 1 << 20) if n_points else 0)
    if method == "cubic":  # pchip per column group: the mirrored series and its spectra in complex128
        fine = 5 * cols * (2 * n_t - 1) * 16
    peak = max(front,
               a_alive + fine + kimage,                      # temporal step: U and F
               a_alive + 2 * kimage,                         # F transposed into K
               a_alive + kimage + padded if upsample > 1 else 0,  # K zero-padded
               a_alive + 2 * padded + out,                   # inverse lateral FFT
               a_alive + out + crop)                         # cropped to the grid asked for
    if method == "kwave":  # two half-lateral spectra (transposed copy) + per-chunk buffers
        peak = int(2.4 * n_t * cols * 2 * b) + n_t * n_y * n_x * b
    peak += n_in * b  # the input
    if method == "tv":  # model-based: its own count (the warm start needs less)
        n_data = n_t * (n_points or n_x * n_y)
        if dx and dt and c:  # the operator's own padding rule
            from driver.physics.forward import _pad_sizes

            pad = _pad_sizes((n_z, n_y, n_x), dx, dz or c * dt, dt, n_t, c, 0.0)
        else:  # the worst usual case dx = c dt (lateral reach of the record = n_t pitches)
            pad = (max(n_z, n_t), n_y + n_t if n_y > 1 else 1, n_x + n_t)
        return max(int(peak * 1.1), tv_memory((n_z, n_y, n_x), pad, n_data, n_t, dtype))
    return int(1.04 * peak)  # 4 % above the count: allocator and FFT-plan overheads


def padded_lateral(n_y: int, n_x: int, square: bool | None = None) -> tuple[int, int]:
    """The lateral transform sizes (n_y', n_x') of the planar methods for an n_y x n_x
    grid (``driver.physics.fast_lengths.fast_lateral``); ``square`` None (pitches unknown): the
    larger of the square and non-square choices, axis by axis."""
    if square is not None:
        return fast_lateral(n_y, n_x, square)
    (ay, ax), (by, bx) = fast_lateral(n_y, n_x, False), fast_lateral(n_y, n_x, True)
    return max(ay, by), max(ax, bx)


def tv_memory(image_shape, padded_shape, n_data: int, n_t: int, dtype=np.float64) -> int:
    """Estimated peak bytes of the model-based reconstruction (`service.recon.tv`): the
    solver's image-sized vectors live while the operator works (the TV proximal map's dual,
    d vectors, and d − 1 of the iterates: fitted to the peak measured on the 48² × 256 case
    of tests/service/test_memory_admission.py, 9 % below the earlier primal-dual solver's
    there) in ``dtype``, three data-sized vectors, and the operator's working arrays on the padded grid in its working
    precision (complex64 for float32, complex128 for float64;
    `service.recon.operator.PlanarOperator`): at its peak the temporal fine grid (L per
    padded half-spectrum column, `driver.physics.nufft.grid_length`) beside the k-space
    image (max(N_z, n_t) per column), plus 25 % (allocator, FFT buffers, the warm start's
    leftovers; tests/service/test_memory_admission.py measures it within 25 %)."""
    from driver.physics.nufft import grid_length

    b = np.dtype(dtype).itemsize
    n_img = int(np.prod(image_shape))
    d = sum(1 for n in image_shape if n > 1)
    solver = (2 * d - 1) * n_img * b + 3 * n_data * b
    nz2, ny2, nx2 = padded_shape
    operator = 2 * b * ny2 * (nx2 // 2 + 1) * (grid_length(n_t) + max(nz2, n_t))
    return int(1.25 * (solver + operator))


def check_memory(needed: int, memory_limit) -> None:
    """ValueError if ``needed`` bytes exceed ``memory_limit`` (default: available now)."""
    limit = available_memory() if memory_limit is None else int(memory_limit)
    if needed > limit:
        raise ValueError(
            f"reconstruction needs about {needed / 2**30:.2f} GiB at its peak, more than the "
            f"limit of {limit / 2**30:.2f} GiB; reduce n_t, n_z, the grid or upsample, or use float32"
        )
