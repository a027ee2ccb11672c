"""k-Wave HDF5: an HDF5 array in k-Wave layout, time first — ``(n_t, n_y, n_x)`` (k-Wave
``'tyz'``) or ``(n_t, n_x)`` (``'ty'``) — at ``key`` (default ``sensor_data/clean``, then
``sensor_data``, then the file's only 2-/3-D dataset) → :class:`GridDataset`.

Spacings: options first, then file attributes. k-Wave files (a ``kwave_DataOrder``
attribute on the array or ``kwave_commit`` on the file, as in ``shared/data``) name the
depth axis x, so their lateral spacings are ``dy_m`` (our y, or our x in 2-D) and ``dz_m``
(our x); other files use ``dx_m``/``dy_m`` for our x/y (the rule's one owner:
:mod:`fpscan.driver.kwave_layout`, shared with the simulator's replay). ``dt_s`` and
``c_m_per_s`` give dt and c. The catch-all of HDF5 files: sniffed last.

Lateral coordinates (``GridDataset.lateral_shift``): where the file gives its sensor
coordinates (1-D datasets ``sensor_z_m``/``sensor_y_m`` in a k-Wave file, ``sensor_x_m``/
``sensor_y_m`` in others: :func:`fpscan.driver.kwave_layout.sensor_coordinate_names`) they are
the grid (unless that axis's spacing is given as an option: it wins); otherwise a k-Wave file follows ``kWaveGrid``'s ``(i - floor(N/2))·dx``, any other
the centred ``(i - (N - 1)/2)·dx``.
"""
from __future__ import annotations

from typing import Any

import h5py
import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.driver import kwave_layout
from fpscan.service.formats.load_options import KwaveOptions
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import MAX_ELEMENTS, GridDataset, grid_array, lateral_shift_of, positive

__all__ = ["FORMAT", "sniff", "load", "find_array"]

DEFAULT_KEYS = ("sensor_data/clean", "sensor_data")


