"""Linear spectral unmixing of per-wavelength p0 volumes into HbO2 and Hb (sO2, THb).

Model (one voxel, wavelengths λ_1..λ_n; Beer-Lambert absorption, Prahl's spectra from
:mod:`fpscan.physics.spectra`):

    p0(λ) = Γ · Φ(λ) · μa(λ),    μa(λ) = ln(10) · (ε_HbO2(λ) · C_HbO2 + ε_Hb(λ) · C_Hb)

with Γ the Grüneisen parameter and Φ(λ) the local fluence. The concentrations are the
non-negative least-squares solution (``scipy.optimize.nnls`` defines it) of
``A · C = p0 / (ln(10) · Γ · Φ)``, ``A = [ε_HbO2 ε_Hb]`` (n × 2, m²/mol), per voxel.

**Fluence assumption (explicit).** Without ``fluence`` the fluence and Γ are assumed to be
the same at every wavelength and in every voxel (one unknown common factor Γ·Φ): the
concentrations are then *relative* (mol/m³ times that unknown factor)
but sO2 = C_HbO2 / (C_HbO2 + C_Hb) does not depend on it. With ``fluence`` (J/m², per
wavelength ``(n,)`` or per voxel ``(n, *S)``, e.g. from a light model fpscan does not
provide) and ``gruneisen`` the p0 volumes are divided by Γ·Φ first and the
concentrations come out in mol/m³ when p0 is in Pa. A fluence that differs between
wavelengths and is not given biases sO2 (spectral colouring); that is the user's call.

For two chromophores the NNLS problem has a closed form that is evaluated for all voxels
at once (:func:`nnls2`): the unconstrained least-squares solution when both components
are ≥ 0, otherwise the better of the two one-component solutions clamped at 0 (the
optimum of a strictly convex quadratic outside the feasible quadrant lies on its
boundary). Tests check it against ``scipy.optimize.nnls`` voxel by voxel.

Pure numpy; no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from fpscan.physics import spectra

__all__ = ["CHUNK", "Unmixed", "too_few_wavelengths", "endmember_matrix", "nnls2", "check_unmix_options", "unmix"]

#: voxels per block of the vectorised NNLS (bounds the temporary memory: ~60 bytes/voxel)
CHUNK = 1 << 20


@dataclass
class Unmixed:
    """Result of :func:`unmix`: HbO2, Hb, THb and sO2 volumes.

    Every volume has the spatial shape ``S`` of the input (``(n_z, n_y, n_x)`` or
    ``(n_z, n_x)``), float32.

    Parameters
    ----------
    hbo2, hb, thb, so2, mask, wavelengths, params
        As the attributes below.

    Attributes
    ----------
    hbo2, hb : ndarray, shape ``S``
        Concentrations of HbO2 and Hb (mol/m³ with fluence and Γ given, else relative units:
        see the module docstring).
    thb : ndarray, shape ``S``
        hbo2 + hb, same units.
    so2 : ndarray, shape ``S``
        hbo2 / thb in [0, 1]; NaN outside ``mask``.
    mask : ndarray of bool, shape ``S``
        True where the signal is strong enough for sO2 (thb ≥ threshold · max(thb)).
    wavelengths : ndarray, shape ``(n_wavelengths,)``
        m.
    params : dict
        Everything used (JSON-serialisable).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.unmix import endmember_matrix, unmix
    >>> w = np.array([7.5e-7, 8.0e-7, 8.5e-7])  # m
    >>> vol = np.einsum("w,zx->wzx", np.log(10) * endmember_matrix(w) @ [0.7, 0.3], np.ones((2, 4)))
    >>> u = unmix(vol, w)  # p0 of blood at sO2 = 0.7, (n_wavelengths, n_z, n_x)
    >>> u.so2.shape, u.so2.dtype, bool(np.allclose(u.so2, 0.7)), bool(u.mask.all())
    ((2, 4), dtype('float32'), True, True)
    """

    hbo2: np.ndarray
    hb: np.ndarray
    thb: np.ndarray
    so2: np.ndarray
    mask: np.ndarray
    wavelengths: np.ndarray
    params: dict = field(default_factory=dict)


def too_few_wavelengths(wavelengths: npt.ArrayLike | None) -> ValueError:
    """The error for an input with fewer than two wavelengths, naming them.

    Parameters
    ----------
    wavelengths : array_like or None
        The dataset's wavelengths, m.

    Returns
    -------
    ValueError
        Not raised: the caller raises it.

    Examples
    --------
    >>> from fpscan.service.recon.unmix import too_few_wavelengths
    >>> print(too_few_wavelengths([7.5e-7]))
    unmixing into HbO2 and Hb needs at least two wavelengths; this dataset has 1 (750 nm)
    >>> print(too_few_wavelengths(None))
    unmixing into HbO2 and Hb needs at least two wavelengths; this dataset has 0 (none recorded)
    """
    w = np.asarray([] if wavelengths is None else wavelengths, dtype=np.float64).reshape(-1)
    nm = ", ".join(f"{v * 1e9:g} nm" for v in w) or "none recorded"
    return ValueError("unmixing into HbO2 and Hb needs at least two wavelengths; this dataset has "
                      f"{w.size} ({nm})")


def endmember_matrix(wavelengths: npt.ArrayLike) -> np.ndarray:
    """Decadic molar extinction [ε_HbO2, ε_Hb] at the wavelengths (Prahl's spectra).

    Parameters
    ----------
    wavelengths : array_like, shape ``(n_wavelengths,)``
        Excitation wavelengths, m (at least two, distinct).

    Returns
    -------
    ndarray, shape ``(n_wavelengths, 2)``
        ε_HbO2 and ε_Hb in m²/mol, one row per wavelength.

    Raises
    ------
    ValueError
        Fewer than two wavelengths (an empty list included), repeats, a wavelength that is
        no excitation wavelength (``fpscan.driver.plan.check_wavelengths``: 400-2000 nm), one outside
        Prahl's table (250-1000 nm) or spectra that cannot be told apart at these wavelengths
        (condition number > 1e6).

    References
    ----------
    .. [1] S. Prahl, "Optical absorption of hemoglobin", Oregon Medical Laser Center (1999),
       omlc.org/spectra/hemoglobin (``fpscan.physics.spectra``).

    Examples
    --------
    >>> from fpscan.service.recon.unmix import endmember_matrix
    >>> endmember_matrix([7.5e-7, 8.5e-7]).round(1)  # HbO2 below Hb at 750 nm, above at 850 nm
    array([[ 51.8, 140.5],
           [105.8,  69.1]])
    >>> endmember_matrix([7.5e-7, 7.5e-7])
    Traceback (most recent call last):
    ...
    ValueError: unmixing needs distinct wavelengths, got [7.5e-07, 7.5e-07] m
    """
    from fpscan.driver.plan import check_wavelengths

    try:
        w = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"wavelengths must be numbers in m, got {wavelengths!r}") from None
    if w.size < 2:
        raise too_few_wavelengths(w)
    if np.unique(w).size != w.size:
        raise ValueError(f"unmixing needs distinct wavelengths, got {[float(v) for v in w]} m")
    check_wavelengths([float(v) for v in w])
    A = spectra.molar_extinction(w)
    cond = np.linalg.cond(A)
    if not np.isfinite(cond) or cond > 1e6:
        raise ValueError(f"HbO2 and Hb cannot be separated at {[round(v * 1e9, 3) for v in w]} nm "
                         f"(condition number {cond:.3g}): choose wavelengths where their spectra differ")
    return A


def nnls2(A: np.ndarray, Y: np.ndarray, *, chunk: int = CHUNK) -> np.ndarray:
    """Exact non-negative least squares for two unknowns, for many right-hand sides at once.

    ``min ||A x - y||, x ≥ 0`` for every column ``y`` of ``Y``: the unconstrained solution
    when both components are ≥ 0, else the better one-component solution clamped at 0.

    Parameters
    ----------
    A : ndarray, shape ``(n, 2)``
        Of full column rank.
    Y : ndarray, shape ``(n, m)``
        One right-hand side per column.
    chunk : int, optional
        Columns per block (bounds the temporary memory).

    Returns
    -------
    ndarray of float64, shape ``(2, m)``
        Equal to ``scipy.optimize.nnls(A, Y[:, j])[0]`` for every j (up to rounding).

    Raises
    ------
    ValueError
        Wrong shapes, a rank-deficient ``A`` or non-finite values.

    References
    ----------
    .. [1] C. L. Lawson, R. J. Hanson, "Solving Least Squares Problems", Prentice-Hall (1974),
       ch. 23 (the NNLS problem ``scipy.optimize.nnls`` solves).

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.optimize import nnls
    >>> from fpscan.service.recon.unmix import nnls2
    >>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> Y = np.array([[1.0, -1.0], [2.0, 1.0], [3.0, 0.0]])
    >>> nnls2(A, Y)  # the second column's x0 is clamped at 0
    array([[1. , 0. ],
           [2. , 0.5]])
    >>> bool(np.allclose(nnls2(A, Y)[:, 1], nnls(A, Y[:, 1])[0]))
    True
    """
    A = np.asarray(A, dtype=np.float64)
    Y = np.asarray(Y)
    if A.ndim != 2 or A.shape[1] != 2 or Y.ndim != 2 or Y.shape[0] != A.shape[0]:
        raise ValueError(f"nnls2 needs A (n, 2) and Y (n, m), got {A.shape} and {Y.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("A contains NaN or inf")
    G = A.T @ A
    g00, g01, g11 = G[0, 0], G[0, 1], G[1, 1]
    det = g00 * g11 - g01 * g01
    if not (g00 > 0 and g11 > 0 and det > 1e-12 * g00 * g11):
        raise ValueError("nnls2: A must have two linearly independent columns")
    m = Y.shape[1]
    X = np.empty((2, m), dtype=np.float64)
    for s in range(0, m, max(1, int(chunk))):
        y = np.asarray(Y[:, s:s + chunk], dtype=np.float64)
        if not np.all(np.isfinite(y)):
            raise ValueError("Y contains NaN or inf")
        b = A.T @ y  # (2, k)
        x0 = (g11 * b[0] - g01 * b[1]) / det
        x1 = (g00 * b[1] - g01 * b[0]) / det
        # one-component solutions clamped at 0, and their decrease of the squared residual
        a0 = np.maximum(b[0], 0.0) / g00
        a1 = np.maximum(b[1], 0.0) / g11
        take0 = a0 * b[0] >= a1 * b[1]  # b0+^2/g00 >= b1+^2/g11
        inside = (x0 >= 0) & (x1 >= 0)
        X[0, s:s + chunk] = np.where(inside, x0, np.where(take0, a0, 0.0))
        X[1, s:s + chunk] = np.where(inside, x1, np.where(take0, 0.0, a1))
    return X


def check_unmix_options(threshold: float, fluence: Any = None, n_wavelengths: int | None = None) -> None:
    """The unmixing options, checked before anything is reconstructed (`fpscan.service.pipeline.run_file`
    asks before it loads, and again with the inputs' ``n_wavelengths``; :func:`unmix` itself).

    Parameters
    ----------
    threshold : float
        The THb mask's fraction of the maximum: finite, in [0, 1).
    fluence : float, sequence of float or ndarray, optional
        J/m²: None, one value, one per wavelength, or an array :func:`unmix` broadcasts; every
        value finite and > 0.
    n_wavelengths : int, optional
        The wavelengths to unmix: a sequence of fluences must have one value, or one per wavelength.

    Raises
    ------
    ValueError
        Naming the option and the rule.

    Examples
    --------
    >>> from fpscan.service.recon.unmix import check_unmix_options
    >>> check_unmix_options(0.1, [2.0, 3.0], n_wavelengths=2)
    >>> check_unmix_options(0.1, [1.0, 2.0, 3.0], n_wavelengths=2)
    Traceback (most recent call last):
    ...
    ValueError: fluence has 3 values for 2 wavelengths (give one, or one per wavelength)
    """
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(threshold) and 0.0 <= threshold < 1.0):
        raise ValueError(f"threshold must lie in [0, 1), got {threshold}")
    if fluence is None:
        return
    try:
        phi = np.asarray(fluence, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"fluence must be numbers in J/m², got {fluence!r}") from None
    if phi.size == 0 or not np.all(np.isfinite(phi)) or np.any(phi <= 0):
        raise ValueError("fluence must be finite and > 0 J/m²")
    if n_wavelengths is not None and phi.ndim == 1 and phi.size not in (1, n_wavelengths):
        raise ValueError(f"fluence has {phi.size} values for {n_wavelengths} wavelengths (give one, or one per "
                         "wavelength)")


def unmix(volumes: np.ndarray, wavelengths: npt.ArrayLike, *, fluence: np.ndarray | float | None = None,
          gruneisen: float = 1.0, threshold: float = 0.1, chunk: int = CHUNK) -> Unmixed:
    """Unmix per-wavelength p0 volumes into HbO2 and Hb (NNLS per voxel), THb and sO2.

    Parameters
    ----------
    volumes : ndarray, shape ``(n_wavelengths, *S)``
        p0 (Pa), one volume per wavelength on one grid (``S`` = ``(n_z, n_y, n_x)`` or
        ``(n_z, n_x)``).
    wavelengths : array_like, shape ``(n_wavelengths,)``
        Excitation wavelengths in m (≥ 2, distinct, in 400-1000 nm: an excitation
        wavelength, ``fpscan.driver.plan.check_wavelengths``, within Prahl's table).
    fluence : ndarray or float, optional
        Fluence Φ in J/m², ``(n_wavelengths,)`` or broadcastable to ``volumes``; None = the
        same unknown fluence everywhere (module docstring).
    gruneisen : float, optional
        Grüneisen parameter Γ (> 0, dimensionless), used with ``fluence``.
    threshold : float, optional
        Fraction in [0, 1) of the largest THb below which a voxel is masked (default 0.1).
    chunk : int, optional
        Voxels per block (memory bound).

    Returns
    -------
    Unmixed

    Raises
    ------
    ValueError
        Fewer than two wavelengths (a single-wavelength dataset), shape mismatch, non-finite
        volumes, fluence ≤ 0, bad threshold, wavelengths outside the table.

    References
    ----------
    .. [1] S. Prahl, "Optical absorption of hemoglobin", Oregon Medical Laser Center (1999),
       omlc.org/spectra/hemoglobin.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.unmix import endmember_matrix, unmix
    >>> w = np.array([7.5e-7, 8.5e-7])  # m
    >>> mu_a = np.log(10) * endmember_matrix(w) @ [0.9, 0.1]  # C_HbO2, C_Hb in mol/m³
    >>> vol = mu_a[:, None] * np.ones((2, 5))  # (n_wavelengths, n_x): Γ Φ = 1
    >>> u = unmix(vol, w, fluence=1.0)
    >>> round(float(u.so2[0]), 4), round(float(u.thb[0]), 4), u.params["fluence"]  # thb in mol/m³
    (0.9, 1.0, 'given')
    >>> unmix(vol[:1], w[:1])
    Traceback (most recent call last):
    ...
    ValueError: unmixing into HbO2 and Hb needs at least two wavelengths; this dataset has 1 (750 nm)
    """
    vol = np.asarray(volumes)
    w = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    A = endmember_matrix(w)
    if vol.ndim < 2 or vol.shape[0] != w.size:
        raise ValueError(f"volumes must be (n_wavelengths={w.size}, *S), got shape {vol.shape}")
    if vol.dtype.kind not in "iuf":
        raise ValueError(f"volumes must hold real numbers, got dtype {vol.dtype}")
    check_unmix_options(threshold, fluence)
    if not (math.isfinite(gruneisen) and gruneisen > 0):
        raise ValueError(f"gruneisen must be > 0, got {gruneisen}")
    shape = vol.shape[1:]
    Y = vol.reshape(w.size, -1)
    scale = math.log(10.0)
    units = "relative (same unknown fluence and Grüneisen parameter assumed at every wavelength and voxel)"
    if fluence is not None:
        phi = np.asarray(fluence, dtype=np.float64)
        if phi.ndim == 1 and phi.shape[0] == w.size:
            phi = phi.reshape((w.size,) + (1,) * len(shape))
        try:
            phi = np.broadcast_to(phi, vol.shape)
        except ValueError:
            raise ValueError(f"fluence of shape {np.shape(fluence)} does not fit volumes {vol.shape}") from None
        if not np.all(np.isfinite(phi)) or np.any(phi <= 0):
            raise ValueError("fluence must be finite and > 0 J/m²")
        Y = vol.reshape(w.size, -1) / phi.reshape(w.size, -1)
        scale *= gruneisen
        units = "mol/m³ (p0 in Pa divided by the given fluence and Grüneisen parameter)"
    X = nnls2(A, Y, chunk=chunk) / scale
    hbo2 = X[0].reshape(shape).astype(np.float32)
    hb = X[1].reshape(shape).astype(np.float32)
    thb = hbo2 + hb
    top = float(thb.max()) if thb.size else 0.0
    mask = (thb >= threshold * top) & (thb > 0) if top > 0 else np.zeros(shape, dtype=bool)
    so2 = np.full(shape, np.nan, dtype=np.float32)
    np.divide(hbo2, thb, out=so2, where=mask)
    params = {"wavelengths_m": [float(v) for v in w], "chromophores": list(spectra.CHROMOPHORES),
              "extinction_source": "Prahl, omlc.org/spectra/hemoglobin (cm^-1/M, decadic)",
              "method": "nnls (closed form for 2 chromophores, = scipy.optimize.nnls)",
              "fluence": "given" if fluence is not None else "assumed uniform", "gruneisen": float(gruneisen),
              "threshold": float(threshold), "concentration_units": units,
              "masked_fraction": float(1.0 - mask.mean()) if mask.size else 1.0}
    return Unmixed(hbo2, hb, thb, so2, mask, w, params)
