"""Quadrature weights for non-equispaced sensor positions: clipped Voronoi areas.

The lateral integral of the inversion formula (the paper, eq. (5)) becomes
``Σ_m h_m g(x_m, t) e^{-i k·x_m}`` for sensors at arbitrary positions ``x_m``; ``h_m``
is the area of the part of the measured plane that sensor ``m`` stands for. The default
is the sensor's Voronoi cell clipped to the region the sensors cover, computed by
nearest-sensor labelling of a fine raster with ``scipy.spatial.cKDTree`` (2-D plane) or
exactly from interval mid-points (1-D line).

Depends on numpy and scipy only.
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

__all__ = ["voronoi_weights", "infer_pitch"]

#: Raster samples per cell aimed at for irregular masks (median cell), and the budget.
_SAMPLES_PER_CELL = 1024
_MAX_RASTER = 1 << 20
#: A cell never reaches farther than this many nearest-neighbour distances.
_REACH = 3.0
_REL_TOL = 1e-6


def _as_positions(positions: npt.ArrayLike) -> np.ndarray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim == 1:
        pos = pos[:, None]
    if pos.ndim != 2 or pos.shape[1] not in (1, 2):
        raise ValueError(f"positions must have shape (n, 1) or (n, 2), got {np.shape(positions)}")
    if pos.shape[0] < 1:
        raise ValueError("positions must hold at least one sensor")
    if not np.all(np.isfinite(pos)):
        raise ValueError("positions contain non-finite values")
    return pos


def infer_pitch(positions: npt.ArrayLike) -> float | None:
    """The pitch of the regular lattice the positions lie on, or None if there is none.

    With g the smallest positive gap between distinct coordinates along any axis, the pitch
    is the largest g/k (k = 1..16) of which every coordinate is an integer multiple from the
    axis minimum (relative tolerance 1e-6), refined over the longest span. So a random subset
    of a lattice whose closest coordinates are 2 and 3 pitches apart still gives the pitch.

    Parameters
    ----------
    positions : array_like, shape ``(n, d)`` (d = 1 or 2) or ``(n,)``
        Sensor positions, m.

    Returns
    -------
    float or None
        The pitch in m; None for a single sensor or positions on no common lattice.

    Raises
    ------
    ValueError
        Bad shapes or non-finite values.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.weights import infer_pitch
    >>> infer_pitch(np.array([[0.0], [2e-4], [5e-4]]))  # gaps of 2 and 3 pitches
    0.0001
    >>> infer_pitch(np.array([[0.0]])) is None
    True
    """
    pos = _as_positions(positions)
    scale = max(float(np.abs(pos).max()), 1e-300)
    gaps = []
    for a in range(pos.shape[1]):
        u = np.unique(pos[:, a])
        g = np.diff(u)
        g = g[g > 1e-9 * scale]
        if g.size:
            gaps.append(float(g.min()))
    if not gaps:
        return None
    rel = pos - pos.min(axis=0)
    for k in range(1, 17):
        p = min(gaps) / k
        kk = rel / p
        if np.max(np.abs(kk - np.round(kk))) <= _REL_TOL * max(1.0, float(kk.max()) * 1e-3):
            # Refine on the longest span: p = span / (number of pitches in it).
            kmax = np.round(kk).max(axis=0)
            a = int(np.argmax(kmax))
            return float(np.ptp(pos[:, a]) / kmax[a])
    return None


def _nn_distance(pos: np.ndarray) -> np.ndarray:
    """Distance of every sensor to its nearest other sensor, ``(n,)`` in m."""
    tree = cKDTree(pos)
    d, _ = tree.query(pos, k=2)
    return d[:, 1]


def _weights_1d(x: np.ndarray, lo: float, hi: float, radius: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="stable")
    xs = x[order]
    mids = 0.5 * (xs[1:] + xs[:-1])
    left = np.concatenate(([lo], mids))
    right = np.concatenate((mids, [hi]))
    r = radius[order]
    left = np.maximum(np.maximum(left, xs - r), lo)
    right = np.minimum(np.minimum(right, xs + r), hi)
    w_sorted = np.maximum(right - left, 0.0)
    w = np.empty_like(w_sorted)
    w[order] = w_sorted
    return w


def voronoi_weights(positions: npt.ArrayLike, pitch: float | None = None, *, bounds: npt.ArrayLike | None = None,
                    samples_per_cell: int = _SAMPLES_PER_CELL) -> np.ndarray:
    """Clipped Voronoi areas of sensors on the sensor plane.

    The covered region is the bounding box of the sensors widened on every side by half the
    median nearest-neighbour distance ``d_med`` (intersected with ``bounds``); each sensor's
    cell is additionally limited to the disc of radius ``3·max(d_i, d_med)`` around it
    (``d_i``: its own nearest-neighbour distance), so sparse masks (a disc of sensors on a
    square lattice) do not claim area far from any sensor, while a uniform random mask still
    covers more than 99.5 % of its box (99.6-99.9 % measured: 3-25 % of a 40² or 64² lattice). The
    weights sum to the covered area. Exactness:

    - every point of a full regular lattice gets exactly pitch² (pitch on a line);
    - an equispaced sub-grid of interval s gets exactly (s·pitch)² each;
    - on a line the cells are exact intervals between mid-points.

    In the plane the cells are measured on a raster of sub-cell centres, an even number per
    pitch and aligned to the lattice, so no raster sample lies on the bisector of two
    axis-aligned lattice neighbours; a sample on any other bisector is shared equally by the
    two sensors (mirror-symmetric masks get mirror-symmetric weights); irregular masks get
    ~1024 raster samples per median cell within a budget of 2²⁰ samples.

    Parameters
    ----------
    positions : array_like, shape ``(n, 2)``, ``(n, 1)`` or ``(n,)``
        (x, y) in m, or x in m (2-D imaging, a line of sensors).
    pitch : float, optional
        The scanner lattice pitch in m the positions lie on; None infers it (``infer_pitch``);
        for positions on no lattice the raster step follows the sensor spacing instead.
    bounds : tuple of (float, float), optional
        Clip box, ``((x_lo, x_hi),)`` or ``((x_lo, x_hi), (y_lo, y_hi))`` in m (e.g. the
        scanner lattice's extent, lattice points ± pitch/2).
    samples_per_cell : int, optional
        Raster samples aimed at per median cell for irregular masks (default 1024: cells to
        ~1 %; lower is faster, the total stays exact).

    Returns
    -------
    ndarray, shape ``(n,)``
        Weights in m² (plane) or m (line), in the order of ``positions``.

    Raises
    ------
    ValueError
        Bad shape, non-finite values, duplicated positions, pitch ≤ 0 or non-finite, bounds
        that are malformed or leave a sensor outside.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", eq. (5) (the weights h_m of the lateral sum).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.weights import voronoi_weights
    >>> voronoi_weights(np.array([[0.0], [1e-4], [3e-4]]))  # m: intervals between mid-points
    array([0.0001 , 0.00015, 0.00015])
    >>> grid = np.stack(np.meshgrid(np.arange(3) * 1e-4, np.arange(3) * 1e-4), -1).reshape(-1, 2)
    >>> bool(np.allclose(voronoi_weights(grid), 1e-8))  # a full lattice: pitch² each
    True
    >>> voronoi_weights(np.zeros((2, 2)))
    Traceback (most recent call last):
    ...
    ValueError: positions contain 1 duplicated sensor position(s)
    """
    pos = _as_positions(positions)
    n, dim = pos.shape
    pitch = _checked_pitch(pitch)
    _refuse_duplicates(pos)
    lattice_pitch = infer_pitch(pos) if pitch is None else pitch
    d = _cell_distances(pos, lattice_pitch)
    d_med = float(np.median(d))
    radius = _REACH * np.maximum(d, d_med)
    box = (pos.min(axis=0) - 0.5 * d_med, pos.max(axis=0) + 0.5 * d_med)
    lo, hi = _clipped_box(pos, box, bounds)

    if dim == 1:
        return _weights_1d(pos[:, 0], float(lo[0]), float(hi[0]), radius)

    # Shortcut: a complete regular grid (a full lattice or an equispaced sub-grid) whose
    # box is not cut by ``bounds``: every cell is a full square of the grid's spacing.
    grid_pitch = infer_pitch(pos) if pitch is not None else lattice_pitch
    if grid_pitch is not None and np.all(lo <= box[0]) and np.all(hi >= box[1]) \
            and _is_full_grid(pos, grid_pitch, d_med):
        return np.full(n, grid_pitch**2)

    base = lattice_pitch if lattice_pitch is not None else float(d.min())
    h = _raster_step(base, hi - lo, n, samples_per_cell)
    samples, frac = _raster(pos.min(axis=0) - 0.5 * base, h, lo, hi)
    return _raster_areas(pos, samples, frac, radius, h)


def _checked_pitch(pitch: float | None) -> float | None:
    """``voronoi_weights``: the pitch as a float (m), refused unless positive and finite."""
    if pitch is None:
        return None
    pitch = float(pitch)
    if not np.isfinite(pitch) or pitch <= 0:
        raise ValueError(f"pitch must be a positive finite length in m, got {pitch}")
    return pitch


def _refuse_duplicates(pos: np.ndarray) -> None:
    """``voronoi_weights``: ValueError if two sensors share a position."""
    n = pos.shape[0]
    if n > 1:
        uniq = np.unique(pos, axis=0)
        if uniq.shape[0] != n:
            raise ValueError(f"positions contain {n - uniq.shape[0]} duplicated sensor position(s)")


def _cell_distances(pos: np.ndarray, lattice_pitch: float | None) -> np.ndarray:
    """Nearest-neighbour distance of every sensor ``(n,)`` in m; a single sensor's is the
    lattice pitch (ValueError without one)."""
    if pos.shape[0] > 1:
        return _nn_distance(pos)
    d = np.full(1, lattice_pitch if lattice_pitch else np.inf)
    if not np.isfinite(d[0]):
        raise ValueError("a single sensor's cell needs a pitch (give pitch=...)")
    return d


def _clipped_box(pos: np.ndarray, box: tuple[np.ndarray, np.ndarray],
                 bounds: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """The covered region ``(lo, hi)`` (each ``(d,)``, m): ``box`` intersected with
    ``bounds`` (checked: ``d`` finite ``(lo, hi)`` pairs holding every sensor)."""
    lo, hi = box[0].copy(), box[1].copy()
    if bounds is None:
        return lo, hi
    dim = pos.shape[1]
    b = np.asarray(bounds, dtype=np.float64).reshape(-1, 2)
    if b.shape[0] != dim or not np.all(np.isfinite(b)) or np.any(b[:, 1] <= b[:, 0]):
        raise ValueError(f"bounds must be {dim} finite (lo, hi) pairs with lo < hi, got {bounds!r}")
    if np.any(pos < b[:, 0] - 1e-12) or np.any(pos > b[:, 1] + 1e-12):
        raise ValueError("bounds must contain every sensor position")
    return np.maximum(lo, b[:, 0]), np.minimum(hi, b[:, 1])


def _is_full_grid(pos: np.ndarray, grid_pitch: float, d_med: float) -> bool:
    """Whether the plane positions ``(n, 2)`` fill a whole grid of spacing ``grid_pitch``
    (m) whose nearest-neighbour distance is that spacing."""
    k = np.round((pos - pos.min(axis=0)) / grid_pitch).astype(np.int64)
    nx, ny = k.max(axis=0) + 1
    return bool(nx * ny == pos.shape[0] and abs(d_med - grid_pitch) <= 1e-9 * grid_pitch)


def _raster_step(base: float, extent: np.ndarray, n: int, samples_per_cell: int) -> float:
    """The raster step h (m): an even number of sub-cells per lattice pitch (or per
    spacing) ``base``, about ``samples_per_cell`` per median cell, at most ``_MAX_RASTER``
    samples over ``extent`` ``(2,)`` m."""
    cell = float(np.prod(extent)) / n
    m = 2
    while cell / (base / m) ** 2 < samples_per_cell and m < 64:
        m += 2
    while float(np.prod(np.ceil(extent / (base / m)))) > _MAX_RASTER and m > 2:
        m -= 2
    h = base / m
    if float(np.prod(np.ceil(extent / h))) > _MAX_RASTER:
        h = float(np.sqrt(np.prod(extent) / _MAX_RASTER))
    return h


def _raster(anchor: np.ndarray, h: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raster sample centres ``(m, 2)`` (x, y) m over ``[lo, hi]``, cell edges at
    ``anchor + j·h`` (aligned to the lattice), and the fraction ``(m,)`` of each raster
    cell inside the box (edge cells cut by it). Raises ValueError for an empty region."""
    j_lo = np.floor((lo - anchor) / h + 1e-9)
    j_hi = np.ceil((hi - anchor) / h - 1e-9)
    axes, fracs = [], []
    for a in range(2):
        edges_lo = anchor[a] + j_lo[a] * h
        count = int(j_hi[a] - j_lo[a])
        c = edges_lo + (np.arange(count) + 0.5) * h
        # fraction of each raster cell inside [lo, hi] (edge cells cut by the box)
        f = (np.minimum(c + h / 2, hi[a]) - np.maximum(c - h / 2, lo[a])) / h
        f = np.where(f > 1 - 1e-9, 1.0, f)
        ok = f > 1e-9
        axes.append(c[ok])
        fracs.append(f[ok])
    if axes[0].size == 0 or axes[1].size == 0:
        raise ValueError("the covered region is empty")
    gx, gy = np.meshgrid(axes[0], axes[1], indexing="xy")
    frac = np.outer(fracs[1], fracs[0]).ravel()
    return np.column_stack((gx.ravel(), gy.ravel())), frac


def _raster_areas(pos: np.ndarray, samples: np.ndarray, frac: np.ndarray, radius: np.ndarray,
                  h: float) -> np.ndarray:
    """Each sensor's area ``(n,)`` in m²: the raster samples (weighted by ``frac``) nearest
    to it and within its ``radius`` (m), a sample on a bisector shared by the two."""
    n = pos.shape[0]
    tree = cKDTree(pos)
    if n == 1:
        dist, label = tree.query(samples, k=1)
        keep = dist <= radius[label]
        counts = np.bincount(label[keep], weights=frac[keep], minlength=n)
        return counts * h * h
    dist, label = tree.query(samples, k=2, workers=-1)
    # A sample on the bisector of two sensors is shared equally (keeps mirror symmetry).
    tie = dist[:, 1] - dist[:, 0] <= 1e-9 * h
    share = np.where(tie, 0.5, 1.0) * frac
    keep0 = dist[:, 0] <= radius[label[:, 0]]
    counts = np.bincount(label[keep0, 0], weights=share[keep0], minlength=n)
    keep1 = tie & (dist[:, 1] <= radius[label[:, 1]])
    counts += np.bincount(label[keep1, 1], weights=share[keep1], minlength=n)
    return counts * h * h
