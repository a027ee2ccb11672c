"""Optical absorption of haemoglobin: molar extinction spectra of HbO2 and Hb.

The numbers are Scott Prahl's compilation "Optical Absorption of Hemoglobin" (Oregon
Medical Laser Center, https://omlc.org/spectra/hemoglobin/summary.html; data of
W. B. Gratzer and N. Kollias), shipped unchanged as ``hemoglobin_prahl.csv`` next to
this module: 250-1000 nm in 2 nm steps, decadic molar extinction coefficients in
cm⁻¹/(mol/L) as published. The file is read once, on first use (no I/O at import).

Units of this API (SI):

- wavelengths in m;
- molar extinction coefficients ε in m²/mol, decadic (base 10) as in the table:
  1 cm⁻¹/(mol/L) = 0.1 m²/mol;
- concentrations in mol/m³ (1 mmol/L = 1 mol/m³; whole blood ≈ 150 g/L / 64 500 g/mol
  ≈ 2.3 mol/m³, see ``BLOOD_THB``);
- absorption coefficients μa in m⁻¹, natural-log (Napierian) as used in p0 = Γ μa Φ:
  μa = ln(10) · (ε_HbO2 · C_HbO2 + ε_Hb · C_Hb)  (Prahl's page, "absorption coefficient").

Between table rows ε is linearly interpolated; a wavelength outside the table's range
(250-1000 nm) raises ``ValueError`` (never extrapolated). Which excitation wavelengths a
plan may ask for (400-2000 nm, no repeats) is the plan's rule,
``fpscan.driver.plan.check_wavelengths``.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from importlib import resources

import numpy as np

__all__ = [
    "CHROMOPHORES", "HB_MOLAR_MASS_G_PER_MOL", "BLOOD_THB", "extinction_table", "table_range",
    "molar_extinction", "absorption",
]

#: chromophore order of every ``(..., 2)`` array in this module and in the unmixing
CHROMOPHORES: tuple[str, str] = ("HbO2", "Hb")
#: molar mass of haemoglobin used by Prahl's page to convert g/L to mol/L, g/mol
HB_MOLAR_MASS_G_PER_MOL = 64500.0
#: total haemoglobin of whole blood (150 g/L), mol/m³
BLOOD_THB = 150.0 / HB_MOLAR_MASS_G_PER_MOL * 1e3

_TABLE_FILE = "hemoglobin_prahl.csv"
_CM1_PER_M_TO_SI = 0.1  # cm⁻¹/(mol/L) -> m²/mol


@functools.cache
def _table() -> tuple[np.ndarray, np.ndarray]:
    text = resources.files("fpscan.physics").joinpath(_TABLE_FILE).read_text(encoding="utf-8")
    rows = _parse(text)
    wl = rows[:, 0] * 1e-9
    eps = rows[:, 1:3] * _CM1_PER_M_TO_SI
    wl.setflags(write=False)
    eps.setflags(write=False)
    return wl, eps


def _parse(text: str) -> np.ndarray:
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    body = lines[1:]  # first non-comment line is the column header
    rows = np.array([[float(v) for v in ln.split(",")] for ln in body], dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != 3 or not np.all(np.diff(rows[:, 0]) > 0):
        raise RuntimeError(f"{_TABLE_FILE}: malformed extinction table")
    return rows


def extinction_table() -> tuple[np.ndarray, np.ndarray]:
    """The published table in SI units (read-only arrays).

    Returns
    -------
    wavelengths : ndarray ``(n,)``, m (250-1000 nm, 2 nm steps).
    epsilon : ndarray ``(n, 2)``
        Decadic molar extinction coefficients in m²/mol, columns ``CHROMOPHORES`` =
        (HbO2, Hb).

    References
    ----------
    .. [1] S. Prahl, "Optical Absorption of Hemoglobin", Oregon Medical Laser Center,
       omlc.org/spectra/hemoglobin (the table shipped as ``hemoglobin_prahl.csv``).

    Examples
    --------
    >>> from fpscan.physics.spectra import extinction_table
    >>> wavelengths, epsilon = extinction_table()
    >>> wavelengths.shape, epsilon.shape
    ((376,), (376, 2))
    """
    return _table()


def table_range() -> tuple[float, float]:
    """(shortest, longest) wavelength of the extinction table, m.

    Returns
    -------
    tuple of float, m.

    Examples
    --------
    >>> from fpscan.physics.spectra import table_range
    >>> [round(w * 1e9) for w in table_range()]  # nm
    [250, 1000]
    """
    wl, _ = _table()
    return float(wl[0]), float(wl[-1])


def _wavelengths(wavelengths: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """A scalar, sequence or array of wavelengths (m) -> finite ``(n,)`` float64, n >= 1."""
    if isinstance(wavelengths, (str, bytes)):
        raise ValueError(f"wavelengths must be numbers in m, got {wavelengths!r}")
    try:
        w = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"wavelengths must be numbers in m, got {wavelengths!r}") from exc
    if w.size == 0:
        raise ValueError("wavelengths: at least one wavelength is required")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"wavelengths must be finite, got {w.tolist()}")
    return w


def molar_extinction(wavelengths: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """Decadic molar extinction coefficients of HbO2 and Hb at the given wavelengths.

    Which wavelengths a plan may ask for (400-2000 nm, no repeats) is
    ``fpscan.driver.plan.check_wavelengths``.

    Parameters
    ----------
    wavelengths : float or sequence or ndarray ``(n_wavelengths,)``, m.

    Returns
    -------
    ndarray ``(n_wavelengths, 2)`` in m²/mol, columns (HbO2, Hb), linearly interpolated
    in Prahl's table.

    Raises
    ------
    ValueError
        An empty list, a non-numeric or non-finite value, or a wavelength outside the
        table (250-1000 nm; never extrapolated).

    References
    ----------
    .. [1] S. Prahl, "Optical Absorption of Hemoglobin", Oregon Medical Laser Center,
       omlc.org/spectra/hemoglobin.

    Examples
    --------
    >>> from fpscan.physics.spectra import molar_extinction
    >>> molar_extinction(800e-9).round(1)  # m²/mol, columns (HbO2, Hb)
    array([[81.6, 76.2]])
    >>> molar_extinction(1100e-9)
    Traceback (most recent call last):
    ...
    ValueError: no haemoglobin extinction data at [1100.0] nm: Prahl's table covers 250-1000 nm
    """
    w = _wavelengths(wavelengths)
    wl, eps = _table()
    outside = w[(w < wl[0] - 1e-15) | (w > wl[-1] + 1e-15)]
    if outside.size:
        raise ValueError(
            f"no haemoglobin extinction data at {[round(float(x) * 1e9, 3) for x in outside]} nm: "
            f"Prahl's table covers {wl[0] * 1e9:.0f}-{wl[-1] * 1e9:.0f} nm")
    wc = np.clip(w, wl[0], wl[-1])
    return np.stack([np.interp(wc, wl, eps[:, 0]), np.interp(wc, wl, eps[:, 1])], axis=-1)


def absorption(wavelengths: float | Sequence[float] | np.ndarray,
               so2: float | np.ndarray, thb: float | np.ndarray) -> np.ndarray:
    """Absorption coefficient μa (m⁻¹, natural log) of haemoglobin at oxygen saturation
    ``so2`` and total concentration ``thb``.

    μa(λ) = ln(10) · thb · (so2 · ε_HbO2(λ) + (1 - so2) · ε_Hb(λ))   (Prahl, omlc.org)

    Parameters
    ----------
    wavelengths : float or sequence or ndarray ``(n_wavelengths,)``, m.
    so2 : float or ndarray, oxygen saturation (fraction, 0..1).
    thb : float or ndarray, total haemoglobin concentration, mol/m³ (>= 0; blood:
        ``BLOOD_THB``); broadcast with ``so2`` to shape ``S``.

    Returns
    -------
    ndarray ``(n_wavelengths, *S)``, μa in m⁻¹.

    Raises
    ------
    ValueError
        Wavelengths as in :func:`molar_extinction`, so2 outside [0, 1], thb < 0 or
        non-finite values.

    References
    ----------
    .. [1] S. Prahl, "Optical Absorption of Hemoglobin", Oregon Medical Laser Center,
       omlc.org/spectra/hemoglobin ("absorption coefficient").

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.spectra import BLOOD_THB, absorption
    >>> absorption(800e-9, so2=0.5, thb=BLOOD_THB).round(1)  # whole blood, m⁻¹
    array([422.4])
    >>> absorption([750e-9, 850e-9], so2=np.array([0.0, 1.0]), thb=BLOOD_THB).shape
    (2, 2)
    """
    s = np.asarray(so2, dtype=np.float64)
    t = np.asarray(thb, dtype=np.float64)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(t))):
        raise ValueError("so2 and thb must be finite")
    if np.any((s < 0) | (s > 1)):
        raise ValueError(f"so2 must lie in [0, 1], got min {s.min()}, max {s.max()}")
    if np.any(t < 0):
        raise ValueError(f"thb must be >= 0 mol/m³, got min {t.min()}")
    eps = molar_extinction(wavelengths)  # (n_w, 2)
    s, t = np.broadcast_arrays(s, t)
    e_ox = eps[:, 0].reshape((-1,) + (1,) * s.ndim)
    e_de = eps[:, 1].reshape((-1,) + (1,) * s.ndim)
    return math.log(10.0) * t * (s * e_ox + (1.0 - s) * e_de)
