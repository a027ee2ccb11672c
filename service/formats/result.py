"""Reconstruction result file (``volume.h5``, ``format`` ``fpscan-result/1``; layout:
:mod:`fpscan.service.storage.results` and docs/file-formats.md): the p0 volume ``/p0``
``(n_z, n_y, n_x)`` or ``(n_z, n_x)`` with its coordinates ``/z``, ``/y``, ``/x`` (m).
Written by :func:`write_volume` (atomically), read by :func:`load` → :class:`ResultVolume`.
An output, not data to reconstruct.

The parameters in the file name the speed of sound as a person reads it (:mod:`fpscan.service.names`:
``sound_speed``, and the autofocus record's ``sound_speed_range``, ``sound_speed_values``),
whatever the code called them (``c``, ``c_range``, ``c_values``); :func:`load` reads a file
an older fpscan wrote with ``c`` under those names too.

The result folder is this format's too: :data:`VOLUME_FILE` and one :func:`mip_file` per
MIP plane, written as a whole by :func:`write_folder` (the MIP pictures drawn by the
caller: ``fpscan.service.storage.results.write_result`` renders them).
"""
from __future__ import annotations

import datetime as _dt
import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np
import numpy.typing as npt

from fpscan.driver.scanfile import PRESSURE_UNITS
from fpscan.service.disk import copy_replaced, file_replaced, fsync_tree
from fpscan.service.formats.registry import Format, Source
from fpscan.service.names import current_names
from fpscan.wire.brief import one_line

if TYPE_CHECKING:
    from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["FORMAT", "RESULT_FORMAT", "ORIENTATION", "P0_UNITS", "COMPRESS_BELOW", "ResultVolume", "sniff",
           "load", "read_result", "read_slice", "write_volume", "params_json", "storage_layout", "VOLUME_FILE",
           "mip_file", "write_reconstruction", "write_folder", "voxel_sizes_um", "volume_description", "open_result",
           "read_slabs", "SLAB_BYTES"]

RESULT_FORMAT = "fpscan-result/1"

#: the one orientation of every array fpscan stores and every picture it draws
#: (docs/file-formats.md "Orientation"), written into result files and exports
ORIENTATION = ("array axes (z, y, x) (2-D: (z, x)), each coordinate increasing with the index; "
               "displayed row 0 at the top as napari, ImageJ and matplotlib imshow do: "
               "x to the right, y downwards, depth z downwards from the sensor plane")
#: the units of p0: calibrated (Pa) or arbitrary (a.u.), as the scan file's pressure
P0_UNITS = PRESSURE_UNITS


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (Path, np.dtype, type)):
        return str(getattr(obj, "__name__", obj))
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def params_json(params: dict) -> str:
    """Canonical JSON of a parameter dict (keys sorted, compact; numpy scalars and arrays
    converted, paths, dtypes and types as text).

    Parameters
    ----------
    params : dict
        The parameters.

    Returns
    -------
    str
        The JSON text.

    Raises
    ------
    ValueError
        NaN/inf, or values JSON cannot express.
    """
    try:
        return json.dumps(params, sort_keys=True, separators=(",", ":"), allow_nan=False,
                          default=_jsonable)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"parameters are not JSON-serialisable: {exc}") from None


def _check_axis(name: str, v: Any, n: int) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) to match p0, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    if n > 1 and not (np.all(np.diff(a) > 0)):
        raise ValueError(f"{name} must be strictly increasing")
    return a


#: compress a volume when a sample of it shrinks to this fraction or less
COMPRESS_BELOW = 0.5
#: bytes of a volume sampled to decide (evenly spaced depth rows)
_PROBE_BYTES = 128 << 10


