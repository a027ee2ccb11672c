"""The sensor mask: lattice points the scanner measures, with their quadrature weights."""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fpscan.service.plans.lattice import Lattice

__all__ = ["Mask", "weight_ratio", "distance_law_weights", "default_weights", "check_poi",
           "check_positive", "check_count", "check_seed", "shortfall"]


#: A mask holding fewer than this fraction of the points asked says why (``shortfall``); the
#: ring designs round their counts to powers of two, so a few percent either way is no shortfall.
SHORTFALL_FRACTION = 0.9


def shortfall(kind: str, requested: int | None, obtained: int, pitch: float | None = None) -> str | None:
    """One line saying why a mask holds fewer points than asked (or, for the angular kinds'
    ring designs, many more).

    Parameters
    ----------
    kind : str
        The mask kind (``"equisteradian"``, ``"poisson"``, ...); the reason is the kind's.
    requested : int or None
        Points asked for; None or 0: nothing was asked, no shortfall.
    obtained : int
        Points the mask holds.
    pitch : float, optional
        The lattice pitch, m, named in the reason of the angular kinds.

    Returns
    -------
    str or None
        The reason when ``obtained`` is below ``SHORTFALL_FRACTION`` (0.9) of ``requested``, or
        for ``equisteradian``/``equiangular`` above ``requested / SHORTFALL_FRACTION``; else None.

    Examples
    --------
    >>> from fpscan.service.plans.mask import shortfall
    >>> print(shortfall("poisson", 100, 50))
    50 of 100 points asked: the minimum distance leaves room for no more on this lattice;
    ask a smaller min_distance
    >>> shortfall("random", 100, 95) is None  # within 10 %
    True
    >>> print(shortfall("equisteradian", 53, 85))
    85 points for the 53 asked: the design's rings hold more points outward, and its last ring is taken
    whole; ask fewer points for fewer
    """
    if requested and kind in ("equisteradian", "equiangular") and obtained * SHORTFALL_FRACTION > requested:
        return (f"{obtained} points for the {requested} asked: the design's rings hold more points outward, and its "
                "last ring is taken whole; ask fewer points for fewer")
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


