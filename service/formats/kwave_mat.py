"""k-Wave MAT-files: ``sensor_data`` as a k-Wave user saves it with MATLAB's or Octave's
``save`` → :class:`fpscan.service.recon.dataset.GridDataset`.

Two containers, one format (sniffed from the content, never the suffix):

- **MAT v5** (MATLAB's ``-v7`` default, zlib-compressed, and ``-v6``, uncompressed; Octave
  writes both): a 128-byte text header (``MATLAB 5.0 MAT-file``), then one data element
  per variable. Read with ``scipy.io.loadmat`` after this module has walked the file
  element by element under a running byte budget, before scipy decodes anything: every
  compressed element inflated, nested ones too (a compressed element whose content is
  compressed again), no further than asked and each element's bytes counted before they are
  inflated — all layers together at most ``fpscan.service.formats.untrusted.MAX_RATIO``
  times the file's bytes (+ 1 MiB), the rule every HDF5 input obeys — and every variable
  read sized from what it declares (each field of a struct or cell, nested or not: its
  elements × its class's size), the uncompressed variables and the arrays read together at
  most ``max_bytes``. A zlib bomb, however it is nested, is refused before its bytes are
  decoded. The variables are held once, uncompressed, in one buffer written as they are
  read, which scipy then reads; a variable declaring more than 64 dimensions is refused as
  corrupt (k-Wave's have at most 4).
- **MAT v7.3** (``save -v7.3``): HDF5 behind a 512-byte text header (``MATLAB 7.3
  MAT-file``). The registry opens it past the header and checks it like every HDF5 input
  (``fpscan.service.formats.untrusted.check_hdf5_file``: no external links or storage, no virtual
  datasets, no dataset declaring more than it stores, none nor all together more than
  ``max_bytes``), and the variables read are sized from what their datasets declare, every
  struct field and each link to it counted, against ``max_bytes`` before any is read; here it is
  read with h5py as MATLAB lays it out: each variable a dataset (or a group for a
  struct) with a ``MATLAB_class`` attribute, stored transposed (HDF5's row-major shape is
  MATLAB's column-major shape reversed), ``MATLAB_empty`` for empty arrays.

What is read (names as k-Wave's examples save them; options first, then the file):

- the data: the variable ``key`` (a ``struct.field`` path allowed), else ``sensor_data``
  (a struct — k-Wave's ``sensor.record`` output — gives its field ``p``), else the file's
  only numeric 2-/3-D variable. Layouts:

  * ``(n_sensors, n_t)``, k-Wave's own (one row per sensor in the order of the sensor
    mask's linear indices): a line of sensors → ``(n_t, n_x)``; with a sensor mask in the
    file (``sensor_mask``, or ``sensor.mask`` of a saved ``sensor`` struct) that is one
    full plane of a 3-D grid (k-Wave ``(Nx, Ny, Nz)``, depth x) → ``(n_t, n_y, n_x)``
    (our y = k-Wave's y, our x = k-Wave's z; ``reshape(sensor_data, Ny, Nz, Nt)`` then
    ``permute([3 1 2])`` as k-Wave's examples do). A 2-D array whose first axis has
    ``Nt`` (``Nt`` or ``kgrid.Nt`` in the file) samples is already time first
    (``sensor_data.'``, kspaceLineRecon's ``p_ty``).
  * ``(n_t, n_y, n_x)`` after that reshape (kspacePlaneRecon's ``p_tyz``), read as is.
- ``dt`` (s): the option, else ``kgrid.dt`` or a variable ``dt``.
- the lateral spacings (m): the options, else ``kgrid.dy`` / ``kgrid.dz`` or variables
  ``dy`` / ``dz``, k-Wave's naming (depth is k-Wave's x: our x is k-Wave's y in 2-D and
  its z in 3-D; the rule's one owner is :mod:`fpscan.driver.kwave_layout`), else a variable
  ``dx`` for every lateral axis (a grid of equal spacings, as ``kWaveGrid(Nx, dx, Ny, dx)``).
- the sound speed (m/s): the option, else ``c0``, ``c``, ``sound_speed`` or a scalar
  ``medium.sound_speed``, else 1500.

- the lateral coordinates (``GridDataset.lateral_shift``): ``kgrid.z_vec``/``kgrid.y_vec``
  (3-D; ``kgrid.y_vec`` in 2-D) of a saved ``struct(kgrid)`` where their lengths match the
  data's, else k-Wave's own ``kWaveGrid`` convention ``(i - floor(N/2))·dx`` (a k-Wave user's
  overlays on ``kgrid`` line up).

A saved ``kWaveGrid`` object (a MATLAB class instance) is opaque outside MATLAB: save its
``dt``, ``dx``, ... as plain variables, or ``kgrid = struct(kgrid)``. Sample 0 is at t = 0
(k-Wave's ``kgrid.t_array``).
"""
from __future__ import annotations

import io
import struct
import warnings
import zlib
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.driver import kwave_layout
from fpscan.service.formats.load_options import KwaveOptions
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import MAX_ELEMENTS, GridDataset, grid_array, lateral_shift_of, positive

