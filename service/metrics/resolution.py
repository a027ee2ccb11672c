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

__all__ = [
    "MIN_FWHM_SAMPLES", "lorentz", "edge_spread", "LorentzFit", "EdgeFit", "fit_lorentz", "fit_edge_spread",
    "side_lobe_level",
]

#: Fits whose FWHM comes out below this many sample spacings are rejected as
#: under-sampled (least squares then degenerates to a 1/(z - z0)² tail; the paper also
#: omitted edges where a single sample marked the transition).
MIN_FWHM_SAMPLES = 0.5


def lorentz(z: np.ndarray, a0: float, z0: float, w: float, baseline: float = 0.0) -> np.ndarray:
    """Cauchy-Lorentz line-spread model ``2 a0 w / (pi (w² + 4 (z - z0)²)) + baseline``.

    Parameters
    ----------
    z : ndarray ``(n,)``, positions (e.g. depth, m).
    a0 : float
        Area under the curve (intensity unit · unit of ``z``); peak height ``2 a0 / (pi w)``.
    z0 : float
        Centre, unit of ``z``.
    w : float
        Full width at half maximum, unit of ``z``.
    baseline : float
        Constant offset, intensity unit.

    Returns
    -------
    ndarray ``(n,)`` of float.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §4 (axial resolution).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import lorentz
    >>> lorentz(np.array([0.0, 1.0]), a0=np.pi, z0=0.0, w=2.0)  # peak 2 a0/(pi w) = 1, half at w/2
    array([1. , 0.5])
    """
    z = np.asarray(z, dtype=float)
    return 2.0 * a0 * w / (np.pi * (w * w + 4.0 * (z - z0) ** 2)) + baseline


def edge_spread(x: np.ndarray, i0: float, a0: float, x0: float, w: float) -> np.ndarray:
    """Arctan edge-spread model ``i0 + a0 (arctan((x - x0)/(w/2))/pi + 1/2)``.

    The derivative is a Lorentzian of FWHM ``|w|`` centred on the edge ``x0``; ``i0`` is
    the level far on the low-x side, ``i0 + a0`` far on the high-x side (``a0 < 0`` for a
    falling edge).

    Parameters
    ----------
    x : ndarray ``(n,)``, positions across the edge (m).
    i0, a0 : float
        Low-side level and step height, intensity unit.
    x0, w : float
        Edge position and FWHM of the line-spread function, unit of ``x``.

    Returns
    -------
    ndarray ``(n,)`` of float.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §4 (lateral resolution).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import edge_spread
    >>> edge_spread(np.array([-1e9, 0.0, 1e9]), i0=0.1, a0=1.0, x0=0.0, w=1e-4)
    array([0.1, 0.6, 1.1])
    """
    x = np.asarray(x, dtype=float)
    return i0 + a0 * (np.arctan((x - x0) / (w / 2.0)) / np.pi + 0.5)


@dataclass(frozen=True)
class LorentzFit:
    """Result of :func:`fit_lorentz`.

    Attributes
    ----------
    fwhm, center : float
        Full width at half maximum (the axial resolution) and centre, unit of ``z`` (m).
    area : float
        a0 of :func:`lorentz` (intensity unit · unit of ``z``).
    peak, baseline, rms_residual : float
        Model maximum, fitted offset (0 without one), RMS of the fit's residual; intensity unit.

    Examples
    --------
    >>> from fpscan.service.metrics import LorentzFit
    >>> LorentzFit(2e-4, 1e-4, 1.0, 3183.1, 0.0, 0.0).to_dict()["fwhm"]
    0.0002
    """

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
    """Result of :func:`fit_edge_spread`.

    Attributes
    ----------
    fwhm, edge : float
        |w| (the lateral resolution) and x0 of :func:`edge_spread`, unit of ``x`` (m).
    low, step, rms_residual : float
        i0, a0 and the RMS of the fit's residual, intensity unit.

    Examples
    --------
    >>> from fpscan.service.metrics import EdgeFit
    >>> EdgeFit(1e-4, 2e-4, 0.1, 1.0, 0.0).to_dict()["edge"]
    0.0002
    """

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


