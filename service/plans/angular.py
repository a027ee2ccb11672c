"""The paper's masks around a point of interest: equiangular (2-D) and equi-steradian
(3-D), from the paper's §5.1 and appendix, its ambiguities resolved as the functions below state.

Schmid et al., "Computational realization of a non-equidistant grid sampling in
photoacoustics with a non-uniform FFT", §5 and Appendix "Algorithm for equi-steradian
sensor arrangement". Weights ∝ r² (2-D) / r³ (3-D), r = distance from the point of
interest (paper §5.2), normalised to the covered area.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fpscan.service.plans.lattice import Lattice
from fpscan.service.plans.mask import Mask, check_count, check_poi, check_positive, distance_law_weights

__all__ = ["equiangular_mask", "equisteradian_mask", "equisteradian_rings", "Ring", "check_depth"]

#: Doubling threshold of the appendix: j_k doubles while r_s > 1.8 r_k.
DOUBLING_FACTOR = 1.8
#: Smallest half-angle (rad) of the aperture seen from the point of interest: below it
#: the design's angles are lost to rounding (1 − cos θ_max underflows) and the point of
#: interest is, for the scanner, at infinity. About ρ_max / depth < 1/1000.
MIN_THETA_MAX = 1e-3


def _aperture(r0: float, rho_max: float) -> float:
    """θ_max = atan(ρ_max/r0), refused (ValueError naming depth) below MIN_THETA_MAX."""
    t_max = math.atan(rho_max / r0)
    if not t_max >= MIN_THETA_MAX:
        raise ValueError(f"depth {r0:g} m is too large for the lattice: the aperture (radius "
                         f"{rho_max:g} m) subtends less than {MIN_THETA_MAX:g} rad from the point of "
                         f"interest; use a depth below {rho_max / math.tan(MIN_THETA_MAX):.3g} m")
    return t_max


@dataclass(frozen=True)
class Ring:
    """One ring of the equi-steradian design.

    Parameters
    ----------
    theta, theta_lo, theta_hi, count, phi0
        As the attributes below.

    Attributes
    ----------
    theta : float
        Polar angle of the ring's points seen from the point of interest, rad.
    theta_lo, theta_hi : float
        The ring's polar band ``[theta_lo, theta_hi]``, rad.
    count : int
        Number of points on the ring (a power of two).
    phi0 : float
        Azimuth of the first point, rad; the points lie at ``phi0 + 2π i / count``
        (``azimuths()``, shape ``(count,)``).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import equisteradian_rings
    >>> ring = equisteradian_rings(2e-3, 2e-3, 50)[1]  # the first ring around the centre point
    >>> ring.count
    4
    >>> np.degrees(ring.azimuths())
    array([ 45., 135., 225., 315.])
    """

    theta: float
    theta_lo: float
    theta_hi: float
    count: int
    phi0: float

    def azimuths(self) -> np.ndarray:
        """Azimuths of the ring's points, ``phi0 + 2π i / count``.

        Returns
        -------
        ndarray, shape ``(count,)``
            rad.

        Examples
        --------
        >>> from fpscan.service.plans.angular import Ring
        >>> Ring(theta=0.5, theta_lo=0.4, theta_hi=0.6, count=2, phi0=0.0).azimuths().round(4)
        array([0.    , 3.1416])
        """
        return self.phi0 + 2 * np.pi * np.arange(self.count) / self.count


def _ring_xy(rho: float, phis: np.ndarray) -> np.ndarray:
    return np.column_stack((rho * np.cos(phis), rho * np.sin(phis)))


def equisteradian_rings(depth: float, rho_max: float, n_points: int) -> list[Ring]:
    """The equi-steradian ring design (paper appendix), before projection and snapping.

    θ_max = atan(ρ_max / r0); Ω = 2π(1 − cos θ_max); ω = Ω/N. Ring 1: one point at θ = 0,
    band [0, θ_1] with 2π(1 − cos θ_1) = ω. Ring k: j_k points (power of two, starting at
    j_{k−1}, doubled while r_s > 1.8·r_k, where r_s is the chord between neighbours on
    ring k and r_k the distance to the closest point of ring k−1, both on the sensor
    plane; a ring after the single centre point always has ≥ 2 points); band
    [θ_{k−1}, θ_k] with ω·j_k = 2π(cos θ_{k−1} − cos θ_k); points at the mid polar angle,
    azimuths φ_{i,k} = φ_{0,k−1} + (2i+1)π/j_k. Rings are added while their band ends
    below θ_max; the ring whose band would reach θ_max is put on θ_max itself (the
    aperture's edge), so the count ends near N.

    Parameters
    ----------
    depth : float
        r0, the point of interest's distance from the sensor plane, m (> 0).
    rho_max : float
        The disc's radius on the sensor plane, m (> 0).
    n_points : int
        N, the requested count (>= 1).

    Returns
    -------
    list of Ring
        The rings, centre first; their counts sum to about N.

    Raises
    ------
    ValueError
        depth or rho_max <= 0 or non-finite, n_points < 1, an aperture under
        ``MIN_THETA_MAX`` (depth too large for ρ_max), a design that does not close within
        n_points + 2 rings (the iteration bound).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", Appendix "Algorithm for equi-steradian sensor arrangement".

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.plans import equisteradian_rings
    >>> rings = equisteradian_rings(2e-3, 2e-3, 50)  # r0 = rho_max: a 45° aperture
    >>> [r.count for r in rings], sum(r.count for r in rings)
    ([1, 4, 8, 8, 16, 16], 53)
    >>> round(float(np.degrees(rings[-1].theta)), 1)  # the last ring on the aperture's edge
    45.0
    """
    r0 = check_positive("depth", depth)
    rho_max = check_positive("rho_max", rho_max)
    n = check_count("n_points", n_points)
    t_max = _aperture(r0, rho_max)
    omega = 2 * math.pi * (1 - math.cos(t_max)) / n
    if n == 1:
        return [Ring(0.0, 0.0, t_max, 1, 0.0)]
    t1 = math.acos(1 - omega / (2 * math.pi))
    rings = [Ring(0.0, 0.0, t1, 1, 0.0)]
    prev_xy = np.zeros((1, 2))
    # every ring holds >= 2 points of solid angle ω, so the design ends within n rings
    # of exact arithmetic; the bound stops a pathological rounding case with the reason
    for _ in range(n + 2):
        prev = rings[-1]
        j = prev.count
        while True:
            c = math.cos(prev.theta_hi) - j * omega / (2 * math.pi)
            hi = math.acos(max(c, -1.0))
            last = hi >= t_max
            theta = t_max if last else 0.5 * (prev.theta_hi + hi)
            rho = r0 * math.tan(theta)
            phis = prev.phi0 + (2 * np.arange(j) + 1) * np.pi / j
            xy = _ring_xy(rho, phis)
            r_k = float(np.min(np.hypot(xy[:, None, 0] - prev_xy[None, :, 0], xy[:, None, 1] - prev_xy[None, :, 1])))
            r_s = 2 * rho * math.sin(math.pi / j) if j > 1 else math.inf
            if r_s > DOUBLING_FACTOR * r_k and j < (1 << 20):
                j *= 2
                continue
            break
        rings.append(Ring(theta, prev.theta_hi, min(hi, t_max), j, float(phis[0])))
        prev_xy = xy
        if last:
            return rings
    raise ValueError(f"the equi-steradian design did not close within {n + 2} rings "
                     f"(depth {r0:g} m, rho_max {rho_max:g} m, n_points {n})")


def check_depth(r0: float, lattice: Lattice) -> float:
    """The point of interest's depth, refused below one lattice pitch.

    Seen from closer than a pitch, the design's angles put nearly every point within a pitch
    of the point of interest and they all snap onto the same few lattice points.

    Parameters
    ----------
    r0 : float
        Depth of the point of interest below the sensor plane, m.
    lattice : Lattice
        The scanner lattice (its pitch).

    Returns
    -------
    float
        ``r0`` unchanged.

    Raises
    ------
    ValueError
        ``r0`` below ``lattice.pitch``, naming the reason.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice
    >>> from fpscan.service.plans.angular import check_depth
    >>> check_depth(2e-3, Lattice(41, 41, 1e-4))
    0.002
    >>> check_depth(5e-5, Lattice(41, 41, 1e-4))
    Traceback (most recent call last):
    ...
    ValueError: depth 5e-05 m is below one lattice pitch (0.0001 m): ...
    """
    if r0 < lattice.pitch:
        raise ValueError(f"depth {r0:g} m is below one lattice pitch ({lattice.pitch:g} m): seen from so close, "
                         "the design's points crowd within a pitch of the point of interest and snap onto the "
                         "same lattice points; give a depth of at least one pitch (e.g. 3.6mm)")
    return r0


def _finish(kind: str, params: dict, lattice: Lattice, pos_design: np.ndarray, poi: tuple[float, float], depth: float,
            power: int, requested: int, ring_of: np.ndarray | None, design: dict) -> Mask:
    idx = lattice.snap(pos_design)
    _, first = np.unique(idx, axis=0, return_index=True)
    keep = np.sort(first)
    idx = idx[keep]
    rings = None if ring_of is None else np.asarray(ring_of)[keep]
    pos = lattice.positions(idx)
    w = distance_law_weights(lattice, pos, poi, depth, power)
    return Mask(kind=kind, params=params, lattice=lattice, indices=idx, weights=w,
                requested_points=requested, poi=poi, depth=depth, rings=rings, design=design)


def equisteradian_mask(lattice: Lattice, depth: float, n_points: int, poi: float | Sequence[float] | None = None) -> Mask:
    """Equi-steradian mask (3-D) around a point of interest (paper appendix).

    ρ_max is the distance from poi to the nearest lattice edge (outermost lattice points), so
    the mask is a disc. The rings of ``equisteradian_rings`` are projected (ρ = r0·tan θ),
    snapped to the lattice and de-duplicated; weights ∝ r³ normalised to the covered area.
    The paper's setup (226 × 226, 60 µm, r0 = 3.6 mm, N = 1625) gives θ_max = 61.9° (its 62°)
    and 1653 points.

    Parameters
    ----------
    lattice : Lattice
        A 2-D scanner lattice (n_y > 1).
    depth : float
        r0, the point of interest's distance from the sensor plane, m (at least one pitch).
    n_points : int
        N requested (1 to the lattice's point count).
    poi : sequence of 2 floats, optional
        The point of interest's lateral position (x, y), m; default the lattice centre.

    Returns
    -------
    Mask
        Kind ``"equisteradian"``, with ``rings`` (ring number per point, 0 = centre) and
        ``design`` (``theta_max``, ``rho_max``, ``ring_theta``, ``ring_count``).

    Raises
    ------
    ValueError
        Line lattice, depth <= 0 or below one pitch, n_points < 1 or above the lattice, poi
        outside or on the edge of the lattice, non-finite values.

    References
    ----------
    .. [1] J. Schmid et al., "Computational Realization of a Non-Equidistant Grid Sampling in
       Photoacoustics with a Non-Uniform FFT", §5 and Appendix; weights §5.2.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, equisteradian_mask
    >>> m = equisteradian_mask(Lattice(41, 41, 1e-4), depth=2e-3, n_points=50)
    >>> m.obtained_points, int(m.rings.max()), m.design["ring_count"]
    (53, 5, [1, 4, 8, 8, 16, 16])
    >>> round(m.weight_ratio, 3)  # outer/inner: (r_edge / r0)³ = (√2)³
    2.828
    """
    if lattice.is_line:
        raise ValueError("an equi-steradian mask needs a 2-D lattice (n_y > 1); use equiangular on a line")
    r0 = check_depth(check_positive("depth", depth), lattice)
    n = check_count("n_points", n_points, lattice.n_points)
    xc, yc = check_poi(lattice, poi)
    hx, hy = lattice.half_extent
    rho_max = min(hx - abs(xc), hy - abs(yc))
    if rho_max <= 0.5 * lattice.pitch:
        raise ValueError("the point of interest lies on the lattice edge: no disc of sensors fits around it")
    rings = equisteradian_rings(r0, rho_max, n)
    pts, ring_of = [], []
    for k, ring in enumerate(rings):
        rho = min(r0 * math.tan(ring.theta), rho_max)
        pts.append(_ring_xy(rho, ring.azimuths()) + np.array([xc, yc]))
        ring_of.append(np.full(ring.count, k))
    pos = np.vstack(pts)
    params = {"depth": r0, "n_points": n, "poi": [xc, yc]}
    design = {
        "theta_max": math.atan(rho_max / r0),
        "rho_max": rho_max,
        "ring_theta": [r.theta for r in rings],
        "ring_count": [r.count for r in rings],
        "design_points": int(pos.shape[0]),
    }
    return _finish("equisteradian", params, lattice, pos, (xc, yc), r0, 3, n, np.concatenate(ring_of), design)


def equiangular_mask(lattice: Lattice, depth: float, n_points: int, poi: float | Sequence[float] | None = None) -> Mask:
    """Equiangular mask (2-D) around a point of interest (paper §5.1).

    θ_max = atan(ρ_max/r0), ρ_max the distance from x_c to the nearer end of the line; sensors
    at θ_i = −θ_max + i·2θ_max/(N−1) (N = 1: θ = 0), x_i = x_c + r0·tan θ_i, snapped,
    duplicates dropped. Weights ∝ r² normalised to the covered length (m).

    Parameters
    ----------
    lattice : Lattice
        A line lattice (n_y = 1).
    depth : float
        r0, the point of interest's distance from the sensor line, m (at least one pitch).
    n_points : int
        N requested (1 to the lattice's point count).
    poi : float, optional
        The point of interest's lateral x, m; default the line's centre.

    Returns
    -------
    Mask
        Kind ``"equiangular"``; ``design["theta"]`` holds the N angles (rad) before snapping.
        Fewer points than asked: ``Mask.shortfall`` says why.

    Raises
    ------
    ValueError
        A 2-D lattice, depth <= 0 or below one pitch, n_points < 1 or above the lattice, poi
        outside the line or on its end, non-finite values.

    References
    ----------
    .. [1] J. Schmid et al., "Computational Realization of a Non-Equidistant Grid Sampling in
       Photoacoustics with a Non-Uniform FFT", §5.1; weights §5.2.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, equiangular_mask
    >>> m = equiangular_mask(Lattice(101, 1, 1e-4), depth=2e-3, n_points=11)
    >>> m.indices[:, 0]  # denser under the point of interest, sparser towards the ends
    array([  0,  22,  33,  40,  45,  50,  55,  60,  67,  78, 100])
    >>> m.weight_ratio  # r² at the ends over r0²: (5² + 2²) / 2² mm²
    7.25
    """
    if not lattice.is_line:
        raise ValueError("an equiangular mask needs a line lattice (n_y = 1); use equisteradian in 3-D")
    r0 = check_depth(check_positive("depth", depth), lattice)
    n = check_count("n_points", n_points, lattice.n_points)
    xc, _ = check_poi(lattice, poi)
    hx, _ = lattice.half_extent
    rho_max = hx - abs(xc)
    if n > 1 and rho_max <= 0:
        raise ValueError("the point of interest lies on the end of the line: no symmetric fan of sensors fits")
    t_max = _aperture(r0, rho_max) if n > 1 else 0.0
    theta = np.zeros(1) if n == 1 else -t_max + np.arange(n) * (2 * t_max / (n - 1))
    x = xc + r0 * np.tan(theta)
    pos = np.column_stack((x, np.zeros(n)))
    params = {"depth": r0, "n_points": n, "poi": [xc, 0.0]}
    design = {"theta_max": t_max, "theta": theta.tolist(), "x_design": x.tolist()}
    return _finish("equiangular", params, lattice, pos, (xc, 0.0), r0, 2, n, None, design)
