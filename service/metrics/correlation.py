"""The correlation coefficient of two images within a region of interest.

Paper, Appendix "Quality measures", eq. (A1):
rho(U1, U2) = Cov(U1, U2) / sqrt(Var(U1) Var(U2)) (Pearson's correlation coefficient),
evaluated on the pixels of the region of interest only (§6, §7).
"""
from __future__ import annotations

import numpy as np

__all__ = ["correlation_coefficient"]


def correlation_coefficient(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Pearson correlation coefficient of ``image`` and ``reference`` over ``mask``.

    Parameters
    ----------
    image, reference : ndarray, same shape (any dimension, e.g. ``(n_z, n_x)`` or an
        xy-MIP ``(n_y, n_x)``); values in any (common or not) unit — the measure is
        invariant to affine maps ``a*U + b`` with ``a > 0``.
    mask : ndarray of bool, same shape, optional
        Region of interest (see :func:`fpscan.service.metrics.roi_mask`); default all pixels.

    Returns
    -------
    float in [-1, 1].

    Raises
    ------
    ValueError
        Shape mismatch, NaN/inf in the region, fewer than 2 pixels, or an image that is
        constant within the region (the coefficient is undefined).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", Appendix "Quality measures", eq. (A1).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import correlation_coefficient
    >>> ref = np.outer(np.hanning(5), np.hanning(5))
    >>> correlation_coefficient(2 * ref + 1, ref)  # invariant to a*U + b, a > 0
    1.0
    >>> correlation_coefficient(-ref, ref)
    -1.0
    >>> correlation_coefficient(np.ones((2, 2)), ref[:2, :2])
    Traceback (most recent call last):
    ...
    ValueError: an image is constant within the region of interest: correlation undefined
    """
    image = np.asarray(image, dtype=float)
    reference = np.asarray(reference, dtype=float)
    if image.shape != reference.shape:
        raise ValueError(f"image shape {image.shape} differs from reference shape {reference.shape}")
    if mask is None:
        a, b = image.ravel(), reference.ravel()
    else:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != image.shape:
            raise ValueError(f"mask shape {mask.shape} differs from image shape {image.shape}")
        a, b = image[mask], reference[mask]
    if a.size < 2:
        raise ValueError(f"the region of interest has {a.size} pixel(s); need at least 2")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("image or reference contains NaN or inf within the region of interest")
    a = a - a.mean()
    b = b - b.mean()
    # Scale first so that tiny or huge values neither underflow nor overflow.
    sa, sb = np.abs(a).max(), np.abs(b).max()
    if sa == 0 or sb == 0:
        raise ValueError("an image is constant within the region of interest: correlation undefined")
    a = a / sa
    b = b / sb
    va, vb = float(a @ a), float(b @ b)
    rho = float(a @ b) / np.sqrt(va * vb)
    return float(np.clip(rho, -1.0, 1.0))