__all__ = ["FORMAT", "sniff", "load", "V5_TEXT", "V73_TEXT", "read_variables"]

#: the start of a MAT v5 file's text header (MATLAB ``-v6``/``-v7`` and Octave alike)
V5_TEXT = b"MATLAB 5.0 MAT-file"
#: the start of a MAT v7.3 file's text header (HDF5 behind 512 bytes)
V73_TEXT = b"MATLAB 7.3 MAT-file"
_MI_INT8, _MI_INT32, _MI_MATRIX, _MI_COMPRESSED = 1, 5, 14, 15
#: the variables this format looks at besides the data (the rest of a file is not decoded)
_NAMES = ("dt", "dx", "dy", "dz", "Nt", "c0", "c", "sound_speed", "kgrid", "medium", "sensor", "sensor_mask",
          "p0", "p0_true", "source")
_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
            "logical"}


def sniff(source: Source) -> bool:
    """True for a MAT v5 file (text header and the version/endian bytes at 124-127) or a
    MAT v7.3 file (its text header, HDF5 behind it).

    Parameters
    ----------
    source : Source
        The opened file (MAT v5) or HDF5 file (MAT v7.3) (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    head = source.head
    if source.h5 is not None:
        return head.startswith(V73_TEXT)
    return head.startswith(V5_TEXT) and len(head) >= 128 and head[126:128] in (b"IM", b"MI")


# ----------------------------------------------------------------------------- MAT v5
#: MAT v5 classes (the ``mxCLASS`` of an array's flags; MathWorks, "MAT-File Format")
_MX_CELL, _MX_STRUCT, _MX_OBJECT, _MX_CHAR, _MX_SPARSE, _MX_OPAQUE = 1, 2, 3, 4, 5, 17
#: bytes per element of each numeric class as ``loadmat(mat_dtype=True)`` returns it
_MX_ITEMSIZE = {6: 8, 7: 4, 8: 1, 9: 1, 10: 2, 11: 2, 12: 4, 13: 4, 14: 8, 15: 8}
_MX_NAMES = {1: "cell", 2: "struct", 3: "object", 4: "char", 5: "sparse", 6: "double", 7: "single", 8: "int8",
             9: "uint8", 10: "int16", 11: "uint16", 12: "int32", 13: "uint32", 14: "int64", 15: "uint64",
             16: "function_handle", 17: "opaque"}
#: what one decoded array costs besides its elements: its Python object and, for a cell or
#: struct, its slot in the parent (counted per element of a cell or struct array too)
_OBJECT_BYTES = 256
#: a char array decodes to 4 bytes a character (numpy ``U1``) and is joined into strings: 8
_CHAR_BYTES = 8
#: the deepest nesting of compressed layers and of arrays in arrays that is read
_MAX_DEPTH = 16
#: compressed bytes read at once from a layer below
_CHUNK = 1 << 16
#: bytes copied at once into the uncompressed stream (a variable's body, read or inflated)
_COPY_CHUNK = 1 << 20
#: the most dimensions a variable may declare: k-Wave's arrays have at most 4 (a 3-D grid and
#: time), MATLAB's own data rarely more than a handful; 64 keeps any plausible array while a
#: hostile one of 100 000 dimensions (4 bytes each, a few kB once compressed) is refused before
#: their product is formed (each a Python int multiplication: quadratic in their number)
_MAX_DIMS = 64


class _Budget:
    """The running bytes budget of one MAT v5 import: ``inflate`` is what every zlib layer
    together may still produce, ``hold`` what the import may still hold decoded."""

    def __init__(self, inflate: int, hold: int, stored: int, max_bytes: int):
        self.inflate, self.hold, self.stored, self.max_bytes = inflate, hold, stored, max_bytes

    def inflated(self, n: int) -> None:
        """Before ``n`` more bytes come out of a compressed layer."""
        from fpscan.service.formats.untrusted import MAX_RATIO

        self.inflate -= n
        if self.inflate < 0:
            raise ValueError(f"a compressed variable of the MAT-file inflates beyond {self._ratio_limit()} bytes "
                             f"through its compressed layers (the file stores {self.stored}: more than "
                             f"{MAX_RATIO}:1, or above the size limit; refused)")

    def _ratio_limit(self) -> int:
        from fpscan.service.formats.untrusted import MAX_RATIO, SMALL_BYTES

        return min(self.max_bytes, MAX_RATIO * self.stored + SMALL_BYTES)

    def held(self, n: int, what: str) -> None:
        """Before ``n`` more bytes are held decoded (``what`` for the reason)."""
        self.hold -= n
        if self.hold < 0:
            raise ValueError(f"the MAT-file's {what} need more than the import's limit of {self.max_bytes} bytes "
                             "decoded (refused before decoding)")


class _Layer:
    """The bytes of a MAT v5 element stream: the file itself (``stored`` None) or the zlib
    stream of a compressed element (``stored`` compressed bytes of the layer ``below``),
    inflated no further than asked (``zlib.decompressobj().decompress(data, max_length)``)."""

    def __init__(self, below: Any, stored: int | None = None):
        self.below, self.left = below, stored
        self.inflater = zlib.decompressobj() if stored is not None else None
        self.tail = b""

    def read(self, n: int) -> bytes:
        """Up to ``n`` bytes (fewer only at the end of the stream)."""
        if self.inflater is None:
            return self.below.read(n)
        out: list[bytes] = []
        need = n
        while need > 0 and not self.inflater.eof:
            data = self.tail
            if not data:
                if not self.left:
                    break
                data = self.below.read(min(_CHUNK, self.left))
                if not data:
                    raise ValueError("the MAT-file is truncated (a compressed variable is cut)")
                self.left -= len(data)
            try:
                chunk = self.inflater.decompress(data, need)
            except zlib.error:
                raise ValueError("the MAT-file is corrupt (a compressed variable does not inflate)") from None
            self.tail = self.inflater.unconsumed_tail
            out.append(chunk)
            need -= len(chunk)
        return b"".join(out)

    def copy_to(self, sink: io.BytesIO, n: int, what: str) -> None:
        """Write the next ``n`` bytes into ``sink``, :data:`_COPY_CHUNK` at a time (no copy
        of the whole is made). Raises ValueError when the stream ends first."""
        left = n
        while left > 0:
            data = self.read(min(left, _COPY_CHUNK))
            if not data:
                raise ValueError(f"the MAT-file is truncated ({what} declares {n} bytes, {n - left} are there)")
            sink.write(data)
            left -= len(data)

    def skip(self, n: int) -> None:
        """Past ``n`` bytes, in chunks (a compressed layer's are inflated and dropped)."""
        while n > 0:
            got = len(self.read(min(n, 1 << 20)))
            if not got:
                raise ValueError("the MAT-file is truncated (an element is cut)")
            n -= got

    def close(self) -> None:
        """Past the rest of this layer's compressed bytes in the layer below (not inflated)."""
        if self.left:
            self.below.skip(self.left)
            self.left = 0


def _elements(layer: _Layer, endian: str, budget: _Budget, out: io.BytesIO, sizes: list[tuple[str, str, int]],
              depth: int = 0) -> None:
    """Every element of ``layer`` (the file, or a compressed element's stream): each
    variable (``miMATRIX``) written to ``out`` uncompressed, as it is read, with its name, class and
    decoded size (:func:`_matrix_size`, read in ``out`` itself) in ``sizes``; each compressed element inflated in
    turn, however deeply nested, its bytes counted (``budget.inflated``) before they are
    inflated and the variables' bytes (``budget.held``) before they are read."""
    inflating = depth > 0
    while True:
        tag = layer.read(8)
        if not tag:
            return
        if len(tag) < 8:
            raise ValueError("the MAT-file is truncated (an element's tag is cut)")
        mtype, nbytes = struct.unpack(endian + "II", tag)
        if mtype >> 16:  # a small data element (its data inside the tag): no variable
            if inflating:
                budget.inflated(8)
            continue
        if inflating:
            budget.inflated(8 + nbytes)
        if mtype == _MI_COMPRESSED:
            if depth >= _MAX_DEPTH:
                raise ValueError(f"the MAT-file nests compressed elements more than {_MAX_DEPTH} deep (refused)")
            inner = _Layer(layer, nbytes)
            _elements(inner, endian, budget, out, sizes, depth + 1)
            inner.close()
        elif mtype == _MI_MATRIX:
            budget.held(8 + nbytes, "variables")
            start = out.tell() + 8
            out.write(tag)
            layer.copy_to(out, nbytes, "a variable")
            sizes.append(_sized(out, start, nbytes, endian, budget.max_bytes))
        else:  # any other top-level element is not a variable: skipped
            layer.skip(nbytes)


def _sized(out: io.BytesIO, start: int, nbytes: int, endian: str, cap: int) -> tuple[str, str, int]:
    """:func:`_matrix_size` of the variable body at ``start`` of ``out`` (``nbytes`` long), read
    in place: the view of ``out`` is released before ``out`` grows again."""
    with out.getbuffer() as whole:
        return _matrix_size(whole[start:start + nbytes], endian, 0, cap)


def _sub_elements(buf: memoryview, endian: str) -> Iterator[tuple[int, memoryview]]:
    """The data elements packed in ``buf`` (a variable's body), one by one: (type, data),
    small (data in the tag) or not (8-byte aligned). Raises ValueError for one cut short."""
    pos, end = 0, len(buf)
    while pos + 8 <= end:
        mtype, nbytes = struct.unpack_from(endian + "II", buf, pos)
        if mtype >> 16:  # small: the byte count in the upper half, the data in the tag's last 4 bytes
            small = mtype >> 16
            if small > 4:
                raise ValueError("the MAT-file is corrupt (a small element holds more than 4 bytes)")
            yield mtype & 0xFFFF, buf[pos + 4:pos + 4 + small]
            pos += 8
            continue
        if pos + 8 + nbytes > end:
            raise ValueError("the MAT-file is corrupt (an element runs past its variable)")
        yield mtype, buf[pos + 8:pos + 8 + nbytes]
        pos += 8 + nbytes + (-nbytes % 8)


def _declared(cls: int, flags: int, subs: Iterator[tuple[int, memoryview]], stored: int,
              endian: str, cap: int) -> tuple[str, int, int]:
    """A variable's name, its number of elements (saturated at ``cap + 1``) and what it decodes
    to besides its nested arrays (:func:`_matrix_size`), from its dimensions and name (the next
    two of ``subs``; none in an opaque object's, whose ``stored`` bytes count twice). More than
    :data:`_MAX_DIMS` dimensions are refused."""
    if cls == _MX_OPAQUE:  # no dimensions or name: three strings and the object's data
        return "", 1, _OBJECT_BYTES + 2 * stored
    dims, named = next(subs, None), next(subs, None)
    if dims is None or named is None or dims[0] != _MI_INT32 or len(dims[1]) % 4:
        raise ValueError("the MAT-file is corrupt (a variable without its dimensions and name)")
    n_dims = len(dims[1]) // 4
    if n_dims > _MAX_DIMS:
        raise ValueError(f"the MAT-file is corrupt (a variable declares {n_dims} dimensions; at most {_MAX_DIMS} "
                         "are read)")
    n = 1
    for d in struct.unpack_from(f"{endian}{n_dims}i", dims[1]):
        if d < 0:
            raise ValueError("the MAT-file is corrupt (a negative dimension)")
        n = min(n * d, cap + 1)  # saturated: beyond the cap the size is refused anyway
    name = bytes(named[1]).split(b"\0", 1)[0].decode("latin-1")
    if cls in _MX_ITEMSIZE:
        per = 1 if flags & 0x200 else _MX_ITEMSIZE[cls]  # logical: bool
        return name, n, _OBJECT_BYTES + n * per * (2 if flags & 0x800 else 1)
    if cls == _MX_CHAR:
        return name, n, _OBJECT_BYTES + n * _CHAR_BYTES
    if cls in (_MX_CELL, _MX_STRUCT, _MX_OBJECT):  # a slot per element; per field once the names are read
        return name, n, _OBJECT_BYTES + n * (8 + _OBJECT_BYTES)
    return name, n, _OBJECT_BYTES + 2 * stored  # sparse, function handles: their parts as stored, twice over


def _matrix_size(body: memoryview, endian: str, depth: int, cap: int) -> tuple[str, str, int]:
    """A variable's (``miMATRIX`` body's) name, class and the bytes it decodes to in
    ``loadmat(mat_dtype=True, simplify_cells=True)``, from what it declares, before any of
    it is decoded: numeric arrays their elements × their class's size (× 2 complex), char
    arrays :data:`_CHAR_BYTES` a character, cell and struct arrays a slot per element (and
    field) and their elements' own sizes, nested however deep; every array
    :data:`_OBJECT_BYTES` more. The walk stops once the size passes ``cap`` (then
    ``cap + 1``): it holds nothing per element. A compressed element inside a variable (not
    something MATLAB writes) is refused. Raises ValueError."""
    if depth > _MAX_DEPTH:
        raise ValueError(f"the MAT-file nests arrays in arrays more than {_MAX_DEPTH} deep (refused)")
    subs = _sub_elements(body, endian)
    first = next(subs, None)
    if first is None or len(first[1]) < 8:
        raise ValueError("the MAT-file is corrupt (a variable without its array flags)")
    flags = struct.unpack_from(endian + "I", first[1])[0]
    cls = flags & 0xFF
    label = _MX_NAMES.get(cls, str(cls))
    name, n, decoded = _declared(cls, flags, subs, len(body), endian, cap)
    fields, length = 1, 0
    for mtype, data in subs:
        if decoded > cap:
            break
        if mtype == _MI_COMPRESSED:
            raise ValueError("the MAT-file holds a compressed element inside a variable (MATLAB never writes one; "
                             "refused)")
        if mtype == _MI_MATRIX:
            decoded += _matrix_size(data, endian, depth + 1, cap - decoded)[2]
        elif cls in (_MX_STRUCT, _MX_OBJECT) and mtype == _MI_INT32 and not length and len(data) >= 4:
            length = struct.unpack_from(endian + "i", data)[0]  # the field names' length, then the names
        elif cls in (_MX_STRUCT, _MX_OBJECT) and mtype == _MI_INT8 and length > 0 and fields == 1:
            fields = max(len(data) // length, 1)
            decoded += n * (fields - 1) * (8 + _OBJECT_BYTES)
    return name, label, min(decoded, cap + 1)


def _inflated_v5(fh: BinaryIO, max_bytes: int) -> tuple[io.BytesIO, list[tuple[str, str, int]], _Budget]:
    """The MAT v5 file open in ``fh`` as an uncompressed v5 file (header and variables,
    every compressed element inflated, nested ones too) in one ``io.BytesIO``, written as the
    elements are read (held once: no list of parts joined), each variable's (name, class,
    decoded bytes) and what is left of the budget. Inflates at most ``MAX_RATIO`` times the
    file's bytes (+ ``SMALL_BYTES``) through all layers together and holds at most
    ``max_bytes``, each element's bytes counted before it is inflated. Raises ValueError."""
    import os

    from fpscan.service.formats.untrusted import MAX_RATIO, SMALL_BYTES

    fh.seek(0)
    header = fh.read(128)
    if len(header) < 128:
        raise ValueError("the MAT-file is truncated (no complete header)")
    endian = "<" if header[126:128] == b"IM" else ">"
    stored = os.fstat(fh.fileno()).st_size
    budget = _Budget(min(max_bytes, MAX_RATIO * stored + SMALL_BYTES), max_bytes, stored, max_bytes)
    out = io.BytesIO()
    out.write(header)
    sizes: list[tuple[str, str, int]] = []
    _elements(_Layer(fh), endian, budget, out, sizes)
    out.seek(0)
    return out, sizes, budget


def _v5_variables(fh: BinaryIO, names: set[str] | None, max_bytes: int,
                  unless: str | None = None) -> tuple[dict[str, Any], list[str]]:
    """The variables ``names`` (None: every one; every one too when the file has no variable
    ``unless``) of the MAT v5 file in ``fh`` (scipy's ``simplify_cells`` form: arrays
    squeezed, structs as dicts) that are numeric, logical, char or structs, and every
    variable's name. Their decoded bytes (:func:`_matrix_size`) are counted against what
    is left of ``max_bytes`` before ``scipy.io.loadmat`` decodes them. Raises ValueError."""
    import scipy.io

    stream, sizes, budget = _inflated_v5(fh, max_bytes)
    listed = [n for n, _, _ in sizes]
    readable = {n for n, cls, _ in sizes if cls in _NUMERIC | {"char", "struct"}}
    if names is None or (unless is not None and unless not in readable):
        names = set(listed)
    wanted = sorted(readable & names)
    if not wanted:
        return {}, listed
    budget.held(sum(d for n, _, d in sizes if n in wanted), "variables " + ", ".join(wanted))
    try:
        with warnings.catch_warnings():  # mat_dtype casts a complex variable to its real part, warning only
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            got = scipy.io.loadmat(stream, variable_names=wanted, simplify_cells=True, mat_dtype=True)
    except MemoryError:
        raise
    except np.exceptions.ComplexWarning:
        raise ValueError("the MAT-file holds complex numbers where k-Wave's are real (sensor data, dt, the grid, "
                         "the speed of sound): arrays must be real") from None
    except Exception as exc:  # scipy raises many kinds on a damaged file
        raise ValueError(f"the MAT-file is not readable ({type(exc).__name__})") from None
    return {k: v for k, v in got.items() if not k.startswith("__")}, listed


# --------------------------------------------------------------------------- MAT v7.3
def _h5_value(obj: Any, depth: int = 0) -> Any:
    """A MAT v7.3 variable as scipy's ``simplify_cells`` gives it: a numeric/logical array
    (MATLAB's shape: HDF5's reversed) squeezed, a char array as text, a struct as a dict of
    its fields; None for what has no plain value here (cells, objects, function handles)."""
    import h5py

    cls = obj.attrs.get("MATLAB_class")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls) if cls is not None else ""
    if isinstance(obj, h5py.Group):
        if cls != "struct" or depth > 4:
            return None
        return {k: _h5_value(v, depth + 1) for k, v in obj.items()}
    if not isinstance(obj, h5py.Dataset):
        return None
    if obj.attrs.get("MATLAB_empty"):
        return np.zeros((0,))
    if cls in _NUMERIC:
        a = obj[()]
        if a.dtype.names and {"real", "imag"} <= set(a.dtype.names):
            a = a["real"] + 1j * a["imag"]
        return np.squeeze(np.asarray(a).T)
    if cls == "char":
        return "".join(map(chr, np.asarray(obj[()]).T.ravel()))
    return None


#: the most arrays and struct fields of a MAT v7.3 file's variables that are read
_MAX_H5_OBJECTS = 100_000


def _h5_size(obj: Any, seen: list[int], depth: int = 0) -> int:
    """The bytes :func:`_h5_value` would decode ``obj`` to, from what its datasets declare
    (shape × type), before any is read: every field of a struct, nested or not, each link
    followed as :func:`_h5_value` follows it (a dataset linked twice counts twice), every
    array :data:`_OBJECT_BYTES` more, a char array :data:`_CHAR_BYTES` a character, a complex
    one twice. ``seen[0]`` counts the objects visited (at most :data:`_MAX_H5_OBJECTS`, else
    ValueError)."""
    import h5py

    seen[0] += 1
    if seen[0] > _MAX_H5_OBJECTS:
        raise ValueError(f"the MAT-file's variables hold more than {_MAX_H5_OBJECTS} arrays and struct fields "
                         "(refused)")
    cls = obj.attrs.get("MATLAB_class")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls) if cls is not None else ""
    if isinstance(obj, h5py.Group):
        if cls != "struct" or depth > 4:
            return _OBJECT_BYTES
        return _OBJECT_BYTES + sum(_h5_size(v, seen, depth + 1) for v in obj.values())
    if not isinstance(obj, h5py.Dataset) or obj.attrs.get("MATLAB_empty"):
        return _OBJECT_BYTES
    n = int(np.prod(obj.shape, dtype=object)) if obj.shape is not None else 0
    if cls == "char":
        return _OBJECT_BYTES + n * _CHAR_BYTES
    if cls in _NUMERIC:
        complex_ = obj.dtype.names is not None and {"real", "imag"} <= set(obj.dtype.names)
        return _OBJECT_BYTES + n * obj.dtype.itemsize * (2 if complex_ else 1)
    return _OBJECT_BYTES


