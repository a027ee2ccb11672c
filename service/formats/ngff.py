"""OME-Zarr (OME-NGFF): a reconstruction's p0 volume as a multiscale image that napari opens
lazily (an export of a result ``volume.h5``, written with ``ome-zarr`` in its current format;
a folder, served zipped over HTTP; no reader here)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.disk import folder_replaced, temp_sibling
from fpscan.service.formats.registry import Format
from fpscan.service.formats.result import ORIENTATION, open_result, volume_description, voxel_sizes_um

__all__ = ["FORMAT", "export_ome_zarr", "pyramid_factors", "PYRAMID_TOP", "PYRAMID_MIN", "ZARR_CHUNK"]


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

    Parameters
    ----------
    shape : tuple of int
        The full-resolution volume's shape, e.g. ``(n_z, n_y, n_x)``.
    names : list of str
        The axes' names, one per axis of ``shape``.

    Returns
    -------
    list of dict of str to int
        One ``{axis: factor}`` per level below the full resolution, coarsest last.

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
    (:data:`fpscan.service.formats.result.ORIENTATION`). The group's ``fpscan`` attribute holds ``p0_unit`` (``"Pa"`` or
    ``"a.u."``), ``orientation``, ``method``, ``input_id``, ``description`` and ``axes``.
    Written to a temporary sibling folder, then renamed over ``out_path`` (an existing
    export there is replaced). The volume is read from the result file block by block
    (``dask``'s synchronous scheduler: one block at a time, in the calling thread) as the
    levels are written, so the memory it takes does not grow with the volume.

    Parameters
    ----------
    result_path : str or os.PathLike
        A reconstruction result ``volume.h5`` (``fpscan.service.formats.result``).
    out_path : str or os.PathLike
        The OME-Zarr folder to write.

    Returns
    -------
    pathlib.Path
        ``out_path``.

    Raises
    ------
    FileNotFoundError
        ``result_path`` does not exist.
    ValueError
        Not a result file, uneven coordinates, or ``out_path`` an existing file.
    """
    import dask
    import dask.array as da
    import zarr
    from ome_zarr.format import CurrentFormat
    from ome_zarr.io import parse_url
    from ome_zarr.scale import Methods
    from ome_zarr.writer import write_image

    out_path = Path(out_path)
    if out_path.exists() and not out_path.is_dir():
        raise ValueError(f"{out_path} is a file; an OME-Zarr export is a folder (name it *.ome.zarr)")
    with open_result(result_path) as r, folder_replaced(out_path, temp_sibling(out_path)) as tmp:
        axes, steps = voxel_sizes_um(r, "OME-Zarr")
        names = [a.lower() for a in axes]
        coords = [r.z, r.y, r.x] if len(axes) == 3 else [r.z, r.x]
        origin = [float(f"{np.asarray(v)[0] * 1e6:.12g}") for v in coords]
        fmt = CurrentFormat()
        chunks = tuple(min(int(n), ZARR_CHUNK) for n in r.p0.shape)
        # read block by block as the levels are written: one task at a time, in this thread
        p0 = da.from_array(r.p0, chunks=chunks, lock=True, asarray=True).astype(np.float32)
        root = zarr.group(store=parse_url(str(tmp), mode="w", fmt=fmt).store)
        writes = write_image(p0, root, scale_factors=pyramid_factors(p0.shape, names), method=Methods.LOCAL_MEAN,
                             fmt=fmt, axes=names, scale=dict(zip(names, steps)),
                             axes_units=dict.fromkeys(names, "micrometer"), storage_options={"chunks": chunks},
                             name=f"p0 ({r.method}, {r.input_id})", compute=False)
        dask.compute(*writes, scheduler="synchronous")
        # the writer places level 0 at the origin: every level moves by the first sample's position
        ome: Any = root.attrs["ome"]
        for level in ome["multiscales"][0]["datasets"]:
            for t in level["coordinateTransformations"]:
                if t["type"] == "translation":
                    t["translation"] = [float(f"{o + v:.12g}") for o, v in zip(origin, t["translation"])]
        root.attrs["ome"] = ome
        root.attrs["fpscan"] = {"p0_unit": r.p0_unit, "orientation": ORIENTATION, "method": r.method,
                                "input_id": r.input_id, "description": volume_description(r),
                                "axes": ["z", "y", "x"] if len(axes) == 3 else ["z", "x"]}
    return out_path


FORMAT = Format(rank=120, name="ome-zarr", title="OME-Zarr, NGFF 0.5 (napari; voxel sizes in µm)", container="file",
                export_from="result", export=export_ome_zarr, suffix=".ome.zarr", media_type="application/zip",
                folder=True, noun="an OME-Zarr image")
