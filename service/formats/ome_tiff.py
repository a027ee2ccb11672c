"""OME-TIFF: a reconstruction's p0 volume for ImageJ/Fiji, napari and other OME readers (an
export of a result ``volume.h5``, written with ``tifffile``; no reader here)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from service.disk import file_replaced
from service.formats._registry import Format
from service.formats.result import read_result, volume_description, voxel_sizes_um

__all__ = ["FORMAT", "export_ome_tiff"]


def export_ome_tiff(result_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Write the p0 of a result file as an OME-TIFF (``tifffile``) for ImageJ/Fiji, napari
    and other OME readers, with the physical voxel sizes.

    3-D ``(n_z, n_y, n_x)`` → OME axes ``ZYX``; 2-D ``(n_z, n_x)`` → ``YX`` (the image's
    depth z is the TIFF's Y). ``PhysicalSizeX``/``Y``/``Z`` in µm from the coordinate
    spacings (a single sample counts as 1 µm); float32 data, the array order of the result
    file (TIFF row 0 = the first, smallest y, drawn at the top by ImageJ and napari as in
    fpscan's pictures: :data:`service.formats.result.ORIENTATION`). The p0 unit and the orientation are in the
    image's OME ``Description`` (``p0 unit: Pa`` or ``p0 unit: a.u.``). Written to a
    temporary sibling, then renamed.

    Parameters
    ----------
    result_path : str or os.PathLike
        A reconstruction result ``volume.h5`` (``service.formats.result``).
    out_path : str or os.PathLike
        The TIFF file to write.

    Returns
    -------
    pathlib.Path
        ``out_path``.

    Raises
    ------
    FileNotFoundError
        ``result_path`` does not exist.
    ValueError
        Not a result file, or coordinates that are not evenly spaced.
    """
    import tifffile

    r = read_result(result_path)
    axes, steps = voxel_sizes_um(r, "OME-TIFF")
    meta: dict[str, Any] = {"axes": axes, "Name": f"p0 ({r.method}, {r.input_id})",
                            "Description": volume_description(r)}
    for a, step in zip(axes, steps):
        meta[f"PhysicalSize{a}"] = step
        meta[f"PhysicalSize{a}Unit"] = "µm"
    with file_replaced(out_path) as tmp:
        tifffile.imwrite(tmp, np.ascontiguousarray(r.p0, dtype=np.float32), ome=True,
                         photometric="minisblack", metadata=meta)
    return Path(out_path)


FORMAT = Format(rank=110, name="ome-tiff", title="OME-TIFF (ImageJ/Fiji, napari; voxel sizes in µm)", container="file",
                export_from="result", export=export_ome_tiff, suffix=".ome.tif", media_type="image/tiff",
                noun="an OME-TIFF image")
