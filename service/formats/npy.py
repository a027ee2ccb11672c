"""NumPy ``.npy``: a 2-D or 3-D array of A-lines, read without pickles (``allow_pickle=False``)
and given to the reconstruction time first, ``(n_t, n_x)`` / ``(n_t, n_y, n_x)``; ``dt`` and
``dx`` are required options (the file holds no spacings), ``dy`` defaults to ``dx``,
``sound_speed`` to 1500 m/s. → :class:`fpscan.service.recon.dataset.GridDataset`.

The file does not say which axis is time, and k-Wave's own order puts it last (``sensor_data``
is ``(n_sensors, n_t)``; reshaped, ``(n_y, n_x, n_t)``). The option ``axes`` says it
(``"y,x,t"``, ``"t,y,x"``, ``"x,t"``, ``"t,x"``, ``"sensor,time"``:
``fpscan.service.formats.load_options.axes_order``); without it, the rule of :func:`time_axes`:
time is the first axis unless the last axis is longer (then the array is refused, naming both
readings: time first or time last), with a ``UserWarning`` where the first axis is not clearly
the longest.
"""
from __future__ import annotations

import os
import warnings
from typing import Any, BinaryIO

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.service.formats.load_options import NpyOptions, axes_order
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import GridDataset, grid_array, positive

__all__ = ["FORMAT", "sniff", "time_axes", "load"]

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


def _layout(axes: str) -> str:
    """``"y,x,t"`` -> ``"(y, x, t)"``."""
    return f"({axes.replace(',', ', ')})"


def time_axes(shape: tuple[int, ...], axes: str | None = None) -> tuple[int, ...]:
    """The transposition that puts an array of ``shape`` time first, ``(t, x)`` / ``(t, y, x)``.

    With ``axes`` it is the declared order. Without, the rule (a misread image is worse than a
    refusal, so only a shape that shows its time axis is read): the candidates are fpscan's time
    first, ``(t, x)`` / ``(t, y, x)``, and k-Wave's time last, ``(x, t)`` (``sensor_data``,
    sensor and time) / ``(y, x, t)``; time is the longer of the first and the last axis (a
    record is longer than the scan is wide in samples: k-Wave's examples have 751 time samples
    on 96 × 96 sensors, 3519 on 1024).

    - the first axis longer than the last and than every other: time first;
    - the first axis longer than the last, but a middle axis longer still: time first, with a
      ``UserWarning`` (plausible, unusual);
    - the first and the last axis as long: time first, with a ``UserWarning`` (the shape does
      not tell: give ``axes`` to say and silence it);
    - the last axis longer than the first: refused (``ValueError``), naming both readings and
      how to say which.

    Parameters
    ----------
    shape : tuple of int
        The array's shape, 2 or 3 axes.
    axes : str or None, optional
        The declared order (``"y,x,t"``, ``"sensor,time"``, ...: any form
        ``fpscan.service.formats.load_options.axes_order`` takes); None: the rule above.

    Returns
    -------
    tuple of int
        The axes of the array in the order ``(t, x)`` / ``(t, y, x)`` (for ``np.transpose``).

    Raises
    ------
    ValueError
        ``axes`` naming a different number of axes than ``shape`` has, or not a valid order;
        an undeclared shape whose last axis is longer than its first.

    Warns
    -----
    UserWarning
        Read time first, undeclared, where the first axis is not clearly the longest.

    Examples
    --------
    >>> from fpscan.service.formats.npy import time_axes
    >>> time_axes((751, 96, 96)), time_axes((96, 96, 751), "y,x,t"), time_axes((128, 534), "sensor,time")
    ((0, 1, 2), (2, 0, 1), (1, 0))
    >>> time_axes((96, 96, 751))
    Traceback (most recent call last):
    ...
    ValueError: which axis of the (96, 96, 751) array is time? Its last axis (751) is longer than its first (96): it may be (y, x, t), time last (k-Wave's sensor order), or (t, y, x), time first (fpscan's): give the load option axes, e.g. axes="y,x,t" or axes="t,y,x" (fpscan recon --axes y,x,t; the upload's field axes)
    """
    shape = tuple(int(n) for n in shape)
    first, last = ("t,x", "x,t") if len(shape) == 2 else ("t,y,x", "y,x,t")
    if axes is not None:
        order = axes_order(axes)
        assert order is not None
        names = order.split(",")
        if len(names) != len(shape):
            raise ValueError(f"axes {order} names {len(names)} axes, the array has {len(shape)}: shape {shape}")
        return tuple(names.index(a) for a in first.split(","))
    say = (f"give the load option axes, e.g. axes=\"{last}\" or axes=\"{first}\" (fpscan recon --axes "
           f"{last}; the upload's field axes)")
    kwave = "k-Wave's sensor_data: sensor, time" if len(shape) == 2 else "k-Wave's sensor order"
    if shape[-1] > shape[0]:
        raise ValueError(f"which axis of the {shape} array is time? Its last axis ({shape[-1]}) is longer than its "
                         f"first ({shape[0]}): it may be {_layout(last)}, time last ({kwave}), or {_layout(first)}, "
                         f"time first (fpscan's): {say}")
    if shape[-1] == shape[0]:
        warnings.warn(f"the {shape} array is read time first, {_layout(first)}, though its last axis is as long "
                      f"(it may be {_layout(last)}, time last: {kwave}): {say}", UserWarning, stacklevel=2)
    elif max(shape) > shape[0]:
        warnings.warn(f"the {shape} array is read time first, {_layout(first)} with {shape[0]} time samples, though "
                      f"its axis 1 ({shape[1]}) is longer: {say}", UserWarning, stacklevel=2)
    return tuple(range(len(shape)))


def load(source: Source, *, dt: float | None = None, dx: float | None = None, dy: float | None = None,
         sound_speed: float | None = None, axes: str | None = None, **_: Any) -> GridDataset:
    """The array as grid data, time first (the rule of :func:`time_axes`).

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
    axes : str, optional
        The array's axis order (``"y,x,t"``, ``"t,y,x"``, ``"x,t"``, ``"t,x"``,
        ``"sensor,time"``); default None: :func:`time_axes`' rule.
    **_
        Other loading options, ignored.

    Returns
    -------
    GridDataset
        ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` data (float32, float64 for wider types),
        ``source`` ``"npy"``.

    Raises
    ------
    ValueError
        Not an array, a pickle, a header declaring more than the file holds, what
        ``grid_array`` refuses, an ``axes`` that does not fit the array, an undeclared array
        whose time axis the shape does not show (:func:`time_axes`), missing or non-positive
        spacings.

    Warns
    -----
    UserWarning
        An undeclared array read time first whose first axis is not clearly the longest.
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
    order = time_axes(data.shape, axes)
    if order != tuple(range(data.ndim)):
        data = np.ascontiguousarray(data.transpose(order))
    if dt is None or dx is None:
        raise ValueError("a .npy array needs dt (s) and dx (m)")
    return GridDataset(data=data, dx=positive("dx", dx), dt=positive("dt", dt),
                       sound_speed=positive("sound_speed", sound_speed if sound_speed is not None else C_DEFAULT),
                       dy=positive("dy", dy) if (dy is not None and data.ndim == 3) else
                       (positive("dx", dx) if data.ndim == 3 else None),
                       source="npy")


FORMAT = Format(rank=10, name="npy", title="NumPy array (n_t, n_y, n_x) or (n_t, n_x); another order with axes",
                container="file", sniff=sniff, load=load, input=True, upload=True, order=10,
                noun="a NumPy .npy array", options=NpyOptions)