def _h5_variables(f: Any, names: set[str], max_bytes: int) -> tuple[dict[str, Any], list[str]]:
    """The variables ``names`` of an open MAT v7.3 file (:func:`_h5_value`) and every
    variable's name (MATLAB's ``#refs#`` and ``#subsystem#`` groups are not variables).
    What they decode to (:func:`_h5_size`) is counted against ``max_bytes`` before any is
    read. Raises ValueError."""
    listed = [k for k in f.keys() if not k.startswith("#")]
    wanted = [k for k in listed if k in names]
    seen = [0]
    need = sum(_h5_size(f[k], seen) for k in wanted)
    if need > max_bytes:
        raise ValueError(f"the MAT-file's variables {', '.join(wanted)} declare {need} bytes decoded (every field, "
                         f"nested or not, each link counted), more than the import's limit of {max_bytes} bytes "
                         "(refused before decoding)")
    return {k: _h5_value(f[k]) for k in wanted}, listed


def read_variables(source: Source, names: set[str], *, max_bytes: int = MAX_ELEMENTS * 8) -> tuple[dict, list[str]]:
    """The variables ``names`` of the MAT-file ``source`` and the names of all its variables.

    Parameters
    ----------
    source : Source
        The opened MAT-file (v5: ``source.fh``; v7.3: ``source.h5``).
    names : set of str
        The variables to read (top-level names).
    max_bytes : int, optional
        The most bytes a MAT v5 file may take decoded: its variables as held uncompressed
        and the arrays of those read (every field of a struct, nested or not), each counted
        from what it declares before it is decoded; and what its compressed elements
        inflate to, through every layer, at most ``fpscan.service.formats.untrusted.MAX_RATIO``
        times the file's bytes (+ 1 MiB). A v7.3 file: what the variables read declare
        (every field of a struct, nested or not, each link counted), before any is read
        (its datasets were checked when it was opened:
        ``fpscan.service.formats.untrusted.check_hdf5_file``).

    Returns
    -------
    tuple of (dict, list of str)
        The variables found, by name (a struct's value is a dict of its fields, arrays in
        MATLAB's index order, squeezed; what has no plain value is left out or None), and the
        names of every variable in the file.

    Raises
    ------
    ValueError
        A file that is not open, truncated or corrupt, or that decodes beyond the limits.
    """
    return _read(source, names, max_bytes)


