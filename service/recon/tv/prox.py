"""tv's proximal map: λ TV + positivity by gradient projection on the dual, in compiled sweeps.

argmin_x ½‖x − v‖² + γ TV(x) over x >= 0 (and x = 0 off a support), TV(x) = Σ_voxels |∇x|₂
with forward differences in voxel units: gradient projection on the dual (Chambolle 2005;
Beck & Teboulle 2009's GP), `PROX_ITER` inner steps warm-started from the previous call's
dual, no operator (`tv_prox`; `tv_prox_stored` keeps the dual between calls in
`fpscan.service.recon.tv.stores`'s fixed point). Each inner step is one compiled sweep over the
volume (`_prox_step`): the primal w lives a few planes at a time and the dual is stepped in
place, so the map needs no work image beyond the dual itself (d images). `tv_norm` is TV(x)
without a work array.

The sweeps are numba kernels (``cache=True``: ``fpscan warmup`` fills their cache;
`fpscan.service.recon.methods.tv`'s ``kernel_modules``). 2-D images run as 3-D views (n_z, 1, n_x).
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from fpscan.service.recon.tv.stores import DUAL_SCALE, restore_dual, store_dual

__all__ = ["PROX_ITER", "tv_prox", "tv_prox_stored", "tv_norm", "primal_step"]

#: inner (dual, no operator) iterations of the TV + positivity proximal map, warm-started from
#: the last call's dual (chosen: docs/tv-measurements.md, "Proximal map")
PROX_ITER = 5


def _as3d(x: np.ndarray) -> np.ndarray:
    """An image (n_z, n_x) or (n_z, n_y, n_x) as a 3-D view (n_z, 1, n_x) / itself."""
    return x.reshape(x.shape[0], 1, x.shape[1]) if x.ndim == 2 else x


def _dual_axes(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The z, y, x components of a dual field (d, *image shape) as 3-D views; in 2-D the y
    component is a placeholder the kernels never touch."""
    if q.shape[0] == 2:
        return _as3d(q[0]), np.zeros((1, 1, 1), dtype=q.dtype), _as3d(q[1])
    return q[0], q[1], q[2]


@numba.njit(cache=True, fastmath=True)
def _transpose_row(qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, z: int, y: int,
                   o: np.ndarray) -> None:
    """Row y of plane z of ∇ᵀq into ``o`` (n_x), in passes without a branch inside (SIMD)."""
    nz, ny, nx = qz.shape
    if z < nz - 1:
        row = qz[z, y]
        for x in range(nx):
            o[x] = -row[x]
    else:
        o[:] = 0.0
    if z > 0:
        row = qz[z - 1, y]
        for x in range(nx):
            o[x] += row[x]
    if has_y:
        if y < ny - 1:
            row = qy[z, y]
            for x in range(nx):
                o[x] -= row[x]
        if y > 0:
            row = qy[z, y - 1]
            for x in range(nx):
                o[x] += row[x]
    row = qx[z, y]
    for x in range(nx - 1):
        o[x] -= row[x]
    for x in range(1, nx):
        o[x] += row[x - 1]


@numba.njit(cache=True, fastmath=True)
def _primal_plane(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
                  positivity: bool, support: np.ndarray, use_support: bool, z: int, out: np.ndarray,
                  o: np.ndarray) -> None:
    """Plane z of `_prox_primal` into the 2-D ``out`` (n_y, n_x), row by row: ∇ᵀq into the
    row ``o`` (n_x, `_transpose_row`), then the projection into ``out`` (which may be v's
    plane z)."""
    ny, nx = out.shape
    for y in range(ny):
        _transpose_row(qz, qy, qx, has_y, z, y, o)
        vr = v[z, y]
        r = out[y]
        for x in range(nx):
            r[x] = vr[x] - gamma * o[x]
        if positivity:
            for x in range(nx):
                r[x] = max(r[x], 0.0)
        if use_support:
            sr = support[z, y]
            for x in range(nx):
                if not sr[x]:
                    r[x] = 0.0


