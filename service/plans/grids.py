"""Masks without a point of interest: full lattice, equispaced sub-grid, hexagonal,
random, Poisson-disc and user point lists. Weights: clipped Voronoi areas."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from fpscan.service.plans.lattice import Lattice
from fpscan.service.plans.mask import Mask, check_count, check_positive, check_seed, default_weights

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["full_mask", "subgrid_mask", "hexagonal_mask", "random_mask", "poisson_mask", "points_mask"]


def _unique_rows(idx: np.ndarray) -> np.ndarray:
    """Unique index rows, first occurrence kept, original order preserved."""
    if idx.shape[0] == 0:
        return idx
    _, first = np.unique(idx, axis=0, return_index=True)
    return idx[np.sort(first)]


def _build(kind: str, params: dict, lattice: Lattice, idx: ArrayLike, requested: int, **extra: Any) -> Mask:
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    if idx.shape[0] == 0:
        raise ValueError(f"{kind} mask: no lattice point selected")
    w = default_weights(lattice, lattice.positions(idx))
    if np.any(w <= 0):
        raise ValueError(f"{kind} mask: a point got no area (duplicated or degenerate positions)")
    return Mask(kind=kind, params=params, lattice=lattice, indices=idx, weights=w,
                requested_points=int(requested), **extra)


def full_mask(lattice: Lattice) -> Mask:
    """Every lattice point, row by row (i_y slowest).

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice.

    Returns
    -------
    Mask
        Kind ``"full"``, ``n_x * n_y`` points, weight pitch² each (pitch on a line lattice).

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, full_mask
    >>> m = full_mask(Lattice(4, 1, 1e-4))
    >>> m.obtained_points, m.weights  # m on a line lattice
    (4, array([0.0001, 0.0001, 0.0001, 0.0001]))
    """
    iy, ix = np.meshgrid(np.arange(lattice.n_y), np.arange(lattice.n_x), indexing="ij")
    idx = np.column_stack((ix.ravel(), iy.ravel()))
    return _build("full", {}, lattice, idx, lattice.n_points)


def _centred_run(n_lattice: int, interval: int, count: int | None, axis: str) -> np.ndarray:
    fit = (n_lattice - 1) // interval + 1
    if count is None:
        count = fit
    count = check_count(f"points per side along {axis}", count)
    if count > fit:
        raise ValueError(
            f"{count} points at interval {interval} do not fit on {n_lattice} lattice points along {axis} "
            f"(at most {fit})"
        )
    span = (count - 1) * interval
    start = (n_lattice - 1 - span) // 2  # centred; half a pitch low when the parity differs
    return start + interval * np.arange(count)


def subgrid_mask(lattice: Lattice, interval: int, n_per_side: int | Sequence[int] | None = None) -> Mask:
    """Equispaced sub-grid: every ``interval``-th lattice point, centred on the lattice.

    Centred half a pitch off centre when the parities of lattice and sub-grid differ. Weight
    (interval·pitch)² each (paper §6: 41 × 41 at interval 5).

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice.
    interval : int
        Lattice points from one sensor to the next (>= 1).
    n_per_side : int or (int, int), optional
        Points per side (or ``(n_x, n_y)``); default as many as fit.

    Returns
    -------
    Mask
        Kind ``"equispaced"``.

    Raises
    ------
    ValueError
        interval < 1, counts < 1 or not fitting on the lattice.

    References
    ----------
    .. [1] J. Schmid et al., "Computational Realization of a Non-Equidistant Grid Sampling in
       Photoacoustics with a Non-Uniform FFT", §6.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, subgrid_mask
    >>> m = subgrid_mask(Lattice(41, 41, 1e-4), 5)
    >>> m.obtained_points, float(m.weights[0])  # 9 x 9 points, (0.5 mm)² each
    (81, 2.5e-07)
    >>> subgrid_mask(Lattice(41, 41, 1e-4), 5, n_per_side=3).indices[:3]  # centred
    array([[15, 15],
           [20, 15],
           [25, 15]])
    """
    interval = check_count("interval", interval)
    if n_per_side is None or np.ndim(n_per_side) == 0:
        nx = ny = cast("int | None", n_per_side)  # one count (or None) for both axes
    else:
        vals = list(cast("Sequence[int]", n_per_side))
        if len(vals) != 2:
            raise ValueError(f"n_per_side must be an int or (n_x, n_y), got {n_per_side!r}")
        nx, ny = vals
    ix = _centred_run(lattice.n_x, interval, nx, "x")
    if lattice.is_line:
        iy = np.zeros(1, dtype=np.int64)
    else:
        iy = _centred_run(lattice.n_y, interval, ny, "y")
    gy, gx = np.meshgrid(iy, ix, indexing="ij")
    idx = np.column_stack((gx.ravel(), gy.ravel()))
    params = {"interval": interval, "n_per_side": [int(ix.size), int(iy.size)]}
    return _build("equispaced", params, lattice, idx, idx.shape[0])


def hexagonal_mask(lattice: Lattice, spacing: float) -> Mask:
    """Hexagonal (triangular) arrangement with neighbour distance ``spacing``.

    Rows ``spacing·√3/2`` apart, every other row shifted by ``spacing/2``, one point at the
    lattice centre; points outside the lattice dropped, the rest snapped (duplicates
    dropped). Mirror-symmetric about both lattice axes up to snapping ties.

    Parameters
    ----------
    lattice : Lattice
        A 2-D scanner lattice (n_y > 1).
    spacing : float
        Neighbour distance, m (at least one pitch, at most the lattice's extent).

    Returns
    -------
    Mask
        Kind ``"hexagonal"``, clipped Voronoi weights (m²).

    Raises
    ------
    ValueError
        spacing <= 0 or non-finite, a line lattice (use subgrid), spacing below one pitch or
        above the lattice's extent.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, hexagonal_mask
    >>> hexagonal_mask(Lattice(41, 41, 1e-4), 5e-4).obtained_points
    77
    >>> hexagonal_mask(Lattice(41, 41, 1e-4), 5e-5)
    Traceback (most recent call last):
    ...
    ValueError: spacing 5e-05 m is below the lattice pitch 0.0001 m
    """
    spacing = check_positive("spacing", spacing)
    if lattice.is_line:
        raise ValueError("a hexagonal mask needs a 2-D lattice (n_y > 1); use subgrid on a line")
    if spacing < lattice.pitch:
        raise ValueError(f"spacing {spacing:g} m is below the lattice pitch {lattice.pitch:g} m")
    hx, hy = lattice.half_extent
    if spacing > 2 * max(hx, hy):
        raise ValueError(f"spacing {spacing:g} m is larger than the lattice ({2 * max(hx, hy):g} m across)")
    dy = spacing * math.sqrt(3) / 2
    rows = np.arange(-math.floor(hy / dy + 1e-9), math.floor(hy / dy + 1e-9) + 1)
    pts = []
    for r in rows:
        shift = 0.5 * spacing if r % 2 else 0.0
        k_max = math.floor((hx + shift) / spacing + 1e-9) + 1
        xs = np.arange(-k_max, k_max + 1) * spacing + shift
        xs = xs[np.abs(xs) <= hx + 1e-9 * lattice.pitch]
        pts.append(np.column_stack((xs, np.full(xs.size, r * dy))))
    pos = np.vstack(pts)
    requested = pos.shape[0]
    idx = _unique_rows(lattice.snap(pos))
    return _build("hexagonal", {"spacing": spacing}, lattice, idx, requested)


def random_mask(lattice: Lattice, n_points: int, seed: int = 0) -> Mask:
    """``n_points`` distinct lattice points drawn uniformly (numpy PCG64), in lattice order.

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice.
    n_points : int
        Number of points (1 to the lattice's point count).
    seed : int, optional
        Random seed in [0, 2**64) (default 0): the same seed gives the same mask.

    Returns
    -------
    Mask
        Kind ``"random"``, clipped Voronoi weights.

    Raises
    ------
    ValueError
        n_points < 1 or more than the lattice holds, a bad seed.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, random_mask
    >>> m = random_mask(Lattice(41, 41, 1e-4), 20, seed=1)
    >>> m.obtained_points, m.params
    (20, {'n_points': 20, 'seed': 1})
    >>> random_mask(Lattice(3, 3, 1e-4), 20)
    Traceback (most recent call last):
    ...
    ValueError: n_points = 20 is more than the lattice holds (9)
    """
    n = check_count("n_points", n_points, lattice.n_points)
    seed = check_seed(seed)
    rng = np.random.default_rng(seed)
    flat = np.sort(rng.choice(lattice.n_points, size=n, replace=False))
    idx = np.column_stack((flat % lattice.n_x, flat // lattice.n_x))
    return _build("random", {"n_points": n, "seed": seed}, lattice, idx, n)


def poisson_mask(lattice: Lattice, min_distance: float, seed: int = 0, n_points: int | None = None) -> Mask:
    """Poisson-disc mask: seeded random lattice points no closer than ``min_distance``.

    Lattice points are visited in a seeded random order, each kept if no kept point lies
    closer than ``min_distance`` (dart throwing over the whole lattice, so the result is
    maximal: every lattice point is within ``min_distance`` of a kept one).

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice.
    min_distance : float
        Minimum distance between points, m (> 0, at most the lattice's diagonal).
    seed : int, optional
        Random seed in [0, 2**64) (default 0).
    n_points : int, optional
        Stop after this many points; default no cap.

    Returns
    -------
    Mask
        Kind ``"poisson"``, points in lattice order (i_y slowest), clipped Voronoi weights.

    Raises
    ------
    ValueError
        min_distance <= 0, non-finite or larger than the lattice's diagonal, n_points < 1 or
        above the lattice, a bad seed.

    Examples
    --------
    >>> from scipy.spatial.distance import pdist
    >>> from fpscan.service.plans import Lattice, poisson_mask
    >>> m = poisson_mask(Lattice(41, 41, 1e-4), 4e-4, seed=0)
    >>> m.obtained_points, bool(pdist(m.positions).min() > 4e-4 * (1 - 1e-9))
    (78, True)
    >>> poisson_mask(Lattice(41, 41, 1e-4), 4e-4, n_points=10).obtained_points
    10
    """
    r = check_positive("min_distance", min_distance)
    hx, hy = lattice.half_extent
    if r > 2 * math.hypot(hx, hy):
        raise ValueError(f"min_distance {r:g} m is larger than the lattice ({2 * math.hypot(hx, hy):g} m across)")
    seed = check_seed(seed)
    limit = lattice.n_points if n_points is None else check_count("n_points", n_points, lattice.n_points)
    rng = np.random.default_rng(seed)
    order = rng.permutation(lattice.n_points)
    params = {"min_distance": r, "seed": seed}
    if n_points is not None:
        params["n_points"] = limit
    if r <= lattice.pitch:
        # distinct lattice points are >= one pitch apart: every visited point is kept
        kept_flat = order[:limit]
        idx = np.column_stack((kept_flat % lattice.n_x, kept_flat // lattice.n_x)).astype(np.int64)
        idx = idx[np.lexsort((idx[:, 0], idx[:, 1]))]
        return _build("poisson", params, lattice, idx, limit if n_points is not None else idx.shape[0])
    # Spatial hash on lattice indices: cell side c lattice pitches, c >= r / pitch.
    rp = r / lattice.pitch
    c = max(1, math.ceil(rp))
    reach = 1
    cells: dict[tuple[int, int], list[tuple[int, int]]] = {}
    kept = []
    r2 = rp * rp * (1 - 1e-12)
    for flat in order:
        ix, iy = int(flat % lattice.n_x), int(flat // lattice.n_x)
        cx, cy = ix // c, iy // c
        ok = True
        for gx in range(cx - reach, cx + reach + 1):
            for gy in range(cy - reach, cy + reach + 1):
                for jx, jy in cells.get((gx, gy), ()):
                    if (jx - ix) ** 2 + (jy - iy) ** 2 < r2:
                        ok = False
                        break
                if not ok:
                    break
            if not ok:
                break
        if ok:
            cells.setdefault((cx, cy), []).append((ix, iy))
            kept.append((ix, iy))
            if len(kept) >= limit:
                break
    idx = np.array(sorted(kept, key=lambda t: (t[1], t[0])), dtype=np.int64)
    return _build("poisson", params, lattice, idx, limit if n_points is not None else idx.shape[0])


def points_mask(lattice: Lattice, points: ArrayLike | None = None, indices: ArrayLike | None = None) -> Mask:
    """A user's points, snapped to the lattice, or lattice indices directly.

    Points that snap to the same lattice point are merged (obtained < requested says so);
    order is kept (the ``auto`` scan order of a point list is ``given``).

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice.
    points : array_like, shape ``(n, 2)`` (or ``(n,)`` / ``(n, 1)`` on a line lattice), optional
        Positions (x, y), m, snapped to the nearest lattice point.
    indices : array_like of int, shape ``(n, 2)``, optional
        Lattice indices (i_x, i_y), 0-based, each at most once. Give exactly one of
        ``points`` and ``indices``.

    Returns
    -------
    Mask
        Kind ``"points"``, clipped Voronoi weights.

    Raises
    ------
    ValueError
        Neither or both given, empty, non-finite, a point more than half a pitch outside the
        lattice, an index outside it, duplicated indices, bad shapes.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, points_mask
    >>> m = points_mask(Lattice(101, 1, 1e-4), points=[0.0, 1e-4, 1.04e-4])  # x in m
    >>> m.indices.tolist(), m.requested_points  # the last two snap to one point
    ([[50, 0], [51, 0]], 3)
    >>> points_mask(Lattice(41, 41, 1e-4))
    Traceback (most recent call last):
    ...
    ValueError: give exactly one of points (m) or indices
    """
    if (points is None) == (indices is None):
        raise ValueError("give exactly one of points (m) or indices")
    if points is not None:
        try:
            pos = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("points must be a list of (x, y) numbers in m") from None
        if pos.ndim == 1 and lattice.is_line:
            pos = pos[:, None]
        if pos.ndim != 2 or pos.shape[0] == 0 or pos.shape[1] not in (1, 2):
            raise ValueError(f"points must be a non-empty (n, 2) list of (x, y) in m, got shape {pos.shape}")
        idx = lattice.snap(pos)
        requested = pos.shape[0]
        params = {"points": [[float(v) for v in row] for row in pos]}
    else:
        try:
            raw = np.asarray(indices, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("indices must be a list of (i_x, i_y) integers") from None
        if raw.ndim != 2 or raw.shape[0] == 0 or raw.shape[1] != 2:
            raise ValueError(f"indices must be a non-empty (n, 2) list, got shape {raw.shape}")
        lattice.positions(raw)  # validates integrality and range
        idx = raw.astype(np.int64)
        if np.unique(idx, axis=0).shape[0] != idx.shape[0]:
            raise ValueError("indices contain duplicates (each lattice point once)")
        requested = idx.shape[0]
        params = {"indices": [[int(v) for v in row] for row in idx]}
    idx = _unique_rows(idx)
    return _build("points", params, lattice, idx, requested)
