"""Regular lateral axes centred on the optical axis (docs/architecture.md convention):
the one implementation of ``x_i = (i - (n - 1)/2)·d`` that the scanner lattice, the
plans, the datasets and the reconstructions share. Pure numpy."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ["centred_axis", "centred_positions", "centred_index", "node_indices"]


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
    >>> from fpscan.physics.axes import centred_axis
    >>> centred_axis(4, 1e-4) * 1e6  # µm
    array([-150.,  -50.,   50.,  150.])
    """
    return (np.arange(int(n)) - (int(n) - 1) / 2.0) * float(d)


def centred_positions(indices: npt.ArrayLike, n: int, d: float) -> np.ndarray:
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
    >>> from fpscan.physics.axes import centred_positions
    >>> centred_positions([0, 3], 4, 1e-4) * 1e6  # µm
    array([-150.,  150.])
    """
    return (np.asarray(indices) - (int(n) - 1) / 2.0) * float(d)


def centred_index(x: npt.ArrayLike, n: int, d: float) -> np.ndarray:
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
    >>> from fpscan.physics.axes import centred_index
    >>> centred_index(np.array([-1.5e-4, 0.0, 1.5e-4]), 4, 1e-4).round(12)
    array([0. , 1.5, 3. ])
    """
    return np.asarray(x) / float(d) + (int(n) - 1) / 2.0


def node_indices(positions: npt.ArrayLike, axes: Sequence[np.ndarray], steps: Sequence[float]
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """The node of a regular grid each sensor sits on, if every one sits on a node.

    Parameters
    ----------
    positions : ndarray ``(n_points, d)``, d = 1 (x) or 2 (x, y); m.
    axes : sequence of d ndarrays, the grid's x (and y) coordinates, m, regular and increasing.
    steps : sequence of d floats, their spacings, m.

    Returns
    -------
    (i_x, i_y) : two ndarrays ``(n_points,)`` int64 (i_y zeros for d = 1), or None when a
    position is more than 1e-6 of a pitch off a node or outside the axes.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.axes import centred_axis, node_indices
    >>> x = centred_axis(4, 1e-4)
    >>> node_indices(np.array([[-1.5e-4], [1.5e-4]]), (x,), (1e-4,))
    (array([0, 3]), array([0, 0]))
    >>> node_indices(np.array([[0.0]]), (x,), (1e-4,)) is None  # between two nodes
    True
    """
    pos = np.asarray(positions, dtype=np.float64)
    idx = []
    for a in range(pos.shape[1]):
        f = (pos[:, a] - axes[a][0]) / steps[a]
        i = np.rint(f)
        if np.any(np.abs(f - i) > 1e-6) or i.min() < 0 or i.max() > len(axes[a]) - 1:
            return None
        idx.append(i.astype(np.int64))
    if len(idx) == 1:
        idx.append(np.zeros_like(idx[0]))
    return idx[0], idx[1]
