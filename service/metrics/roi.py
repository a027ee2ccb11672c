"""Regions of interest (ROI) for the quality measures.

The paper (§6, §7) evaluates the correlation coefficient only within a region of
interest: a centred disc, intersected with the "pixels of interest" whose value in the
reference image (the model standard) is at least a fraction of its maximum (4 % in §7).
The Tenenbaum sharpness is evaluated on the smallest rectangle containing that region.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["axes_for", "disc_mask", "roi_mask", "bounding_box"]


def axes_for(shape: tuple[int, ...], axes: Sequence[np.ndarray] | None) -> list[np.ndarray]:
    """The coordinate vectors of an image: ``axes`` checked against ``shape``, or the voxel
    indices when there are none.

    Parameters
    ----------
    shape : tuple of int
        The image's shape, e.g. ``(n_z, n_x)`` or ``(n_z, n_y, n_x)``.
    axes : sequence of 1-D arrays or None
        One coordinate vector per image axis, in image axis order, m (any unit, used
        consistently); None: ``0, 1, ..., n - 1`` along each axis.

    Returns
    -------
    list of ndarray
        One float vector per axis, of that axis's length.

    Raises
    ------
    ValueError
        Not one vector per axis, a vector of the wrong length or not 1-D, or a non-finite one.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics.roi import axes_for
    >>> [a.tolist() for a in axes_for((2, 3), None)]
    [[0.0, 1.0], [0.0, 1.0, 2.0]]
    >>> axes_for((2, 3), [np.zeros(2)])
    Traceback (most recent call last):
    ...
    ValueError: need one coordinate vector per image axis: 1 given for shape (2, 3)
    """
    if axes is None:
        return [np.arange(n, dtype=float) for n in shape]
    if len(axes) != len(shape):
        raise ValueError(f"need one coordinate vector per image axis: {len(axes)} given for shape {shape}")
    out = []
    for k, (a, n) in enumerate(zip(axes, shape)):
        a = np.asarray(a, dtype=float)
        if a.ndim != 1 or a.size != n:
            raise ValueError(f"coordinate vector {k} has shape {a.shape}, image axis {k} has length {n}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"coordinate vector {k} is not finite")
        out.append(a)
    return out


def disc_mask(axes: Sequence[np.ndarray], diameter: float, center: Sequence[float] | None = None) -> np.ndarray:
    """Boolean disc (2-D) or ball (3-D) on a regular grid.

    Parameters
    ----------
    axes : sequence of 1-D arrays
        Coordinate vector of each image axis, in image axis order (e.g. ``(z, x)`` for a
        ``(n_z, n_x)`` image, ``(y, x)`` for an xy-MIP), m (any unit, used consistently).
    diameter : float
        Disc diameter, same unit as ``axes``; must be > 0.
    center : sequence of float, optional
        Centre, one coordinate per axis; default the middle of each axis
        (``(a[0] + a[-1]) / 2``).

    Returns
    -------
    ndarray of bool, shape ``(len(axes[0]), len(axes[1]), ...)``
        True where the pixel centre is within ``diameter / 2`` of ``center`` (boundary
        included).

    Raises
    ------
    ValueError
        Non-positive or non-finite diameter, a centre of the wrong length.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import disc_mask
    >>> x = np.arange(5) * 1e-4  # pixel centres, m
    >>> disc_mask((x, x), 3e-4).astype(int)  # diameter 0.3 mm around the centre
    array([[0, 0, 0, 0, 0],
           [0, 1, 1, 1, 0],
           [0, 1, 1, 1, 0],
           [0, 1, 1, 1, 0],
           [0, 0, 0, 0, 0]])
    """
    axes = [np.asarray(a, dtype=float) for a in axes]
    if not all(a.ndim == 1 and a.size > 0 for a in axes):
        raise ValueError("axes must be non-empty 1-D coordinate vectors")
    if not np.isfinite(diameter) or diameter <= 0:
        raise ValueError(f"diameter must be a positive finite number, got {diameter!r}")
    if center is None:
        center = [(a[0] + a[-1]) / 2 for a in axes]
    if len(center) != len(axes):
        raise ValueError(f"center has {len(center)} coordinates, the image has {len(axes)} axes")
    grids = np.meshgrid(*axes, indexing="ij")
    r2 = sum((g - c) ** 2 for g, c in zip(grids, center))
    radius = diameter / 2
    return r2 <= radius * radius * (1 + 1e-12)


def roi_mask(
    reference: np.ndarray,
    *,
    axes: Sequence[np.ndarray] | None = None,
    diameter: float | None = None,
    center: Sequence[float] | None = None,
    threshold: float | None = None,
) -> np.ndarray:
    """Region of interest: a disc intersected with the pixels above a threshold.

    Parameters
    ----------
    reference : ndarray, 2-D or 3-D
        The reference image (model standard), e.g. the full-data reconstruction's MIP.
    axes : sequence of 1-D arrays, optional
        Coordinate vectors of the image axes (see :func:`disc_mask`); default pixel indices.
    diameter : float, optional
        Disc diameter in the unit of ``axes``; None: no disc (the whole image).
    center : sequence of float, optional
        Disc centre; default the image centre.
    threshold : float, optional
        Keep pixels whose reference value is at least ``threshold * max(reference)``
        (paper §7: 0.04); must be in [0, 1]. None: no threshold.

    Returns
    -------
    ndarray of bool, the shape of ``reference``.

    Raises
    ------
    ValueError
        Non-finite reference, reference maximum <= 0 with a threshold, threshold outside
        [0, 1], bad axes or diameter.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §6 and §7 (pixels of interest: at least 4 % of the maximum).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import roi_mask
    >>> ref = np.outer(np.hanning(7), np.hanning(7))
    >>> int(roi_mask(ref, threshold=0.5).sum())  # the 3 x 3 pixels at >= half the peak
    9
    >>> int(roi_mask(ref, diameter=2.0, threshold=0.04).sum())  # and within 1 pixel of the centre
    5
    """
    reference = np.asarray(reference)
    if reference.ndim < 1 or reference.size == 0:
        raise ValueError("reference image is empty")
    if not np.all(np.isfinite(reference)):
        raise ValueError("reference image contains NaN or inf")
    mask = np.ones(reference.shape, dtype=bool)
    if diameter is not None:
        mask &= disc_mask(axes_for(reference.shape, axes), diameter, center)
    if threshold is not None:
        if not (0.0 <= threshold <= 1.0):
            raise ValueError(f"threshold is a fraction of the reference maximum in [0, 1], got {threshold!r}")
        peak = float(reference.max())
        if peak <= 0:
            raise ValueError("reference maximum is <= 0: a relative threshold is undefined")
        mask &= reference >= threshold * peak
    return mask


def bounding_box(mask: np.ndarray) -> tuple[slice, ...]:
    """The smallest axis-aligned rectangle (box) containing every True pixel of ``mask``.

    Parameters
    ----------
    mask : ndarray of bool, any shape (e.g. ``(n_z, n_x)``), with at least one True pixel.

    Returns
    -------
    tuple of slice, one per axis; ``image[bounding_box(mask)]`` is the rectangle.

    Raises
    ------
    ValueError
        If ``mask`` has no True pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import bounding_box
    >>> mask = np.zeros((4, 6), bool)
    >>> mask[1, 2] = mask[2, 4] = True
    >>> bounding_box(mask)
    (slice(1, 3, None), slice(2, 5, None))
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        raise ValueError("the region of interest is empty")
    out = []
    for axis in range(mask.ndim):
        other = tuple(a for a in range(mask.ndim) if a != axis)
        hit = np.flatnonzero(mask.any(axis=other) if other else mask)
        out.append(slice(int(hit[0]), int(hit[-1]) + 1))
    return tuple(out)
