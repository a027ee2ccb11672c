"""tv's 16-bit stores: what waits between two iterations at half its bytes or less.

The solver (`fpscan.service.recon.tv.fista`) keeps three vectors between iterations in fixed point
(package doc, "Memory"):

- the proximal map's dual (|components| <= 1): int16 with the quantum 1 / 32767 for a
  float32 solver, float32 for a float64 one (`store_dual`, `restore_dual`);
- the last preconditioned gradient G(A y − g), which only the next gain test reads:
  int16 with the quantum max|·| / 32767 (`store_gradient`; `gain_lower_bound` subtracts
  what the rounding can add, so the test stays a lower bound of ‖BA‖);
- the last move b = x − x_prev, from which y = x + β b was made: int16 with the quantum
  max|b| / 32767 (`store_move`); x is read back as y − β q round(b / q), exactly, so only y,
  the extrapolation point, carries the rounding (`extrapolate_fixed`).

The compiled loops here are numba kernels (``cache=True``: ``fpscan warmup`` fills their
cache; `fpscan.service.recon.methods.tv`'s ``kernel_modules``). Measurements:
docs/tv-measurements.md, "Memory".
"""
from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from fpscan.physics import workspace

__all__ = ["DUAL_SCALE", "store_dual", "restore_dual", "store_gradient", "gain_lower_bound", "store_move", "extrapolate_fixed"]

#: the fixed-point scale of a float32 dual between calls (`store_dual`): |q| <= 1 as int16, q · 32767
DUAL_SCALE = 32767.0


def store_dual(dual: np.ndarray) -> np.ndarray:
    """The proximal map's dual at half the working precision's bytes, for the wait between
    iterations (`fpscan.service.recon.tv.fista.run_fista`).

    float32 -> int16 fixed point, round(q · `DUAL_SCALE`) (error <= 1.5e-5, where float16
    kept 2⁻¹¹ near 1); float64 -> float32. By compiled parallel loops: numpy's float16 casts
    took 0.06-0.08 s a call on the three images of a 512 × 128² volume, 3 s of tv's 30 s there.

    Parameters
    ----------
    dual : ndarray
        The dual ``(d, n_z, n_x)`` / ``(d, n_z, n_y, n_x)`` (any shape), C-contiguous, float32 or
        float64, |components| <= 1 (dimensionless).

    Returns
    -------
    ndarray
        Its shape: int16 (from float32) or float32 (from float64); `restore_dual` undoes it.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import restore_dual, store_dual
    >>> q = np.array([[-1.0, 0.5, 1e-6]], dtype=np.float32)
    >>> store_dual(q).tolist(), store_dual(q.astype(np.float64)).dtype
    ([[-32767, 16384, 0]], dtype('float32'))
    >>> float(np.abs(restore_dual(store_dual(q), np.float32) - q).max()) < 1.6e-5
    True
    """
    if dual.dtype == np.float32:
        out = workspace.take(dual.shape, np.int16)
        _quantise(dual.reshape(-1), out.reshape(-1), DUAL_SCALE)
    else:
        out = workspace.take(dual.shape, np.float32)
        _cast(dual.reshape(-1), out.reshape(-1))
    return out


def store_gradient(g: np.ndarray) -> tuple[np.ndarray, float]:
    """A preconditioned gradient G(A y − g) kept for the next iteration's gain
    (`fpscan.service.recon.tv.fista.run_fista`) as 16-bit fixed point.

    (round(g / q), q) with the quantum q = max |g| / 32767 (1 for g = 0), so that each value is
    off by at most q / 2 (`gain_lower_bound` subtracts that).

    Parameters
    ----------
    g : ndarray
        The gradient, an image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` (any shape, C-contiguous),
        float32 or float64, in the image's unit.

    Returns
    -------
    tuple
        ``(values, quantum)``: int16 values, flat ``(g.size,)``, and q (g's unit).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import store_gradient
    >>> values, quantum = store_gradient(np.array([[2.0, -1.0], [0.0, 0.5]]))
    >>> values.tolist(), quantum == 2.0 / 32767
    ([32767, -16383, 0, 8192], True)
    >>> store_gradient(np.zeros(3))[1]  # nothing to scale: the quantum is 1
    1.0
    """
    flat = g.reshape(-1)
    top = _max_abs(flat)
    quantum = top / DUAL_SCALE if top > 0 else 1.0
    out = workspace.take(flat.shape, np.int16)
    _quantise(flat, out, 1.0 / quantum)
    return out, quantum


