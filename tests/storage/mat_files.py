"""MATLAB MAT-files for the tests, laid out as MATLAB writes them.

MATLAB's ``save -v7.3`` cannot be run here (Octave cannot write it either), so
:func:`write_mat73` writes what it writes: HDF5 behind a 512-byte user block holding the
text header (``MATLAB 7.3 MAT-file, ...``, the subsystem offset, version 0x0200 and the
endian indicator ``IM``), every variable a dataset at the root stored transposed (HDF5 is
row-major, MATLAB column-major: a MATLAB ``(128, 534)`` array is an HDF5 ``(534, 128)``
dataset) with its ``MATLAB_class`` attribute, scalars as ``(1, 1)``, a struct as a group
with ``MATLAB_class = "struct"`` holding its fields. MAT v5 files come from
``scipy.io.savemat`` (the layout Octave's ``save -v6``/``-v7`` writes).
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

__all__ = ["MAT73_HEADER", "write_mat73", "write_mat5"]

MAT73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Nov 25 15:01:37 2026 HDF5 schema 1.00 ."
                .ljust(116, b" ") + b"\x00" * 8 + (0x0200).to_bytes(2, "little") + b"IM").ljust(512, b"\x00")
_CLASS = {np.dtype(np.float64): "double", np.dtype(np.float32): "single", np.dtype(np.int16): "int16",
          np.dtype(np.uint8): "uint8", np.dtype(np.int32): "int32", np.dtype(bool): "logical"}


def _put(group: h5py.Group, name: str, value) -> None:
    if isinstance(value, dict):
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_("struct")
        for k, v in value.items():
            _put(sub, k, v)
        return
    a = np.asarray(value)
    if a.ndim < 2:
        a = a.reshape(1, -1) if a.ndim == 1 else a.reshape(1, 1)
    cls = _CLASS[a.dtype]
    stored = a.astype(np.uint8) if cls == "logical" else a
    ds = group.create_dataset(name, data=np.ascontiguousarray(stored.T))
    ds.attrs["MATLAB_class"] = np.bytes_(cls)
    if cls == "logical":
        ds.attrs["MATLAB_int_decode"] = np.int32(1)


def write_mat73(path: str | Path, variables: dict) -> Path:
    """Write ``variables`` (name -> array in MATLAB's index order, or a dict for a struct)
    as a MATLAB v7.3 MAT-file (module docstring); returns the path."""
    path = Path(path)
    with h5py.File(path, "w", userblock_size=512, libver="earliest") as f:
        for name, value in variables.items():
            _put(f, name, value)
    with open(path, "r+b") as fh:
        fh.write(MAT73_HEADER)
    return path


def write_mat5(path: str | Path, variables: dict, *, compressed: bool = True) -> Path:
    """Write ``variables`` as a MAT v5 file (``scipy.io.savemat``: ``-v7`` compressed by
    default, ``compressed=False`` for ``-v6``); returns the path."""
    import scipy.io

    path = Path(path)
    scipy.io.savemat(path, variables, do_compression=compressed, oned_as="row", appendmat=False)
    return path
