"""NumPy ``.npy``: an array in k-Wave layout, time first — ``(n_t, n_y, n_x)`` or
``(n_t, n_x)`` — read without pickles (``allow_pickle=False``); ``dt`` and ``dx`` are
required options (the file holds no spacings), ``dy`` defaults to ``dx``, ``sound_speed`` to
1500 m/s. → :class:`fpscan.service.recon.dataset.GridDataset`.
"""
from __future__ import annotations

import os
from typing import Any, BinaryIO

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.service.formats.load_options import GridSpacing
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import GridDataset, grid_array, positive

__all__ = ["FORMAT", "sniff", "load"]

MAGIC = b"\x93NUMPY"


def sniff(source: Source) -> bool:
    """True for a file with the ``.npy`` magic.

    Parameters
    ----------
    source : Source
        The opened file.

    Returns
    -------
    bool
        Whether it starts with :data:`MAGIC`.
    """
    return source.head.startswith(MAGIC)


def _header(fh: BinaryIO) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from the header of the open ``.npy`` file ``fh``, which must hold
    the bytes it declares (an absurd shape is refused before anything is allocated).
    Leaves ``fh`` at 0."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fh)
        read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, _fortran, dtype = read(fh)
    except (ValueError, OSError, EOFError, SyntaxError):
        raise ValueError("file is not a NumPy .npy array (pickles are refused)") from None
    if dtype.hasobject:
        raise ValueError("file is not a NumPy .npy array (pickles are refused)")
    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
    size = os.fstat(fh.fileno()).st_size - fh.tell()
    fh.seek(0)
    if declared > size:
        raise ValueError(f"the .npy header declares {tuple(shape)} {dtype} ({declared} bytes), more than the "
                         f"file holds ({size} bytes)")
    return tuple(shape), dtype


def load(source: Source, *, dt: float | None = None, dx: float | None = None, dy: float | None = None,
         sound_speed: float | None = None, **_: Any) -> GridDataset:
    """The array as grid data, time first.

    Parameters
    ----------
    source : Source
        The opened file (``source.fh``).
    dt : float
        Sample interval, s (required).
    dx : float
        Lateral pitch, m (required).
    dy : float, optional
        The y pitch, m (3-D data; default ``dx``).
    sound_speed : float, optional
        Sound speed, m/s (default 1500).
    **_
        Other loading options, ignored.

    Returns
    -------
    GridDataset
        ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` data in the file's dtype, ``source`` ``"npy"``.

    Raises
    ------
    ValueError
        Not an array, a pickle, a header declaring more than the file holds, what
        ``grid_array`` refuses, missing or non-positive spacings.
    """
    if source.fh is None:
        raise ValueError("file is not a NumPy .npy array (pickles are refused)")
    _header(source.fh)
    try:
        a = np.load(source.fh, allow_pickle=False)
    except (ValueError, OSError, EOFError):
        raise ValueError("file is not a NumPy .npy array (pickles are refused)") from None
    if not isinstance(a, np.ndarray):
        raise ValueError("file is not a single NumPy array")
    data = grid_array(a)
    if dt is None or dx is None:
        raise ValueError("a .npy array needs dt (s) and dx (m)")
    return GridDataset(data=data, dx=positive("dx", dx), dt=positive("dt", dt),
                       sound_speed=positive("sound_speed", sound_speed if sound_speed is not None else C_DEFAULT),
                       dy=positive("dy", dy) if (dy is not None and data.ndim == 3) else
                       (positive("dx", dx) if data.ndim == 3 else None),
                       source="npy")


FORMAT = Format(rank=10, name="npy", title="NumPy array, k-Wave layout (n_t, n_y, n_x) or (n_t, n_x)",
                container="file", sniff=sniff, load=load, input=True, upload=True, order=10,
                noun="a NumPy .npy array", options=GridSpacing)