@numba.njit(parallel=True, cache=True)
def _prox_primal(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
                 positivity: bool, support: np.ndarray, use_support: bool, out: np.ndarray) -> None:
    """The primal step ``out`` = P(v − γ ∇ᵀq) voxel by voxel (`_primal_plane` per plane), ∇ᵀ
    the transpose of the forward differences (0 at the last index): (∇ᵀq)_i = Σ_a
    [i_a < n_a − 1] (−q_a)_i + [i_a > 0] (q_a)_{i − e_a}; P clips below 0 (``positivity``)
    and zeroes off ``support`` (``use_support``). ``out`` may be ``v``: each voxel reads only
    its own v."""
    for z in numba.prange(v.shape[0]):
        o = np.empty(v.shape[2], dtype=out.dtype)
        _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, z, out[z], o)


@numba.njit(cache=True, fastmath=True)
def _dual_row(a_diff: np.ndarray, b_diff: np.ndarray, e_diff: np.ndarray, qz: np.ndarray, qy: np.ndarray,
              qx: np.ndarray, has_y: bool, step: float, n: int) -> None:
    """One row of the dual step from the rows of w's differences along z, y, x (a zero row
    where the difference is 0): q ← (q + step ∇w) / max(1, |·|), in place; a loop without
    branches (SIMD)."""
    for x in range(n):
        a = qz[x] + step * a_diff[x]
        b = qy[x] + step * b_diff[x] if has_y else 0.0
        e = qx[x] + step * e_diff[x]
        inv = 1.0 / max(1.0, math.sqrt(a * a + b * b + e * e))
        qz[x] = a * inv
        qx[x] = e * inv
        if has_y:
            qy[x] = b * inv


@numba.njit(cache=True, fastmath=True)
def _dual_plane(cur: np.ndarray, nxt: np.ndarray, z: int, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray,
                has_y: bool, step: float, scratch: np.ndarray) -> None:
    """Plane z of the dual step (w's plane z ``cur``, plane z + 1 ``nxt``), row by row:
    ``scratch`` (>= 3, n_x) holds the row's differences of w along z, y and x."""
    nz = qz.shape[0]
    ny, nx = cur.shape
    dz, dy, dx = scratch[0], scratch[1], scratch[2]
    for y in range(ny):
        c = cur[y]
        if z < nz - 1:
            nr = nxt[y]
            for x in range(nx):
                dz[x] = nr[x] - c[x]
        else:
            dz[:] = 0.0
        if has_y and y < ny - 1:
            cy = cur[y + 1]
            for x in range(nx):
                dy[x] = cy[x] - c[x]
        else:
            dy[:] = 0.0
        for x in range(nx - 1):
            dx[x] = c[x + 1] - c[x]
        dx[nx - 1] = 0.0
        # in 2-D qy is a (1, 1, 1) placeholder `_dual_row` never touches
        _dual_row(dz, dy, dx, qz[z, y], qy[z, y] if has_y else qy[0, 0], qx[z, y], has_y, step, nx)


