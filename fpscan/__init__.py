"""fpscan: planar Fabry–Pérot photoacoustic scanning — the user-facing Python API in one
flat namespace.

``import fpscan`` is light (nothing below is imported until first used, PEP 562); each
name comes from the package that owns it, so ``fpscan.X`` is exactly the object the
command line, the server and the web page use:

- plans and sensor masks (:mod:`fpscan.service.plans`): ``Lattice``, ``Mask``, ``make_mask`` and
  the per-kind functions (``full_mask``, ``subgrid_mask``, ``hexagonal_mask``,
  ``random_mask``, ``poisson_mask``, ``points_mask``, ``equiangular_mask``,
  ``equisteradian_mask``), ``MASK_KINDS``, ``Plan``, ``Acquisition``, ``make_plan``,
  ``plan_from_spec``, ``load_plan``, ``weight_ratio``, ``preview_png``;
- datasets (:mod:`fpscan.service.storage.loader`): ``load_dataset`` (any supported file,
  :mod:`fpscan.service.formats`), ``load_wavelengths``; the input model ``GridDataset``,
  ``PointDataset`` (:mod:`fpscan.service.recon.dataset`); ``subsample(dataset, mask_or_plan)``: the
  A-lines a sensor mask picks out of dense data (a sparse scan from a dense one or a k-Wave
  simulation, equal to the replay scan's; :mod:`fpscan.service.subsample`);
- reconstruction (:mod:`fpscan.service.pipeline`, the one dispatch): ``reconstruct(dataset,
  method, **options)`` for every method of ``METHODS`` (``nedner``, ``ner``, ``linear``,
  ``nearest``, ``cubic``, ``kwave``, ``tv``), ``Reconstruction``, ``Cancelled``; ``tv_problem(dataset,
  **options)``: the problem ``tv`` solves (its operator as a ``pylops.LinearOperator``, the data,
  the warm start, the grid and λ) for pylops' and pyproximal's solvers;
- scan files (:mod:`fpscan.driver.scanfile`): ``read_scan``, ``ScanFile``, ``ScanData``,
  ``pressure_unit``;
- results (:mod:`fpscan.service.storage.results`): ``write_result`` (``volume.h5`` + MIP PNGs),
  ``write_volume``, ``read_result``, ``ResultVolume``;
- export (:mod:`fpscan.service.formats`, one module per format): ``export_file(src, out, format)`` for
  every format of ``export_formats()`` (a scan file: ``"ipasc"``; a result volume:
  ``"ome-tiff"``, ``"ome-zarr"``, ...), ``export_ome_tiff``, ``export_ome_zarr``, ``export_ipasc``
  (a scan file to IPASC HDF5);
- pictures (:mod:`fpscan.service.pictures.render`): ``render_mip``, ``render_mips``, ``render_so2``;
- spectral unmixing: ``unmix``, ``so2_map``, ``thb_map``;
- metrics (:mod:`fpscan.service.metrics`): ``correlation_coefficient``, ``mip``, ``mips``,
  ``fit_edge_spread``, ``fit_lorentz``, ``edge_spread``, ``lorentz``, ``side_lobe_level``,
  ``tenenbaum_sharpness``, ``cc_vs_diameter``, ``cc_vs_pixels``, ``sharpness_vs_diameter``,
  ``roi_mask``, ``disc_mask``, ``bounding_box``, ``EdgeFit``, ``LorentzFit``;
- phantoms (:mod:`fpscan.physics`): ``Ball``, ``ball_alines``, ``ball_p0``;
- the HTTP client (:mod:`fpscan.clients.http`): ``Client``, ``AsyncClient``, ``ApiError`` and its
  subclasses;
- what a plugin (a reconstruction method or file format of another package) builds on:
  :mod:`fpscan.plugins` (``import fpscan.plugins``; docs/plugins.md);
- ``__version__``.

Arrays follow one convention (docs/file-formats.md "Orientation"): p0 is ``(n_z, n_y,
n_x)`` (2-D ``(n_z, n_x)``), coordinates increasing with the index, SI units (m, s, Pa
or a.u.), and every picture and export shows row 0 at the top, as napari, ImageJ and
``matplotlib.pyplot.imshow`` do.

Examples
--------
A 3-D scan of one ball on a full 16 × 16 lattice, reconstructed with NER, written as a
result folder and exported for napari:

>>> import numpy as np
>>> import fpscan
>>> lattice = fpscan.Lattice(16, 16, 100e-6)
>>> mask = fpscan.make_mask("full", lattice)
>>> mask.obtained_points
256
>>> alines = fpscan.ball_alines(mask.positions, [fpscan.Ball(x=0.3e-3, y=0.4e-3, z=1.2e-3, radius=2e-4,
...                                                          amplitude=1.0)], 4e-8, 96, 1500.0)
>>> data = alines.T.reshape(96, 16, 16)          # (n_t, n_y, n_x): time first
>>> ds = fpscan.GridDataset(data=data, dx=100e-6, dy=100e-6, dt=4e-8, sound_speed=1500.0)
>>> rec = fpscan.reconstruct(ds, "ner")
>>> rec.p0.shape                 # (n_z, n_y, n_x): rows of the pitch down to c·t_last = 5.7 mm
(58, 16, 16)
>>> iz, iy, ix = np.unravel_index(np.argmax(rec.p0), rec.p0.shape)
>>> bool(rec.y[iy] > 0 and rec.x[ix] > 0)        # the ball's +x, +y quadrant
True
>>> "tv" in fpscan.METHODS and "nedner" in fpscan.METHODS
True

>>> import tempfile, pathlib
>>> out = pathlib.Path(tempfile.mkdtemp())
>>> summary = fpscan.write_result(out / "result", rec, input_id="example")
>>> summary["planes"]
['xy', 'xz', 'yz']
>>> vol = fpscan.read_result(out / "result" / "volume.h5")
>>> vol.p0.shape, vol.p0_unit
((58, 16, 16), 'a.u.')
>>> fpscan.export_file(out / "result" / "volume.h5", out / "p0.ome.zarr", "ome-zarr").name
'p0.ome.zarr'

The server's client (``fpscan serve`` on a URL):

>>> fpscan.Client.__name__
'Client'
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: name → the module that owns it
_EXPORTS: dict[str, str] = {
    # plans and masks
    **dict.fromkeys(["Lattice", "Mask", "make_mask", "full_mask", "subgrid_mask", "hexagonal_mask",
                     "random_mask", "poisson_mask", "points_mask", "equiangular_mask", "equisteradian_mask",
                     "MASK_KINDS", "Plan", "Acquisition", "make_plan", "plan_from_spec", "weight_ratio",
                     "preview_png"], "fpscan.service.plans"),
    # datasets and the one reconstruction dispatch
    **dict.fromkeys(["load_dataset", "load_wavelengths"], "fpscan.service.storage.loader"),
    **dict.fromkeys(["GridDataset", "PointDataset"], "fpscan.service.recon.dataset"),
    **dict.fromkeys(["reconstruct", "METHODS", "Cancelled", "tv_problem"], "fpscan.service.pipeline"),
    "Reconstruction": "fpscan.service.recon.reconstruction",
    "subsample": "fpscan.service.subsample",
    # scan files
    **dict.fromkeys(["read_scan", "ScanFile", "ScanData", "pressure_unit"], "fpscan.driver.scanfile"),
    # results and exports
    **dict.fromkeys(["write_result", "write_volume", "read_result", "ResultVolume"], "fpscan.service.storage.results"),
    **dict.fromkeys(["export_file", "export_formats"], "fpscan.service.formats"),
    "export_ome_tiff": "fpscan.service.formats.ome_tiff",
    "export_ome_zarr": "fpscan.service.formats.ngff",
    # pictures, spectral unmixing
    **dict.fromkeys(["render_mip", "render_mips", "render_so2"], "fpscan.service.pictures.render"),
    "unmix": "fpscan.service.recon.unmix",
    **dict.fromkeys(["so2_map", "thb_map"], "fpscan.service.spectral"),
    # metrics
    **dict.fromkeys(["correlation_coefficient", "mip", "mips", "fit_edge_spread", "fit_lorentz",
                     "edge_spread", "lorentz", "side_lobe_level", "tenenbaum_sharpness", "cc_vs_diameter",
                     "cc_vs_pixels", "sharpness_vs_diameter", "roi_mask", "disc_mask", "bounding_box",
                     "EdgeFit", "LorentzFit"], "fpscan.service.metrics"),
    # phantoms
    **dict.fromkeys(["Ball", "ball_alines", "ball_p0"], "fpscan.physics"),
    # the HTTP client
    **dict.fromkeys(["Client", "AsyncClient", "ApiError", "AuthError", "Conflict", "NotFound",
                     "FpscanClientError", "JobFailed", "JobCancelled", "JobError", "ServerUnavailable",
                     "WaitTimeout"], "fpscan.clients.http"),
}
#: a public name that differs from its owner's
_RENAMED = {"export_ipasc": ("fpscan.service.formats.ipasc", "export_scan"),
            "load_plan": ("fpscan.service.formats.plan", "read_plan")}

#: the public names (tests check them against _EXPORTS and _RENAMED)
__all__ = [
    "Acquisition", "ApiError", "AsyncClient", "AuthError", "Ball", "Cancelled", "Client",
    "Conflict", "EdgeFit", "FpscanClientError", "GridDataset", "JobCancelled",
    "JobError", "JobFailed", "Lattice", "LorentzFit", "MASK_KINDS", "METHODS", "Mask", "NotFound",
    "Plan", "PointDataset", "Reconstruction", "ResultVolume", "ScanData", "ScanFile",
    "ServerUnavailable", "WaitTimeout", "__version__", "ball_alines", "ball_p0", "bounding_box",
    "cc_vs_diameter", "cc_vs_pixels", "correlation_coefficient", "disc_mask", "edge_spread",
    "equiangular_mask", "equisteradian_mask", "export_file", "export_formats", "export_ipasc",
    "export_ome_tiff", "export_ome_zarr", "fit_edge_spread", "fit_lorentz", "full_mask", "hexagonal_mask",
    "load_dataset", "load_plan", "load_wavelengths", "lorentz", "make_mask", "make_plan", "mip",
    "mips", "plan_from_spec", "points_mask", "poisson_mask", "pressure_unit", "preview_png",
    "random_mask", "read_result", "read_scan", "reconstruct", "render_mip", "render_mips",
    "render_so2", "roi_mask", "sharpness_vs_diameter", "side_lobe_level", "so2_map", "subgrid_mask", "subsample",
    "tenenbaum_sharpness", "thb_map", "tv_problem", "unmix", "weight_ratio", "write_result", "write_volume",
]

if TYPE_CHECKING:
    from fpscan.clients.http import (
        ApiError,
        AsyncClient,
        AuthError,
        Client,
        Conflict,
        FpscanClientError,
        JobCancelled,
        JobError,
        JobFailed,
        NotFound,
        ServerUnavailable,
        WaitTimeout,
    )
    from fpscan.driver.scanfile import ScanData, ScanFile, pressure_unit, read_scan
    from fpscan.physics import Ball, ball_alines, ball_p0
    from fpscan.service.formats import export_file, export_formats
    from fpscan.service.formats.ipasc import export_scan as export_ipasc
    from fpscan.service.formats.ngff import export_ome_zarr
    from fpscan.service.formats.ome_tiff import export_ome_tiff
    from fpscan.service.formats.plan import read_plan as load_plan
    from fpscan.service.metrics import (
        EdgeFit,
        LorentzFit,
        bounding_box,
        cc_vs_diameter,
        cc_vs_pixels,
        correlation_coefficient,
        disc_mask,
        edge_spread,
        fit_edge_spread,
        fit_lorentz,
        lorentz,
        mip,
        mips,
        roi_mask,
        sharpness_vs_diameter,
        side_lobe_level,
        tenenbaum_sharpness,
    )
    from fpscan.service.pictures.render import render_mip, render_mips, render_so2
    from fpscan.service.pipeline import METHODS, Cancelled, reconstruct, tv_problem
    from fpscan.service.plans import (
        MASK_KINDS,
        Acquisition,
        Lattice,
        Mask,
        Plan,
        equiangular_mask,
        equisteradian_mask,
        full_mask,
        hexagonal_mask,
        make_mask,
        make_plan,
        plan_from_spec,
        points_mask,
        poisson_mask,
        preview_png,
        random_mask,
        subgrid_mask,
        weight_ratio,
    )
    from fpscan.service.recon.dataset import GridDataset, PointDataset
    from fpscan.service.recon.reconstruction import Reconstruction
    from fpscan.service.recon.unmix import unmix
    from fpscan.service.spectral import so2_map, thb_map
    from fpscan.service.storage.loader import load_dataset, load_wavelengths
    from fpscan.service.storage.results import ResultVolume, read_result, write_result, write_volume
    from fpscan.service.subsample import subsample

    __version__: str


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fpscan")
    except PackageNotFoundError:  # a source tree that is not installed
        return "0+unknown"


def __getattr__(name: str) -> Any:
    """The public names, imported from their owners on first use (PEP 562)."""
    if name == "__version__":
        value: Any = _version()
    elif name in _EXPORTS:
        try:
            value = getattr(importlib.import_module(_EXPORTS[name]), name)
        except ImportError as exc:  # the base install: the client only
            raise ImportError(f"fpscan.{name} needs the scanner/reconstruction side: "
                              f"pip install 'fpscan[driver]' ({exc})") from exc
    elif name in _RENAMED:
        module, attr = _RENAMED[name]
        value = getattr(importlib.import_module(module), attr)
    else:
        raise AttributeError(f"module 'fpscan' has no attribute {name!r}")
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
