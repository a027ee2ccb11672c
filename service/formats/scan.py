"""fpscan scan file (:mod:`fpscan.driver.scanfile`, ``fpscan-scan/1`` and ``/2``): its
*completed* points, the DC-normalised pressure, the plan's positions, weights and lattice
→ :class:`fpscan.service.recon.dataset.PointDataset`. May hold several excitation wavelengths
(``wavelength_index`` chooses one; default the first).

A thin registry entry: the layout has one owner, :mod:`fpscan.driver.scanfile`, which writes it
while acquiring (``ScanFile``), reopens it to resume (``ScanFile.open_append``) and reads
it (``read_open_scan``, on the file the registry opened once); here only the detection by
its ``format`` attribute and the mapping of the read scan to point data.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.service.disk import copy_replaced
from fpscan.service.formats.load_options import WavelengthChoice
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import PointDataset, check_wavelength_index, lattice_axes

if TYPE_CHECKING:
    from fpscan.driver.scanfile import ScanData

__all__ = ["FORMAT", "sniff", "load"]


def sniff(source: Source) -> bool:
    """True for an HDF5 file whose ``format`` attribute is ``fpscan-scan/<version>``
    (``fpscan.driver.scanfile.FORMAT_FAMILY``).

    Parameters
    ----------
    source : Source
        The opened HDF5 file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    from fpscan.driver.scanfile import FORMAT_FAMILY

    return source.attr("format").startswith(FORMAT_FAMILY)


def load(source: Source, *, allow_empty: bool = False, wavelength_index: int = 0, all_wavelengths: bool = False,
         **_: Any) -> PointDataset | list[PointDataset]:
    """The scan's completed points at one excitation wavelength as point data, or at all.

    Parameters
    ----------
    source : Source
        The opened HDF5 scan file.
    allow_empty : bool, optional
        Accept a scan with no completed point (an empty dataset).
    wavelength_index : int, optional
        The excitation wavelength to read (default 0, the first).
    all_wavelengths : bool, optional
        A list, one dataset per wavelength of the scan, from one read of the file.
    **_
        Other loading options, ignored.

    Returns
    -------
    PointDataset or list of PointDataset
        DC-normalised pressure ``(n, n_t)`` float64, the plan's positions and weights, its
        lattice and indices; ``wavelengths``: the one wavelength read (m);
        ``meta["wavelengths"]`` all the scan's, ``meta["wavelength_index"]`` the one read.
        With ``all_wavelengths`` a list.

    Raises
    ------
    ValueError
        No point is complete (unless ``allow_empty``), the plan is invalid, or the wavelength
        index is out of range (naming the scan's wavelengths).
    """
    from fpscan.driver.scanfile import read_open_scan

    scan = read_open_scan(source.h5, source.path)
    if all_wavelengths:
        return [_dataset(scan, k, allow_empty) for k in range(max(1, int(np.size(scan.wavelengths))))]
    return _dataset(scan, wavelength_index, allow_empty)


def _dataset(scan: ScanData, wavelength_index: int, allow_empty: bool) -> PointDataset:
    """One wavelength's completed points of the scan read (``fpscan.driver.scanfile.ScanData``)."""
    from fpscan.driver.plan import check_plan
    from fpscan.driver.scanfile import pressure_unit

    check_wavelength_index(wavelength_index, scan.wavelengths, "scan")
    scan = scan.at_wavelength(wavelength_index).completed_only() if wavelength_index else scan.completed_only()
    check_plan(scan.plan)  # its lattice becomes the reconstruction grid: bounded there
    if scan.n_points == 0 and not allow_empty:
        raise ValueError("the scan file has no completed A-lines")
    lat = scan.plan.get("lattice", {})
    positions = np.asarray(scan.positions, dtype=np.float64)
    two_d = positions.shape[1] == 1 or int(lat.get("n_y", 2)) == 1
    if lat:
        gx, gy = lattice_axes(lat)
        lattice = {"n_x": int(lat["n_x"]), "n_y": int(lat.get("n_y", 1)), "pitch": float(lat["pitch"])}
    else:
        gx = np.unique(positions[:, 0])
        gy = np.unique(positions[:, 1]) if positions.shape[1] > 1 else np.zeros(1)
        lattice = None
    all_w = np.ravel(np.asarray(scan.wavelengths, dtype=np.float64))
    wavelengths = (float(all_w[wavelength_index]),) if all_w.size else None
    return PointDataset(
        alines=scan.pressure, positions=positions[:, :1] if two_d else positions,
        weights=np.asarray(scan.weights, dtype=np.float64), dt=scan.dt, sound_speed=scan.sound_speed,
        grid=(gx,) if two_d else (gx, gy), source="fpscan",
        meta={"plan_id": scan.plan_id, "plan": scan.plan, "indices": scan.indices,
              "wavelengths": scan.wavelengths, "n_points_planned": int(scan.attrs["n_points"]),
              "wavelength_index": int(wavelength_index), "p0_unit": pressure_unit(scan.instrument)},
        indices=np.asarray(scan.indices, dtype=np.int64).reshape(-1, 2), lattice=lattice,
        wavelengths=wavelengths)


FORMAT = Format(rank=40, name="fpscan", title="fpscan scan file", container="hdf5", sniff=sniff, load=load,
                input=True, upload=True, wavelengths=True, order=10, noun="a scan file", options=WavelengthChoice,
                export_from="fpscan", export=copy_replaced, suffix=".h5", media_type="application/x-hdf5")
