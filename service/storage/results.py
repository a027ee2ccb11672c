"""Result files: a reconstructed p0 volume in HDF5, written atomically.

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

Exports are formats of the registry (``fpscan.service.formats.export_file``, one module each:
OME-TIFF ``fpscan.service.formats.ome_tiff``, OME-Zarr ``fpscan.service.formats.ngff``, ...); a folder export is
served zipped (:func:`zip_folder`).

The file is written to a temporary sibling, fsynced, then renamed over ``path``
(``os.replace``), so a reader sees either the old file or the complete new one. The
format -- its reader and detection (``ResultVolume``, :func:`read_result`), its writers
(:func:`write_volume`, :func:`write_reconstruction`, the folder's ``write_folder``) and
its file names -- lives in :mod:`fpscan.service.formats.result`; storage keeps what is not the
format: drawing the MIPs (:func:`write_result`) and zipping.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.formats.result import (
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
from fpscan.service.formats.result import RESULT_FORMAT as FORMAT

__all__ = ["FORMAT", "ORIENTATION", "P0_UNITS", "ResultVolume", "read_result", "params_json", "storage_layout",
           "write_volume", "write_reconstruction", "write_result", "zip_folder", "COMPRESS_BELOW"]

def write_result(out_dir: str | os.PathLike, rec: Any, *, input_id: str) -> dict:
    """Write the result folder of a reconstruction, as every caller writes it.

    The job worker and ``fpscan recon`` both call this: its MIP pictures ``mip_{xy,xz,yz}``
    (``mip_xz`` only in 2-D; :func:`fpscan.service.pictures.render.render_mips`) are drawn here, the
    folder (``volume.h5`` and the PNGs, renamed into place, an existing ``out_dir`` replaced)
    is written by its format, :func:`fpscan.service.formats.result.write_folder`.

    The pictures are drawn in a thread while the volume is written and flushed to disk
    (``os.fsync``, which releases the GIL: most of a large result's write time).

    Parameters
    ----------
    out_dir : str or os.PathLike
        The result folder to write (replaced if it exists).
    rec : Reconstruction
        The reconstruction: ``p0`` of shape ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``, depths ``z``
        ``(n_z,)`` and lateral positions ``x`` ``(n_x,)`` (and ``y`` ``(n_y,)`` in 3-D) in m,
        optionally ``p0_unit`` (``"Pa"`` or ``"a.u."``, the colour bar's label) and its params.
    input_id : str
        The id of the scan or dataset it was reconstructed from (stored in the file).

    Returns
    -------
    dict
        ``{"shape", "max", "planes", "params_used"}``.

    Raises
    ------
    ValueError
        As :func:`write_volume` (a bad ``p0``, axes, unit or params).
    """
    from concurrent.futures import ThreadPoolExecutor

    from fpscan.service.pictures.render import render_mips

    with ThreadPoolExecutor(1, thread_name_prefix="mip-pictures") as pool:
        pngs = pool.submit(render_mips, np.asarray(rec.p0), rec.z, rec.x, getattr(rec, "y", None),
                           colorbar_label=f"p0 ({getattr(rec, 'p0_unit', 'a.u.')})")
        return write_folder(out_dir, rec, input_id=input_id, mips=pngs.result)


def zip_folder(folder: str | os.PathLike, out_path: str | os.PathLike, *, arcname: str | None = None) -> Path:
    """Zip ``folder`` (e.g. an OME-Zarr export) into ``out_path``.

    The files are stored uncompressed (float data barely compresses), each copied in
    pieces (``zipfile``), written to a temporary sibling, then renamed over ``out_path``
    (``fpscan.service.disk.file_replaced``: the temporary file is removed on failure).
    Symbolic links in ``folder`` are left out.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder to zip (its files, recursively).
    out_path : str or os.PathLike
        The zip file to write.
    arcname : str or None, optional
        The folder name of the files in the archive; default None: ``folder``'s name.

    Returns
    -------
    pathlib.Path
        ``out_path``.
    """
    import zipfile

    from fpscan.service.disk import file_replaced

    folder, out_path = Path(folder), Path(out_path)
    arcname = arcname or folder.name
    with file_replaced(out_path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as z:
        for p in sorted(folder.rglob("*")):
            if p.is_file() and not p.is_symlink():
                z.write(p, f"{arcname}/{p.relative_to(folder).as_posix()}")
    return out_path