def _read(source: Source, names: set[str], max_bytes: int, unless: str | None = None) -> tuple[dict, list[str]]:
    """:func:`read_variables`, reading every variable instead where the file has no variable
    ``unless`` among them (in one pass of a MAT v5 file)."""
    if source.h5 is not None:
        variables, listed = _h5_variables(source.h5, names, max_bytes)
        if unless is not None and unless not in variables:
            del variables
            variables, listed = _h5_variables(source.h5, set(listed), max_bytes)
        return variables, listed
    if source.fh is None:
        raise ValueError("the MAT-file is not open")
    return _v5_variables(source.fh, names, max_bytes, unless)


# ----------------------------------------------------------------------------- layout
def _get(variables: dict, path: str) -> Any:
    """``path`` (``name`` or ``struct.field``) in ``variables``; None when absent."""
    value: Any = variables
    for part in path.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def _scalar(value: Any, name: str) -> float | None:
    """A one-element numeric value as a float; None for None; ValueError for anything else."""
    if value is None:
        return None
    a = np.asarray(value)
    if a.dtype.kind not in "biuf" or a.size != 1:
        raise ValueError(f"{name} in the MAT-file must be one real number, got {a.dtype} {a.shape}")
    return float(a.ravel()[0])


def _first(variables: dict, *paths: str) -> tuple[float | None, str | None]:
    """The first of ``paths`` present as a scalar, with its path; (None, None)."""
    for p in paths:
        value = _get(variables, p)
        if value is not None:
            return _scalar(value, p), p
    return None, None


