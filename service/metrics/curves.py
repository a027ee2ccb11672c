"""Quality curves of paper §7: correlation coefficient vs number of pixels of interest,
and correlation coefficient / Tenenbaum sharpness vs ROI diameter.

- "CC vs pixels of interest" (paper Fig. "Correlation coefficient calculated on
  different number of pixels"): within a fixed disc, pixels of interest are added in
  decreasing order of the reference (model standard) intensity; the CC is evaluated on
  the first n of them.
- "CC vs ROI diameter" (paper Fig. "Correlation Coefficient ... for an increasing
  diameter of the confining disc"): pixels of interest are those with at least
  ``threshold`` (4 %) of the reference maximum, within a disc of growing diameter.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from fpscan.service.metrics.correlation import correlation_coefficient
from fpscan.service.metrics.roi import axes_for, roi_mask
from fpscan.service.metrics.sharpness import tenenbaum_sharpness

__all__ = ["cc_vs_pixels", "cc_vs_diameter", "sharpness_vs_diameter"]


def _same_shape(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image, dtype=float)
    reference = np.asarray(reference, dtype=float)
    if image.shape != reference.shape:
        raise ValueError(f"image shape {image.shape} differs from reference shape {reference.shape}")
    return image, reference


def cc_vs_pixels(
    image: np.ndarray, reference: np.ndarray, counts: Sequence[int] | np.ndarray, *, region: np.ndarray | None = None
) -> np.ndarray:
    """Correlation coefficient on the n brightest reference pixels, for each n in ``counts``.

    Parameters
    ----------
    image, reference : ndarray, same shape (e.g. xy-MIPs ``(n_y, n_x)``).
    counts : sequence of int
        Numbers of pixels of interest, each in ``[2, region.sum()]``.
    region : ndarray of bool, optional
        The confining disc (see :func:`fpscan.service.metrics.disc_mask`); default all pixels.

    Returns
    -------
    ndarray ``(len(counts),)`` of correlation coefficients; NaN where the coefficient is
    undefined (an image constant on those pixels).

    Raises
    ------
    ValueError
        Shape mismatch, counts outside ``[2, number of pixels in region]``, NaN/inf.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §7 (CC vs number of pixels of interest).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import cc_vs_pixels
    >>> ref = np.outer(np.hanning(9), np.hanning(9))
    >>> cc_vs_pixels(2 * ref, ref, [4, 25]).tolist()
    [1.0, 1.0]
    """
    image, reference = _same_shape(image, reference)
    if region is None:
        region = np.ones(reference.shape, dtype=bool)
    region = np.asarray(region, dtype=bool)
    if region.shape != reference.shape:
        raise ValueError(f"region shape {region.shape} differs from image shape {reference.shape}")
    idx = np.flatnonzero(region.ravel())
    ref = reference.ravel()[idx]
    img = image.ravel()[idx]
    if not (np.all(np.isfinite(ref)) and np.all(np.isfinite(img))):
        raise ValueError("image or reference contains NaN or inf within the region")
    order = np.argsort(-ref, kind="stable")
    ref, img = ref[order], img[order]
    n_pixels = np.asarray(counts, dtype=int)
    if n_pixels.ndim != 1 or n_pixels.size == 0:
        raise ValueError("counts must be a non-empty 1-D sequence of integers")
    if n_pixels.min() < 2 or n_pixels.max() > idx.size:
        raise ValueError(f"pixel counts must lie in [2, {idx.size}] (pixels in the region), got {n_pixels.min()}..{n_pixels.max()}")
    out = np.empty(n_pixels.size)
    for k, n in enumerate(n_pixels):
        try:
            out[k] = correlation_coefficient(img[:n], ref[:n])
        except ValueError:
            out[k] = np.nan
    return out


def _per_diameter(fn: Callable[[np.ndarray, np.ndarray, np.ndarray], float], image: np.ndarray,
                  reference: np.ndarray, axes: Sequence[np.ndarray] | None, diameters: Sequence[float] | np.ndarray,
                  threshold: float | None, center: Sequence[float] | None) -> np.ndarray:
    image, reference = _same_shape(image, reference)
    axes = axes_for(reference.shape, axes)
    diameters = np.asarray(diameters, dtype=float)
    if diameters.ndim != 1 or diameters.size == 0 or np.any(~np.isfinite(diameters)) or np.any(diameters <= 0):
        raise ValueError("diameters must be a non-empty 1-D sequence of positive numbers")
    out = np.full(diameters.size, np.nan)
    for k, d in enumerate(diameters):
        mask = roi_mask(reference, axes=axes, diameter=float(d), center=center, threshold=threshold)
        if mask.sum() < 2:
            continue
        try:
            out[k] = fn(image, reference, mask)
        except ValueError:
            pass
    return out


def cc_vs_diameter(
    image: np.ndarray,
    reference: np.ndarray,
    diameters: Sequence[float],
    *,
    axes: Sequence[np.ndarray] | None = None,
    threshold: float = 0.04,
    center: Sequence[float] | None = None,
) -> np.ndarray:
    """Correlation coefficient within ``disc(diameter) ∩ {reference >= threshold·max}``.

    Parameters
    ----------
    image, reference : ndarray, same shape (e.g. xy-MIPs ``(n_y, n_x)``).
    diameters : sequence of float, disc diameters in the unit of ``axes`` (m), > 0.
    axes : coordinate vectors of the image axes (e.g. ``(y, x)``); default pixel indices.
    threshold : fraction of the reference maximum (paper: 0.04).
    center : disc centre; default the image centre.

    Returns
    -------
    ndarray ``(len(diameters),)``; NaN where the region holds fewer than 2 pixels or the
    coefficient is undefined.

    Raises
    ------
    ValueError
        Shape mismatch, bad diameters, axes or threshold.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §7 (CC vs ROI diameter, pixels of interest at >= 4 %).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import cc_vs_diameter
    >>> ref = np.outer(np.hanning(9), np.hanning(9))
    >>> cc_vs_diameter(2 * ref + 1, ref, [0.5, 5.0]).tolist()  # 0.5 px holds 1 pixel: NaN
    [nan, 1.0]
    """
    return _per_diameter(correlation_coefficient, image, reference, axes, diameters, threshold, center)


def sharpness_vs_diameter(
    image: np.ndarray,
    reference: np.ndarray,
    diameters: Sequence[float],
    *,
    axes: Sequence[np.ndarray] | None = None,
    threshold: float = 0.04,
    center: Sequence[float] | None = None,
) -> np.ndarray:
    """Tenenbaum sharpness of ``image`` on the bounding rectangle of the ROI of each
    diameter (ROI as in :func:`cc_vs_diameter`, defined on ``reference``).

    Parameters
    ----------
    image, reference : ndarray, same shape ``(n_rows, n_cols)`` (e.g. xy-MIPs ``(n_y, n_x)``).
    diameters : sequence of float, disc diameters in the unit of ``axes`` (m), > 0.
    axes : coordinate vectors of the image axes (e.g. ``(y, x)``); default pixel indices.
    threshold : fraction of the reference maximum (paper: 0.04).
    center : disc centre; default the image centre.

    Returns
    -------
    ndarray ``(len(diameters),)`` in (image unit)²; NaN where the ROI holds fewer than 2
    pixels.

    Raises
    ------
    ValueError
        As :func:`cc_vs_diameter`.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §7 (Tenenbaum sharpness on pixels of interest at >= 4 %).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import sharpness_vs_diameter
    >>> ref = np.outer(np.hanning(9), np.hanning(9))
    >>> sharpness_vs_diameter(ref, ref, [0.5, 5.0]).round(3).tolist()
    [nan, 2.724]
    """
    return _per_diameter(lambda im, _ref, m: tenenbaum_sharpness(im, m), image, reference, axes, diameters, threshold, center)