def check_positive(name: str, value: Any, unit: str = "m") -> float:
    """``value`` as a finite float > 0.

    Parameters
    ----------
    name : str
        The parameter's name, used in the error message.
    value : float or anything ``float()`` takes
        The value, in ``unit``.
    unit : str, optional
        Its unit, named in the error message (default ``"m"``).

    Returns
    -------
    float
        ``float(value)``.

    Raises
    ------
    ValueError
        Not a number, non-finite or <= 0; the message names ``name``.

    Examples
    --------
    >>> from fpscan.service.plans.mask import check_positive
    >>> check_positive("pitch", "6e-5")
    6e-05
    >>> check_positive("pitch", 0)
    Traceback (most recent call last):
    ...
    ValueError: pitch must be > 0 m, got 0.0
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in {unit}, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if v <= 0:
        raise ValueError(f"{name} must be > 0 {unit}, got {v}")
    return v


def check_count(name: str, value: Any, maximum: int | None = None, minimum: int = 1) -> int:
    """``value`` as an int in ``[minimum, maximum]``.

    Parameters
    ----------
    name : str
        The parameter's name, used in the error message.
    value : int or integral float
        The count (``12.0`` is 12; ``True`` is refused).
    maximum : int, optional
        Largest allowed value (e.g. the lattice's point count); default no limit.
    minimum : int, optional
        Smallest allowed value (default 1).

    Returns
    -------
    int

    Raises
    ------
    ValueError
        Not an integer, or outside the range; the message names ``name``.

    Examples
    --------
    >>> from fpscan.service.plans.mask import check_count
    >>> check_count("n_points", 12.0)
    12
    >>> check_count("n_points", 20, maximum=15)
    Traceback (most recent call last):
    ...
    ValueError: n_points = 20 is more than the lattice holds (15)
    """
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


def check_seed(value: Any) -> int:
    """A random seed: an integer in [0, 2**64).

    Parameters
    ----------
    value : int
        The seed (numpy PCG64).

    Returns
    -------
    int

    Raises
    ------
    ValueError
        Not an integer, negative or >= 2**64.

    Examples
    --------
    >>> from fpscan.service.plans.mask import check_seed
    >>> check_seed(7)
    7
    >>> check_seed(-1)
    Traceback (most recent call last):
    ...
    ValueError: seed must be >= 0, got -1
    """
    seed = check_count("seed", value, minimum=0)
    if seed >= 2**64:
        raise ValueError(f"seed must be < 2**64, got {value!r}")
    return seed


def check_poi(lattice: Lattice, poi: Any) -> tuple[float, float]:
    """The point of interest's lateral position ``(x, y)`` in m.

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice the point must lie within (its outermost points included).
    poi : None, float or sequence of 1 or 2 floats
        None: the lattice centre; a number: x (y = 0); ``(x,)`` or ``(x, y)``; m.

    Returns
    -------
    tuple of float
        ``(x, y)`` in m.

    Raises
    ------
    ValueError
        Non-numeric or non-finite values, more than two numbers, a point outside the lattice.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice
    >>> from fpscan.service.plans.mask import check_poi
    >>> lat = Lattice(41, 41, 1e-4)  # 4 mm across
    >>> check_poi(lat, None), check_poi(lat, 1e-3), check_poi(lat, (1e-3, -1e-3))
    ((0.0, 0.0), (0.001, 0.0), (0.001, -0.001))
    >>> check_poi(lat, 5e-3)
    Traceback (most recent call last):
    ...
    ValueError: point of interest (0.005, 0) m lies outside the lattice (|x| <= 0.002 m, |y| <= 0.002 m)
    """
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


def default_weights(lattice: Lattice, positions: np.ndarray, **options: Any) -> np.ndarray:
    """Clipped Voronoi areas of mask positions: the default quadrature weights.

    Exactly ``voronoi_weights(positions, pitch)`` — the weights
    ``fpscan.service.recon.reconstruct_points`` uses by default, so an equispaced sub-grid gets
    (interval·pitch)² everywhere, edges included.

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice (its pitch and whether it is a line).
    positions : ndarray, shape ``(n, 2)``
        Mask positions (x, y), m (y ignored on a line lattice).
    **options
        Passed to ``fpscan.physics.weights.voronoi_weights`` (e.g. ``samples_per_cell``).

    Returns
    -------
    ndarray, shape ``(n,)``
        Weights in m² (m on a line lattice), summing to the area the mask covers.

    Raises
    ------
    ValueError
        What ``voronoi_weights`` refuses (non-finite or duplicated positions).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import Lattice, full_mask
    >>> from fpscan.service.plans.mask import default_weights
    >>> lat = Lattice(3, 3, 1e-4)
    >>> w = default_weights(lat, full_mask(lat).positions)
    >>> w.shape, bool(np.allclose(w, 1e-8))  # pitch² each
    ((9,), True)
    """
    from fpscan.physics.weights import voronoi_weights  # scipy on use: the plan models import this module

    pos = positions[:, :1] if lattice.is_line else positions
    return voronoi_weights(pos, lattice.pitch, **options)


def distance_law_weights(lattice: Lattice, positions: np.ndarray, poi: Sequence[float], depth: float,
                         power: int) -> np.ndarray:
    """Weights ∝ r**power, r the distance of each sensor from the point of interest.

    The point of interest lies ``depth`` (m) below ``poi``; paper §5.2: r² for equiangular
    (2-D), r³ for equi-steradian (3-D). The weights are normalised so they sum to the area
    the mask covers (the sum of its clipped Voronoi areas).

    Parameters
    ----------
    lattice : Lattice
        The scanner lattice (for the covered area).
    positions : ndarray, shape ``(n, 2)``
        Sensor positions (x, y), m.
    poi : sequence of 2 floats
        Lateral position (x, y) of the point of interest, m.
    depth : float
        Its distance from the sensor plane, m.
    power : int
        The exponent (2 or 3).

    Returns
    -------
    ndarray, shape ``(n,)``
        Weights in m² (m on a line lattice).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §5.2.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import Lattice
    >>> from fpscan.service.plans.mask import distance_law_weights
    >>> line = Lattice(101, 1, 1e-4)
    >>> w = distance_law_weights(line, np.array([[0.0, 0.0], [2e-3, 0.0]]), (0.0, 0.0), 2e-3, 2)
    >>> round(float(w[1] / w[0]), 6)  # r² = 2 depth² against depth²
    2.0
    >>> round(float(w.sum()), 6)  # m: the length the two sensors cover
    0.004
    """
    # only the total is needed: a coarse raster gives it (edge cells are cut exactly)
    area = float(default_weights(lattice, positions, samples_per_cell=16).sum())
    r2 = (positions[:, 0] - poi[0]) ** 2 + (positions[:, 1] - poi[1]) ** 2 + depth**2
    h = r2 ** (power / 2)
    return h * (area / h.sum())


def weight_ratio(positions: np.ndarray, weights: np.ndarray, centre: Sequence[float] = (0.0, 0.0)) -> float:
    """Outer/inner weight ratio of a mask.

    The mean weight of the sensor(s) farthest from ``centre`` (lateral distance) over that of
    the sensor(s) nearest to it (paper §6: 9.7 for its equi-steradian mask, 17 for its
    equiangular one).

    Parameters
    ----------
    positions : ndarray, shape ``(n, 2)``
        Sensor positions (x, y), m.
    weights : ndarray, shape ``(n,)``
        Their weights (any unit).
    centre : sequence of 2 floats, optional
        Lateral centre (x, y), m; default the optical axis.

    Returns
    -------
    float
        The ratio; 1.0 for a single sensor.

    References
    ----------
    .. [1] J. Schmid et al., "Computational Realization of a Non-Equidistant Grid Sampling in
       Photoacoustics with a Non-Uniform FFT", §6.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import weight_ratio
    >>> weight_ratio(np.array([[0.0, 0.0], [1e-3, 0.0]]), np.array([1.0, 4.0]))
    4.0
    >>> weight_ratio(np.zeros((1, 2)), np.ones(1))
    1.0
    """
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
    """A sensor mask on a scanner lattice: the points measured and their quadrature weights.

    Made by ``make_mask`` or the per-kind functions (``full_mask``, ``equisteradian_mask``, ...).

    Parameters
    ----------
    kind, params, lattice, indices, weights, requested_points, poi, depth, rings, design
        As the attributes below.

    Attributes
    ----------
    kind : str
        Mask kind name (see ``make_mask``).
    params : dict
        The parameters it was made from (JSON-safe, SI units).
    lattice : Lattice
        The scanner lattice.
    indices : ndarray of int64, shape ``(n, 2)``
        Lattice indices (i_x, i_y), unique, inside the lattice.
    weights : ndarray, shape ``(n,)``
        Quadrature weights in m² (m on a line lattice), > 0, summing to the area the mask covers.
    requested_points : int
        How many points were asked for (``obtained_points`` = n).
    poi : tuple of float or None
        Point of interest (x, y) in m, or None (then the lattice centre is used for the weight
        ratio and the ring order).
    depth : float or None
        The point of interest's distance from the sensor plane in m, or None.
    rings : ndarray of int, shape ``(n,)``, or None
        Ring number per point for ring-structured masks, else None.
    design : dict
        Extra design values (e.g. the equiangular angles before snapping).
    positions : ndarray, shape ``(n, 2)``
        Positions (x, y) in m (y = 0 on a line lattice).
    obtained_points : int
        n.
    weight_ratio : float
        Outer/inner weight ratio about the point of interest (see ``weight_ratio``).
    shortfall : str or None
        Why the mask has fewer points than asked, or None.
    covered_area : float
        Sum of the weights: m² (m on a line lattice).

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, full_mask
    >>> m = full_mask(Lattice(3, 3, 1e-4))
    >>> m.obtained_points, m.indices.shape, m.weights.shape
    (9, (9, 2), (9,))
    >>> round(m.covered_area, 12), m.weight_ratio  # m², 0.3 mm x 0.3 mm; equal weights
    (9e-08, 1.0)
    >>> m.recon_positions().shape  # (x, y) in m, as fpscan.service.recon takes them
    (9, 2)
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

    def __repr__(self) -> str:
        """One line: the kind, points obtained of the lattice's, the lattice and the weight
        ratio (never the arrays).

        Examples
        --------
        >>> from fpscan.service.plans import Lattice, full_mask
        >>> full_mask(Lattice(3, 3, 1e-4))
        Mask(full: 9 of 9 points on 3x3 at 100 µm, weight ratio 1)
        """
        lat = self.lattice
        return (f"Mask({self.kind}: {self.obtained_points} of {lat.n_x * lat.n_y} points on {lat.n_x}x{lat.n_y} at "
                f"{lat.pitch * 1e6:.4g} µm, weight ratio {self.weight_ratio:.4g})")

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
        """The positions in the form ``fpscan.service.recon`` takes them.

        Returns
        -------
        ndarray, shape ``(n, 1)`` (line lattice: x) or ``(n, 2)`` ((x, y))
            m.

        Examples
        --------
        >>> from fpscan.service.plans import Lattice, full_mask
        >>> full_mask(Lattice(3, 1, 1e-4)).recon_positions().shape
        (3, 1)
        """
        pos = self.positions
        return pos[:, :1].copy() if self.lattice.is_line else pos