def _data_array(variables: dict, key: str | None, listed: list[str]) -> tuple[np.ndarray, str]:
    """The data variable (module docstring) and its name. Raises ValueError naming what
    the file holds."""
    if key is not None:
        value = _get(variables, key)
        if value is None:
            raise ValueError(f"no variable {key!r} in the MAT-file (variables: {', '.join(listed) or 'none'})")
        name = key
    elif "sensor_data" in variables:
        value, name = variables["sensor_data"], "sensor_data"
    else:
        found = [k for k, v in variables.items() if isinstance(v, np.ndarray) and v.ndim in (2, 3)
                 and k not in _NAMES]
        p0 = [p for p in ("p0", "p0_true", "source.p0") if _get(variables, p) is not None]
        if not found and p0:  # k-Wave's input, not its output
            raise ValueError(f"the MAT-file holds an initial pressure {p0[0]} (a phantom: k-Wave's source.p0) but no "
                             f"sensor data (variables: {', '.join(listed) or 'none'}): it is a phantom, not a scan to "
                             "reconstruct")
        if len(found) != 1:
            raise ValueError(f"no variable sensor_data in the MAT-file and cannot tell which holds the data "
                             f"(variables: {', '.join(listed) or 'none'}); give key")
        value, name = variables[found[0]], found[0]
    if isinstance(value, dict):  # k-Wave's sensor.record output: a struct of what was recorded
        if "p" not in value:
            raise ValueError(f"{name} is a struct without a field p (fields: {', '.join(value)}); give key")
        value, name = value["p"], f"{name}.p"
    a = np.asarray(value)
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name} must hold real numbers, got {a.dtype}")
    return a, name


