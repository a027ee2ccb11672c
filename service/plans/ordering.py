"""Scan orderings of a mask's points (DESIGN §4): serpentine, ring by ring alternating,
nearest-neighbour (greedy, to shorten galvo travel), or as given (the mask's own order,
e.g. a user's point list)."""
from __future__ import annotations

import numpy as np

__all__ = ["ORDERS", "auto_order", "serpentine_order", "ring_order", "nearest_neighbour_order", "scan_order"]

ORDERS = ("serpentine", "rings", "nearest", "given")


def serpentine_order(indices) -> np.ndarray:
    """Permutation ``(n,)`` visiting rows of equal i_y in increasing i_y, x increasing on
    even-numbered occupied rows and decreasing on odd ones (boustrophedon).
    indices: ``(n, 2)`` lattice indices (i_x, i_y)."""
    idx = np.asarray(indices)
    rows, row_rank = np.unique(idx[:, 1], return_inverse=True)
    x_key = np.where(row_rank % 2 == 0, idx[:, 0], -idx[:, 0])
    return np.lexsort((x_key, row_rank))


def ring_order(positions, rings=None, centre=(0.0, 0.0), ring_width: float | None = None) -> np.ndarray:
    """Permutation ``(n,)`` ring by ring outward, azimuth increasing on even-numbered rings
    and decreasing on odd ones (alternating direction).

    positions: ``(n, 2)`` in m; rings: ``(n,)`` ring numbers (e.g. an equi-steradian mask's);
    without them points are binned by lateral distance from ``centre`` in bins of
    ``ring_width`` m (default: the median nearest-neighbour distance).
    Points on a line (all y equal) are ordered by increasing x."""
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


def nearest_neighbour_order(positions, start: int = 0) -> np.ndarray:
    """Greedy nearest-neighbour tour ``(n,)`` from point ``start``: always move to the
    closest unvisited point (ties: lowest index). positions ``(n, d)`` in m.
    O(n log n) typical with a k-d tree rebuilt as points are used up."""
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


def auto_order(mask) -> str:
    """What ``order="auto"`` means for ``mask``: ``rings`` for ring-structured masks
    (equi-steradian), ``given`` for a user's point list (kept as listed), else ``serpentine``."""
    if mask.rings is not None:
        return "rings"
    return "given" if mask.kind == "points" else "serpentine"


def scan_order(mask, order: str = "auto") -> np.ndarray:
    """The permutation ``(n,)`` putting ``mask``'s points in scan order.

    order: ``"auto"`` (``auto_order``: rings for ring-structured masks such as
    equi-steradian, given for point lists, serpentine otherwise), ``"serpentine"``, ``"rings"``, ``"nearest"`` (greedy nearest-neighbour
    tour starting from the first point of the auto order) or ``"given"`` (the mask's own
    order, e.g. a user's point list as listed).
    Raises ValueError naming the order for an unknown order name."""
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
