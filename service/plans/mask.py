"""The sensor mask: lattice points the scanner measures, with their quadrature weights."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .lattice import Lattice

__all__ = ["Mask", "weight_ratio", "distance_law_weights", "default_weights", "check_poi",
           "check_positive", "check_count", "check_seed", "shortfall"]


#: A mask holding fewer than this fraction of the points asked says why (``shortfall``); the
#: ring designs round their counts to powers of two, so a few percent either way is no shortfall.
SHORTFALL_FRACTION = 0.9


def shortfall(kind: str, requested: int | None, obtained: int, pitch: float | None = None) -> str | None:
    """One line saying why a ``kind`` mask obtained fewer than ``SHORTFALL_FRACTION`` of the
    ``requested`` points (``pitch``: the lattice pitch, m), or None when it did not."""
    if not requested or obtained >= SHORTFALL_FRACTION * requested:
        return None
    at = f" ({pitch:g} m)" if pitch else ""
    why = {
        "equisteradian": f"near the point of interest the design's points lie closer than the lattice pitch{at} and "
                         "merge when snapped to it; ask fewer points, a deeper point of interest or a finer pitch",
        "equiangular": f"the design's points lie closer than the lattice pitch{at} (near the point of interest, or "
                       "piled at the line's ends by a steep fan) and merge when snapped to it; ask fewer points, a "
                       "deeper point of interest or a finer pitch",
        "poisson": "the minimum distance leaves room for no more on this lattice; ask a smaller min_distance",
        "points": "points that snap to the same lattice point count once",
    }.get(kind, "the lattice holds no more for these parameters")
    return f"{obtained} of {requested} points asked: {why}"


def check_positive(name: str, value, unit: str = "m") -> float:
    """``value`` as a finite float > 0, else ValueError naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in {unit}, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if v <= 0:
        raise ValueError(f"{name} must be > 0 {unit}, got {v}")
    return v