def _mask(variables: dict) -> np.ndarray | None:
    """The saved sensor mask (``sensor_mask`` or ``sensor.mask``) as a boolean array, or None."""
    m = _get(variables, "sensor_mask")
    if m is None:
        m = _get(variables, "sensor.mask")
    if m is None:
        return None
    m = np.asarray(m)
    return m != 0 if m.dtype.kind in "biuf" else None


def _time_first(a: np.ndarray, n_t: int | None, mask: np.ndarray | None, name: str) -> tuple[np.ndarray, str]:
    """``a`` in k-Wave's ``(n_sensors, n_t)`` or time-first layout as ``(n_t, n_x)`` /
    ``(n_t, n_y, n_x)``, and the layout read (module docstring). Raises ValueError."""
    if a.ndim == 3:
        if n_t is not None and a.shape[0] != n_t and a.shape[2] == n_t:  # (n_y, n_x, n_t): time last
            return np.ascontiguousarray(np.transpose(a, (2, 0, 1))), "(n_y, n_x, n_t)"
        return a, "(n_t, n_y, n_x)"
    if a.ndim != 2:
        raise ValueError(f"{name} must be (n_sensors, n_t) or (n_t, n_y, n_x), got shape {a.shape}")
    if n_t is not None and a.shape[0] == n_t and a.shape[1] != n_t:
        return a, "(n_t, n_x)"
    if n_t is not None and a.shape[1] != n_t:
        raise ValueError(f"{name} has shape {a.shape} but the file's Nt is {n_t}")
    n_s = a.shape[0]
    if mask is None or mask.ndim < 2 or mask.ndim > 3:
        return np.ascontiguousarray(a.T), "(n_sensors, n_t): a line of sensors"
    if int(mask.sum()) != n_s:
        raise ValueError(f"the sensor mask holds {int(mask.sum())} points but {name} has {n_s} rows")
    rows = np.flatnonzero(mask.reshape(mask.shape[0], -1).any(axis=1))
    plane = mask[rows[0]] if len(rows) == 1 else None
    if plane is None or not plane.all():
        raise ValueError(f"the sensor mask is not one full {'row' if mask.ndim == 2 else 'plane'} of the grid "
                         "(fpscan reads a line or plane of sensors on one depth; save the data of a sparse mask "
                         "as an fpscan scan file or on the full lattice)")
    if mask.ndim == 2:
        return np.ascontiguousarray(a.T), "(n_sensors, n_t): a line of sensors (sensor mask)"
    n_y, n_z = plane.shape  # mask order: k-Wave's y fastest, then z
    cube = a.reshape(n_z, n_y, a.shape[1])  # [iz, iy, t]
    return np.ascontiguousarray(np.transpose(cube, (2, 1, 0))), "(n_sensors, n_t): a plane of sensors (sensor mask)"


