"""tv's vector kernels, one set per array namespace: the compiled loops on the CPU, CuPy on a GPU.

The solver's loop (`fpscan.service.recon.tv.fista.run_fista`: the steps, the momentum and its restarts,
the step's L, the λ continuation and the stopping rule) is written once; the work it does on
whole images goes through a :class:`Kernels` set chosen by the start image's array type
(`fpscan.service.recon.tv.fista.kernels_for`). On NumPy arrays that is the numba kernels of
`fpscan.service.recon.tv.prox`, `fpscan.service.recon.tv.stores` and `fpscan.service.recon.tv.fista` (their
memory-saving sweeps, `fpscan.service.recon.tv.fista.COMPILED`); on CuPy arrays the same arithmetic as array expressions (:func:`array_kernels`, also run on NumPy by
the tests, which compare it with the compiled set): the proximal map's dual gradient projection
as a primal step and a dual step over the whole volume (the compiled sweep does the same sums
plane by plane), the 16-bit stores with the same rounding, every sum in float64.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Kernels", "array_kernels", "array_module"]


class Kernels(NamedTuple):
    """The whole-image operations of tv's solver (module doc), each as the compiled set's
    function of the same name documents it (flat views where that one takes them).

    Attributes
    ----------
    contiguous : callable
        ``contiguous(x)``: x C-contiguous.
    zeros_move : callable
        ``zeros_move(n)``: n int16 zeros (the start's move).
    subtract : callable
        ``subtract(a, b)``: a − b in a's dtype.
    axpy, moves : callable
        `fpscan.service.recon.tv.fista.axpy`, `fpscan.service.recon.tv.fista.moves`.
    store_move, extrapolate_fixed, store_gradient, gain_lower_bound : callable
        `fpscan.service.recon.tv.stores`'s.
    tv_norm, tv_prox_stored : callable
        `fpscan.service.recon.tv.prox`'s.
    masked : callable
        ``masked(x, support)``: x with zeros off the support, x's dtype.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.kernels import Kernels, array_kernels
    >>> k = array_kernels(np)
    >>> isinstance(k, Kernels), k.masked(np.ones(3), np.array([True, False, True])).tolist()
    (True, [1.0, 0.0, 1.0])
    """

    contiguous: Callable[[Any], Any]
    zeros_move: Callable[[int], Any]
    subtract: Callable[[Any, Any], Any]
    axpy: Callable[[Any, Any, float], None]
    moves: Callable[..., tuple[float, float, float, float, float, float]]
    store_move: Callable[..., tuple[Any, float]]
    extrapolate_fixed: Callable[[Any, Any, float], None]
    store_gradient: Callable[[Any], tuple[Any, float]]
    gain_lower_bound: Callable[[Any, tuple[Any, float]], float]
    tv_norm: Callable[[Any], float]
    tv_prox_stored: Callable[..., tuple[Any, Any]]
    masked: Callable[[Any, Any], Any]


def array_module(x: Any) -> ModuleType:
    """The array module of ``x``.

    Parameters
    ----------
    x : array
        A NumPy or CuPy array.

    Returns
    -------
    module
        ``numpy`` for a NumPy array, ``cupy`` for a CuPy one.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.kernels import array_module
    >>> array_module(np.zeros(2)) is np
    True
    """
    if isinstance(x, np.ndarray):
        return np
    import cupy

    return cupy


# -- the array-expression set --------------------------------------------------------------
_SCALE = 32767.0  # `fpscan.service.recon.tv.stores.DUAL_SCALE`


def _quantise(xp: ModuleType, q: Any, scale: float) -> Any:
    """`stores._quantise`: round(clip(q · scale, ±32767)) as int16, in float64."""
    return xp.floor(xp.clip(q.astype(np.float64) * scale, -32767.0, 32767.0) + 0.5).astype(np.int16)


def _grad(xp: ModuleType, w: Any) -> list[Any]:
    """Forward differences of a 3-D w along z, y, x (0 at the last index): `prox._dual_plane`'s."""
    out = []
    for axis in range(3):
        d = xp.zeros_like(w)
        n = w.shape[axis]
        hi = [slice(None)] * 3
        lo = [slice(None)] * 3
        hi[axis], lo[axis] = slice(1, n), slice(0, n - 1)
        d[tuple(lo)] = w[tuple(hi)] - w[tuple(lo)]
        out.append(d)
    return out


def _grad_t(xp: ModuleType, q: list[Any], has_y: bool) -> Any:
    """∇ᵀq (`prox._transpose_row`): Σ_a [i_a < n_a − 1] (−q_a)_i + [i_a > 0] (q_a)_{i − e_a}."""
    o = xp.zeros_like(q[0])
    for axis in range(3):
        if axis == 1 and not has_y:
            continue
        n = o.shape[axis]
        hi = [slice(None)] * 3
        lo = [slice(None)] * 3
        hi[axis], lo[axis] = slice(1, n), slice(0, n - 1)
        o[tuple(lo)] -= q[axis][tuple(lo)]
        o[tuple(hi)] += q[axis][tuple(lo)]
    return o


def _as3d(x: Any) -> Any:
    """An image (n_z, n_x) or (n_z, n_y, n_x) as a 3-D view (n_z, 1, n_x) / itself."""
    return x.reshape(x.shape[0], 1, x.shape[1]) if x.ndim == 2 else x


class _ArrayKernels:
    """The array-expression set's functions on one array module (:func:`array_kernels`)."""

    def __init__(self, xp: ModuleType) -> None:
        self.xp = xp

    def axpy(self, y: Any, x: Any, s: float) -> None:
        y[...] = (y.astype(np.float64) + s * x.astype(np.float64)).astype(y.dtype)

    def moves(self, xn: Any, v: Any, gy: Any, inv_l: float, b_last: Any, scale_last: float,
              beta: float) -> tuple[float, float, float, float, float, float]:
        xp = self.xp
        xi = xn.astype(np.float64)
        yi = v.astype(np.float64) + inv_l * gy.astype(np.float64)
        a = xi - yi
        b = xi - (yi - scale_last * b_last.astype(np.float64))
        c = a + beta * b
        return (float(xp.dot(a, b)), float(xp.dot(a, a)), float(xp.dot(c, c)), float(xp.dot(b, b)),
                float(xp.dot(xi, xi)), float(xp.abs(b).max()) if b.size else 0.0)

    def store_move(self, xn: Any, v: Any, gy: Any, inv_l: float, b_last: Any, scale_last: float,
                   b_max: float) -> tuple[Any, float]:
        quantum = b_max / _SCALE if b_max > 0 else 0.0
        x = v.astype(np.float64) + inv_l * gy.astype(np.float64) - scale_last * b_last.astype(np.float64)
        return _quantise(self.xp, xn.astype(np.float64) - x, 1.0 / quantum if quantum > 0 else 0.0), quantum

    def extrapolate_fixed(self, xn: Any, b: Any, scale: float) -> None:
        xn[...] = (xn.astype(np.float64) + scale * b.astype(np.float64)).astype(xn.dtype)

    def store_gradient(self, g: Any) -> tuple[Any, float]:
        flat = g.reshape(-1)
        top = float(self.xp.abs(flat).max()) if flat.size else 0.0
        quantum = top / _SCALE if top > 0 else 1.0
        return _quantise(self.xp, flat, 1.0 / quantum), quantum

    def gain_lower_bound(self, g: Any, stored: tuple[Any, float]) -> float:
        values, quantum = stored
        d = g.astype(np.float64) - values.astype(np.float64) * quantum
        measured = math.sqrt(float(self.xp.dot(d, d)))
        return max(0.0, measured - 0.5 * quantum * math.sqrt(g.size) * (1.0 + 1e-6))

    def tv_norm(self, x: Any) -> float:
        d = _grad(self.xp, _as3d(self.xp.ascontiguousarray(x)))
        total = sum(di.astype(np.float64) ** 2 for di in d)
        return float(self.xp.sqrt(total).sum())

    def project(self, x: Any, positivity: bool, support: Any) -> Any:
        if positivity:
            self.xp.maximum(x, 0, out=x)
        if support is not None:
            x[~support] = 0
        return x

    def primal(self, v3: Any, q: list[Any], has_y: bool, gamma: float, positivity: bool, support: Any) -> Any:
        """`fpscan.service.recon.tv.prox.primal_step`: P(v − γ ∇ᵀq)."""
        return self.project(v3 - gamma * _grad_t(self.xp, q, has_y), positivity, support)

    def _dual(self, stored: Any, v: Any, v3: Any) -> list[Any]:
        """The dual (z, y, x components as 3-D arrays) from its stored form (`stores.restore_dual`)."""
        xp, has_y = self.xp, v.ndim == 3
        if stored is None:
            return [xp.zeros_like(v3) for _ in range(3)]
        if stored.dtype == np.int16:
            restored = stored.astype(v.dtype) * v.dtype.type(1.0 / _SCALE)
        else:
            restored = stored.astype(v.dtype)
        return [_as3d(restored[0]), _as3d(restored[1]) if has_y else xp.zeros_like(v3), _as3d(restored[-1])]

    def tv_prox_stored(self, v: Any, gamma: float, positivity: bool, support: Any, stored: list[Any],
                       poll: Callable[[], None] | None = None) -> tuple[Any, Any]:
        """`prox.tv_prox_stored`: `PROX_ITER` dual gradient-projection steps, each a primal step
        and a dual step over the whole volume, the dual kept in 16 bits between calls."""
        from fpscan.service.recon.tv.prox import PROX_ITER

        xp = self.xp
        old = stored.pop()
        if gamma <= 0:
            return self.project(v.copy(), positivity, support), old
        has_y = v.ndim == 3
        v3 = _as3d(xp.ascontiguousarray(v))
        s3 = None if support is None else _as3d(support)
        q = self._dual(old, v, v3)
        del old
        step = 1.0 / (4.0 * v.ndim * gamma)  # 1 / (γ ‖∇‖²), ‖∇‖² <= 4 d
        for i in range(PROX_ITER):
            if poll is not None and i % 5 == 4:
                poll()
            g = _grad(xp, self.primal(v3, q, has_y, gamma, positivity, s3))
            new = [q[a].astype(np.float64) + step * g[a].astype(np.float64) for a in range(3)]
            if not has_y:
                new[1] = xp.zeros(v3.shape)
            inv = 1.0 / xp.maximum(1.0, xp.sqrt(new[0] * new[0] + new[1] * new[1] + new[2] * new[2]))
            q = [(n * inv).astype(v.dtype) for n in new]
            del new, inv, g
        full = xp.stack([p.reshape(v.shape) for p in ([q[0], q[1], q[2]] if has_y else [q[0], q[2]])])
        kept = _quantise(xp, full, _SCALE) if v.dtype == np.float32 else full.astype(np.float32)
        del q, full
        scale = 1.0 / _SCALE if kept.dtype == np.int16 else 1.0
        kq = [_as3d(kept[0].astype(v.dtype)), _as3d(kept[1].astype(v.dtype)) if has_y else xp.zeros_like(v3),
              _as3d(kept[-1].astype(v.dtype))]  # the stored values, their scale on γ (the map is linear in q)
        x = self.primal(v3, kq, has_y, gamma * scale, positivity, s3)
        return x.reshape(v.shape), kept


def array_kernels(xp: ModuleType) -> Kernels:
    """The kernel set on ``xp`` (``cupy`` on a GPU; ``numpy`` in the tests): the compiled set's
    arithmetic as array expressions (module doc), every sum in float64.

    Parameters
    ----------
    xp : module
        ``cupy`` or ``numpy``.

    Returns
    -------
    Kernels

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.kernels import array_kernels
    >>> k = array_kernels(np)
    >>> k.tv_norm(np.array([[0.0, 1.0], [0.0, 1.0]]))
    2.0
    >>> values, quantum = k.store_gradient(np.array([2.0, -1.0]))
    >>> values.tolist(), quantum == 2.0 / 32767
    ([32767, -16383], True)
    """
    k = _ArrayKernels(xp)
    return Kernels(xp.ascontiguousarray, lambda n: xp.zeros(n, dtype=np.int16),
                   lambda a, b: xp.subtract(a, b, dtype=a.dtype), k.axpy, k.moves, k.store_move,
                   k.extrapolate_fixed, k.store_gradient, k.gain_lower_bound, k.tv_norm, k.tv_prox_stored,
                   lambda x, support: xp.where(support, x, 0).astype(x.dtype))
