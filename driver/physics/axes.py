"""Regular lateral axes centred on the optical axis (docs/architecture.md convention):
the one implementation of ``x_i = (i - (n - 1)/2)·d`` that the scanner lattice, the
plans, the datasets and the reconstructions share. Pure numpy."""
from __future__ import annotations

import numpy as np

__all__ = ["centred_axis", "centred_positions", "centred_index"]


def centred_axis(n: int, d: float) -> np.ndarray:
    """Coordinates ``x_i = (i - (n - 1)/2)·d`` for ``i = 0..n-1``.

    Parameters
    ----------
    n : number of points (>= 0).
    d : spacing in m.

    Returns
    -------
    ndarray ``(n,)`` float64, m, symmetric about 0.

    Examples
    --------
    >>> from driver.physics.axes import centred_axis
    >>> centred_axis(4, 1e-4) * 1e6  # µm
    array([-150.,  -50.,   50.,  150.])
    """
    return (np.arange(int(n)) - (int(n) - 1) / 2.0) * float(d)


def centred_positions(indices, n: int, d: float) -> np.ndarray:
    """Coordinates of lattice indices on a centred axis: ``(i - (n - 1)/2)·d``, the same
    numbers as ``centred_axis(n, d)[indices]``.

    Parameters
    ----------
    indices : int or ndarray of int, any shape; lattice indices ``i`` (0 .. n-1).
    n : number of points of the axis.
    d : spacing in m.

    Returns
    -------
    ndarray, the shape of ``indices``, float64 in m.

    Examples
    --------
    >>> from driver.physics.axes import centred_positions
    >>> centred_positions([0, 3], 4, 1e-4) * 1e6  # µm
    array([-150.,  150.])
    """
    return (np.asarray(indices) - (int(n) - 1) / 2.0) * float(d)


def centred_index(x, n: int, d: float) -> np.ndarray:
    """The fractional index ``x/d + (n - 1)/2`` of coordinates on a centred axis: the
    inverse of :func:`centred_positions`, used where sensor positions meet a grid (NUFFT
    angles ``2π·index/n``).

    Parameters
    ----------
    x : float or ndarray, any shape; coordinates in m.
    n : number of points of the axis.
    d : spacing in m.

    Returns
    -------
    ndarray, the shape of ``x``, float64 (dimensionless index; integers at grid points).

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.axes import centred_index
    >>> centred_index(np.array([-1.5e-4, 0.0, 1.5e-4]), 4, 1e-4).round(12)
    array([0. , 1.5, 3. ])
    """
    return np.asarray(x) / float(d) + (int(n) - 1) / 2.0