def gain_lower_bound(g: np.ndarray, stored: tuple[np.ndarray, float]) -> float:
    """‖g − g_prev‖ from below, with g_prev kept by `store_gradient`.

    The distance to the fixed-point values less the most their rounding can move it, q √N / 2
    (‖e‖ for |e_i| <= q / 2; with 1e-6 of it for the float64 sums), so that the solver's L rises
    only where ‖BA‖ really exceeds it.

    Parameters
    ----------
    g : ndarray
        The new gradient, flat ``(N,)``, float32 or float64.
    stored : tuple
        ``(values, quantum)`` from `store_gradient` of a gradient of N values.

    Returns
    -------
    float
        A lower bound of ‖g − g_prev‖₂ (g's unit), >= 0.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import gain_lower_bound, store_gradient
    >>> kept = store_gradient(np.array([1.0, 0.0]))
    >>> gain_lower_bound(np.array([1.0, 0.0]), kept)  # the same vector
    0.0
    >>> 0.99 < gain_lower_bound(np.array([1.0, 1.0]), kept) <= 1.0
    True
    """
    values, quantum = stored
    measured = _difference_norm_fixed(g, values, quantum)
    return max(0.0, measured - 0.5 * quantum * math.sqrt(g.size) * (1.0 + 1e-6))


@numba.njit(parallel=True, cache=True)
def _max_abs(a: np.ndarray) -> float:
    """The largest |a_i| of a flat array (0 for an empty one), in float64."""
    top = 0.0
    for i in numba.prange(a.size):
        top = max(top, abs(np.float64(a[i])))
    return top


@numba.njit(parallel=True, cache=True)
def _difference_norm_fixed(a: np.ndarray, s: np.ndarray, quantum: float) -> float:
    """‖a − s · quantum‖₂ of a flat array and fixed-point values ``s``, summed in float64."""
    total = 0.0
    for i in numba.prange(a.size):
        d = np.float64(a[i]) - np.float64(s[i]) * quantum
        total += d * d
    return math.sqrt(total)


def restore_dual(stored: np.ndarray, dtype: npt.DTypeLike) -> np.ndarray:
    """`store_dual` undone: the dual in the working precision.

    Parameters
    ----------
    stored : ndarray
        `store_dual`'s array: int16 (fixed point of scale `DUAL_SCALE`) or float32.
    dtype : dtype
        The working precision: float32 (from int16) or float64 (from float32).

    Returns
    -------
    ndarray
        A new array of ``stored``'s shape and ``dtype``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import restore_dual
    >>> restore_dual(np.array([32767, -16384], dtype=np.int16), np.float32).tolist()
    [1.0, -0.5000152587890625]
    >>> restore_dual(np.array([0.25], dtype=np.float32), np.float64).dtype
    dtype('float64')
    """
    out = workspace.take(stored.shape, dtype)
    if stored.dtype == np.int16:
        _dequantise(stored.reshape(-1), out.reshape(-1), 1.0 / DUAL_SCALE)
    else:
        _cast(stored.reshape(-1), out.reshape(-1))
    return out


@numba.njit(parallel=True, cache=True)
def _quantise(q: np.ndarray, out: np.ndarray, scale: float) -> None:
    """Fixed point: out = round(clip(q · scale, -32767, 32767)) (flat arrays; ``out`` int16)."""
    for i in numba.prange(q.size):
        out[i] = math.floor(min(max(q[i] * scale, -32767.0), 32767.0) + 0.5)


