"""IPASC HDF5 (International Photoacoustic Standardisation Consortium; the reader and the
exporter of scan files: :mod:`service.storage.ipasc`) → :class:`PointDataset`. May hold
several excitation wavelengths (``wavelength_index`` chooses one; default the first).
Written by ``service.storage.ipasc.export_scan`` (from a scan file).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from service.formats._registry import Format, Source
from service.recon.dataset import PointDataset, check_wavelength_index
from service.storage.ipasc import export_scan, read_open_ipasc

__all__ = ["FORMAT", "sniff", "load"]


def sniff(source: Source) -> bool:
    """True for an HDF5 file with IPASC's ``/binary_time_series_data``."""
    return "binary_time_series_data" in source.h5


def _wavelengths(f: Any) -> np.ndarray:
    """The file's ``meta_data/acquisition_wavelengths`` (m), empty when absent (no data read)."""
    ds = f.get("meta_data/acquisition_wavelengths")
    try:
        return np.ravel(np.asarray(ds[()], dtype=np.float64)) if ds is not None else np.zeros(0)
    except (TypeError, ValueError):
        return np.zeros(0)


def load(source: Source, *, wavelength_index: int = 0, all_wavelengths: bool = False,
         **_: Any) -> PointDataset | list[PointDataset]:
    """The file as point data (``read_open_ipasc``) at excitation wavelength
    ``wavelength_index`` (``wavelengths``: that one, ``meta["wavelengths"]`` all the
    file's); ``all_wavelengths``: a list, one dataset per wavelength the file records,
    read from the one open file. Raises ValueError, also for an index out of range
    (naming the file's wavelengths)."""
    if all_wavelengths:
        return [_dataset(source, k) for k in range(max(1, _wavelengths(source.h5).size))]
    return _dataset(source, wavelength_index)


def _dataset(source: Source, wavelength_index: int) -> PointDataset:
    """The dataset of one wavelength of the open IPASC file."""
    if wavelength_index:
        check_wavelength_index(wavelength_index, _wavelengths(source.h5), "file")
    r = read_open_ipasc(source.h5, wavelength_index=wavelength_index)
    plan, indices = r["plan"], r["indices"]
    lattice = None
    if isinstance(plan, dict) and isinstance(plan.get("lattice"), dict) and indices is not None:
        lat = plan["lattice"]
        lattice = {"n_x": int(lat["n_x"]), "n_y": int(lat.get("n_y", 1)), "pitch": float(lat["pitch"])}
        indices = np.asarray(indices, dtype=np.int64).reshape(-1, 2)
    wl = r["wavelengths"]
    return PointDataset(alines=r["alines"], positions=r["positions"], weights=r["weights"],
                        dt=r["dt"], c=r["c"], grid=r["grid"], source="ipasc",
                        meta={"uuid": r["uuid"], "plan": plan, "indices": r["indices"],
                              "wavelengths": wl, "wavelength_index": int(wavelength_index)},
                        indices=indices if lattice is not None else None, lattice=lattice,
                        wavelengths=(float(np.ravel(wl)[wavelength_index]),)
                        if wl is not None and np.size(wl) > wavelength_index else None)


FORMAT = Format(name="ipasc", title="IPASC HDF5", container="hdf5", sniff=sniff, load=load, write=export_scan,
                input=True, upload=True, wavelengths=True, order=50, noun="an IPASC file")
