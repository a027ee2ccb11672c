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
    """
    return (np.arange(int(n)) - (int(n) - 1) / 2.0) * float(d)


def centred_positions(indices, n: int, d: float) -> np.ndarray:
    """Coordinates (m) of lattice indices ``indices`` (any shape, integers) on a centred
    axis of ``n`` points at spacing ``d``: ``(i - (n - 1)/2)·d``, the same numbers as
    ``centred_axis(n, d)[indices]``."""
    return (np.asarray(indices) - (int(n) - 1) / 2.0) * float(d)


def centred_index(x, n: int, d: float) -> np.ndarray:
    """The fractional index ``x/d + (n - 1)/2`` of coordinates ``x`` (m, any shape) on a
    centred axis of ``n`` points at spacing ``d`` (m): the inverse of
    :func:`centred_positions`, used where sensor positions meet a grid (NUFFT angles
    ``2π·index/n``)."""
    return np.asarray(x) / float(d) + (int(n) - 1) / 2.0
