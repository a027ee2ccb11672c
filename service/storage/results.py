"""Result files: a reconstructed p0 volume in HDF5 (DESIGN §6), written atomically.

Layout (``format`` attribute ``fpscan-result/1``; docs/file-formats.md):

===========  =============================  =============================================
path         shape, dtype                   meaning
===========  =============================  =============================================
``/p0``      (n_z, n_y, n_x) or (n_z, n_x)  initial pressure (the input's units), row 0
             float32 (float64 if asked),    at the sensor plane z = 0
             gzip-1 where that pays
``/z``       (n_z,) float64                 depth of each row, m (HDF5 dimension scale)
``/y``       (n_y,) float64                 lateral y, m (3-D only; dimension scale)
``/x``       (n_x,) float64                 lateral x, m (dimension scale)
``/params``  group, no datasets             one attribute per parameter, its JSON text
===========  =============================  =============================================

Root attributes: ``format``, ``method``, ``params`` (JSON of every parameter),
``input_id``, ``created_utc``, ``software_version``, ``units``, ``p0_unit`` (``"Pa"``
for a calibrated scan, else ``"a.u."``; also ``/p0``'s ``units`` attribute) and
``orientation`` (:data:`ORIENTATION`: row 0 of ``/p0``'s y axis is the smallest y, shown
at the top by napari, ImageJ and ``imshow``, as in fpscan's own pictures).

Exports (:func:`export_volume`, the one dispatch, :data:`EXPORT_FORMATS`): OME-TIFF
(:func:`export_ome_tiff`) and OME-Zarr (:func:`export_ome_zarr`), both in the result
file's array order with physical voxel sizes in µm and the p0 unit.

The file is written to a temporary sibling, fsynced, then renamed over ``path``
(``os.replace``), so a reader sees either the old file or the complete new one. The
format -- its reader and detection (``ResultVolume``, :func:`read_result`), its writers
(:func:`write_volume`, :func:`write_reconstruction`, the folder's ``write_folder``) and
its file names -- lives in :mod:`service.formats.result`; storage keeps what is not the
format: drawing the MIPs (:func:`write_result`), the exports and zipping.
"""
from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from service.formats.result import (
    COMPRESS_BELOW,
    ORIENTATION,
    P0_UNITS,
    ResultVolume,
    params_json,
    read_result,
    storage_layout,
    write_folder,
    write_reconstruction,
    write_volume,
)
from service.formats.result import RESULT_FORMAT as FORMAT

__all__ = ["FORMAT", "ORIENTATION", "P0_UNITS", "ResultVolume", "read_result", "params_json", "storage_layout",
           "write_volume", "write_reconstruction", "write_result", "export_ome_tiff", "export_ome_zarr",
           "EXPORT_FORMATS", "export_volume", "zip_folder", "COMPRESS_BELOW", "PYRAMID_TOP", "PYRAMID_MIN", "ZARR_CHUNK",
           "pyramid_factors"]

def write_result(out_dir: str | os.PathLike, rec: Any, *, input_id: str) -> dict:
    """The result folder of a reconstruction, as every caller writes it (the job worker
    and ``fpscan recon``): its MIP pictures ``mip_{xy,xz,yz}`` (``mip_xz`` only in 2-D;
    :func:`service.storage.render.render_mips`) drawn here, the folder (``volume.h5`` and
    the PNGs, renamed into place, an existing ``out_dir`` replaced) written by its format,
    :func:`service.formats.result.write_folder`. Returns ``{"shape", "max", "planes",
    "params_used"}``. Raises ValueError as :func:`write_volume`.

    The pictures are drawn in a thread while the volume is written and flushed to disk
    (``os.fsync``, which releases the GIL: most of a large result's write time)."""
    from concurrent.futures import ThreadPoolExecutor

    from service.storage.render import render_mips

    with ThreadPoolExecutor(1, thread_name_prefix="mip-pictures") as pool:
        pngs = pool.submit(render_mips, np.asarray(rec.p0), rec.z, rec.x, getattr(rec, "y", None),
                           colorbar_label=f"p0 ({getattr(rec, 'p0_unit', 'a.u.')})")
        return write_folder(out_dir, rec, input_id=input_id, mips=pngs.result)


def _voxel_sizes_um(r: ResultVolume, what: str) -> tuple[str, list[float]]:
    """The export axes (``"ZYX"``, 2-D ``"YX"`` with depth as Y) and the voxel size of each
    in µm (a single sample counts as 1 µm). Raises ValueError for an uneven axis."""
    def step_um(v: np.ndarray, name: str) -> float:
        if len(v) < 2:
            return 1.0
        d = np.diff(v)
        if not np.allclose(d, d[0], rtol=1e-6, atol=0):
            raise ValueError(f"{name} is not evenly spaced: {what} needs one voxel size per axis")
        return float(f"{d[0] * 1e6:.12g}")  # µm, without the last bits of rounding noise

    if r.p0.ndim == 3 and r.y is not None:
        return "ZYX", [step_um(r.z, "z"), step_um(r.y, "y"), step_um(r.x, "x")]
    return "YX", [step_um(r.z, "z"), step_um(r.x, "x")]


