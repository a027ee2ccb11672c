"""OME-TIFF: a reconstruction's p0 volume for ImageJ/Fiji, napari and other OME readers (an
export of a result ``volume.h5``, written with ``tifffile``; no reader here)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.disk import file_replaced
from fpscan.service.formats.registry import Format
from fpscan.service.formats.result import (
    ResultVolume,
    open_result,
    read_slabs,
    volume_description,
    voxel_sizes_um,
)

__all__ = ["FORMAT", "export_ome_tiff", "plane_positions_um"]


def _um(v: float) -> float:
    """Metres to µm, without the last bits of rounding noise."""
    return float(f"{float(v) * 1e6:.12g}")


def plane_positions_um(r: ResultVolume) -> dict[str, list]:
    """The OME ``Plane`` positions of a volume's OME-TIFF, in µm: one entry per TIFF plane.

    3-D ``(n_z, n_y, n_x)``: ``n_z`` planes at ``PositionX = x[0]``, ``PositionY = y[0]``,
    ``PositionZ = z[k]``; 2-D ``(n_z, n_x)`` (depth as the image's Y): one plane at
    ``PositionX = x[0]``, ``PositionY = z[0]``. Each with its unit ``"µm"``.

    Parameters
    ----------
    r : ResultVolume
        The volume (``x``, ``y``, ``z`` in m).

    Returns
    -------
    dict of str to list
        tifffile's per-plane ``Plane`` metadata: ``PositionX``, ``PositionXUnit``, ...
    """
    if r.p0.ndim == 3 and r.y is not None:
        n = int(r.p0.shape[0])
        pos = {"X": [_um(r.x[0])] * n, "Y": [_um(r.y[0])] * n, "Z": [_um(v) for v in r.z]}
    else:
        pos = {"X": [_um(r.x[0])], "Y": [_um(r.z[0])]}
    out: dict[str, list] = {}
    for a, values in pos.items():
        out[f"Position{a}"] = values
        out[f"Position{a}Unit"] = ["µm"] * len(values)
    return out


def export_ome_tiff(result_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Write the p0 of a result file as an OME-TIFF (``tifffile``) for ImageJ/Fiji, napari
    and other OME readers, with the physical voxel sizes.

    3-D ``(n_z, n_y, n_x)`` → OME axes ``ZYX``; 2-D ``(n_z, n_x)`` → ``YX`` (the image's
    depth z is the TIFF's Y). ``PhysicalSizeX``/``Y``/``Z`` in µm from the coordinate
    spacings (a single sample counts as 1 µm); float32 data, the array order of the result
    file (TIFF row 0 = the first, smallest y, drawn at the top by ImageJ and napari as in
    fpscan's pictures: :data:`fpscan.service.formats.result.ORIENTATION`). The p0 unit and the orientation are in the
    image's OME ``Description`` (``p0 unit: Pa`` or ``p0 unit: a.u.``). The image's
    coordinates, the same as the result file's ``/x``, ``/y``, ``/z`` and the OME-Zarr
    ``translation``: every OME ``Plane`` gives its position in µm, ``PositionX``/``PositionY``
    the first voxel's centre (``x[0]``, ``y[0]``; 2-D: ``x[0]`` and the first depth ``z[0]``)
    and, 3-D, ``PositionZ`` the plane's depth ``z[k]``. Written to a temporary sibling, then
    renamed; a 3-D volume is read and written one depth plane (one TIFF page) at a time, so the
    memory it takes is a plane's, not the volume's.

    Parameters
    ----------
    result_path : str or os.PathLike
        A reconstruction result ``volume.h5`` (``fpscan.service.formats.result``).
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

    with open_result(result_path) as r:
        axes, steps = voxel_sizes_um(r, "OME-TIFF")
        meta: dict[str, Any] = {"axes": axes, "Name": f"p0 ({r.method}, {r.input_id})",
                                "Description": volume_description(r)}
        for a, step in zip(axes, steps):
            meta[f"PhysicalSize{a}"] = step
            meta[f"PhysicalSize{a}Unit"] = "µm"
        meta["Plane"] = plane_positions_um(r)
        shape = tuple(int(n) for n in r.p0.shape)
        # 3-D: one depth plane (one TIFF page) read at a time; 2-D: its one page
        pages = (page for slab in read_slabs(r.p0, 0, max_bytes=0) for page in slab) if len(shape) == 3 \
            else iter([np.ascontiguousarray(r.p0[()], dtype=np.float32)])
        with file_replaced(out_path) as tmp:
            tifffile.imwrite(tmp, pages, shape=shape, dtype=np.float32, ome=True, photometric="minisblack",
                             metadata=meta)
    return Path(out_path)


FORMAT = Format(rank=110, name="ome-tiff", title="OME-TIFF (ImageJ/Fiji, napari; voxel sizes in µm)", container="file",
                export_from="result", export=export_ome_tiff, suffix=".ome.tif", media_type="image/tiff",
                noun="an OME-TIFF image")
