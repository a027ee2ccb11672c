"""k-Wave MAT-files: ``sensor_data`` as a k-Wave user saves it with MATLAB's or Octave's
``save`` → :class:`fpscan.service.recon.dataset.GridDataset`.

Two containers, one format (sniffed from the content, never the suffix):

- **MAT v5** (MATLAB's ``-v7`` default, zlib-compressed, and ``-v6``, uncompressed; Octave
  writes both): a 128-byte text header (``MATLAB 5.0 MAT-file``), then one data element
  per variable. Read with ``scipy.io.loadmat`` after this module has inflated every
  compressed element itself, bounded: at most ``max_bytes`` decoded in all and at most
  ``fpscan.service.formats.untrusted.MAX_RATIO`` times the bytes stored (+ 1 MiB), the rule every
  HDF5 input obeys, so a zlib bomb is refused before a byte of it is decoded past that.
- **MAT v7.3** (``save -v7.3``): HDF5 behind a 512-byte text header (``MATLAB 7.3
  MAT-file``). The registry opens it past the header and checks it like every HDF5 input
  (``fpscan.service.formats.untrusted.check_hdf5_file``: no external links or storage, no virtual
  datasets, no dataset declaring more than it stores or than ``max_bytes``); here it is
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
import zlib
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
_MI_MATRIX, _MI_COMPRESSED = 14, 15
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
def _inflated_v5(fh: BinaryIO, max_bytes: int) -> bytes:
    """The MAT v5 file open in ``fh`` with every compressed element inflated (header and
    elements as an uncompressed v5 file), decoding at most ``max_bytes`` in all and at most
    ``MAX_RATIO`` times the bytes stored (+ ``SMALL_BYTES``). Raises ValueError."""
    from fpscan.service.formats.untrusted import MAX_RATIO, SMALL_BYTES

    fh.seek(0)
    header = fh.read(128)
    if len(header) < 128:
        raise ValueError("the MAT-file is truncated (no complete header)")
    endian = "<" if header[126:128] == b"IM" else ">"
    out = [header]
    decoded = stored = 0
    while True:
        tag = fh.read(8)
        if not tag:
            break
        if len(tag) < 8:
            raise ValueError("the MAT-file is truncated (an element's tag is cut)")
        mtype, nbytes = struct.unpack(endian + "II", tag)
        if mtype >> 16:  # a small data element (its data inside the tag): no variable
            continue
        body = fh.read(nbytes)
        if len(body) < nbytes:
            raise ValueError(f"the MAT-file is truncated (an element declares {nbytes} bytes, {len(body)} are there)")
        stored += 8 + nbytes
        if mtype == _MI_COMPRESSED:
            limit = min(max_bytes - decoded, MAX_RATIO * stored + SMALL_BYTES - decoded)
            inflater = zlib.decompressobj()
            try:
                element = inflater.decompress(body, max(limit, 0) + 1)
            except zlib.error:
                raise ValueError("the MAT-file is corrupt (a compressed variable does not inflate)") from None
            if len(element) > limit or inflater.unconsumed_tail:
                raise ValueError(f"a compressed variable of the MAT-file inflates beyond {max(limit, 0)} bytes "
                                 f"(the file stores {stored}: more than {MAX_RATIO}:1, or above the size limit; "
                                 "refused)")
            decoded += len(element)
            out.append(element)
        elif mtype == _MI_MATRIX:
            decoded += 8 + nbytes
            if decoded > max_bytes:
                raise ValueError(f"the MAT-file's variables declare more than the limit of {max_bytes} bytes")
            out.append(tag + body)
        # any other top-level element is not a variable: skipped
    return b"".join(out)


def _v5_variables(fh: BinaryIO, names: set[str], max_bytes: int) -> tuple[dict[str, Any], list[str]]:
    """The variables ``names`` of the MAT v5 file in ``fh`` (scipy's ``simplify_cells``
    form: arrays squeezed, structs as dicts) that are numeric, logical, char or structs,
    and every variable's name. Raises ValueError."""
    import scipy.io

    stream = io.BytesIO(_inflated_v5(fh, max_bytes))
    try:
        listed = scipy.io.whosmat(stream)
    except Exception as exc:  # scipy raises many kinds on a damaged file
        raise ValueError(f"the MAT-file is not readable ({type(exc).__name__})") from None
    wanted = []
    for name, shape, cls in listed:
        if name not in names or cls not in (_NUMERIC | {"char", "struct"}):
            continue
        if cls in _NUMERIC and int(np.prod(shape, dtype=object)) * 8 > max_bytes:
            raise ValueError(f"variable {name!r} declares {tuple(shape)} elements, more than the limit of "
                             f"{max_bytes} bytes")
        wanted.append(name)
    if not wanted:
        return {}, [n for n, _, _ in listed]
    stream.seek(0)
    try:
        got = scipy.io.loadmat(stream, variable_names=wanted, simplify_cells=True, mat_dtype=True)
    except Exception as exc:
        raise ValueError(f"the MAT-file is not readable ({type(exc).__name__})") from None
    return {k: v for k, v in got.items() if not k.startswith("__")}, [n for n, _, _ in listed]


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


def _h5_variables(f: Any, names: set[str]) -> tuple[dict[str, Any], list[str]]:
    """The variables ``names`` of an open MAT v7.3 file (:func:`_h5_value`) and every
    variable's name (MATLAB's ``#refs#`` and ``#subsystem#`` groups are not variables)."""
    listed = [k for k in f.keys() if not k.startswith("#")]
    return {k: _h5_value(f[k]) for k in listed if k in names}, listed


def read_variables(source: Source, names: set[str], *, max_bytes: int = MAX_ELEMENTS * 8) -> tuple[dict, list[str]]:
    """The variables ``names`` of the MAT-file ``source`` and the names of all its variables.

    Parameters
    ----------
    source : Source
        The opened MAT-file (v5: ``source.fh``; v7.3: ``source.h5``).
    names : set of str
        The variables to read (top-level names).
    max_bytes : int, optional
        The most bytes a MAT v5 file's compressed elements may inflate to, in all.

    Returns
    -------
    tuple of (dict, list of str)
        The variables found, by name (a struct's value is a dict of its fields, arrays in
        MATLAB's index order, squeezed; what has no plain value is left out or None), and the
        names of every variable in the file.

    Raises
    ------
    ValueError
        A file that is not open, truncated or corrupt, or inflates beyond the limits.
    """
    if source.h5 is not None:
        return _h5_variables(source.h5, names)
    if source.fh is None:
        raise ValueError("the MAT-file is not open")
    return _v5_variables(source.fh, names, max_bytes)


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
        The most bytes the compressed variables may inflate to (MAT v5).
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
    variables, listed = read_variables(source, names, max_bytes=max_bytes)
    if not key and "sensor_data" not in variables:  # the data under another name: every variable
        variables, listed = read_variables(source, set(listed), max_bytes=max_bytes)
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
