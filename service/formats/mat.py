"""MATLAB/Octave ``.mat``: a reconstruction's p0 volume in k-Wave's layout and naming, for a
MATLAB or Octave user (``load('p0.mat')``) and for k-Wave (``source.p0``); an export of a
result ``volume.h5``, written with ``scipy.io.savemat`` as MAT v5 (MATLAB's ``-v7``:
zlib-compressed). No reader here: fpscan's k-Wave MAT-file reader
(:mod:`fpscan.service.formats.kwave_mat`) detects the file and names it an initial pressure,
not a scan to reconstruct.

**Layout.** k-Wave names the depth axis x (``kWaveGrid(Nx, dx, Ny, dy, Nz, dz)``, the sensor
plane at ``x`` index 1 as in k-Wave's planar-sensor examples, ``sensor.mask(1, :, :) = 1``),
and its ``source.p0`` is indexed ``p0(ix, iy, iz)`` on that grid. fpscan's p0 is
``(n_z, n_y, n_x)`` (depth first): the same array, so nothing is transposed, only the axes
are renamed — k-Wave's x is fpscan's depth z, k-Wave's y is fpscan's y, k-Wave's z is
fpscan's lateral x; in 2-D ``(n_z, n_x)`` is k-Wave's ``(Nx, Ny)``: x the depth, y fpscan's
lateral x (the rule :mod:`fpscan.driver.kwave_layout` owns, and that
:mod:`fpscan.service.formats.kwave_mat` reads ``dy``/``dz``/``kgrid.z_vec`` by). In MATLAB,
``size(p0)`` is ``[Nx Ny Nz]`` = ``[n_z n_y n_x]``.

Variables (1-D vectors as MATLAB columns ``(N, 1)``):

==============  ==========================================================================
``p0``          ``(Nx, Ny, Nz)`` (2-D ``(Nx, Ny)``), single (double where the result
                file stores float64); unit ``p0_unit``
``x``           ``(Nx, 1)`` double, m: depth from the sensor plane (fpscan's ``z``)
``y``           ``(Ny, 1)`` double, m: fpscan's ``y`` (3-D); fpscan's lateral ``x`` (2-D)
``z``           ``(Nz, 1)`` double, m: fpscan's lateral ``x`` (3-D only)
``dx``          double, m: the depth spacing (fpscan's ``dz``)
``dy``          double, m: the spacing of ``y``
``dz``          double, m: the spacing of ``z`` (3-D only: fpscan's lateral ``dx``)
``p0_unit``     char: ``'Pa'`` (a calibrated scan) or ``'a.u.'``
``method``      char: the reconstruction method (``'ner'``, ...)
``input_id``    char: the scan job or dataset the volume came from
``axis_order``  char: this layout in words
==============  ==========================================================================

A spacing of an axis of one sample is NaN. MAT v5 holds at most 2 GiB per variable
(:data:`MAX_VARIABLE_BYTES`): a bigger p0 is refused (MAT v7.3, HDF5, would hold it; this
module does not write it).

Sources: k-Wave's documentation of ``kWaveGrid`` (x, y, z; ``Nx``, ``dx``, ...), of
``source.p0`` ("initial pressure within the acoustic medium", an ``Nx × Ny × Nz`` matrix on
the grid) and of ``kspaceFirstOrder3D``'s ``sensor_data`` (``(n_sensors, Nt)``); MATLAB's
``save`` documentation (``-v6``/``-v7``: variables up to 2 GB each; ``-v7.3``, HDF5, for
larger).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.disk import file_replaced
from fpscan.service.formats.registry import Format
from fpscan.service.formats.result import ResultVolume, open_result, read_slabs

__all__ = ["FORMAT", "MAX_VARIABLE_BYTES", "export_mat", "mat_variables"]

#: the most bytes one variable of a MAT v5 file (MATLAB's ``-v6``/``-v7``) may hold: 2 GiB
MAX_VARIABLE_BYTES = 2**31


def _step(v: np.ndarray) -> float:
    """The spacing of a regular coordinate vector (m); NaN for a single sample."""
    return float(v[1] - v[0]) if len(v) > 1 else float("nan")


def _column(v: np.ndarray) -> np.ndarray:
    """A coordinate vector as a float64 ``(N, 1)`` column (MATLAB's ``x_vec`` shape)."""
    return np.asarray(v, dtype=np.float64).reshape(-1, 1)


def mat_variables(r: ResultVolume) -> dict[str, Any]:
    """The variables of the ``.mat`` export of a result volume (module docstring).

    Parameters
    ----------
    r : ResultVolume
        The volume: ``p0`` ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``, coordinates ``z``, ``y``,
        ``x`` in m (:func:`fpscan.service.formats.result.read_result`).

    Returns
    -------
    dict of str to ndarray or str
        ``p0`` in k-Wave's order ``(Nx, Ny, Nz)`` = fpscan's ``(n_z, n_y, n_x)`` (2-D
        ``(Nx, Ny)`` = ``(n_z, n_x)``), float32 unless stored float64; ``x`` (depth), ``y``,
        ``z`` as ``(N, 1)`` float64 columns in m, k-Wave's naming; ``dx``, ``dy`` (, ``dz``)
        spacings in m; ``p0_unit``, ``method``, ``input_id``, ``axis_order`` as text.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.formats.result import ResultVolume
    >>> r = ResultVolume(p0=np.zeros((4, 3), np.float32), z=np.arange(4) * 1e-4,
    ...                  x=np.array([-1e-4, 0.0, 1e-4]), y=None, method="ner", params={}, input_id="abc")
    >>> v = mat_variables(r)
    >>> v["p0"].shape, v["x"].shape, v["y"].shape, "z" in v, round(v["dy"], 6)
    ((4, 3), (4, 1), (3, 1), False, 0.0001)
    """
    p0 = np.asarray(r.p0)
    return {"p0": p0 if p0.dtype == np.float64 else p0.astype(np.float32), **_axis_variables(r, p0.ndim)}


def _axis_variables(r: ResultVolume, ndim: int) -> dict[str, Any]:
    """The variables of :func:`mat_variables` but ``p0``: the axes, their spacings and the texts."""
    lateral = (r.y, r.x) if ndim == 3 and r.y is not None else (r.x,)
    out: dict[str, Any] = {"x": _column(r.z), "dx": _step(r.z)}
    for name, v in zip(("y", "z"), lateral, strict=False):
        out[name] = _column(v)
        out[f"d{name}"] = _step(v)
    if ndim == 3:
        order = ("p0(ix, iy, iz), k-Wave's naming: x = depth from the sensor plane (fpscan z), "
                 "y = fpscan y, z = fpscan lateral x; coordinates in m")
    else:
        order = ("p0(ix, iy), k-Wave's naming: x = depth from the sensor plane (fpscan z), "
                 "y = fpscan lateral x; coordinates in m")
    out.update(p0_unit=r.p0_unit, method=r.method, input_id=r.input_id, axis_order=order)
    return out


def export_mat(result_path: str | os.PathLike, out_path: str | os.PathLike, *,
               max_variable_bytes: int = MAX_VARIABLE_BYTES) -> Path:
    """Write the p0 of a result file and its axes as a MATLAB/Octave MAT v5 file in k-Wave's
    layout (``scipy.io.savemat``, ``format="5"``, zlib-compressed, 1-D as columns; ``p0``, the
    last variable, streamed from the result file in slabs as ``savemat`` would write it, so the
    memory it takes does not grow with the volume).

    Parameters
    ----------
    result_path : str or os.PathLike
        A reconstruction result ``volume.h5`` (``fpscan.service.formats.result``).
    out_path : str or os.PathLike
        The ``.mat`` file to write (a temporary sibling, then renamed into place).
    max_variable_bytes : int, optional
        The most bytes one variable may hold (default :data:`MAX_VARIABLE_BYTES`, MAT v5's
        2 GiB).

    Returns
    -------
    pathlib.Path
        ``out_path``; its variables: :func:`mat_variables` (``p0`` ``(Nx, Ny, Nz)`` =
        fpscan's ``(n_z, n_y, n_x)``, x the depth; module docstring).

    Raises
    ------
    FileNotFoundError
        ``result_path`` does not exist.
    ValueError
        ``result_path`` is not a result file; p0 holds more than ``max_variable_bytes``
        (MAT v5's limit of 2 GiB per variable; MAT v7.3, HDF5, is not written here).

    Examples
    --------
    >>> import numpy as np, scipy.io, fpscan, tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> ds = fpscan.GridDataset(data=np.zeros((8, 4, 5), np.float32), dx=1e-4, dy=1e-4, dt=4e-8, sound_speed=1500.0)
    >>> _ = fpscan.write_result(d / "r", fpscan.reconstruct(ds, "ner"), input_id="zeros")
    >>> m = scipy.io.loadmat(export_mat(d / "r" / "volume.h5", d / "p0.mat"))
    >>> m["p0"].shape[1:], m["z"].shape, str(m["method"][0])
    ((4, 5), (5, 1), 'ner')
    """
    import scipy.io

    with open_result(result_path) as r:
        dtype = _p0_dtype(r.p0)
        nbytes = int(np.prod(r.p0.shape, dtype=np.int64)) * dtype.itemsize
        if nbytes > max_variable_bytes:
            raise ValueError(f"p0 {tuple(r.p0.shape)} {dtype} holds {nbytes} bytes, more than a MAT v5 file's limit "
                             f"of {max_variable_bytes} bytes ({max_variable_bytes / 2**30:g} GiB) per variable; MAT "
                             "v7.3 (HDF5) would hold it but fpscan does not write it: export it as ome-zarr, ome-tiff "
                             "or npz, or read the result volume.h5 (HDF5) with MATLAB's h5read")
        with file_replaced(out_path) as tmp, open(tmp, "wb") as fh:
            scipy.io.savemat(fh, _axis_variables(r, len(r.p0.shape)), format="5", do_compression=True,
                             oned_as="column")
            _append_compressed_matrix(fh, "p0", r.p0, dtype)
    return Path(out_path)


def _p0_dtype(p0: Any) -> np.dtype:
    """The dtype of p0 in the ``.mat`` export: float64 where the result file stores it, else float32."""
    return np.dtype(np.float64) if p0.dtype == np.float64 else np.dtype(np.float32)


#: the most bytes of p0 the export reads at once: a slab along the last axis (column-major order) reads
#: every HDF5 chunk of a compressed result (whole depth rows), so fewer, larger slabs decompress it fewer times
MATRIX_SLAB_BYTES = 16 * 2**20

#: MAT v5 data types and array classes (MathWorks, "MAT-File Format", Tables 1-1 and 1-3)
_MI_INT8, _MI_INT32, _MI_UINT32, _MI_SINGLE, _MI_DOUBLE, _MI_MATRIX, _MI_COMPRESSED = 1, 5, 6, 7, 9, 14, 15
_MX_CLASS = {np.dtype(np.float64): (6, _MI_DOUBLE), np.dtype(np.float32): (7, _MI_SINGLE)}


def _append_compressed_matrix(fh: Any, name: str, array: Any, dtype: np.dtype) -> None:
    """Append ``array`` (an HDF5 dataset or ndarray; float32 or float64) to the open MAT v5
    file ``fh`` as the compressed variable ``name`` (at most 4 characters), read in slabs
    along its last axis, so that its column-major bytes are written in order and the memory
    it takes is a slab's (:data:`MATRIX_SLAB_BYTES`; ``fpscan.service.formats.result.read_slabs``).

    The element is the one ``scipy.io.savemat(..., do_compression=True)`` writes (MathWorks,
    "MAT-File Format", "Compressed Data Elements" and "miMATRIX"): an ``miCOMPRESSED`` tag
    whose byte count is written once the zlib stream is done, then the zlib stream of an
    ``miMATRIX`` element: array flags (class single or double), dimensions (int32), the name
    (a small data element) and the real part (``miSINGLE``/``miDOUBLE``, column-major, padded
    to 8 bytes), in the file's native byte order (that of its header, as scipy writes it).
    """
    import struct
    import zlib

    shape = tuple(int(n) for n in array.shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    mclass, mtype = _MX_CLASS[dtype]
    dims = struct.pack(f"=II{len(shape)}i", _MI_INT32, 4 * len(shape), *shape)
    label = name.encode("ascii")
    assert len(label) <= 4  # one small data element
    header = (struct.pack("=IIII", _MI_UINT32, 8, mclass, 0) + dims + b"\0" * (-len(dims) % 8)
              + struct.pack("=I4s", (len(label) << 16) | _MI_INT8, label) + struct.pack("=II", mtype, nbytes))
    start = fh.tell()
    fh.write(struct.pack("=II", _MI_COMPRESSED, 0))
    stream = zlib.compressobj()
    written = 0

    def put(data: bytes) -> None:
        nonlocal written
        packed = stream.compress(data)
        written += len(packed)
        fh.write(packed)

    put(struct.pack("=II", _MI_MATRIX, len(header) + nbytes + (-nbytes % 8)) + header)
    for slab in read_slabs(array, len(shape) - 1, dtype=dtype, max_bytes=MATRIX_SLAB_BYTES):
        put(slab.tobytes(order="F"))
    put(b"\0" * (-nbytes % 8))
    tail = stream.flush()
    written += len(tail)
    fh.write(tail)
    if written >= 2**32:
        raise ValueError(f"{name} compresses to {written} bytes, more than a MAT v5 element's 4 GiB")
    end = fh.tell()
    fh.seek(start + 4)
    fh.write(struct.pack("=I", written))
    fh.seek(end)


FORMAT = Format(rank=140, name="mat", title="MATLAB/Octave .mat (k-Wave layout)", container="file",
                export_from="result", export=export_mat, suffix=".mat", media_type="application/x-matlab-data",
                noun="a MATLAB .mat file")