def _lorentz_start(u: np.ndarray, q: np.ndarray, baseline: bool) -> np.ndarray:
    """Global grid search over (centre, width) with the linear parameters (area,
    baseline) solved exactly by least squares: a robust start for few-sample profiles."""
    k = int(np.argmax(q))
    span = max(u[-1] - u[0], 1.0)
    centres = u[k] + np.linspace(-1.0, 1.0, 41)
    widths = np.geomspace(0.05, 10 * span, 80)
    w = widths[:, None, None]
    f = 2.0 * w / (np.pi * (w * w + 4.0 * (u[None, None, :] - centres[None, :, None]) ** 2))  # (n_w, n_c, n)
    if baseline:
        fm = f.mean(axis=2, keepdims=True)
        fc = f - fm
        qc = q - q.mean()
        a = np.einsum("wcn,n->wc", fc, qc) / np.maximum(np.einsum("wcn,wcn->wc", fc, fc), 1e-300)
        b = q.mean() - a * fm[..., 0]
        model = a[..., None] * f + b[..., None]
    else:
        a = np.einsum("wcn,n->wc", f, q) / np.einsum("wcn,wcn->wc", f, f)
        model = a[..., None] * f
    err = np.sum((model - q) ** 2, axis=2)
    i, j = np.unravel_index(int(np.argmin(err)), err.shape)
    start = [a[i, j], centres[j], widths[i]]
    if baseline:
        start.append(b[i, j])
    return np.array(start)


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
        peak, or an under-sampled peak (fitted FWHM < ``MIN_FWHM_SAMPLES`` spacings).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §4 (Lorentz fit over 8 samples around the maximum).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import fit_lorentz, lorentz
    >>> z = np.linspace(-5e-4, 5e-4, 41)  # depth, m
    >>> fit = fit_lorentz(z, lorentz(z, a0=1.0, z0=1e-4, w=2e-4))
    >>> print(f"FWHM {fit.fwhm * 1e6:.1f} um at {fit.center * 1e6:.1f} um")
    FWHM 200.0 um at 100.0 um
    """
    min_points = 5 if baseline else 4
    z, p = _check_profile(z, profile, min_points)
    k = int(np.argmax(p))
    sl = _window(z.size, k, window, min_points)
    z, p = z[sl], p[sl]
    k = int(np.argmax(p))
    base0 = float(np.min(p)) if baseline else 0.0
    height = p[k] - base0
    if height <= 0:
        raise ValueError("the profile has no positive peak to fit")
    # Fit in normalised units (samples, peak = 1) so that every parameter is O(1).
    step = float(np.median(np.diff(z)))
    u = (z - z[k]) / step
    q = p / height
    popt = _lorentz_start(u, q, baseline)

    def jac(uu: np.ndarray, *params: float) -> np.ndarray:
        a0, z0, w = params[:3]
        d = w * w + 4.0 * (uu - z0) ** 2
        cols = [2.0 * w / (np.pi * d), 16.0 * a0 * w * (uu - z0) / (np.pi * d * d),
                2.0 * a0 * (d - 2.0 * w * w) / (np.pi * d * d)]
        if baseline:
            cols.append(np.ones_like(uu))
        return np.column_stack(cols)

    try:
        polished, _ = curve_fit(lorentz, u, q, p0=popt, jac=jac, method="lm", maxfev=2000)
        if (np.all(np.isfinite(polished)) and abs(polished[1] - u[k]) <= u[-1] - u[0]
                and np.sum((q - lorentz(u, *polished)) ** 2) <= np.sum((q - lorentz(u, *popt)) ** 2)):
            popt = polished
    except (RuntimeError, ValueError):
        pass  # keep the grid-search optimum
    resid = (q - lorentz(u, *popt)) * height
    a, uc, w = (float(v) for v in popt[:3])
    b = float(popt[3]) * height if baseline else 0.0
    w = abs(w)
    if w < MIN_FWHM_SAMPLES:
        raise ValueError(f"the line-spread profile is under-sampled: fitted FWHM {w:.3g} samples "
                         f"< {MIN_FWHM_SAMPLES} (a sharper peak than the sampling can measure)")
    return LorentzFit(
        fwhm=w * step, center=float(z[k]) + uc * step, area=a * height * step,
        peak=2 * a * height / (np.pi * w) + b, baseline=b,
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
        Bad shapes, fewer than 5 samples, a flat profile, a fit that does not converge, or
        an under-sampled edge (fitted width < ``MIN_FWHM_SAMPLES`` spacings).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §4 (edge-spread fit across a bar edge).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import edge_spread, fit_edge_spread
    >>> x = np.linspace(-1e-3, 1e-3, 41)  # m
    >>> fit = fit_edge_spread(x, edge_spread(x, i0=0.1, a0=1.0, x0=2e-4, w=1e-4))
    >>> print(f"FWHM {fit.fwhm * 1e6:.1f} um, edge at {fit.edge * 1e6:.1f} um")
    FWHM 100.0 um, edge at 200.0 um
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
    # Fit in normalised units (samples from the first point, unit step height).
    step = float(np.median(np.diff(x)))
    scale = abs(hi - lo)
    u = (x - x[0]) / step
    q = (p - lo) / scale
    sgn = 1.0 if hi > lo else -1.0
    frac = q * sgn
    crossing = np.flatnonzero(np.diff(np.sign(frac - 0.5)) != 0)
    u0 = float(u[crossing[0]]) + 0.5 if crossing.size else float(u[u.size // 2])
    # 25 %-75 % rise distance equals w for the arctan model.
    inside = np.flatnonzero((frac > 0.25) & (frac < 0.75))
    w0 = max(float(u[inside[-1]] - u[inside[0]]) + 1.0, 1.0) if inside.size else 1.0
    span = u[-1] - u[0]
    try:
        popt, _ = curve_fit(
            edge_spread, u, q, p0=[0.0, sgn, u0, w0],
            bounds=([-np.inf, -np.inf, -span, 1e-3], [np.inf, np.inf, 2 * span, 1e3 * span]),
            maxfev=20000,
        )
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"edge-spread fit did not converge: {exc}") from exc
    i0, a0, ue, w = (float(v) for v in popt)
    if abs(w) < MIN_FWHM_SAMPLES:
        raise ValueError(f"the edge is under-sampled: fitted width {abs(w):.3g} samples "
                         f"< {MIN_FWHM_SAMPLES} (a sharper edge than the sampling can measure)")
    resid = (q - edge_spread(u, *popt)) * scale
    return EdgeFit(fwhm=abs(w) * step, edge=float(x[0]) + ue * step, low=lo + i0 * scale, step=a0 * scale,
                   rms_residual=float(np.sqrt(np.mean(resid**2))))


def side_lobe_level(profile: np.ndarray) -> float:
    """Peak side-lobe level of a line-spread profile, as a fraction of its peak.

    The main lobe is the run of samples around the maximum over which the profile
    decreases monotonically on both sides; the side-lobe level is the largest ``|value|``
    outside it divided by the peak value (0 when the main lobe fills the profile).
    Convert to dB with ``20 log10``.

    Parameters
    ----------
    profile : ndarray ``(n,)`` with a positive maximum (any intensity unit).

    Returns
    -------
    float >= 0, dimensionless.

    Raises
    ------
    ValueError
        Not 1-D, fewer than 3 samples, NaN/inf, or a maximum <= 0.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import side_lobe_level
    >>> side_lobe_level(np.array([0.3, 0.0, 1.0, 0.0, 0.3]))  # 20 log10(0.3): -10.5 dB
    0.3
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
