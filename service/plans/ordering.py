"""Scan orderings of a mask's points: serpentine, ring by ring alternating,
nearest-neighbour (greedy, to shorten galvo travel), or as given (the mask's own order,
e.g. a user's point list)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike

    from fpscan.service.plans.mask import Mask

__all__ = ["ORDERS", "auto_order", "serpentine_order", "ring_order", "nearest_neighbour_order", "scan_order"]

ORDERS = ("serpentine", "rings", "nearest", "given")


def serpentine_order(indices: ArrayLike) -> np.ndarray:
    """Boustrophedon scan order of lattice indices.

    Rows of equal i_y are visited in increasing i_y, x increasing on even-numbered occupied
    rows and decreasing on odd ones.

    Parameters
    ----------
    indices : array_like of int, shape ``(n, 2)``
        Lattice indices (i_x, i_y).

    Returns
    -------
    ndarray of int, shape ``(n,)``
        The permutation: ``indices[order]`` is in scan order.

    Examples
    --------
    >>> from fpscan.service.plans import serpentine_order
    >>> serpentine_order([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]])
    array([0, 1, 2, 5, 4, 3])
    """
    idx = np.asarray(indices)
    rows, row_rank = np.unique(idx[:, 1], return_inverse=True)
    x_key = np.where(row_rank % 2 == 0, idx[:, 0], -idx[:, 0])
    return np.lexsort((x_key, row_rank))


def ring_order(positions: ArrayLike, rings: ArrayLike | None = None, centre: Sequence[float] = (0.0, 0.0),
               ring_width: float | None = None) -> np.ndarray:
    """Scan order ring by ring outward, the azimuth direction alternating from ring to ring.

    Azimuth increases on even-numbered rings and decreases on odd ones. Points on a line
    (all y equal) are ordered by increasing x.

    Parameters
    ----------
    positions : array_like, shape ``(n, 2)``
        Positions (x, y), m.
    rings : array_like of int, shape ``(n,)``, optional
        Ring numbers (e.g. an equi-steradian mask's). Without them points are binned by
        lateral distance from ``centre`` in bins of ``ring_width``.
    centre : sequence of 2 floats, optional
        Centre (x, y) of the rings, m; default the optical axis.
    ring_width : float, optional
        Bin width, m; default the median nearest-neighbour distance.

    Returns
    -------
    ndarray of int, shape ``(n,)``
        The permutation.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import ring_order
    >>> pos = np.array([[0, 0], [1e-4, 0], [0, 1e-4], [-1e-4, 0], [0, -1e-4], [2e-4, 0]])
    >>> ring_order(pos, ring_width=1e-4)  # centre, ring 1 clockwise from -90°, then ring 2
    array([0, 4, 3, 2, 1, 5])
    >>> ring_order(np.array([[2e-4, 0], [0, 0], [1e-4, 0]]))  # a line: by x
    array([1, 2, 0])
    """
    pos = np.asarray(positions, dtype=np.float64)
    n = pos.shape[0]
    if n <= 1:
        return np.arange(n)
    if np.ptp(pos[:, 1]) == 0:
        return np.argsort(pos[:, 0], kind="stable")
    dx, dy = pos[:, 0] - centre[0], pos[:, 1] - centre[1]
    if rings is None:
        if ring_width is None:
            from scipy.spatial import cKDTree  # on use (start-up time of the plan models)

            d, _ = cKDTree(pos).query(pos, k=2)
            ring_width = float(np.median(d[:, 1]))
        rings = np.floor(np.hypot(dx, dy) / ring_width + 0.5).astype(np.int64)
    _, rank = np.unique(np.asarray(rings), return_inverse=True)
    az = np.mod(np.arctan2(dy, dx), 2 * np.pi)
    az_key = np.where(rank % 2 == 0, az, -az)
    return np.lexsort((az_key, rank))


def nearest_neighbour_order(positions: ArrayLike, start: int = 0) -> np.ndarray:
    """Greedy nearest-neighbour tour: always move to the closest unvisited point.

    Ties go to the lowest index. O(n log n) typical with a k-d tree rebuilt as points are used
    up.

    Parameters
    ----------
    positions : array_like, shape ``(n, d)``
        Positions, m.
    start : int, optional
        Index of the first point (default 0).

    Returns
    -------
    ndarray of int64, shape ``(n,)``
        The tour, a permutation starting with ``start``.

    Raises
    ------
    ValueError
        ``start`` not an index of a point.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import nearest_neighbour_order
    >>> nearest_neighbour_order(np.array([[0.0], [3e-4], [1e-4], [2e-4]]))
    array([0, 2, 3, 1])
    >>> nearest_neighbour_order(np.zeros((2, 2)), start=2)
    Traceback (most recent call last):
    ...
    ValueError: start must index a point (0..1), got 2
    """
    pos = np.asarray(positions, dtype=np.float64)
    n = pos.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not 0 <= start < n:
        raise ValueError(f"start must index a point (0..{n - 1}), got {start}")
    visited = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.int64)
    cur = start
    remaining = np.arange(n)
    from scipy.spatial import cKDTree  # on use (start-up time of the plan models)

    tree = cKDTree(pos)
    for step in range(n):
        order[step] = cur
        visited[cur] = True
        if step == n - 1:
            break
        # Rebuild the tree when most of its points are used up.
        if remaining.size > 64 and visited[remaining].mean() > 0.5:
            remaining = remaining[~visited[remaining]]
            tree = cKDTree(pos[remaining])
        k = min(8, remaining.size)
        nxt = -1
        while nxt < 0:
            dist, j = tree.query(pos[cur], k=k)
            dist, j = np.atleast_1d(dist), np.atleast_1d(j)
            cand = remaining[j]
            ok = ~visited[cand]
            if ok.any():
                dmin = dist[ok].min()
                nxt = int(cand[ok & (dist <= dmin)].min())
            elif k >= remaining.size:
                raise RuntimeError("nearest-neighbour ordering lost track of unvisited points")
            else:
                k = min(2 * k, remaining.size)
        cur = nxt
    return order


def auto_order(mask: Mask) -> str:
    """What ``order="auto"`` means for a mask.

    Parameters
    ----------
    mask : Mask
        The mask (its ``rings`` and ``kind``).

    Returns
    -------
    str
        ``"rings"`` for ring-structured masks (equi-steradian), ``"given"`` for a user's point
        list (kept as listed), else ``"serpentine"``.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, equisteradian_mask, full_mask
    >>> from fpscan.service.plans.ordering import auto_order
    >>> auto_order(equisteradian_mask(Lattice(41, 41, 1e-4), 2e-3, 50))
    'rings'
    >>> auto_order(full_mask(Lattice(3, 3, 1e-4)))
    'serpentine'
    """
    if mask.rings is not None:
        return "rings"
    return "given" if mask.kind == "points" else "serpentine"


def scan_order(mask: Mask, order: str = "auto") -> np.ndarray:
    """The permutation putting a mask's points in scan order.

    Parameters
    ----------
    mask : Mask
        The mask.
    order : str, optional
        ``"auto"`` (default; ``auto_order``: rings for ring-structured masks such as
        equi-steradian, given for point lists, serpentine otherwise), ``"serpentine"``,
        ``"rings"``, ``"nearest"`` (greedy nearest-neighbour tour starting from the first point
        of the auto order) or ``"given"`` (the mask's own order).

    Returns
    -------
    ndarray of int, shape ``(n,)``
        ``mask.indices[scan_order(mask)]`` is in scan order.

    Raises
    ------
    ValueError
        An unknown order name (naming it).

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, full_mask, scan_order
    >>> m = full_mask(Lattice(3, 2, 1e-4))
    >>> m.indices[scan_order(m)].tolist()  # serpentine
    [[0, 0], [1, 0], [2, 0], [2, 1], [1, 1], [0, 1]]
    >>> scan_order(m, "given")
    array([0, 1, 2, 3, 4, 5])
    >>> scan_order(m, "spiral")
    Traceback (most recent call last):
    ...
    ValueError: unknown order 'spiral'; known: auto, serpentine, rings, nearest, given
    """
    if order not in ("auto", *ORDERS):
        raise ValueError(f"unknown order {order!r}; known: auto, {', '.join(ORDERS)}")
    if order == "auto":
        order = auto_order(mask)
    if order == "serpentine":
        return serpentine_order(mask.indices)
    if order == "rings":
        return ring_order(mask.positions, mask.rings, mask.centre)
    if order == "given":
        return np.arange(mask.indices.shape[0])
    if order == "nearest":
        first = scan_order(mask, "auto")
        tour = nearest_neighbour_order(mask.positions, start=int(first[0]))
        return tour
    raise ValueError(f"unknown order {order!r}; known: auto, {', '.join(ORDERS)}")
