"""Maximum-intensity projections (MIPs) of a reconstructed volume.

Volumes are ``(n_z, n_y, n_x)`` (DESIGN §3): the xy-MIP projects along z (axis 0),
the xz-MIP along y (axis 1), the yz-MIP along x (axis 2).
"""
from __future__ import annotations

import numpy as np

#: MIP name -> the axis of a ``(n_z, n_y, n_x)`` volume it projects along.
MIP_AXES = {"xy": 0, "xz": 1, "yz": 2}


def mip(volume: np.ndarray, plane: str = "xy", *, absolute: bool = False) -> np.ndarray:
    """Maximum-intensity projection of a volume onto one plane.

    Parameters
    ----------
    volume : ndarray, shape ``(n_z, n_y, n_x)``.
    plane : {"xy", "xz", "yz"}
        ``"xy"`` -> shape ``(n_y, n_x)`` (max over z); ``"xz"`` -> ``(n_z, n_x)`` (max over
        y); ``"yz"`` -> ``(n_z, n_y)`` (max over x).
    absolute : bool
        Project ``|volume|`` instead of the signed values.

    Raises
    ------
    ValueError
        Not 3-D, empty, an unknown plane, or NaN in the volume.
    """
    volume = np.asarray(volume)
    if volume.ndim != 3 or volume.size == 0:
        raise ValueError(f"a MIP needs a non-empty (n_z, n_y, n_x) volume, got shape {volume.shape}")
    if plane not in MIP_AXES:
        raise ValueError(f"unknown MIP plane {plane!r}; choose one of {sorted(MIP_AXES)}")
    if np.isnan(volume).any():
        raise ValueError("volume contains NaN")
    v = np.abs(volume) if absolute else volume
    return v.max(axis=MIP_AXES[plane])


def mips(volume: np.ndarray, *, absolute: bool = False) -> dict[str, np.ndarray]:
    """All three MIPs: ``{"xy": (n_y, n_x), "xz": (n_z, n_x), "yz": (n_z, n_y)}``.

    Raises ValueError as :func:`mip`.
    """
    return {plane: mip(volume, plane, absolute=absolute) for plane in MIP_AXES}