def _ground_truth(variables: dict, data: np.ndarray, dz: float | None) -> dict:
    """``{"p0", "p0_dz"}`` from a ``p0``, ``p0_true`` or ``source.p0`` whose lateral shape
    is the data's (k-Wave's ``(Nx, Ny[, Nz])``, depth first, is ours); ``{}`` when none."""
    for path in ("p0_true", "p0", "source.p0"):
        p0 = _get(variables, path)
        if p0 is None:
            continue
        p0 = np.asarray(p0)
        if p0.dtype.kind in "biuf" and p0.ndim == data.ndim and p0.shape[1:] == data.shape[1:]:
            return {"p0": p0.astype(np.float64), **({"p0_dz": dz} if dz is not None else {})}
    return {}


def load(source: Source, *, key: str | None = None, dt: float | None = None, dx: float | None = None,
         dy: float | None = None, sound_speed: float | None = None, ground_truth: bool = False,
         max_bytes: int = MAX_ELEMENTS * 8, **_: Any) -> GridDataset:
    """The MAT-file's sensor data as grid data (module docstring).

    Parameters
    ----------
    source : Source
        The opened MAT-file.
    key : str, optional
        The data variable (a ``struct.field`` path allowed; default ``sensor_data``, else the
        file's only numeric 2-/3-D variable).
    dt : float, optional
        Sample interval, s (default ``kgrid.dt`` or a variable ``dt``).
    dx, dy : float, optional
        Lateral pitches, m (default from the file, module docstring; ``dy`` 3-D only).
    sound_speed : float, optional
        Sound speed, m/s (default ``c0``, ``c``, ``sound_speed`` or ``medium.sound_speed``,
        else 1500).
    ground_truth : bool, optional
        Also the file's p0 (``p0_true``, ``p0`` or ``source.p0`` matching the data's lateral
        shape) in ``meta["p0"]`` with its depth spacing ``meta["p0_dz"]`` (m).
    max_bytes : int, optional
        The most bytes a MAT v5 file may take decoded (:func:`read_variables`).
    **_
        Other loading options, ignored.

    Returns
    -------
    GridDataset
        ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` data, ``source`` ``"kwave-mat"``, ``meta`` with
        ``key``, ``layout``, ``kwave_naming`` and ``mat_version``.

    Raises
    ------
    ValueError
        A truncated or corrupt file, a compressed variable inflating beyond the limits, no
        data variable (naming the variables there), a layout that does not fit (the mask's
        point count, ``Nt``), what ``grid_array`` refuses, spacings neither given nor in the
        file (naming the options to give).
    """
    names = set(_NAMES) | {"sensor_data"} | ({key.split(".")[0]} if key else set())
    # without sensor_data (and no key) the data is under another name: every variable
    variables, listed = _read(source, names, max_bytes, unless=None if key else "sensor_data")
    raw, name = _data_array(variables, key, listed)
    n_t = _first(variables, "kgrid.Nt", "Nt")[0]
    data, layout = _time_first(raw, int(n_t) if n_t is not None else None, _mask(variables), name)
    data = grid_array(data)
    kgrid = isinstance(variables.get("kgrid"), dict)
    spacing = {s: _first(variables, f"kgrid.{s}", s)[0] for s in ("dx", "dy", "dz")}
    # k-Wave's naming (depth = x) where the file says so: a kgrid struct, a dz, or a 2-D dy
    kwave = kgrid or spacing["dz"] is not None or (data.ndim == 2 and spacing["dy"] is not None)
    file_attrs: dict[str, Any] = {f"{s}_m": v for s, v in spacing.items() if v is not None}
    if kwave:
        file_attrs["kwave_commit"] = "MAT-file"
    lat_x, lat_y = kwave_layout.lateral_spacings({}, file_attrs, data.ndim)
    if lat_x is None:
        lat_x = spacing["dx"]
    if data.ndim == 3 and lat_y is None:
        lat_y = spacing["dx"] if kwave else lat_x
    dt_file = _first(variables, "kgrid.dt", "dt")[0]
    dt = dt if dt is not None else dt_file
    dx = dx if dx is not None else lat_x
    if dt is None:
        raise ValueError("dt is neither given nor in the MAT-file (a variable dt or kgrid.dt): give dt")
    if dx is None:
        raise ValueError("the lateral spacing is neither given (dx) nor in the MAT-file (a variable dx, dy/dz "
                         "or kgrid's): give dx")
    dx = positive("dx", dx)
    dy = positive("dy", dy if dy is not None else lat_y if lat_y is not None else dx) if data.ndim == 3 else None
    c_file = _first(variables, "c0", "c", "sound_speed", "medium.sound_speed")[0]
    sound_speed = sound_speed if sound_speed is not None else c_file
    meta: dict[str, Any] = {"key": name, "layout": layout, "kwave_naming": kwave,
                            "mat_version": "7.3" if source.h5 is not None else "5"}
    if ground_truth:
        meta.update(_ground_truth(variables, data, spacing["dx"] if spacing["dx"] is not None else dx))
    vecs = ("kgrid.z_vec", "kgrid.y_vec") if data.ndim == 3 else ("kgrid.y_vec",)
    coords = tuple(_vector(_get(variables, v), n) for v, n in zip(vecs, (data.shape[-1], data.shape[1]), strict=False))
    shift = lateral_shift_of(data.shape, (dx,) if dy is None else (dx, dy), coords, kwave_grid=True)
    return GridDataset(data=data, dx=dx, dy=dy, dt=positive("dt", dt),
                       sound_speed=positive("sound_speed", sound_speed if sound_speed is not None else C_DEFAULT),
                       source="kwave-mat", meta=meta,
                       lateral_shift=shift)


def _vector(value: Any, n: int) -> np.ndarray | None:
    """A saved ``kgrid`` coordinate vector (m) of ``n`` real numbers, else None (the grid is
    then k-Wave's own convention)."""
    if value is None:
        return None
    a = np.asarray(value)
    return a.astype(np.float64).reshape(-1) if a.dtype.kind in "iuf" and a.size == n else None


FORMAT = Format(rank=30, name="kwave-mat", title="k-Wave MAT-file (MATLAB/Octave save: v5, v7, v7.3)", container="any",
                sniff=sniff, load=load, input=True, upload=True, order=20, noun="a k-Wave MAT-file",
                options=KwaveOptions)
