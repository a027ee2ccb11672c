"""Maximum-intensity projections (MIPs) of a reconstructed volume: the one ``mip`` of
fpscan (the pictures of ``fpscan.service.pictures.render`` draw it too).

Volumes are ``(n_z, n_y, n_x)`` (docs/file-formats.md, "Orientation"): the xy-MIP projects
along z (axis 0), the xz-MIP along y (axis 1), the yz-MIP along x (axis 2). A 2-D image
``(n_z, n_x)`` has only the xz plane: the image itself.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MIP_AXES", "mip", "mips"]

#: MIP name -> the axis of a ``(n_z, n_y, n_x)`` volume it projects along.
MIP_AXES = {"xy": 0, "xz": 1, "yz": 2}


def mip(volume: np.ndarray, plane: str = "xy", *, absolute: bool = False) -> np.ndarray:
    """Maximum-intensity projection of a volume onto one plane.

    Parameters
    ----------
    volume : ndarray, shape ``(n_z, n_y, n_x)``, or a 2-D image ``(n_z, n_x)`` (plane
        ``"xz"`` only: returned as it is).
    plane : {"xy", "xz", "yz"}
        ``"xy"`` -> shape ``(n_y, n_x)`` (max over z); ``"xz"`` -> ``(n_z, n_x)`` (max over
        y); ``"yz"`` -> ``(n_z, n_y)`` (max over x).
    absolute : bool
        Project ``|volume|`` instead of the signed values.

    Returns
    -------
    ndarray, 2-D, the dtype and unit of ``volume`` (shapes above).

    Raises
    ------
    ValueError
        Not 2-D/3-D, empty, an unknown plane (or not ``"xz"`` for a 2-D image), or NaN in
        the volume.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import mip
    >>> volume = np.arange(24.0).reshape(2, 3, 4)  # (n_z, n_y, n_x)
    >>> mip(volume, "xy")  # max over z
    array([[12., 13., 14., 15.],
           [16., 17., 18., 19.],
           [20., 21., 22., 23.]])
    >>> mip(volume, "yz").shape  # (n_z, n_y)
    (2, 3)
    """
    volume = np.asarray(volume)
    if plane not in MIP_AXES:
        raise ValueError(f"unknown MIP plane {plane!r}; choose one of {sorted(MIP_AXES)}")
    if volume.ndim not in (2, 3) or volume.size == 0:
        raise ValueError(f"a MIP needs a non-empty (n_z, n_y, n_x) volume, got shape {volume.shape}")
    if volume.ndim == 2 and plane != "xz":
        raise ValueError(f"a 2-D volume (n_z, n_x) has only the xz plane, not {plane!r}")
    v = np.abs(volume) if absolute else volume
    out = v if v.ndim == 2 else v.max(axis=MIP_AXES[plane])
    # the maximum propagates NaN: every sample lies on one ray, so a NaN anywhere shows here
    # (one pass over the volume instead of two)
    if np.isnan(out).any():
        raise ValueError("volume contains NaN")
    return out


def mips(volume: np.ndarray, *, absolute: bool = False) -> dict[str, np.ndarray]:
    """All three MIPs: ``{"xy": (n_y, n_x), "xz": (n_z, n_x), "yz": (n_z, n_y)}``.

    Parameters
    ----------
    volume : ndarray, shape ``(n_z, n_y, n_x)``.
    absolute : bool
        Project ``|volume|`` instead of the signed values.

    Returns
    -------
    dict of str to ndarray
        Plane name -> its MIP (:func:`mip`).

    Raises
    ------
    ValueError
        As :func:`mip` (a 2-D image has only the xz plane: use ``mip(image, "xz")``).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.metrics import mips
    >>> {plane: m.shape for plane, m in mips(np.zeros((2, 3, 4))).items()}
    {'xy': (3, 4), 'xz': (2, 4), 'yz': (2, 3)}
    """
    return {plane: mip(volume, plane, absolute=absolute) for plane in MIP_AXES}