@numba.njit(parallel=True, cache=True)
def _prox_step(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
               positivity: bool, support: np.ndarray, use_support: bool, step: float, starts: np.ndarray,
               planes: np.ndarray, rows: np.ndarray) -> None:
    """One inner step of the dual gradient projection in one sweep, q updated in place: w =
    P(v − γ ∇ᵀq) plane by plane, each plane of w made just before the dual step of the plane
    above it needs it (from q not yet stepped there), then q ← the projected step (`_dual_plane`). The
    volume's planes split into slabs [starts[k], starts[k + 1]) swept in parallel; ``planes``
    (n_slabs, 3, n_y, n_x) holds w at each slab's first plane, made from the old q before any
    slab steps, and each slab's two-plane ring; ``rows`` (n_slabs, 4, n_x) its scratch rows.
    The same arithmetic as a full primal sweep followed by a full dual sweep, without the
    image w: one pass over v and q."""
    nz = v.shape[0]
    n_slabs = starts.shape[0] - 1
    for k in numba.prange(n_slabs):
        _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, starts[k], planes[k, 0],
                      rows[k, 3])
    for k in numba.prange(n_slabs):
        z0 = starts[k]
        z1 = starts[k + 1]
        cur = planes[k, 0]
        ring = 1
        for z in range(z0, z1):
            if z + 1 < z1:
                nxt = planes[k, ring]
                _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, z + 1, nxt, rows[k, 3])
            elif z + 1 < nz:
                nxt = planes[k + 1, 0]
            else:
                nxt = cur  # the last plane: no difference along z
            _dual_plane(cur, nxt, z, qz, qy, qx, has_y, step, rows[k])
            cur = nxt
            ring = 3 - ring


@numba.njit(parallel=True, cache=True)
def _tv_norm_kernel(x: np.ndarray) -> float:
    """Σ_voxels sqrt(Σ_a (forward difference along a)²) of a 3-D array, the differences in
    x's dtype (as the proximal map sees them), the sum in float64."""
    nz, ny, nx = x.shape
    total = 0.0
    for z in numba.prange(nz):
        row = 0.0
        for y in range(ny):
            for i in range(nx):
                c = x[z, y, i]
                d0 = np.float64(x[z + 1, y, i] - c) if z < nz - 1 else 0.0
                d1 = np.float64(x[z, y + 1, i] - c) if y < ny - 1 else 0.0
                d2 = np.float64(x[z, y, i + 1] - c) if i < nx - 1 else 0.0
                row += math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        total += row
    return total


def tv_norm(x: np.ndarray) -> float:
    """TV(x) = Σ_voxels |∇x|₂, the isotropic total variation with forward differences in voxel
    units, summed in float64; no work array.

    Parameters
    ----------
    x : ndarray
        An image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or float64 (the differences in its
        dtype, as the proximal map sees them), in its unit (Pa).

    Returns
    -------
    float
        TV(x), x's unit.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.prox import tv_norm
    >>> tv_norm(np.array([[0.0, 1.0], [0.0, 1.0]]))  # one unit step along x on each of 2 rows
    2.0
    >>> tv_norm(np.ones((3, 4, 5)))
    0.0
    """
    return float(_tv_norm_kernel(_as3d(np.ascontiguousarray(x))))


