"""NumPy ``.npz``: a reconstruction's p0 volume with its coordinates, for a script that wants
plain arrays (``np.load``) and no HDF5 reader (an export of a result ``volume.h5``; no reader
here).

Added as one file and its entry point in pyproject.toml (docs/plugins.md): the registry
registers it on import (``fpscan.service.plugins``), and ``fpscan export
--format npz``, ``GET /api/jobs/{id}/export/npz``, ``Client.export(job, "npz", ...)`` and the
web page's downloads follow from :data:`FORMAT`.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.disk import file_replaced
from fpscan.service.formats.registry import Format
from fpscan.service.formats.result import open_result, read_slabs

__all__ = ["FORMAT", "export_npz"]


def export_npz(result_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Write the p0 of a result file and its coordinates as an uncompressed NumPy ``.npz``.

    Parameters
    ----------
    result_path : str or os.PathLike
        A reconstruction result ``volume.h5`` (``fpscan.service.formats.result``).
    out_path : str or os.PathLike
        The ``.npz`` file to write (a temporary sibling, then renamed into place); the volume
        is read and written in depth slabs (``fpscan.service.formats.result.read_slabs``), so the
        memory it takes does not grow with the volume.

    Returns
    -------
    pathlib.Path
        ``out_path``. Its arrays: ``p0`` float32 ``(n_z, n_y, n_x)`` (3-D) or ``(n_z, n_x)``
        (2-D), the result file's array order and unit (``p0_unit``: ``"Pa"`` or ``"a.u."``);
        ``z``, ``x`` (and ``y`` in 3-D) float64 coordinate vectors in m; ``method`` and
        ``input_id`` as 0-d strings.

    Raises
    ------
    FileNotFoundError
        ``result_path`` does not exist.
    ValueError
        ``result_path`` is not a result file.

    Examples
    --------
    >>> import numpy as np, fpscan, tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> ds = fpscan.GridDataset(data=np.zeros((8, 4, 4), np.float32), dx=1e-4, dy=1e-4, dt=4e-8, sound_speed=1500.0)
    >>> _ = fpscan.write_result(d / "r", fpscan.reconstruct(ds, "ner"), input_id="zeros")
    >>> out = export_npz(d / "r" / "volume.h5", d / "p0.npz")
    >>> sorted(np.load(out))
    ['input_id', 'method', 'p0', 'p0_unit', 'x', 'y', 'z']
    """
    import zipfile

    from numpy.lib import format as npy

    with open_result(result_path) as r:
        arrays: dict[str, Any] = {"p0": r.p0, "z": r.z, "x": r.x, "p0_unit": np.array(r.p0_unit),
                                  "method": np.array(r.method), "input_id": np.array(r.input_id)}
        if r.y is not None:
            arrays["y"] = r.y
        # as np.savez writes it (uncompressed, each member forced to ZIP64), p0 in depth slabs
        with file_replaced(out_path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
            for name, value in arrays.items():
                with z.open(f"{name}.npy", "w", force_zip64=True) as fh:
                    if name != "p0":
                        npy.write_array(fh, np.asanyarray(value), allow_pickle=False)
                        continue
                    npy.write_array_header_1_0(fh, {"descr": npy.dtype_to_descr(np.dtype(np.float32)),
                                                    "fortran_order": False, "shape": tuple(value.shape)})
                    for slab in read_slabs(value, 0):
                        fh.write(slab.data)
    return Path(out_path)


FORMAT = Format(rank=130, name="npz", title="NumPy .npz (p0, z, y, x in m)", container="file", export_from="result",
                export=export_npz, suffix=".npz", media_type="application/octet-stream",
                noun="a NumPy .npz archive")