def sniff(source: Source) -> bool:
    """Any HDF5 file (the catch-all: the other HDF5 formats are sniffed first).

    Parameters
    ----------
    source : Source
        The opened HDF5 file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.h5 is not None


def find_array(f: h5py.File, key: str | None = None) -> h5py.Dataset:
    """The dataset holding the data: ``key``, else ``sensor_data/clean``, ``sensor_data``, else
    the file's only 2-/3-D dataset.

    Parameters
    ----------
    f : h5py.File
        The open file.
    key : str, optional
        The dataset's path in the file.

    Returns
    -------
    h5py.Dataset
        The dataset (not read).

    Raises
    ------
    ValueError
        Naming what is missing: no dataset ``key``, or no default key and not exactly one 2-/3-D
        dataset.
    """
    if key is not None:
        if key not in f or not isinstance(f[key], h5py.Dataset):
            raise ValueError(f"no dataset {key!r} in the HDF5 file")
        return f[key]
    for k in DEFAULT_KEYS:
        if k in f and isinstance(f[k], h5py.Dataset):
            return f[k]
    found: list[h5py.Dataset] = []
    f.visititems(lambda n, o: found.append(o) if isinstance(o, h5py.Dataset) and o.ndim in (2, 3) else None)
    if len(found) != 1:
        raise ValueError(f"no 'sensor_data/clean' or 'sensor_data' dataset, and cannot tell "
                         f"which dataset holds the data ({len(found)} 2-/3-D datasets); give key")
    return found[0]


def _ground_truth(f: h5py.File, data: np.ndarray, dx: float) -> dict:
    """The reference files' ground truth: ``{"p0": (n_z, [n_y,] n_x) float64, "p0_dz": m}``
    from a ``p0`` dataset matching ``data``'s lateral shape (depth spacing: its
    ``spacing_m`` attribute, else ``dx``); ``{}`` when there is none that matches."""
    ds = f.get("p0")
    if not isinstance(ds, h5py.Dataset) or ds.ndim != data.ndim or ds.shape[1:] != data.shape[1:]:
        return {}
    spacing = ds.attrs.get("spacing_m")
    return {"p0": np.asarray(ds[...], dtype=np.float64),
            "p0_dz": float(np.asarray(spacing).ravel()[0]) if spacing is not None else dx}


def load(source: Source, *, key: str | None = None, dt: float | None = None, dx: float | None = None,
         dy: float | None = None, sound_speed: float | None = None, ground_truth: bool = False,
         **_: Any) -> GridDataset:
    """The array at ``key`` as grid data (module docstring).

    Parameters
    ----------
    source : Source
        The opened HDF5 file.
    key : str, optional
        The dataset holding the data (:func:`find_array`).
    dt : float, optional
        Sample interval, s (default the file's ``dt_s``).
    dx, dy : float, optional
        Lateral pitches, m (default the file's attributes; ``dy`` defaults to ``dx``; 3-D only).
    sound_speed : float, optional
        Sound speed, m/s (default the file's ``c_m_per_s``, else 1500).
    ground_truth : bool, optional
        Also the file's ``p0`` (the k-Wave reference files' initial pressure) in ``meta["p0"]``
        with its depth spacing ``meta["p0_dz"]`` (m), when it matches the data's lateral shape.
    **_
        Other loading options, ignored.

    Returns
    -------
    GridDataset
        ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` data, ``source`` ``"kwave-hdf5"``, ``meta`` with
        ``key`` and ``kwave_naming``.

    Raises
    ------
    ValueError
        A MATLAB v7.3 MAT-file, no such dataset, too large, what ``grid_array`` refuses,
        spacings neither given nor in the file.
    """
    if source.head.startswith(b"MATLAB"):  # HDF5 behind MATLAB's header: arrays stored transposed
        raise ValueError("this is a MATLAB v7.3 MAT-file (HDF5 with MATLAB's transposed layout): read it with "
                         "format kwave-mat")
    f = source.h5
    ds = find_array(f, key)
    if ds.size > MAX_ELEMENTS:
        raise ValueError(f"array too large ({ds.size} elements)")
    data = grid_array(ds[()])
    fa, da, name = dict(f.attrs), dict(ds.attrs), ds.name

    def get(attr: str) -> Any:
        return kwave_layout.attribute(da, fa, attr)

    kwave = kwave_layout.is_kwave_named(da, fa)
    lat_x, lat_y = kwave_layout.lateral_spacings(da, fa, data.ndim)
    given = (dx is not None, dy is not None)  # a spacing given explicitly wins over the file's coordinates
    dt = dt if dt is not None else get("dt_s")
    dx = dx if dx is not None else lat_x
    if dt is None:
        raise ValueError("dt is neither given nor in the file (attribute dt_s)")
    if dx is None:
        raise ValueError("the lateral spacing is neither given (dx) nor in the file")
    dx = positive("dx", dx)
    if data.ndim == 3:
        dy = positive("dy", dy if dy is not None else (lat_y if lat_y is not None else dx))
    else:
        dy = None
    sound_speed = sound_speed if sound_speed is not None else get("c_m_per_s")
    meta = {"key": name, "kwave_naming": kwave, **(_ground_truth(f, data, dx) if ground_truth else {})}
    spacings = (dx,) if dy is None else (dx, dy)
    coords = tuple(None if g else v for g, v in zip(given, _coordinates(f, kwave, data.ndim), strict=False))
    shift = lateral_shift_of(data.shape, spacings, coords, kwave_grid=kwave)
    return GridDataset(data=data, dx=dx, dy=dy, dt=positive("dt", dt),
                       sound_speed=positive("sound_speed", sound_speed if sound_speed is not None else C_DEFAULT),
                       source="kwave-hdf5", meta=meta,
                       lateral_shift=shift)


def _coordinates(f: h5py.File, kwave: bool, ndim: int) -> tuple[np.ndarray | None, ...]:
    """The file's sensor coordinates ``(x,)`` / ``(x, y)`` (m; None where it gives none):
    the 1-D datasets :func:`fpscan.driver.kwave_layout.sensor_coordinate_names` names."""
    out: list[np.ndarray | None] = []
    for n in kwave_layout.sensor_coordinate_names(kwave, ndim):
        obj = f.get(n) if n else None
        if isinstance(obj, h5py.Dataset) and obj.ndim == 1 and obj.size <= 1 << 20:
            out.append(np.asarray(obj[()], dtype=np.float64))
        else:
            out.append(None)
    return tuple(out)


FORMAT = Format(rank=20, name="kwave-hdf5", title="HDF5, k-Wave layout", container="hdf5", sniff=sniff, load=load,
                input=True, upload=True, order=90, noun="an HDF5 array in k-Wave layout", options=KwaveOptions)
