"""The copies, fills and checks between the transforms, on every core (numba ``prange``).

Between its FFTs and its compiled temporal kernels a reconstruction moves whole volumes: the
data into the zero-padded grid of the lateral FFT, a slab's spectrum into the whole spectrum,
the image out of its inverse transform, a finiteness check of the input. Written as numpy
statements these run on one core and, at 16 threads, took most of NER's time (its parallel
parts scaled 9-11x, NER as a whole 2.7x: docs/performance.md). Here each runs on every core of
numba's pool, writing its output row by row, so that a volume's pages are also first written
(and faulted in, where fresh) in parallel.

Every kernel is ``@numba.njit(cache=True)`` (`fpscan.service.recon.warmup` fills the cache).
Importing this module imports numba: callers import it on first use, for arrays too large for
numpy alone (`fpscan.physics.fft_engine.is_small`).
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["nonfinite", "pad_rows", "pad_volume", "embed_rows", "embed_row_set", "take_rows", "crop_rows", "gather_nodes",
           "zero_columns", "zero_beyond", "fill_zero", "place_points", "scale_rows", "difference_norm"]


@numba.njit(parallel=True, cache=True)
def nonfinite(bits: np.ndarray, mask: int) -> bool:
    """Whether the IEEE 754 numbers whose bits ``bits`` holds include a NaN or an infinity:
    those whose exponent bits (``mask``) are all set. Integer arithmetic on the bits, so that
    the loop runs in SIMD lanes (a floating-point sum runs in order) and no value can overflow.

    Parameters
    ----------
    bits : ndarray ``(n,)`` uint32 (float32 viewed) or uint64 (float64 viewed).
    mask : int
        The exponent bits: ``0x7F800000`` (float32) or ``0x7FF0000000000000`` (float64).

    Returns
    -------
    bool
    """
    n = bits.shape[0]
    block = 1 << 16
    m = bits.dtype.type(mask)
    found = 0
    for b in numba.prange((n + block - 1) // block):
        low = m
        for i in range(b * block, min(n, (b + 1) * block)):
            low = min(low, (bits[i] & m) ^ m)  # 0 where every exponent bit is set
        if low == 0:
            found += 1
    return found > 0


@numba.njit(parallel=True, cache=True)
def pad_rows(src: np.ndarray, dst: np.ndarray, off: int) -> None:
    """dst[i, j, off:off + n] = src[i, j, :], the rest of each row zero, for the rows of ``src``
    ``(m, r, n)`` in ``dst`` ``(m, r, n')``, n' >= off + n (the x axis zero-padded to its FFT
    length; ``off`` > 0: centred in it).

    Parameters
    ----------
    src : ndarray ``(m, r, n)``
    dst : ndarray ``(m, r, n')``, written in place.
    off : int, the first sample of each row of ``src`` in ``dst``.
    """
    m, r, n = src.shape
    n2 = dst.shape[2]
    zero = dst.dtype.type(0)
    for q in numba.prange(m * r):
        i = q // r
        j = q - i * r
        s = src[i, j]
        d = dst[i, j]
        for k in range(off):
            d[k] = zero
        for k in range(n):
            d[off + k] = s[k]
        for k in range(off + n, n2):
            d[k] = zero


@numba.njit(parallel=True, cache=True)
def pad_volume(src: np.ndarray, dst: np.ndarray) -> None:
    """dst[i, j, k] = src[i, j, k] inside ``src`` ``(m, r, n)``, zero elsewhere in ``dst``
    ``(m' >= m, r' >= r, n' >= n)``: a volume zero-padded at the end of every axis.

    Parameters
    ----------
    src : ndarray ``(m, r, n)``
    dst : ndarray ``(m', r', n')``, written in place.
    """
    m, r, n = src.shape
    m2, r2, n2 = dst.shape
    zero = dst.dtype.type(0)
    for q in numba.prange(m2 * r2):
        i = q // r2
        j = q - i * r2
        d = dst[i, j]
        if i < m and j < r:
            s = src[i, j]
            for k in range(n):
                d[k] = s[k]
            for k in range(n, n2):
                d[k] = zero
        else:
            for k in range(n2):
                d[k] = zero


@numba.njit(parallel=True, cache=True)
def embed_rows(src: np.ndarray, dst: np.ndarray, off: int) -> None:
    """dst[i, off:off + r] = src[i], every other row of dst[i] zero: each plane ``(r, n)`` of
    ``src`` ``(m, r, n)`` in the plane ``(r', n)`` of ``dst`` ``(m, r', n)``, r' >= off + r
    (the y axis zero-padded; ``off`` > 0: centred in it).

    Parameters
    ----------
    src : ndarray ``(m, r, n)``
    dst : ndarray ``(m, r', n)``, written in place.
    off : int, the first row of each plane of ``src`` in ``dst``.
    """
    m, r, n = src.shape
    r2 = dst.shape[1]
    zero = dst.dtype.type(0)
    for q in numba.prange(m * r2):
        i = q // r2
        j = q - i * r2
        d = dst[i, j]
        if off <= j < off + r:
            s = src[i, j - off]
            for k in range(n):
                d[k] = s[k]
        else:
            for k in range(n):
                d[k] = zero


@numba.njit(parallel=True, cache=True)
def embed_row_set(src: np.ndarray, slot: np.ndarray, dst: np.ndarray) -> None:
    """dst[i, j] = src[i, slot[j]] where slot[j] >= 0, else zero: the rows of ``src``
    ``(m, r, n)`` placed at chosen rows of ``dst`` ``(m, len(slot), n)`` (a lateral spectrum
    of sensors on some of the grid's rows).

    Parameters
    ----------
    src : ndarray ``(m, r, n)``
    slot : ndarray ``(r',)`` int64, the row of ``src`` each row of ``dst`` takes, or -1.
    dst : ndarray ``(m, r', n)``, written in place.
    """
    m = dst.shape[0]
    r2 = dst.shape[1]
    n = dst.shape[2]
    zero = dst.dtype.type(0)
    for q in numba.prange(m * r2):
        i = q // r2
        j = q - i * r2
        d = dst[i, j]
        if slot[j] >= 0:
            s = src[i, slot[j]]
            for k in range(n):
                d[k] = s[k]
        else:
            for k in range(n):
                d[k] = zero


@numba.njit(parallel=True, cache=True)
def take_rows(src: np.ndarray, rows: np.ndarray, dst: np.ndarray) -> None:
    """dst[i, j] = src[i, rows[j]]: chosen rows of each plane of ``src`` ``(m, r, n)`` into
    ``dst`` ``(m, len(rows), n)``.

    Parameters
    ----------
    src : ndarray ``(m, r, n)``
    rows : ndarray ``(r',)`` int64
    dst : ndarray ``(m, r', n)``, written in place.
    """
    m, r2, n = dst.shape
    for q in numba.prange(m * r2):
        i = q // r2
        j = q - i * r2
        s = src[i, rows[j]]
        d = dst[i, j]
        for k in range(n):
            d[k] = s[k]


@numba.njit(parallel=True, cache=True)
def crop_rows(src: np.ndarray, dst: np.ndarray, oy: int, ox: int) -> None:
    """dst[i, j, k] = src[i, oy + j, ox + k] for the extent of ``dst`` ``(m, r, n)``: a window
    of each plane of ``src`` ``(m, r' >= oy + r, n' >= ox + n)`` (an image cropped to the grid
    asked for, or to the image inside a padded working grid).

    Parameters
    ----------
    src : ndarray ``(m, r', n')``
    dst : ndarray ``(m, r, n)``, written in place.
    oy, ox : int, the window's first row and sample.
    """
    m, r, n = dst.shape
    for q in numba.prange(m * r):
        i = q // r
        j = q - i * r
        s = src[i, oy + j]
        d = dst[i, j]
        for k in range(n):
            d[k] = s[ox + k]


@numba.njit(parallel=True, cache=True)
def gather_nodes(g: np.ndarray, rows: np.ndarray, cols: np.ndarray, a: int, out: np.ndarray) -> None:
    """out[p, a + t] = g[t, rows[p], cols[p]] for every point p and plane t of ``g``
    ``(m, r, n)``: the values at chosen nodes, time ``a`` to ``a + m`` of their series.

    Parameters
    ----------
    g : ndarray ``(m, r, n)``
    rows, cols : ndarray ``(n_points,)`` int64
    a : int, the first time sample.
    out : ndarray ``(n_points, n_t)``, written in place at those samples.
    """
    m = g.shape[0]
    for p in numba.prange(rows.shape[0]):
        y = rows[p]
        x = cols[p]
        o = out[p]
        for t in range(m):
            o[a + t] = g[t, y, x]


@numba.njit(parallel=True, cache=True)
def zero_columns(x: np.ndarray, cols: np.ndarray) -> None:
    """x[:, cols] = 0 for a 2-D ``x``, row by row on every core.

    Parameters
    ----------
    x : ndarray ``(m, n)``, written in place.
    cols : ndarray ``(k,)`` int64
    """
    zero = x.dtype.type(0)
    for i in numba.prange(x.shape[0]):
        row = x[i]
        for c in cols:
            row[c] = zero


@numba.njit(parallel=True, cache=True)
def zero_beyond(x: np.ndarray, first: np.ndarray) -> None:
    """x[c, first[c]:] = 0 for a 2-D ``x`` (a band limit: each column's rows above its cut).

    Parameters
    ----------
    x : ndarray ``(m, n)``, written in place.
    first : ndarray ``(m,)`` int64, the first row zeroed of each.
    """
    zero = x.dtype.type(0)
    n = x.shape[1]
    for c in numba.prange(x.shape[0]):
        row = x[c]
        for j in range(max(0, first[c]), n):
            row[j] = zero


@numba.njit(parallel=True, cache=True)
def fill_zero(x: np.ndarray) -> None:
    """x[...] = 0 for a C-contiguous array given flat, in blocks of 64 Ki elements.

    Parameters
    ----------
    x : ndarray ``(n,)``, written in place.
    """
    n = x.shape[0]
    block = 1 << 16
    zero = x.dtype.type(0)
    for b in numba.prange((n + block - 1) // block):
        for i in range(b * block, min(n, (b + 1) * block)):
            x[i] = zero


@numba.njit(parallel=True, cache=True)
def place_points(values: np.ndarray, scale: np.ndarray, rows: np.ndarray, cols: np.ndarray, a: int,
                 dst: np.ndarray) -> None:
    """dst[t, rows[p], cols[p]] = values[p, a + t] * scale[p] for every point p and plane t of
    ``dst`` ``(m, n_y, n_x)``, zero elsewhere: weighted A-lines placed on their nodes of a grid
    (distinct nodes), time ``a`` to ``a + m``.

    Parameters
    ----------
    values : ndarray ``(n_points, n_t)``
    scale : ndarray ``(n_points,)`` float64
    rows, cols : ndarray ``(n_points,)`` int64, the nodes.
    a : int, the first time sample.
    dst : ndarray ``(m, n_y, n_x)``, written in place.
    """
    m = dst.shape[0]
    n_p = values.shape[0]
    zero = dst.dtype.type(0)
    for t in numba.prange(m):
        plane = dst[t]
        for j in range(plane.shape[0]):
            for k in range(plane.shape[1]):
                plane[j, k] = zero
    for p in numba.prange(n_p):
        v = values[p]
        s = scale[p]
        y = rows[p]
        x = cols[p]
        for t in range(m):
            dst[t, y, x] = v[a + t] * s


@numba.njit(parallel=True, cache=True)
def scale_rows(x: np.ndarray, first: float, last: float) -> None:
    """x[0] *= first, x[-1] *= last for a 2-D ``x``, each row's elements in parallel.

    Parameters
    ----------
    x : ndarray ``(m, n)``, written in place.
    first, last : float
    """
    m, n = x.shape
    for k in numba.prange(n):
        x[0, k] *= first
        x[m - 1, k] *= last


@numba.njit(parallel=True, cache=True)
def difference_norm(a: np.ndarray, b: np.ndarray) -> float:
    """‖a − b‖₂ of two flat arrays, summed in float64 on every core (no work array; numpy's
    ``linalg.norm(a - b)`` makes the difference and sums in BLAS, whose OpenBLAS threads then spin
    for about 0.1 s, taking a core from the compiled kernels that follow). Blocks of 4096 terms
    are summed on the threads and their sums added in order, so that the result does not depend
    on the number of threads (tv's stopping rule and momentum restarts compare residuals: a
    different last bit could change the iteration a run stops at).

    Parameters
    ----------
    a, b : ndarray
        Flat ``(N,)`` arrays (float32 or float64).

    Returns
    -------
    float
        The distance, their unit.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.array_kernels import difference_norm
    >>> difference_norm(np.array([3.0, 0.0]), np.array([0.0, 4.0]))
    5.0
    >>> difference_norm(np.ones(3, dtype=np.float32), np.ones(3, dtype=np.float32))
    0.0
    """
    n = a.size
    block = 4096
    parts = np.empty((n + block - 1) // block, np.float64)
    for k in numba.prange(parts.size):  # fixed blocks, summed in order: the same bits on any number of threads
        part = 0.0
        for i in range(k * block, min(n, (k + 1) * block)):
            d = np.float64(a[i]) - np.float64(b[i])
            part += d * d
        parts[k] = part
    total = 0.0
    for k in range(parts.size):
        total += parts[k]
    return math.sqrt(total)
