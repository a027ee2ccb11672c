"""Resolution measures: line-spread and edge-spread fits, side-lobe level (paper §4).

- Axial resolution: the FWHM ``w`` of a Cauchy-Lorentz distribution fitted to a depth
  profile through a thin (delta-like) absorber,
  ``I(z) = 2 a0 w / (pi (w² + 4 (z - z0)²))`` (paper §4, USAF chart, 8 samples around
  the maximum).
- Lateral resolution: an edge-spread function fitted across an edge,
  ``I(x) = I0 + a0 (arctan((x - x0) / (w/2)) / pi + 1/2)``, whose ``w`` is the FWHM of
  the associated (Lorentzian) line-spread function (paper §4).

Fits use ``scipy.optimize.curve_fit`` (Levenberg-Marquardt / trust-region).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import curve_fit


def lorentz(z: np.ndarray, a0: float, z0: float, w: float, baseline: float = 0.0) -> np.ndarray:
    """Cauchy-Lorentz line-spread model ``2 a0 w / (pi (w² + 4 (z - z0)²)) + baseline``.

    ``w`` is the full width at half maximum (same unit as ``z``), ``z0`` the centre,
    ``a0`` the area under the curve (peak height ``2 a0 / (pi w)``). Source: paper §4.
    """
    z = np.asarray(z, dtype=float)
    return 2.0 * a0 * w / (np.pi * (w * w + 4.0 * (z - z0) ** 2)) + baseline


def edge_spread(x: np.ndarray, i0: float, a0: float, x0: float, w: float) -> np.ndarray:
    """Arctan edge-spread model ``i0 + a0 (arctan((x - x0)/(w/2))/pi + 1/2)``.

    The derivative is a Lorentzian of FWHM ``|w|`` centred on the edge ``x0``; ``i0`` is
    the level far on the low-x side, ``i0 + a0`` far on the high-x side (``a0 < 0`` for a
    falling edge). Source: paper §4.
    """
    x = np.asarray(x, dtype=float)
    return i0 + a0 * (np.arctan((x - x0) / (w / 2.0)) / np.pi + 0.5)


@dataclass(frozen=True)
class LorentzFit:
    """Result of :func:`fit_lorentz`: ``fwhm`` and ``center`` in the unit of ``z``,
    ``area`` (a0), ``peak`` (model maximum), ``baseline``, ``rms_residual``."""

    fwhm: float
    center: float
    area: float
    peak: float
    baseline: float
    rms_residual: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class EdgeFit:
    """Result of :func:`fit_edge_spread`: ``fwhm`` (|w|) and ``edge`` (x0) in the unit
    of ``x``, ``low`` (i0), ``step`` (a0), ``rms_residual``."""

    fwhm: float
    edge: float
    low: float
    step: float
    rms_residual: float

    def to_dict(self) -> dict:
        return asdict(self)


def _check_profile(x: np.ndarray, profile: np.ndarray, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    p = np.asarray(profile, dtype=float)
    if x.ndim != 1 or p.ndim != 1 or x.shape != p.shape:
        raise ValueError(f"coordinates {x.shape} and profile {p.shape} must be 1-D of the same length")
    if x.size < min_points:
        raise ValueError(f"need at least {min_points} samples for this fit, got {x.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(p))):
        raise ValueError("coordinates or profile contain NaN or inf")
    if np.any(np.diff(x) <= 0):
        raise ValueError("coordinates must be strictly increasing")
    return x, p


def _window(n: int, centre: int, window: int | None, min_points: int) -> slice:
    if window is None:
        return slice(0, n)
    if window < min_points:
        raise ValueError(f"window must hold at least {min_points} samples, got {window}")
    lo = max(0, min(centre - window // 2, n - window))
    return slice(lo, min(n, lo + window))


def fit_lorentz(
    z: np.ndarray, profile: np.ndarray, *, window: int | None = None, baseline: bool = False
) -> LorentzFit:
    """Fit the Lorentz line-spread model to a profile; its ``fwhm`` is the axial resolution.

    Parameters
    ----------
    z : ndarray ``(n,)``, strictly increasing sample positions (e.g. depth, m).
    profile : ndarray ``(n,)``, the line-spread profile (a peak, positive).
    window : int, optional
        Fit only this many samples centred on the maximum (the paper used 8); default all.
    baseline : bool
        Also fit a constant offset (default: the paper's model, no offset).

    Returns
    -------
    LorentzFit

    Raises
    ------
    ValueError
        Bad shapes, fewer than 4 samples (5 with baseline), a profile without a positive
        peak, or a fit that does not converge.
    """
    min_points = 5 if baseline else 4
    z, p = _check_profile(z, profile, min_points)
    k = int(np.argmax(p))
    sl = _window(z.size, k, window, min_points)
    z, p = z[sl], p[sl]
    k = int(np.argmax(p))
    peak = p[k]
    base0 = float(np.min(p)) if baseline else 0.0
    if peak - base0 <= 0:
        raise ValueError("the profile has no positive peak to fit")
    above = np.flatnonzero(p - base0 >= (peak - base0) / 2)
    step = float(np.median(np.diff(z)))
    w0 = max(float(z[above[-1]] - z[above[0]]) + step, step) if above.size else step
    a0 = (peak - base0) * np.pi * w0 / 2
    p0 = [a0, float(z[k]), w0] + ([base0] if baseline else [])
    lower = [-np.inf, z[0] - (z[-1] - z[0]), 1e-6 * step] + ([-np.inf] if baseline else [])
    upper = [np.inf, z[-1] + (z[-1] - z[0]), np.inf] + ([np.inf] if baseline else [])
    try:
        popt, _ = curve_fit(lorentz, z, p, p0=p0, bounds=(lower, upper), maxfev=20000)
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"Lorentz fit did not converge: {exc}") from exc
    a, zc, w = (float(v) for v in popt[:3])
    b = float(popt[3]) if baseline else 0.0
    resid = p - lorentz(z, *popt)
    return LorentzFit(
        fwhm=abs(w), center=zc, area=a, peak=2 * a / (np.pi * abs(w)) + b, baseline=b,
        rms_residual=float(np.sqrt(np.mean(resid**2))),
    )


def fit_edge_spread(x: np.ndarray, profile: np.ndarray, *, window: int | None = None) -> EdgeFit:
    """Fit the arctan edge-spread model; its ``fwhm`` is the lateral resolution.

    Parameters
    ----------
    x : ndarray ``(n,)``, strictly increasing positions across the edge (m).
    profile : ndarray ``(n,)``, intensities across one edge (rising or falling).
    window : int, optional
        Fit only this many samples centred on the steepest point; default all.

    Returns
    -------
    EdgeFit (``fwhm`` = |w|).

    Raises
    ------
    ValueError
        Bad shapes, fewer than 5 samples, a flat profile, or a fit that does not converge.
    """
    x, p = _check_profile(x, profile, 5)
    grad = np.gradient(p, x)
    k = int(np.argmax(np.abs(grad)))
    sl = _window(x.size, k, window, 5)
    x, p = x[sl], p[sl]
    n_end = max(1, x.size // 8)
    lo, hi = float(np.mean(p[:n_end])), float(np.mean(p[-n_end:]))
    if hi == lo:
        raise ValueError("the profile has no edge (same level on both sides)")
    mid = (lo + hi) / 2
    crossing = np.flatnonzero(np.diff(np.sign(p - mid)) != 0)
    x0 = float(x[crossing[0]]) if crossing.size else float(x[x.size // 2])
    step = float(np.median(np.diff(x)))
    # 25 %-75 % rise distance equals w for the arctan model.
    frac = (p - lo) / (hi - lo)
    inside = np.flatnonzero((frac > 0.25) & (frac < 0.75))
    w0 = max(float(x[inside[-1]] - x[inside[0]]) + step, step) if inside.size else step
    span = x[-1] - x[0]
    try:
        popt, _ = curve_fit(
            edge_spread, x, p, p0=[lo, hi - lo, x0, w0],
            bounds=([-np.inf, -np.inf, x[0] - span, 1e-6 * step], [np.inf, np.inf, x[-1] + span, np.inf]),
            maxfev=20000,
        )
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"edge-spread fit did not converge: {exc}") from exc
    i0, a0, xe, w = (float(v) for v in popt)
    resid = p - edge_spread(x, *popt)
    return EdgeFit(fwhm=abs(w), edge=xe, low=i0, step=a0, rms_residual=float(np.sqrt(np.mean(resid**2))))


def side_lobe_level(profile: np.ndarray) -> float:
    """Peak side-lobe level of a line-spread profile, as a fraction of its peak.

    The main lobe is the run of samples around the maximum over which the profile
    decreases monotonically on both sides; the side-lobe level is the largest ``|value|``
    outside it divided by the peak value (0 when the main lobe fills the profile).
    Convert to dB with ``20 log10``.

    Parameters
    ----------
    profile : ndarray ``(n,)`` with a positive maximum.

    Raises
    ------
    ValueError
        Not 1-D, fewer than 3 samples, NaN/inf, or a maximum <= 0.
    """
    p = np.asarray(profile, dtype=float)
    if p.ndim != 1 or p.size < 3:
        raise ValueError(f"need a 1-D profile of at least 3 samples, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("profile contains NaN or inf")
    k = int(np.argmax(p))
    peak = p[k]
    if peak <= 0:
        raise ValueError("profile maximum is <= 0")
    lo = k
    while lo > 0 and p[lo - 1] < p[lo]:
        lo -= 1
    hi = k
    while hi < p.size - 1 and p[hi + 1] < p[hi]:
        hi += 1
    outside = np.concatenate([p[:lo], p[hi + 1:]])
    if outside.size == 0:
        return 0.0
    return float(np.max(np.abs(outside)) / peak)