def tv_prox(v: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None, dual: np.ndarray | None,
             poll: Callable[[], None] | None = None,
             in_place: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """The proximal map of γ TV + positivity: argmin_x ½‖x − v‖² + γ TV(x) over x >= 0 (with
    ``positivity``) and x = 0 off ``support``.

    Gradient projection on the dual (Chambolle, J. Math. Imaging Vis. 20 (2004) 89 and EMMCVPR
    2005; Beck & Teboulle, IEEE Trans. Image Process. 18 (2009) 2419, their GP), `PROX_ITER`
    steps from ``dual`` (the previous call's, a warm start, updated in place). No operator.
    Each inner step is one compiled sweep over the volume (the primal w lives a few planes at a
    time), the dual stepped in place: no work image beyond the dual itself (d images, made when
    ``dual`` is None).

    Parameters
    ----------
    v : ndarray
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or float64, in its unit (Pa).
    gamma : float
        γ (v's unit); <= 0: only the projection.
    positivity : bool
        Constrain x >= 0.
    support : ndarray of bool or None
        v's shape: x = 0 where False (None: everywhere allowed).
    dual : ndarray or None
        The dual ``(d, *v.shape)`` of v's dtype (z, (y,) x), updated in place; None: 0.
    poll : callable, optional
        Called every few inner steps (a cancel may raise there).
    in_place : bool, optional
        Write x into ``v`` (C-contiguous; default True), else into a new array.

    Returns
    -------
    tuple
        ``(x, dual)``: x of v's shape and dtype, and the dual after the steps (``dual`` itself
        where given; unchanged, possibly None, at γ <= 0).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.prox import tv_norm, tv_prox
    >>> v = np.array([[0.0, 0.0, 1.0, 1.0]]) + np.array([[0.1, -0.1, 0.1, -0.1]])
    >>> x, dual = tv_prox(v.copy(), 0.05, False, None, None)
    >>> dual.shape, bool(tv_norm(x) < tv_norm(v))
    ((2, 1, 4), True)
    >>> tv_prox(np.array([[-1.0, 2.0]]), 0.0, True, None, None)[0].tolist()  # γ = 0: the projection
    [[0.0, 2.0]]
    """
    if gamma <= 0:
        return _project(v if in_place else v.copy(), positivity, support), dual
    v = np.ascontiguousarray(v)  # the kernels see it through 3-D views
    q = np.zeros((v.ndim,) + v.shape, dtype=v.dtype) if dual is None else dual
    _dual_steps(v, q, float(gamma), positivity, support, poll)
    x = v if in_place else np.empty_like(v)
    _prox_primal(_as3d(v), *_dual_axes(q), v.ndim == 3, float(gamma), positivity, *_support3(support), _as3d(x))
    return x, q


def tv_prox_stored(v: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None,
                    stored: list[np.ndarray | None],
                    poll: Callable[[], None] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """`tv_prox` (not in place: v is kept) with its dual kept between calls in half the working
    precision's bytes (`fpscan.service.recon.tv.stores.store_dual`).

    ``stored`` is a list holding the last call's stored dual (None: 0), taken out of it: it is
    restored, freed, stepped, stored anew and freed again before the new iterate is made, whose
    final primal step reads the stored dual (the map is linear in it: γ ∇ᵀ(s / 32767) =
    (γ / 32767) ∇ᵀ s). So the full-precision dual (d images) and the new iterate are never held
    together, nor the old and the new stored dual: d + d/2 images at most beside v (the paper's
    scan: tv's peak 9.3 -> 8.4 images, now inside the operator).

    Parameters
    ----------
    v : ndarray
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or float64 (Pa).
    gamma : float
        γ (v's unit); <= 0: only the projection.
    positivity : bool
        Constrain x >= 0.
    support : ndarray of bool or None
        v's shape: x = 0 where False (None: everywhere allowed).
    stored : list
        One element, the last call's stored dual (`store_dual`'s form, ``(d, *v.shape)``) or
        None; popped.
    poll : callable, optional
        Called every few inner steps (a cancel may raise there).

    Returns
    -------
    tuple
        ``(x, stored dual)``: a new x of v's shape and dtype, and the new stored dual (int16 for
        float32, float32 for float64); at γ <= 0 the projection of v and the stored dual unchanged.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.prox import tv_prox_stored
    >>> v = np.array([[0.0, 0.2, 1.0, 0.9]], dtype=np.float32)
    >>> x, kept = tv_prox_stored(v, 0.05, True, None, [None])
    >>> x.dtype, kept.dtype, kept.shape
    (dtype('float32'), dtype('int16'), (2, 1, 4))
    >>> x2, kept2 = tv_prox_stored(v, 0.05, True, None, [kept])  # warm-started from the stored dual
    >>> x2.shape
    (1, 4)
    """
    old = stored.pop()
    if gamma <= 0:
        return _project(v.copy(), positivity, support), old
    v = np.ascontiguousarray(v)
    q = np.zeros((v.ndim,) + v.shape, dtype=v.dtype) if old is None else restore_dual(old, v.dtype)
    del old
    _dual_steps(v, q, float(gamma), positivity, support, poll)
    kept = store_dual(q)
    del q
    x = np.empty_like(v)
    scale = 1.0 / DUAL_SCALE if kept.dtype == np.int16 else 1.0
    _prox_primal(_as3d(v), *_dual_axes(kept), v.ndim == 3, float(gamma) * scale, positivity, *_support3(support),
                 _as3d(x))
    return x, kept


def primal_step(v: np.ndarray, dual: np.ndarray, gamma: float, positivity: bool = False,
                support: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
    """The proximal map's primal step P(v − γ ∇ᵀq) (the compiled sweep each inner step of
    `tv_prox` makes), ∇ᵀ the transpose of the forward differences in voxel units (0 at the
    last index): (∇ᵀq)_i = Σ_a [i_a < n_a − 1] (−q_a)_i + [i_a > 0] (q_a)_{i − e_a}; P clips
    below 0 with ``positivity`` and zeroes off ``support``.

    Parameters
    ----------
    v : ndarray
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or float64 (C-contiguous: else
        copied).
    dual : ndarray
        q, ``(d, *v.shape)`` of v's dtype, its components along z, (y,) x in that order, C-contiguous.
    gamma : float
        γ, in v's unit.
    positivity : bool, optional
        Clip below 0 (default False).
    support : ndarray of bool, optional
        v's shape: zero where False (default: none).
    out : ndarray, optional
        Where to write (v's shape and dtype; may be ``v``); default a new array.

    Returns
    -------
    ndarray
        ``out``: P(v − γ ∇ᵀq), v's shape and dtype.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.prox import primal_step
    >>> q = np.zeros((2, 2, 3))
    >>> q[1, 0, 0] = 1.0  # the x component at (0, 0): ∇ᵀq = −1 there, +1 at (0, 1)
    >>> primal_step(np.zeros((2, 3)), q, 1.0).tolist()
    [[1.0, -1.0, 0.0], [0.0, 0.0, 0.0]]
    >>> primal_step(np.zeros((2, 3)), q, 1.0, positivity=True).tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    """
    v = np.ascontiguousarray(v)
    x = np.empty_like(v) if out is None else out
    _prox_primal(_as3d(v), *_dual_axes(dual), v.ndim == 3, float(gamma), positivity, *_support3(support), _as3d(x))
    return x


def _project(x: np.ndarray, positivity: bool, support: np.ndarray | None) -> np.ndarray:
    """The image ``x`` clipped below 0 (``positivity``) and zeroed off ``support``, in place."""
    if positivity:
        np.maximum(x, 0, out=x)
    if support is not None:
        x[~support] = 0
    return x


def _support3(support: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The kernels' (support as a 3-D bool array, whether there is one): a placeholder when None."""
    if support is None:
        return np.zeros((1, 1, 1), bool), False
    return _as3d(np.ascontiguousarray(support, dtype=bool)), True


def _dual_steps(v: np.ndarray, q: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None,
                poll: Callable[[], None] | None) -> None:
    """`PROX_ITER` inner steps of `tv_prox`'s dual gradient projection on ``q`` (d, *v.shape),
    in place: w = P(v − γ ∇ᵀq); q ← (q + step ∇w) / max(1, |·|), step = 1 / (γ ‖∇‖²)."""
    supp, has_support = _support3(support)
    has_y = v.ndim == 3
    v3 = _as3d(v)
    n_slabs = max(1, min(v3.shape[0], 2 * numba.get_num_threads()))
    starts = np.linspace(0, v3.shape[0], n_slabs + 1).astype(np.int64)
    planes = np.empty((n_slabs, 3) + v3.shape[1:], dtype=v.dtype)  # w's first plane and a ring of two
    rows = np.empty((n_slabs, 4, v3.shape[2]), dtype=v.dtype)  # each slab's rows: w's differences, ∇ᵀq
    step = 1.0 / (4.0 * v.ndim * gamma)  # 1 / (γ ‖∇‖²), ‖∇‖² <= 4 d
    for i in range(PROX_ITER):
        if poll is not None and i % 5 == 4:
            poll()
        _prox_step(v3, *_dual_axes(q), has_y, gamma, positivity, supp, has_support, step, starts, planes, rows)