def check_count(name: str, value, maximum: int | None = None, minimum: int = 1) -> int:
    """``value`` as an int in [minimum, maximum], else ValueError naming ``name``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an integer, got {value!r}") from None
    if not math.isfinite(f) or f != int(f):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(f)
    if v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {v}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} = {v} is more than the lattice holds ({maximum})")
    return v


def check_seed(value) -> int:
    """A random seed: an integer in [0, 2**64), else ValueError."""
    seed = check_count("seed", value, minimum=0)
    if seed >= 2**64:
        raise ValueError(f"seed must be < 2**64, got {value!r}")
    return seed


def check_poi(lattice: Lattice, poi) -> tuple[float, float]:
    """The point of interest's lateral position ``(x, y)`` in m (default: the lattice
    centre). Accepts None, a number (x; y = 0) or a sequence of 1 or 2 numbers.
    Raises ValueError for non-finite values or a point outside the lattice."""
    if poi is None:
        return (0.0, 0.0)
    if np.ndim(poi) == 0:
        vals = [poi]
    else:
        vals = list(np.asarray(poi, dtype=object).ravel())
    if len(vals) not in (1, 2):
        raise ValueError(f"poi must be x or (x, y) in m, got {poi!r}")
    try:
        xy = [float(v) for v in vals] + [0.0] * (2 - len(vals))
    except (TypeError, ValueError):
        raise ValueError(f"poi must be numbers in m, got {poi!r}") from None
    if not all(math.isfinite(v) for v in xy):
        raise ValueError(f"poi must be finite, got {poi!r}")
    if not lattice.contains(xy[0], xy[1]):
        hx, hy = lattice.half_extent
        raise ValueError(
            f"point of interest ({xy[0]:g}, {xy[1]:g}) m lies outside the lattice "
            f"(|x| <= {hx:g} m, |y| <= {hy:g} m)"
        )
    return (xy[0], xy[1])


def default_weights(lattice: Lattice, positions: np.ndarray, **options) -> np.ndarray:
    """Clipped Voronoi areas (DESIGN §3.3) of mask positions ``(n, 2)`` in m: ``(n,)`` in
    m² (m on a line lattice), exactly ``voronoi_weights(positions, pitch)`` — the weights
    ``service.recon.reconstruct_points`` uses by default, so an equispaced sub-grid gets
    (interval·pitch)² everywhere, edges included. ``options`` go to ``voronoi_weights``."""
    from driver.physics.weights import voronoi_weights  # scipy on use: the plan models import this module

    pos = positions[:, :1] if lattice.is_line else positions
    return voronoi_weights(pos, lattice.pitch, **options)


def distance_law_weights(lattice: Lattice, positions: np.ndarray, poi, depth: float,
                         power: int) -> np.ndarray:
    """Weights ∝ r**power, r = distance of each sensor from the point of interest at
    ``depth`` (m) above ``poi`` = (x, y) in m (paper §5.2: r² for equiangular 2-D, r³ for
    equi-steradian 3-D), normalised so they sum to the area the mask covers (the sum of its
    clipped Voronoi areas). positions ``(n, 2)`` in m; returns ``(n,)`` in m² (m on a line)."""
    # only the total is needed: a coarse raster gives it (edge cells are cut exactly)
    area = float(default_weights(lattice, positions, samples_per_cell=16).sum())
    r2 = (positions[:, 0] - poi[0]) ** 2 + (positions[:, 1] - poi[1]) ** 2 + depth**2
    h = r2 ** (power / 2)
    return h * (area / h.sum())


def weight_ratio(positions: np.ndarray, weights: np.ndarray, centre=(0.0, 0.0)) -> float:
    """Outer/inner weight ratio: the mean weight of the sensor(s) farthest from ``centre``
    (lateral distance) over that of the sensor(s) nearest to it (paper §6: 9.7 for its
    equi-steradian mask, 17 for its equiangular one). 1.0 for a single sensor."""
    pos = np.asarray(positions, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if pos.shape[0] == 1:
        return 1.0
    d = np.hypot(pos[:, 0] - centre[0], pos[:, 1] - centre[1])
    tol = 1e-9 * max(float(d.max()), 1e-300)
    outer = w[d >= d.max() - tol].mean()
    inner = w[d <= d.min() + tol].mean()
    return float(outer / inner)


@dataclass(frozen=True, eq=False)
class Mask:
    """A sensor mask on a scanner lattice.

    Attributes
    ----------
        kind: mask kind name (see ``make_mask``).
        params: the parameters it was made from (JSON-safe, SI units).
        lattice: the scanner lattice.
        indices: ``(n, 2)`` int64 lattice indices (i_x, i_y), unique, inside the lattice.
        weights: ``(n,)`` quadrature weights in m² (m on a line lattice), > 0, summing
            to the area the mask covers.
        requested_points: how many points were asked for (``obtained_points`` = n).
        poi: point of interest (x, y) in m, or None (then the lattice centre is used
            for the weight ratio and the ring order).
        depth: the point of interest's distance from the sensor plane in m, or None.
        rings: ``(n,)`` ring number per point for ring-structured masks, else None.
        design: extra design values (e.g. the equiangular angles before snapping).
    """

    kind: str
    params: dict
    lattice: Lattice
    indices: np.ndarray
    weights: np.ndarray
    requested_points: int
    poi: tuple[float, float] | None = None
    depth: float | None = None
    rings: np.ndarray | None = None
    design: dict = field(default_factory=dict)

    @property
    def positions(self) -> np.ndarray:
        """``(n, 2)`` positions (x, y) in m (y = 0 on a line lattice)."""
        return self.lattice.positions(self.indices)

    @property
    def obtained_points(self) -> int:
        return int(self.indices.shape[0])

    @property
    def centre(self) -> tuple[float, float]:
        return self.poi if self.poi is not None else (0.0, 0.0)

    @property
    def weight_ratio(self) -> float:
        """Outer/inner weight ratio about the point of interest (see ``weight_ratio``)."""
        return weight_ratio(self.positions, self.weights, self.centre)

    @property
    def shortfall(self) -> str | None:
        """Why the mask has fewer points than asked (``shortfall``), or None."""
        return shortfall(self.kind, self.requested_points, self.obtained_points, self.lattice.pitch)

    @property
    def covered_area(self) -> float:
        """Sum of the weights: m² (m on a line lattice)."""
        return float(self.weights.sum())

    def recon_positions(self) -> np.ndarray:
        """Positions in the form ``service.recon`` takes: ``(n, 1)`` x in m on a line
        lattice (2-D imaging), ``(n, 2)`` (x, y) in m otherwise."""
        pos = self.positions
        return pos[:, :1].copy() if self.lattice.is_line else pos
