"""Tenenbaum sharpness (focus function) of an image.

Paper, Appendix "Quality measures": F = sum_{x,y} (g * U)^2 + (g^T * U)^2 with g the
Sobel operator [[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], normalised by the number of
pixels N (F / N). Evaluated on the smallest rectangle containing the region of interest
(§6, §7). Implemented with ``scipy.ndimage.sobel`` (the same kernel), borders by
reflection so that a constant image has sharpness exactly 0.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from fpscan.service.metrics.roi import bounding_box

__all__ = ["tenenbaum_sharpness"]


def tenenbaum_sharpness(image: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Normalised Tenenbaum sharpness F/N of a 2-D image.

    Parameters
    ----------
    image : ndarray, shape ``(n_rows, n_cols)`` (e.g. ``(n_z, n_x)`` or an xy-MIP
        ``(n_y, n_x)``); value unit u. The result is in u² (it scales with the square of
        the image, so compare images of a common scale).
    mask : ndarray of bool, same shape, optional
        Region of interest; the sharpness is computed on its bounding rectangle
        (:func:`fpscan.service.metrics.bounding_box`). Default: the whole image.

    Returns
    -------
    float >= 0: mean over the rectangle's pixels of (Sobel_rows U)² + (Sobel_cols U)².

    Raises
    ------
    ValueError
        Not 2-D, empty, NaN/inf, mask of a different shape or without any pixel.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", Appendix "Quality measures" (Tenenbaum sharpness, Sobel operator).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import tenenbaum_sharpness
    >>> tenenbaum_sharpness(np.zeros((4, 4)))  # a constant image has no edges
    0.0
    >>> img = np.outer(np.hanning(5), np.hanning(5))
    >>> tenenbaum_sharpness(img), tenenbaum_sharpness(2 * img)  # scales with the square
    (3.5, 14.0)
    """
    image = np.asarray(image, dtype=float)
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"Tenenbaum sharpness needs a non-empty 2-D image, got shape {image.shape}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != image.shape:
            raise ValueError(f"mask shape {mask.shape} differs from image shape {image.shape}")
        image = image[bounding_box(mask)]
    if not np.all(np.isfinite(image)):
        raise ValueError("image contains NaN or inf")
    gx = ndimage.sobel(image, axis=1, mode="reflect")
    gy = ndimage.sobel(image, axis=0, mode="reflect")
    return float(np.mean(gx * gx + gy * gy))