@numba.njit(parallel=True, cache=True)
def _dequantise(s: np.ndarray, out: np.ndarray, inv_scale: float) -> None:
    """Fixed point undone: out = s · inv_scale (flat arrays)."""
    for i in numba.prange(s.size):
        out[i] = s[i] * inv_scale


@numba.njit(parallel=True, cache=True)
def _cast(src: np.ndarray, out: np.ndarray) -> None:
    """A parallel copy: out = src, converted to ``out``'s dtype (flat arrays)."""
    for i in numba.prange(src.size):
        out[i] = src[i]



def store_move(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray,
                scale_last: float, b_max: float) -> tuple[np.ndarray, float]:
    """The move b = x_new − x as 16-bit fixed point (FISTA's extrapolation's; Beck & Teboulle 2009).

    x = v + inv_l gy − scale_last b_last as `fpscan.service.recon.tv.fista.moves` reads it; the move
    is kept as (round(b / q), q) with q = ``b_max`` / 32767. y = x_new + β q round(b / q) then
    differs from the exact extrapolation by at most β q / 2 a voxel, and x = y − β q round(b / q)
    is exact (to the working precision's rounding), which is all the solver needs of x.

    Parameters
    ----------
    xn, v, gy : ndarray
        Flat ``(N,)`` arrays of one dtype (float32 or float64): the new iterate, the gradient step
        v = y − gy / L and the gradient G(A y − g), in the image's unit.
    inv_l : float
        1 / L.
    b_last : ndarray of int16
        The last move's fixed-point values ``(N,)``.
    scale_last : float
        Its scale (β q of the last move; 0 at the start).
    b_max : float
        max |b| (`fpscan.service.recon.tv.fista.moves`); 0: no move.

    Returns
    -------
    tuple
        ``(values, quantum)``: int16 ``(N,)`` and q (0 for no move).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import store_move
    >>> zero = np.zeros(2, dtype=np.int16)
    >>> values, q = store_move(np.array([1.0, 0.5]), np.zeros(2), np.zeros(2), 1.0, zero, 0.0, 1.0)
    >>> values.tolist(), q == 1.0 / 32767
    ([32767, 16384], True)
    >>> store_move(np.zeros(2), np.zeros(2), np.zeros(2), 1.0, zero, 0.0, 0.0)[1]  # no move
    0.0
    """
    quantum = b_max / DUAL_SCALE if b_max > 0 else 0.0
    out = workspace.take(xn.shape, np.int16)
    _quantise_move(xn, v, gy, inv_l, b_last, scale_last, 1.0 / quantum if quantum > 0 else 0.0, out)
    return out, quantum


@numba.njit(parallel=True, cache=True)
def _quantise_move(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray,
                   scale_last: float, mult: float, out: np.ndarray) -> None:
    """The move's fixed point: out = round(clip((x_new − x) · mult, ±32767)), with
    x = v + inv_l gy − scale_last b_last (flat arrays)."""
    for i in numba.prange(xn.size):
        x = np.float64(v[i]) + inv_l * np.float64(gy[i]) - scale_last * np.float64(b_last[i])
        out[i] = math.floor(min(max((np.float64(xn[i]) - x) * mult, -32767.0), 32767.0) + 0.5)


@numba.njit(parallel=True, cache=True)
def extrapolate_fixed(xn: np.ndarray, b: np.ndarray, scale: float) -> None:
    """In place, xn ← xn + scale · b: FISTA's next y = x_new + β q b in the new iterate's place.

    Parameters
    ----------
    xn : ndarray
        The new iterate, flat ``(N,)``, float32 or float64; overwritten.
    b : ndarray of int16
        The move's fixed-point values ``(N,)`` (`store_move`).
    scale : float
        β q.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.stores import extrapolate_fixed
    >>> x = np.array([1.0, 2.0])
    >>> extrapolate_fixed(x, np.array([2, -4], dtype=np.int16), 0.25)
    >>> x.tolist()
    [1.5, 1.0]
    """
    for i in numba.prange(xn.size):
        xn[i] = xn[i] + scale * b[i]