def storage_layout(p0: np.ndarray) -> dict[str, Any]:
    """HDF5 storage options for a result volume ``p0`` (``(n_z, n_y, n_x)`` or
    ``(n_z, n_x)``), measured for speed (``benchmarks/bench_recon.py --writer``).

    A reconstruction with noise everywhere compresses poorly: gzip with byte shuffle saves
    ~14 % of a float32 volume and writes at ~10-25 MB/s, where contiguous storage writes at
    ~300-500 MB/s. A volume that is mostly exact zeros (positivity, model-based ``tv``) or
    otherwise redundant shrinks to a few per cent at ~200 MB/s with gzip level 1. So a
    sample of 16 evenly spaced depth rows (at most 128 kB) is compressed with zlib level 1 after
    byte shuffling; when it shrinks to ``COMPRESS_BELOW`` or less the volume is stored
    chunked (whole depth rows, ~1 MB chunks), gzip level 1 with shuffle, else contiguous
    and uncompressed. Either way any HDF5 reader reads it (gzip is HDF5's built-in
    filter); ``docs/file-formats.md`` states the rule.

    Parameters
    ----------
    p0 : ndarray
        The volume as it will be stored, ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``.

    Returns
    -------
    dict of str to object
        Keyword arguments for ``h5py.Group.create_dataset``: ``{}`` (contiguous) or
        ``chunks``, ``compression``, ``compression_opts`` and ``shuffle``.
    """
    import zlib

    rows = p0.shape[0]
    row_bytes = max(1, p0[0].nbytes)
    n_probe = min(rows, 16)
    sample = p0[np.linspace(0, rows - 1, n_probe).astype(np.intp)]
    if p0.ndim == 3 and sample.nbytes > _PROBE_BYTES:  # evenly spaced y lines of those rows
        n_lines = max(1, _PROBE_BYTES // (n_probe * p0.shape[2] * p0.itemsize))
        sample = sample[:, np.linspace(0, p0.shape[1] - 1, min(n_lines, p0.shape[1])).astype(np.intp)]
    sample = np.ascontiguousarray(sample)
    raw = sample.view(np.uint8).reshape(-1, sample.itemsize)
    shuffled = np.ascontiguousarray(raw.T).tobytes()  # HDF5's shuffle: byte planes
    if len(zlib.compress(shuffled, 1)) > COMPRESS_BELOW * len(shuffled):
        return {}  # contiguous, uncompressed
    per_chunk = max(1, min(rows, (1 << 20) // row_bytes))
    return {"chunks": (per_chunk, *p0.shape[1:]), "compression": "gzip", "compression_opts": 1,
            "shuffle": True}


def write_volume(path: str | os.PathLike, p0: np.ndarray, z: np.ndarray, x: np.ndarray,
                 y: np.ndarray | None = None, *, method: str, params: dict, input_id: str,
                 software_version: str | None = None, dtype: npt.DTypeLike | None = None,
                 p0_unit: str = "a.u.") -> Path:
    """Write a result file atomically (see module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (a temporary sibling, flushed, then renamed into place).
    p0 : ndarray
        ``(n_z, n_y, n_x)`` with ``y`` given, or ``(n_z, n_x)`` with ``y=None``; real, finite.
    z, x : ndarray
        Strictly increasing coordinates in m, ``(n_z,)`` and ``(n_x,)``.
    y : ndarray, optional
        Strictly increasing y coordinates ``(n_y,)`` in m; None for a 2-D ``p0``.
    method : str
        The reconstruction method's name (non-empty).
    params : dict
        Every parameter of the reconstruction, JSON-serialisable; the speed of sound is
        stored as ``sound_speed`` (an earlier release's ``c`` too, nested:
        :func:`fpscan.service.names.current_names`).
    input_id : str
        The input's id.
    software_version : str, optional
        Recorded as the attribute ``software_version`` (default the installed fpscan's).
    dtype : float32 or float64, optional
        The stored dtype; by default float32, unless the reconstruction asked for float64
        (``params["dtype"] == "float64"``). Compressed where that pays
        (:func:`storage_layout`).
    p0_unit : {"a.u.", "Pa"}, optional
        The unit of p0 (:data:`P0_UNITS`).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        Naming the fault: a bad ``p0_unit`` or ``dtype``, p0 not real, of the wrong shape or
        not finite, ``y`` given for 2-D (or missing for 3-D), coordinates of the wrong shape,
        not finite or not increasing, an empty ``method``, ``params`` that are no dict or not
        JSON-serialisable.
    OSError
        The file cannot be written.
    """
    if p0_unit not in P0_UNITS:
        raise ValueError(f"p0_unit must be one of {', '.join(P0_UNITS)}, got {p0_unit!r}")
    p0 = np.asarray(p0)
    if p0.dtype.kind not in "iuf":
        raise ValueError(f"p0 must be real numbers, got {p0.dtype}")
    if dtype is None:
        dtype = np.float64 if isinstance(params, dict) and params.get("dtype") == "float64" \
            else np.float32
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    if p0.ndim not in (2, 3) or min(p0.shape) < 1:
        raise ValueError(f"p0 must be (n_z, n_x) or (n_z, n_y, n_x), got shape {p0.shape}")
    if (p0.ndim == 3) != (y is not None):
        raise ValueError("give y for a 3-D p0 and y=None for a 2-D p0")
    if not np.isfinite(p0).all():
        raise ValueError("p0 contains NaN or infinite values")
    p0 = p0.astype(dtype, copy=False)
    z = _check_axis("z", z, p0.shape[0])
    x = _check_axis("x", x, p0.shape[-1])
    y = _check_axis("y", y, p0.shape[1]) if p0.ndim == 3 else None
    if not isinstance(method, str) or not method:
        raise ValueError("method must be a non-empty string")
    if not isinstance(input_id, str):
        raise ValueError("input_id must be a string")
    if not isinstance(params, dict):
        raise ValueError(f"params must be a dict, got {type(params).__name__}")
    stored = current_names(params)  # the speed of sound as sound_speed, whatever a caller's params said
    all_json = params_json(stored)
    each = {str(k): params_json({"v": v})[5:-1] for k, v in stored.items()}
    if software_version is None:
        from fpscan.driver.acquire import software_version as installed_version

        software_version = installed_version()

    path = Path(path)
    with file_replaced(path) as tmp:  # a temporary sibling, renamed over path; removed on any error
        with h5py.File(tmp, "w") as f:
            d = f.create_dataset("p0", data=p0, **storage_layout(p0))
            axes = [("z", z)] + ([("y", y)] if y is not None else []) + [("x", x)]
            for i, (name, vec) in enumerate(axes):
                s = f.create_dataset(name, data=vec)
                s.attrs["units"] = "m"
                s.make_scale(name)
                d.dims[i].attach_scale(s)
                d.dims[i].label = name
            d.attrs["units"] = p0_unit
            d.attrs["orientation"] = ORIENTATION
            g = f.create_group("params")
            for k, v in each.items():
                g.attrs[k] = v
            a = f.attrs
            a["format"] = RESULT_FORMAT
            a["method"] = method
            a["params"] = all_json
            a["input_id"] = input_id
            a["software_version"] = software_version
            a["created_utc"] = _dt.datetime.now(_dt.UTC).isoformat()
            a["units"] = f"m for coordinates; p0 in {p0_unit}"
            a["p0_unit"] = p0_unit
            a["orientation"] = ORIENTATION
        fsync_tree(tmp, parent=False)  # its data on disk before the rename names it
    return path


#: the result folder's volume file (the MIPs beside it: :func:`mip_file`)
VOLUME_FILE = "volume.h5"


def mip_file(plane: str) -> str:
    """The name of the result folder's MIP picture of ``plane``.

    Parameters
    ----------
    plane : str
        ``"xy"``, ``"xz"`` or ``"yz"``.

    Returns
    -------
    str
        ``mip_<plane>.png``.
    """
    return f"mip_{plane}.png"


def write_reconstruction(path: str | os.PathLike, rec: Reconstruction, *, input_id: str,
                         method: str | None = None, software_version: str | None = None) -> Path:
    """Write a ``fpscan.service.recon.Reconstruction`` as a result file (:func:`write_volume`).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    rec : Reconstruction
        The reconstruction: ``p0``, ``z``, ``x``, ``y``, ``params`` (and ``p0_unit``, default
        ``"a.u."``).
    input_id : str
        The input's id.
    method : str, optional
        The method's name (default ``rec.params["method"]``).
    software_version : str, optional
        As :func:`write_volume`.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        No method given or in the params, and as :func:`write_volume`.
    """
    params = dict(getattr(rec, "params", None) or {})
    method = method or params.get("method")
    if not method:
        raise ValueError("no method given and the reconstruction's params have no 'method'")
    return write_volume(path, rec.p0, rec.z, rec.x, getattr(rec, "y", None),
                        method=str(method), params=params, input_id=input_id,
                        software_version=software_version, p0_unit=getattr(rec, "p0_unit", "a.u."))


def write_folder(out_dir: str | os.PathLike, rec: Reconstruction, *, input_id: str,
                 mips: dict[str, bytes] | Callable[[], dict[str, bytes]]) -> dict:
    """Write the result folder of a reconstruction ``rec``.

    :data:`VOLUME_FILE` (:func:`write_reconstruction`) and the PNG bytes of each MIP plane in
    ``mips`` (:func:`mip_file`), written into a temporary sibling folder renamed into place
    (an existing ``out_dir`` is replaced).

    Parameters
    ----------
    out_dir : str or os.PathLike
        The result folder.
    rec : Reconstruction
        The reconstruction.
    input_id : str
        The input's id.
    mips : dict of str to bytes, or callable
        PNG bytes per plane (``"xy"``, ...), or a callable returning them, called once the
        volume is written (and flushed to disk): a caller can draw the pictures meanwhile.

    Returns
    -------
    dict
        ``{"shape", "max", "max_index", "planes", "params_used"}``: ``max_index`` the array
        index of the maximum, depth first, where the web page opens its depth slice (None for
        an empty volume); ``planes`` sorted; ``params_used`` the scalar parameters the
        reconstruction used.

    Raises
    ------
    ValueError
        As :func:`write_volume`, and what ``mips()`` raises.
    """
    import time

    from fpscan.service.disk import folder_replaced

    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + f".tmp-{os.getpid()}-{time.monotonic_ns()}")
    tmp.mkdir(parents=True)
    with folder_replaced(out_dir, tmp):
        p0 = np.asarray(rec.p0)
        write_reconstruction(tmp / VOLUME_FILE, rec, input_id=input_id)
        if callable(mips):
            mips = mips()
        for plane, png in mips.items():
            (tmp / mip_file(plane)).write_bytes(png)
    # the values the reconstruction used (defaults and the input's c, dt, dx filled in)
    used = {k: v for k, v in json.loads(params_json(dict(getattr(rec, "params", None) or {}))).items()
            if v is None or isinstance(v, (bool, int, float, str))}
    peak = [int(i) for i in np.unravel_index(int(np.argmax(p0)), p0.shape)] if p0.size else None
    return {"shape": list(p0.shape), "max": float(np.max(p0)) if p0.size else 0.0, "max_index": peak,
            "planes": sorted(mips), "params_used": used}


@dataclass
class ResultVolume:
    """A result file's content.

    Attributes
    ----------
    p0 : ndarray
        The volume ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``, as stored.
    z, x : ndarray
        Coordinate vectors in m.
    y : ndarray or None
        The y coordinates in m; None in 2-D.
    method : str
        The reconstruction method's name.
    params : dict
        The reconstruction's parameters (the speed of sound as ``sound_speed``, also from a
        file an older fpscan wrote with ``c``).
    input_id : str
        The input's id.
    attrs : dict
        All root attributes, as stored (text decoded).
    """

    p0: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray | None
    method: str
    params: dict
    input_id: str
    attrs: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        """One line: the method, p0's shape and dtype, the input's id and each axis's extent (never
        the arrays).

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.formats.result import ResultVolume
        >>> ResultVolume(p0=np.zeros((4, 3), np.float32), z=np.arange(4) * 1e-4, x=np.array([-1e-4, 0.0, 1e-4]),
        ...              y=None, method="ner", params={}, input_id="abc")
        ResultVolume(ner: p0 (4, 3) float32, input abc, z 0 to 0.3 mm, x -0.1 to 0.1 mm)
        """
        extents = [(n, v) for n, v in (("z", self.z), ("y", self.y), ("x", self.x)) if v is not None and len(v)]
        span = "".join(f", {n} {float(v[0]) * 1e3:.4g} to {float(v[-1]) * 1e3:.4g} mm" for n, v in extents)
        return one_line(f"ResultVolume({self.method}: p0 {tuple(self.p0.shape)} {self.p0.dtype}, input "
                        f"{self.input_id[:16]}{span})")

    @property
    def ndim(self) -> int:
        return self.p0.ndim

    @property
    def p0_unit(self) -> str:
        """``"Pa"`` (calibrated scan) or ``"a.u."`` (files before the attribute: a.u.)."""
        return "Pa" if self.attrs.get("p0_unit") == "Pa" else "a.u."


def sniff(source: Source) -> bool:
    """True for an HDF5 file whose ``format`` attribute is ``fpscan-result/<version>``.

    Parameters
    ----------
    source : Source
        The opened HDF5 file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.attr("format").startswith("fpscan-result/")


def load(source: Source, **_: Any) -> ResultVolume:
    """The result file's volume, coordinates and attributes.

    The parameters come with the person's names (``sound_speed``; a file an older fpscan wrote
    with ``c`` reads the same).

    Parameters
    ----------
    source : Source
        The opened HDF5 file.
    **_
        Loading options, ignored.

    Returns
    -------
    ResultVolume
        The whole volume, read.

    Raises
    ------
    ValueError
        Not a result file.
    """
    return _volume(source, whole=True)


def _volume(source: Source, *, whole: bool) -> ResultVolume:
    """The result file's :class:`ResultVolume`, its ``p0`` read (``whole``) or the HDF5 dataset
    itself (read by slicing); ValueError for a file that is not a result."""
    f = source.h5
    attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    if attrs.get("format") != RESULT_FORMAT or not isinstance(f.get("p0"), h5py.Dataset):
        raise ValueError(f"{source.path} is not an {RESULT_FORMAT} file")
    p0 = f["p0"][()] if whole else f["p0"]
    z, x = f["z"][()], f["x"][()]
    y = f["y"][()] if "y" in f else None
    return ResultVolume(p0=p0, z=z, x=x, y=y, method=str(attrs["method"]),
                        params=current_names(json.loads(attrs["params"])), input_id=str(attrs["input_id"]),
                        attrs=attrs)


@contextmanager
def open_result(path: str | os.PathLike) -> Iterator[ResultVolume]:
    """A result file open for reading in parts: what an export reads, a slab at a time
    (:func:`read_slabs`), so that its peak memory does not grow with the volume.

    Parameters
    ----------
    path : str or os.PathLike
        The ``volume.h5``.

    Returns
    -------
    contextlib.AbstractContextManager of ResultVolume
        Entered, the volume: ``z``, ``x``, ``y`` and the attributes read, ``p0`` the HDF5
        dataset itself (``(n_z, n_y, n_x)`` or ``(n_z, n_x)``; ``p0[k]`` reads one depth
        plane), valid until the block ends. A file open by a writer (the SWMR flag) is read
        whole instead, in a bounded child (:func:`read_result`).

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Not a result file.
    """
    from fpscan.service.formats.registry import open_source
    from fpscan.service.formats.untrusted import writer_flagged

    if writer_flagged(path):
        yield read_result(path)
        return
    with open_source(path, "hdf5", name="result") as src:
        yield _volume(src, whole=False)


#: the most bytes :func:`read_slabs` reads at once (by default)
SLAB_BYTES = 4 * 2**20


def read_slabs(p0: Any, axis: int = 0, *, dtype: npt.DTypeLike = np.float32,
               max_bytes: int = SLAB_BYTES) -> Iterator[np.ndarray]:
    """A volume read in slabs along one axis, each of at most ``max_bytes`` (at least one
    plane): how the exports stream a result's p0 (:func:`open_result`) with a bounded peak.

    Parameters
    ----------
    p0 : h5py.Dataset or ndarray
        The volume, e.g. ``(n_z, n_y, n_x)``.
    axis : int, optional
        The axis the slabs follow (default 0, depth: whole HDF5 chunks of a result file,
        :func:`storage_layout`); the slabs' concatenation along it is ``p0``.
    dtype : numpy dtype, optional
        The slabs' dtype (default float32).
    max_bytes : int, optional
        The most bytes of one slab (default :data:`SLAB_BYTES`, 4 MiB).

    Returns
    -------
    iterator of ndarray
        The slabs in order, C-contiguous, of ``dtype``.

    Examples
    --------
    >>> [s.shape for s in read_slabs(np.zeros((5, 4, 4)), axis=0, max_bytes=2 * 64)]
    [(2, 4, 4), (2, 4, 4), (1, 4, 4)]
    """
    dtype = np.dtype(dtype)
    n = int(p0.shape[axis])
    plane = max(1, int(np.prod(p0.shape, dtype=np.int64)) // max(n, 1) * dtype.itemsize)
    step = max(1, int(max_bytes) // plane)
    for start in range(0, n, step):
        index = [slice(None)] * len(p0.shape)
        index[axis] = slice(start, min(start + step, n))
        yield np.ascontiguousarray(p0[tuple(index)], dtype=dtype)


def voxel_sizes_um(r: ResultVolume, what: str) -> tuple[str, list[float]]:
    """The axes of a volume's export (``"ZYX"``; 2-D ``"YX"``, depth z as the image's Y) and the
    voxel size of each in µm (a single sample counts as 1 µm): what OME-TIFF and OME-Zarr state.

    Parameters
    ----------
    r : ResultVolume
    what : str
        The export, for the message (``"OME-TIFF"``).

    Returns
    -------
    tuple of (str, list of float)

    Raises
    ------
    ValueError
        An axis that is not evenly spaced.
    """
    def step_um(v: np.ndarray, name: str) -> float:
        if len(v) < 2:
            return 1.0
        d = np.diff(v)
        if not np.allclose(d, d[0], rtol=1e-6, atol=0):
            raise ValueError(f"{name} is not evenly spaced: {what} needs one voxel size per axis")
        return float(f"{d[0] * 1e6:.12g}")  # µm, without the last bits of rounding noise

    if r.p0.ndim == 3 and r.y is not None:
        return "ZYX", [step_um(r.z, "z"), step_um(r.y, "y"), step_um(r.x, "x")]
    return "YX", [step_um(r.z, "z"), step_um(r.x, "x")]


def volume_description(r: ResultVolume) -> str:
    """One line an export carries about its volume: method, p0 unit, axes and :data:`ORIENTATION`.

    Parameters
    ----------
    r : ResultVolume

    Returns
    -------
    str
    """
    return (f"fpscan p0 ({r.method}); p0 unit: {r.p0_unit}; "
            f"{'axes (z, y, x)' if r.p0.ndim == 3 else 'axes (z, x): depth z as the image Y'}; "
            f"orientation: {ORIENTATION}")


def read_result(path: str | os.PathLike) -> ResultVolume:
    """Read a result file (through the registry: opened once, checked).

    Parameters
    ----------
    path : str or os.PathLike
        The ``volume.h5``.

    Returns
    -------
    ResultVolume
        Its content.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Not a result file.
    """
    from fpscan.service.formats.registry import load as load_as

    return load_as(path, "result")[1]


def read_slice(path: str | os.PathLike, index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """One depth slice of a result file's p0, read without loading the whole volume.

    Parameters
    ----------
    path : str or os.PathLike
        The ``volume.h5``.
    index : int
        The depth sample, in [0, n_z).

    Returns
    -------
    tuple of (ndarray, ndarray, ndarray, ndarray or None)
        The slice ``(n_y, n_x)`` (or the image row ``(n_x,)`` of a 2-D result), then ``z``,
        ``x`` and ``y`` (None in 2-D), m.

    Raises
    ------
    ValueError
        ``index`` not an integer in range, or not a result file.
    FileNotFoundError
        No file at ``path``.
    """
    from fpscan.service.formats.registry import open_source

    with open_source(path, "hdf5", name="result") as src:
        f = src.h5
        if "p0" not in f or "z" not in f or "x" not in f:
            raise ValueError(f"{src.path} is not an {RESULT_FORMAT} file")
        ds = f["p0"]
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) \
                or not 0 <= index < ds.shape[0]:
            raise ValueError(f"index must be an integer in [0, {ds.shape[0]}) (depth samples)")
        img = ds[index]
        z, x = f["z"][()], f["x"][()]
        y = f["y"][()] if "y" in f else None
    return img, z, x, y


FORMAT = Format(rank=70, name="result", title="fpscan reconstruction result (volume.h5)", container="hdf5",
                sniff=sniff, load=load, write=write_volume, order=30, noun="a reconstruction result",
                export_from="result", export=copy_replaced, suffix=".h5", media_type="application/x-hdf5",
                refuse="this is a reconstruction result (a p0 volume), not data to reconstruct: open it with "
                       "h5py, or `fpscan export` it to OME-TIFF for ImageJ/napari")