def _description(r: ResultVolume) -> str:
    return (f"fpscan p0 ({r.method}); p0 unit: {r.p0_unit}; "
            f"{'axes (z, y, x)' if r.p0.ndim == 3 else 'axes (z, x): depth z as the image Y'}; "
            f"orientation: {ORIENTATION}")


def export_ome_tiff(result_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Write the p0 of a result file as an OME-TIFF (``tifffile``) for ImageJ/Fiji, napari
    and other OME readers, with the physical voxel sizes.

    3-D ``(n_z, n_y, n_x)`` → OME axes ``ZYX``; 2-D ``(n_z, n_x)`` → ``YX`` (the image's
    depth z is the TIFF's Y). ``PhysicalSizeX``/``Y``/``Z`` in µm from the coordinate
    spacings (a single sample counts as 1 µm); float32 data, the array order of the result
    file (TIFF row 0 = the first, smallest y, drawn at the top by ImageJ and napari as in
    fpscan's pictures: :data:`ORIENTATION`). The p0 unit and the orientation are in the
    image's OME ``Description`` (``p0 unit: Pa`` or ``p0 unit: a.u.``). Written to a
    temporary sibling, then renamed. Returns ``out_path``. Raises FileNotFoundError,
    ValueError (not a result file, or coordinates that are not evenly spaced).
    """
    import tifffile

    r = read_result(result_path)
    axes, steps = _voxel_sizes_um(r, "OME-TIFF")
    sizes = {f"PhysicalSize{a}": step for a, step in zip(axes, steps)}
    meta: dict[str, Any] = {"axes": axes, "Name": f"p0 ({r.method}, {r.input_id})",
                            "Description": _description(r)}
    for key, value in sizes.items():
        meta[key] = value
        meta[f"{key}Unit"] = "µm"
    out_path = Path(out_path)
    tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        tifffile.imwrite(tmp, np.ascontiguousarray(r.p0, dtype=np.float32), ome=True,
                         photometric="minisblack", metadata=meta)
        os.replace(tmp, out_path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out_path


#: the largest axis (samples) of an OME-Zarr export's coarsest pyramid level: levels halve
#: every axis until the volume fits it (napari then opens a large volume at a coarse level
#: first and loads finer chunks as one zooms in)
PYRAMID_TOP = 256
#: no axis of a pyramid level below this many samples (a level is added only while it holds)
PYRAMID_MIN = 8
#: chunk edge (samples) of every level: napari reads the chunks it shows, not the array
ZARR_CHUNK = 128


def pyramid_factors(shape: tuple[int, ...], names: list[str]) -> list[dict[str, int]]:
    """The downsampling factors of an OME-Zarr export's pyramid levels below the full
    resolution: ``{axis: 2**k}`` for every axis, k = 1, 2, ... while the level before still
    has an axis longer than :data:`PYRAMID_TOP` and every axis of the new level keeps at least
    :data:`PYRAMID_MIN` samples. ``[]`` for a volume small enough to show at once.

    Examples
    --------
    >>> pyramid_factors((1024, 226, 226), ["z", "y", "x"])
    [{'z': 2, 'y': 2, 'x': 2}, {'z': 4, 'y': 4, 'x': 4}]
    >>> pyramid_factors((96, 40, 40), ["z", "y", "x"])
    []
    """
    out: list[dict[str, int]] = []
    f = 1
    while max(n // f for n in shape) > PYRAMID_TOP and min(n // (2 * f) for n in shape) >= PYRAMID_MIN:
        f *= 2
        out.append(dict.fromkeys(names, f))
    return out


def export_ome_zarr(result_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Write the p0 of a result file as an OME-Zarr image at ``out_path`` (a folder,
    conventionally ``*.ome.zarr``) with ``ome-zarr``'s writer in its default, current format:
    NGFF 0.5 on Zarr v3 (what napari-ome-zarr and the OME readers of that version open
    without a version warning).

    A multiscale pyramid: level ``s0`` is the volume, float32 ``(n_z, n_y, n_x)`` with axes
    ``z``, ``y``, ``x`` (2-D ``(n_z, n_x)``: ``y``, ``x`` with depth as y, as the OME-TIFF) of
    type ``space`` and unit ``micrometer``; levels ``s1``, ``s2``, ... halve every axis
    (:func:`pyramid_factors`: until the coarsest fits :data:`PYRAMID_TOP` samples per axis;
    block means, skimage's ``downscale_local_mean``), each in chunks of at most
    :data:`ZARR_CHUNK` samples per axis, so napari opens a large volume lazily. Each level's
    ``coordinateTransformations``: ``scale`` = its voxel size in µm, ``translation`` = the
    position of its first voxel's centre in µm (level 0: the first sample's position, the
    centred lateral axes and the depth from the sensor plane). The array order of the result
    file: row 0 = the smallest y, displayed at the top by napari as in fpscan's pictures
    (:data:`ORIENTATION`). The group's ``fpscan`` attribute holds ``p0_unit`` (``"Pa"`` or
    ``"a.u."``), ``orientation``, ``method``, ``input_id``, ``description`` and ``axes``.
    Written to a temporary sibling folder, then renamed over ``out_path`` (an existing
    export there is replaced). Returns ``out_path``. Raises FileNotFoundError, ValueError
    (not a result file, uneven coordinates, ``out_path`` an existing file).
    """
    import zarr
    from ome_zarr.format import CurrentFormat
    from ome_zarr.io import parse_url
    from ome_zarr.scale import Methods
    from ome_zarr.writer import write_image

    from service.disk import folder_replaced

    r = read_result(result_path)
    axes, steps = _voxel_sizes_um(r, "OME-Zarr")
    names = [a.lower() for a in axes]
    coords = [r.z, r.y, r.x] if len(axes) == 3 else [r.z, r.x]
    origin = [float(f"{np.asarray(v)[0] * 1e6:.12g}") for v in coords]
    out_path = Path(out_path)
    if out_path.exists() and not out_path.is_dir():
        raise ValueError(f"{out_path} is a file; an OME-Zarr export is a folder (name it *.ome.zarr)")
    tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    fmt = CurrentFormat()
    p0 = np.ascontiguousarray(r.p0, dtype=np.float32)
    with folder_replaced(out_path, tmp):
        root = zarr.group(store=parse_url(str(tmp), mode="w", fmt=fmt).store)
        write_image(p0, root, scale_factors=pyramid_factors(p0.shape, names), method=Methods.LOCAL_MEAN, fmt=fmt,
                    axes=names, scale=dict(zip(names, steps)), axes_units=dict.fromkeys(names, "micrometer"),
                    storage_options={"chunks": tuple(min(n, ZARR_CHUNK) for n in p0.shape)},
                    name=f"p0 ({r.method}, {r.input_id})")
        # the writer places level 0 at the origin: every level moves by the first sample's position
        ome: Any = root.attrs["ome"]
        for level in ome["multiscales"][0]["datasets"]:
            for t in level["coordinateTransformations"]:
                if t["type"] == "translation":
                    t["translation"] = [float(f"{o + v:.12g}") for o, v in zip(origin, t["translation"])]
        root.attrs["ome"] = ome
        root.attrs["fpscan"] = {"p0_unit": r.p0_unit, "orientation": ORIENTATION, "method": r.method,
                                "input_id": r.input_id, "description": _description(r),
                                "axes": ["z", "y", "x"] if len(axes) == 3 else ["z", "x"]}
    return out_path


#: the export formats of a result volume: name → (file suffix, exporter)
EXPORT_FORMATS = {"ome-tiff": (".ome.tif", export_ome_tiff), "ome-zarr": (".ome.zarr", export_ome_zarr)}


def export_volume(result_path: str | os.PathLike, out_path: str | os.PathLike, format: str = "ome-tiff") -> Path:
    """Export the p0 of a result file as ``format`` (a key of :data:`EXPORT_FORMATS`:
    ``"ome-tiff"`` → :func:`export_ome_tiff`, ``"ome-zarr"`` → :func:`export_ome_zarr`),
    the one export dispatch of ``fpscan export``, the HTTP download routes and the
    ``fpscan`` package. Returns ``out_path``. Raises ValueError (unknown format, and as
    the exporter), FileNotFoundError."""
    if format not in EXPORT_FORMATS:
        raise ValueError(f"format must be one of {', '.join(EXPORT_FORMATS)}, got {format!r}")
    return EXPORT_FORMATS[format][1](result_path, out_path)


def zip_folder(folder: str | os.PathLike, out_path: str | os.PathLike, *, arcname: str | None = None) -> Path:
    """Zip ``folder`` (e.g. an OME-Zarr export) into ``out_path``, its files under
    ``arcname`` (default the folder's name) — stored uncompressed (float data barely
    compresses), written to a temporary sibling, then renamed. Returns ``out_path``."""
    import zipfile

    folder, out_path = Path(folder), Path(out_path)
    arcname = arcname or folder.name
    tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as z:
            for p in sorted(folder.rglob("*")):
                if p.is_file():
                    z.write(p, f"{arcname}/{p.relative_to(folder).as_posix()}")
        os.replace(tmp, out_path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out_path
