"""MATLAB MAT-files for the tests, laid out as MATLAB writes them.

MATLAB's ``save -v7.3`` cannot be run here (Octave cannot write it either), so
:func:`write_mat73` writes what it writes: HDF5 behind a 512-byte user block holding the
text header (``MATLAB 7.3 MAT-file, ...``, the subsystem offset, version 0x0200 and the
endian indicator ``IM``), every variable a dataset at the root stored transposed (HDF5 is
row-major, MATLAB column-major: a MATLAB ``(128, 534)`` array is an HDF5 ``(534, 128)``
dataset) with its ``MATLAB_class`` attribute, scalars as ``(1, 1)``, a struct as a group
with ``MATLAB_class = "struct"`` holding its fields. MAT v5 files come from
``scipy.io.savemat`` (the layout Octave's ``save -v6``/``-v7`` writes); hostile MAT v5
files are written by hand, element by element (:func:`mat5_file`, :func:`mat5_matrix`,
:func:`mat5_struct`, :func:`mat5_compressed`), as the MAT-file format's reference lays them out
(MathWorks, "MAT-File Format", R2024a: a 128-byte header, then tagged data elements, 8-byte
aligned; ``miMATRIX`` = 14, ``miCOMPRESSED`` = 15, a zlib stream).
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import h5py
import numpy as np

__all__ = ["MAT73_HEADER", "write_mat73", "write_mat5", "MAT5_HEADER", "mat5_element", "mat5_matrix", "mat5_double",
           "mat5_struct", "mat5_compressed", "mat5_zeros_double", "mat5_file"]

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


# ------------------------------------------------------------------ MAT v5 by hand
#: a MAT v5 file's 128-byte header: text, subsystem offset, version 0x0100, endian "IM"
MAT5_HEADER = (b"MATLAB 5.0 MAT-file, written by hand".ljust(116, b" ") + b"\x00" * 8
               + (0x0100).to_bytes(2, "little") + b"IM")
_MI_INT8, _MI_INT32, _MI_UINT32, _MI_DOUBLE, _MI_MATRIX, _MI_COMPRESSED = 1, 5, 6, 9, 14, 15
_MX_STRUCT, _MX_DOUBLE = 2, 6


def mat5_element(mtype: int, data: bytes) -> bytes:
    """A data element: its tag (type, byte count) and ``data`` padded to 8 bytes."""
    return struct.pack("<II", mtype, len(data)) + data + b"\x00" * (-len(data) % 8)


def mat5_matrix(name: str, mx_class: int, dims: tuple[int, ...], body: bytes, *, more: int = 0) -> bytes:
    """A ``miMATRIX`` element: array flags (class ``mx_class``), dimensions, name, then
    ``body`` (the class's own sub-elements); its tag also counts ``more`` bytes that follow
    (zeros :func:`mat5_compressed` appends)."""
    inner = (mat5_element(_MI_UINT32, struct.pack("<II", mx_class, 0))
             + mat5_element(_MI_INT32, struct.pack(f"<{len(dims)}i", *dims))
             + mat5_element(_MI_INT8, name.encode()) + body)
    return struct.pack("<II", _MI_MATRIX, len(inner) + more) + inner


def mat5_double(name: str, values) -> bytes:
    """A double matrix (MATLAB's column-major order) named ``name``."""
    a = np.atleast_2d(np.asarray(values, dtype="<f8"))
    return mat5_matrix(name, _MX_DOUBLE, a.shape, mat5_element(_MI_DOUBLE, a.T.tobytes()))


def mat5_zeros_double(name: str, n: int) -> bytes:
    """The start of an ``(n, 1)`` double matrix of zeros: its tags declare the ``8 n`` bytes of
    zeros, which :func:`mat5_compressed` (``zeros=8 n``) appends."""
    return mat5_matrix(name, _MX_DOUBLE, (n, 1), struct.pack("<II", _MI_DOUBLE, 8 * n), more=8 * n)


def mat5_struct(name: str, fields: dict[str, bytes], *, more: int = 0) -> bytes:
    """A 1x1 struct of ``fields`` (field name -> a ``miMATRIX`` element, its own name empty);
    its tag also counts ``more`` bytes that follow (the zeros of its last field)."""
    names = b"".join(f.encode().ljust(32, b"\x00") for f in fields)
    body = struct.pack("<HHi", _MI_INT32, 4, 32) + mat5_element(_MI_INT8, names) + b"".join(fields.values())
    return mat5_matrix(name, _MX_STRUCT, (1, 1), body, more=more)


def mat5_compressed(element: bytes, *, zeros: int = 0) -> bytes:
    """A ``miCOMPRESSED`` element (not padded, as MATLAB writes it) holding ``element`` and then
    ``zeros`` zero bytes (a whole number of MiB), zlib-compressed. The zeros are never held:
    their deflate stream is one full-flush block of 1 MiB of zeros repeated, the Adler-32
    computed (RFC 1950, RFC 1951) -- an attacker's few kB that declare gigabytes."""
    chunk = 1 << 20
    assert zeros % chunk == 0, "whole MiB of zeros"
    deflate = zlib.compressobj(9, zlib.DEFLATED, -15)
    prefix = deflate.compress(element) + deflate.flush(zlib.Z_FULL_FLUSH)
    block = deflate.compress(bytes(chunk)) + deflate.flush(zlib.Z_FULL_FLUSH) if zeros else b""
    adler = zlib.adler32(element)
    a = adler & 0xFFFF
    b = ((adler >> 16) + zeros * a) % 65521  # over zeros: a unchanged, b grows by a per byte
    z = b"\x78\xda" + prefix + block * (zeros // chunk) + b"\x03\x00" + struct.pack(">I", (b << 16) | a)
    return struct.pack("<II", _MI_COMPRESSED, len(z)) + z


def mat5_file(path: str | Path, *elements: bytes) -> Path:
    """A MAT v5 file of :data:`MAT5_HEADER` and ``elements``; returns the path."""
    path = Path(path)
    path.write_bytes(MAT5_HEADER + b"".join(elements))
    return path
