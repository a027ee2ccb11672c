"""Input validation and the peak-memory estimate shared by the reconstructions."""
from __future__ import annotations

import os

import numpy as np


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


def check_eps(eps) -> float:
    """NUFFT tolerance in [1e-14, 1e-1] or ValueError."""
    e = float(eps)
    if not (1e-14 <= e <= 1e-1):
        raise ValueError(f"eps must be in [1e-14, 1e-1], got {eps!r}")
    return e


def check_dtype(dtype) -> np.dtype:
    """float32 or float64 or ValueError."""
    dt = np.dtype(dtype)
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dt}")
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
    ``service.recon.planar._fast_lateral``, e.g. 226 -> 240, and the estimate counts
    those; ``square``: dy = dx, which may give both axes one length; None: unknown, the
    larger of the two);
    ``n_z`` output depth samples (default n_t); ``upsample`` lateral factor; ``dtype``
    float32/float64; ``method`` "ner"/"linear"/"nearest"/"cubic"/"nedner"/"kwave";
    ``n_points`` sensors for NEDNER (adds the type-1 NUFFT's full-plane spectrum).
    ``method="tv"`` gives `tv_memory` on the free-space operator's padded grid
    (`driver.physics.forward`'s padding rule) when the pitch ``dx`` (m), ``dt`` (s) and
    ``c`` (m/s) are given (``dz`` default c·dt), else on a conservative one (dx = c·dt).

    The estimate adds the arrays alive at the worst moment of the pipeline: the lateral
    spectrum (n_t x n_y x (n_x/2+1) complex), the oversampled temporal grid (about twice
    that), the k-space image (n_z columns) and the output volume, plus 10 % slack.
    """
    b = np.dtype(dtype).itemsize
    n_z = n_t if n_z is None else n_z
    n_in = n_t * n_y * n_x  # the input, as given
    if method not in ("tv", "kwave"):  # the transform sizes the planar methods use
        n_y, n_x = padded_lateral(n_y, n_x, square)
    cols = n_y * (n_x // 2 + 1)
    spectrum = n_t * cols * 2 * b
    fine = 2 * (n_t + 1) * cols * 2 * b if method in ("ner", "nedner") else (2 * n_t) * cols * 2 * b
    kimage = n_z * cols * 2 * b
    out = n_z * n_y * n_x * upsample ** (2 if n_y > 1 else 1) * b
    peak = max(spectrum + fine, fine + kimage, kimage * (1 + upsample**2) + out)
    if method == "nedner":
        peak = max(peak, 2 * n_t * n_y * n_x * 2 * b + (n_points or 0) * n_t * 3 * b)
    if method == "kwave":  # two half-lateral spectra (transposed copy) + per-chunk buffers
        peak = int(2.4 * spectrum) + n_t * n_y * n_x * b
    peak += n_in * b  # the input
    if method == "tv":  # model-based: its own count (the warm start needs less)
        n_data = n_t * (n_points or n_x * n_y)
        if dx and dt and c:  # the operator's own padding rule
            from driver.physics.forward import _pad_sizes

            pad = _pad_sizes((n_z, n_y, n_x), dx, dz or c * dt, dt, n_t, c, 0.0)
        else:  # the worst usual case dx = c dt (lateral reach of the record = n_t pitches)
            pad = (max(n_z, n_t), n_y + n_t if n_y > 1 else 1, n_x + n_t)
        return max(int(peak * 1.1), tv_memory((n_z, n_y, n_x), pad, n_data, n_t, dtype))
    return int(peak * 1.1)


def padded_lateral(n_y: int, n_x: int, square: bool | None = None) -> tuple[int, int]:
    """The lateral transform sizes (n_y', n_x') of the planar methods for an n_y x n_x
    grid (``service.recon.planar._fast_lateral``); ``square`` None (pitches unknown): the
    larger of the square and non-square choices, axis by axis."""
    from service.recon.planar import _fast_lateral

    if square is not None:
        return _fast_lateral(n_y, n_x, square)
    (ay, ax), (by, bx) = _fast_lateral(n_y, n_x, False), _fast_lateral(n_y, n_x, True)
    return max(ay, by), max(ax, bx)


def tv_memory(image_shape, padded_shape, n_data: int, n_t: int, dtype=np.float64) -> int:
    """Estimated peak bytes of the model-based reconstruction (`service.recon.tv`): the
    solver's image-sized vectors (p, its previous and extrapolated values, Kᵀy, and the
    stacked K p with its d gradient components, twice) in ``dtype``, three data-sized
    vectors, and the operator's float64/complex128 working arrays on the padded grid
    (lateral spectrum, temporal fine grid, k-space image: about 10 complex values per
    padded half-spectrum column and depth row), plus 30 % (a 64 x 64 x 256 run peaked at
    0.72 GiB above the interpreter against 0.72 GiB estimated with 10 %)."""
    b = np.dtype(dtype).itemsize
    n_img = int(np.prod(image_shape))
    d = sum(1 for n in image_shape if n > 1)
    solver = (4 + 2 * d) * n_img * b + 3 * n_data * b
    nz2, ny2, nx2 = padded_shape
    operator = 10 * 16 * max(nz2, n_t) * ny2 * (nx2 // 2 + 1)
    return int(1.3 * (solver + operator))


def check_memory(needed: int, memory_limit) -> None:
    """ValueError if ``needed`` bytes exceed ``memory_limit`` (default: available now)."""
    limit = available_memory() if memory_limit is None else int(memory_limit)
    if needed > limit:
        raise ValueError(
            f"reconstruction needs about {needed / 2**30:.2f} GiB at its peak, more than the "
            f"limit of {limit / 2**30:.2f} GiB; reduce n_t, n_z, the grid or upsample, or use float32"
        )
