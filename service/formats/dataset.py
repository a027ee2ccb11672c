"""The canonical dataset file (format ``fpscan-dataset/1``), in which the server keeps
every upload: it stores a :class:`GridDataset` or a :class:`PointDataset` exactly (dtype
included), so a reconstruction of it equals one of the original file. Written by
:func:`write` (``fpscan.service.storage.loader.import_dataset``), read by :func:`load`.
"""
from __future__ import annotations

import os
from typing import Any

import h5py
import numpy as np

from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import GridDataset, PointDataset, p0_unit

__all__ = ["FORMAT", "DATASET_FORMAT", "sniff", "load", "write"]

DATASET_FORMAT = "fpscan-dataset/1"
#: the speed of sound's attribute (m/s), as a person reads it (:mod:`fpscan.service.names`); files
#: written before it say ``c``, still read
_SPEED = "sound_speed"


def sniff(source: Source) -> bool:
    """True for an HDF5 file with ``format`` ``fpscan-dataset/1`` (or, as earlier versions wrote,
    a ``layout`` attribute ``grid`` or ``points``).

    Parameters
    ----------
    source : Source
        The opened file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.attr("format") == DATASET_FORMAT or source.attr("layout") in ("grid", "points")


def write(path: str | os.PathLike, ds: GridDataset | PointDataset) -> None:
    """Write the canonical dataset file (format ``fpscan-dataset/1``), exactly (dtype kept).

    Layout ``grid``: ``/data`` ``(n_t, n_y, n_x)``/``(n_t, n_x)``; attributes ``dt`` (s),
    ``dx``, ``dy`` (3-D; m), ``sound_speed`` (m/s), ``t0`` (s). Layout ``points``: ``/alines``
    ``(n, n_t)``, ``/positions`` ``(n, d)`` m, ``/weights`` ``(n,)`` (if any), ``/grid_x``,
    ``/grid_y`` (3-D) m; attributes ``dt``, ``sound_speed``, ``t0``; a lattice adds ``/lattice``
    ``(n, 2)`` indices (i_x, i_y) and attributes ``lattice_shape`` ``(n_y, n_x)``, ``pitch``.
    Both: attribute ``format``, ``layout``, ``source``; ``wavelengths_m`` when known, and
    ``wavelength_index`` (into the source file's wavelengths) when it was chosen from a
    multi-wavelength file; ``p0_unit`` (``"Pa"`` for calibrated pressure, else ``"a.u."``:
    :func:`fpscan.service.recon.dataset.p0_unit`); ``lateral_shift_m`` (m) when the data carry one
    (:class:`fpscan.service.recon.dataset.GridDataset`'s ``lateral_shift``).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced if it exists).
    ds : GridDataset or PointDataset
        The dataset.

    Raises
    ------
    OSError
        The file cannot be written.
    """
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": DATASET_FORMAT, "layout": ds.kind, "dt": float(ds.dt), _SPEED: float(ds.sound_speed),
                        "t0": float(ds.t0), "source": ds.source})
        if ds.wavelengths is not None:
            f.attrs["wavelengths_m"] = np.asarray(ds.wavelengths, dtype=np.float64)
        if (ds.meta or {}).get("wavelength_index") is not None:
            f.attrs["wavelength_index"] = int(ds.meta["wavelength_index"])
        f.attrs["p0_unit"] = p0_unit(ds)
        if ds.lateral_shift is not None:
            f.attrs["lateral_shift_m"] = np.asarray(ds.lateral_shift, dtype=np.float64)
        if isinstance(ds, GridDataset):
            f.create_dataset("data", data=ds.data)
            f.attrs["dx"] = float(ds.dx)
            if ds.dy is not None and ds.data.ndim == 3:
                f.attrs["dy"] = float(ds.dy)
            return
        f.create_dataset("alines", data=np.asarray(ds.alines))
        f.create_dataset("positions", data=np.asarray(ds.positions, dtype=np.float64))
        if ds.weights is not None:
            f.create_dataset("weights", data=np.asarray(ds.weights, dtype=np.float64))
        f.create_dataset("grid_x", data=np.asarray(ds.grid[0], dtype=np.float64))
        if len(ds.grid) > 1:
            f.create_dataset("grid_y", data=np.asarray(ds.grid[1], dtype=np.float64))
        if ds.lattice is not None and ds.indices is not None:
            f.create_dataset("lattice", data=np.asarray(ds.indices, dtype=np.int64))
            f.attrs["lattice_shape"] = (int(ds.lattice.get("n_y", 1)), int(ds.lattice["n_x"]))
            f.attrs["pitch"] = float(ds.lattice["pitch"])


def _read(d: h5py.Dataset) -> np.ndarray:
    """The whole of ``d``, read into memory of the work-array pool (`fpscan.physics.workspace`:
    a job worker's next input of the same size lands in pages already mapped, where a fresh
    array's pages were faulted in one by one as HDF5 copied into them); a small or non-native
    one as h5py reads it."""
    from fpscan.physics import workspace

    if d.dtype.kind not in "fiu" or not d.dtype.isnative or d.shape is None or d.size * d.dtype.itemsize < workspace.MIN_BYTES:
        return d[()]
    out = workspace.take(d.shape, d.dtype)
    d.read_direct(out)
    return out


def load(source: Source, **_: Any) -> GridDataset | PointDataset:
    """Read a canonical dataset file (:func:`write`).

    Also the layout without the ``format`` attribute, and the speed of sound as ``c`` rather
    than ``sound_speed``, that earlier versions wrote.

    Parameters
    ----------
    source : Source
        The opened HDF5 file.
    **_
        Other loading options, ignored.

    Returns
    -------
    GridDataset or PointDataset
        The dataset as written (dtype kept).

    Raises
    ------
    ValueError
        A file that is not one (missing attributes or datasets, an unknown layout).
    """
    def text(v: Any) -> str:
        return v.decode() if isinstance(v, bytes) else str(v)

    f = source.h5
    try:
        layout = text(f.attrs["layout"])
        dt, t0 = float(f.attrs["dt"]), float(f.attrs.get("t0", 0.0))
        c = float(f.attrs[_SPEED] if _SPEED in f.attrs else f.attrs["c"])  # "c": an older fpscan's name
        wl = f.attrs.get("wavelengths_m")
        wavelengths = tuple(float(w) for w in np.ravel(wl)) if wl is not None and np.size(wl) else None
        origin = text(f.attrs.get("source", "dataset"))
        meta: dict[str, Any] = ({"wavelength_index": int(f.attrs["wavelength_index"])}
                                if "wavelength_index" in f.attrs else {})
        if text(f.attrs.get("p0_unit", "a.u.")) == "Pa":
            meta["p0_unit"] = "Pa"
        ls = f.attrs.get("lateral_shift_m")
        shift = tuple(float(v) for v in np.ravel(ls)) if ls is not None and np.size(ls) else None
        if layout == "grid":
            data = _read(f["data"])
            dy = float(f.attrs["dy"]) if "dy" in f.attrs and data.ndim == 3 else None
            return GridDataset(data=data, dx=float(f.attrs["dx"]), dt=dt, sound_speed=c, dy=dy, t0=t0,
                               source=origin, wavelengths=wavelengths, meta=meta, lateral_shift=shift)
        if layout != "points":
            raise ValueError(f"unknown dataset layout {layout!r}")
        gx = f["grid_x"][()]
        grid = (gx, f["grid_y"][()]) if "grid_y" in f else (gx,)
        indices = lattice = None
        if "lattice" in f:
            n_y, n_x = (int(v) for v in f.attrs["lattice_shape"])
            lattice = {"n_x": n_x, "n_y": n_y, "pitch": float(f.attrs["pitch"])}
            indices = f["lattice"][()].astype(np.int64).reshape(-1, 2)
        return PointDataset(alines=f["alines"][()], positions=f["positions"][()],
                            weights=f["weights"][()] if "weights" in f else None, dt=dt, sound_speed=c,
                            grid=grid, t0=t0, source=origin, indices=indices, lattice=lattice,
                            wavelengths=wavelengths, meta=meta, lateral_shift=shift)
    except (KeyError, TypeError) as exc:
        raise ValueError(f"not a canonical dataset file ({exc})") from None


FORMAT = Format(rank=60, name="dataset", title="fpscan dataset (the server's stored upload)", container="hdf5",
                sniff=sniff, load=load, write=write, input=True, order=20, noun="an fpscan dataset file")
