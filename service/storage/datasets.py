"""Dataset import for reconstruction: one uniform object from any supported input.

Inputs (``format``; ``None`` = detect from the content):

- ``"fpscan"``: our scan file (:mod:`driver.scanfile`): its *completed* points, the
  DC-normalised pressure, the plan's positions/weights and lattice → :class:`PointDataset`.
- ``"ipasc"``: an IPASC HDF5 file (:mod:`service.storage.ipasc`) → :class:`PointDataset`.
- ``"kwave-hdf5"``: an HDF5 array in k-Wave layout, time first — ``(n_t, n_y, n_x)``
  (k-Wave ``'tyz'``) or ``(n_t, n_x)`` (``'ty'``) — at ``key`` (default
  ``sensor_data/clean``, then ``sensor_data``, then the file's only 2-/3-D dataset) →
  :class:`GridDataset`. Spacings: arguments first, then file attributes. k-Wave files
  (a ``kwave_DataOrder`` attribute on the array or ``kwave_commit`` on the file, as in
  ``shared/data``) name the depth axis x, so their lateral spacings are ``dy_m`` (our y,
  or our x in 2-D) and ``dz_m`` (our x); other files use ``dx_m``/``dy_m`` for our x/y
  (the rule's one owner: :mod:`driver.kwave_layout`, shared with the simulator's replay).
  ``dt_s`` and ``c_m_per_s`` give dt and c.
- ``"npy"``: a NumPy ``.npy`` array in the same layout (loaded with
  ``allow_pickle=False``); ``dt`` and ``dx`` are required arguments.
- ``"dataset"``: the canonical dataset file (:func:`write_dataset`, format
  ``fpscan-dataset/1``), in which the server keeps every upload; it stores either kind
  exactly (dtype included), so a reconstruction of it equals one of the original file.

Every reader of a file for reconstruction calls :func:`load_dataset` (the job worker, the
local ``fpscan recon``, the live preview, the experiments) and hands the result to
:func:`service.pipeline.reconstruct`. A point dataset that covers its whole lattice turns
into grid data with :meth:`PointDataset.to_grid` (so grid methods work on a full-lattice
scan everywhere); grid data into point data with :meth:`GridDataset.to_points`.
A dataset may carry the excitation ``wavelengths`` (m) it was acquired at.

Multi-wavelength files (an fpscan scan or an IPASC file with several excitation
wavelengths) hold one data set per wavelength; a dataset is one of them, chosen with
``wavelength`` (an index into the file's wavelengths) in :func:`load_dataset`, or all of
them, one dataset each, with :func:`load_wavelengths` (``wavelength="all"``). Without a
choice the first wavelength (index 0) is read: documented, never silent: the dataset's
``wavelengths`` is that one wavelength, ``meta`` records ``wavelength_index`` and the
file's ``wavelengths``, and every reconstruction of it records ``wavelength_index`` and
``wavelength_nm`` in its params (:func:`wavelength_params`).

Lateral grids are centred on the optical axis (docs/architecture.md):
``x_i = (i - (n_x - 1)/2)·dx``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from driver import kwave_layout
from driver.constants import C_DEFAULT
from driver.physics.axes import centred_axis

FORMATS = ("fpscan", "ipasc", "kwave-hdf5", "npy", "dataset")
DATASET_FORMAT = "fpscan-dataset/1"
MAX_ELEMENTS = 2 ** 31
#: ``wavelength="all"``: every wavelength of a multi-wavelength file, one dataset (one volume) each
ALL_WAVELENGTHS = "all"
#: the formats that may hold several excitation wavelengths
MULTI_WAVELENGTH_FORMATS = ("fpscan", "ipasc")


def check_wavelength(wavelength: Any, *, allow_all: bool = True) -> int | str | None:
    """A wavelength choice as given: ``None`` (the default: the first), an index >= 0
    (an int, or its decimal text as a command line gives it) or ``"all"`` (when
    ``allow_all``). Returns the int index, ``"all"`` or None; raises ValueError naming
    the choice otherwise."""
    if wavelength is None:
        return None
    if isinstance(wavelength, str):
        if wavelength.strip().lower() == ALL_WAVELENGTHS and allow_all:
            return ALL_WAVELENGTHS
        if wavelength.strip().isdigit():
            return int(wavelength.strip())
    elif not isinstance(wavelength, bool) and isinstance(wavelength, (int, np.integer)) and wavelength >= 0:
        return int(wavelength)
    what = "an index >= 0 into the file's wavelengths" + (" or 'all'" if allow_all else "")
    raise ValueError(f"wavelength must be {what}, got {wavelength!r}")


def _nm(wavelengths: Any) -> str:
    return ", ".join(f"{float(w) * 1e9:g} nm" for w in np.ravel(np.asarray(wavelengths, dtype=np.float64)))


def file_wavelengths(ds: GridDataset | PointDataset) -> np.ndarray:
    """The excitation wavelengths (m, ``(n_w,)``) of the file ``ds`` was read from (all of
    them, not only the one ``ds`` holds); empty when the file records none."""
    w = (ds.meta or {}).get("wavelengths")
    if w is None:
        w = ds.wavelengths
    return np.asarray([] if w is None else w, dtype=np.float64).reshape(-1)


def wavelength_params(ds: GridDataset | PointDataset) -> dict:
    """What a reconstruction of ``ds`` records about its wavelength: ``wavelength_index``
    (into the file's wavelengths, when read from a multi-wavelength file) and
    ``wavelength_nm`` (when ``ds`` holds one known wavelength's data); ``{}`` otherwise."""
    out: dict = {}
    if (ds.meta or {}).get("wavelength_index") is not None:
        out["wavelength_index"] = int(ds.meta["wavelength_index"])
    w = np.asarray([] if ds.wavelengths is None else ds.wavelengths, dtype=np.float64).reshape(-1)
    if w.size == 1:
        out["wavelength_nm"] = round(float(w[0]) * 1e9, 6)
    return out




@dataclass
class GridDataset:
    """Data on a regular sensor grid. ``data``: ``(n_t, n_y, n_x)`` or ``(n_t, n_x)``
    (time first); ``dx``, ``dy`` (None in 2-D) lateral spacings in m; ``dt`` s; ``c`` m/s;
    ``t0`` s (time of sample 0); ``source`` (format); ``meta`` (anything else)."""

    data: np.ndarray
    dx: float
    dt: float
    c: float
    dy: float | None = None
    t0: float = 0.0
    source: str = ""
    meta: dict = field(default_factory=dict)
    wavelengths: tuple[float, ...] | None = None

    kind = "grid"

    @property
    def ndim(self) -> int:
        """2 (line sensor) or 3 (planar sensor)."""
        return self.data.ndim

    def axes(self) -> tuple[np.ndarray, ...]:
        """Lateral coordinate vectors: ``(x,)`` in 2-D, ``(x, y)`` in 3-D, m, centred."""
        x = centred_axis(self.data.shape[-1], self.dx)
        if self.data.ndim == 2:
            return (x,)
        return x, centred_axis(self.data.shape[1], self.dy or self.dx)

    def to_points(self) -> PointDataset:
        """Every grid point as a sensor: ``alines`` ``(n_y·n_x, n_t)`` in C order of
        ``(n_y, n_x)``, positions ``(n, 2)`` (x, y) (``(n, 1)`` in 2-D), no weights (the
        reconstruction then uses clipped Voronoi areas, here the grid cells), ``grid`` =
        :meth:`axes`."""
        axes = self.axes()
        if self.data.ndim == 2:
            alines, positions = self.data.T, axes[0][:, None]
        else:
            yy, xx = np.meshgrid(axes[1], axes[0], indexing="ij")
            alines = self.data.reshape(self.data.shape[0], -1).T
            positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
        return PointDataset(alines=alines, positions=positions, weights=None, dt=self.dt, c=self.c,
                            grid=axes, t0=self.t0, source=self.source, meta=dict(self.meta),
                            wavelengths=self.wavelengths)


@dataclass
class PointDataset:
    """A-lines at arbitrary sensor positions. ``alines`` ``(n, n_t)``; ``positions``
    ``(n, 2)`` (x, y) m or ``(n, 1)`` in 2-D; ``weights`` ``(n,)`` area weights or None
    (then the reconstruction computes Voronoi weights); ``dt`` s; ``c`` m/s; ``grid``: the
    regular lateral vectors ``(x,)``/``(x, y)`` to reconstruct on; ``t0`` s; ``source``;
    ``meta`` (plan, ...); ``indices`` ``(n, 2)`` lattice (i_x, i_y) and ``lattice``
    ``{"n_x", "n_y", "pitch"}`` when the points come from a scanner lattice (then a full
    lattice can use the grid methods, :meth:`to_grid`); ``wavelengths`` (m) or None."""

    alines: np.ndarray
    positions: np.ndarray
    weights: np.ndarray | None
    dt: float
    c: float
    grid: tuple
    t0: float = 0.0
    source: str = ""
    meta: dict = field(default_factory=dict)
    indices: np.ndarray | None = None
    lattice: dict | None = None
    wavelengths: tuple[float, ...] | None = None

    kind = "points"

    @property
    def ndim(self) -> int:
        """2 (line sensor, positions ``(n, 1)``) or 3 (planar sensor)."""
        return 3 if self.positions.shape[1] == 2 else 2

    def _filled(self) -> np.ndarray | None:
        """``(n_y, n_x)`` bool: which lattice points the data hold (None: no lattice)."""
        if self.indices is None or self.lattice is None:
            return None
        n_x, n_y = int(self.lattice["n_x"]), int(self.lattice.get("n_y", 1))
        idx = np.asarray(self.indices, dtype=np.int64).reshape(-1, 2)
        filled = np.zeros((n_y, n_x), dtype=bool)
        if len(idx):
            filled[idx[:, 1], idx[:, 0]] = True
        return filled

    @property
    def full_lattice(self) -> bool:
        """True when the points are every point of their lattice (exactly once)."""
        filled = self._filled()
        return filled is not None and bool(filled.all()) and len(np.asarray(self.indices)) == filled.size

    def to_grid(self) -> GridDataset:
        """The A-lines of a full-lattice dataset as grid data ``(n_t, n_y, n_x)``
        (``(n_t, n_x)`` for a line lattice), ``dx = dy`` = the lattice pitch, same dtype.
        Raises ValueError when the data are not on a lattice or lattice points are
        missing."""
        filled = self._filled()
        if filled is None or self.lattice is None:
            raise ValueError("this method needs data on a full regular grid; the input is a set of "
                             "sensor points (use 'nedner')")
        if not filled.all() or len(np.asarray(self.indices)) != filled.size:
            missing = int((~filled).sum())
            raise ValueError(f"this method needs every lattice point; {missing} of {filled.size} are "
                             "missing (use 'nedner' for a sensor mask)")
        n_y, n_x = filled.shape
        idx = np.asarray(self.indices, dtype=np.int64).reshape(-1, 2)
        n_t = self.alines.shape[1]
        data = np.empty((n_t, n_y, n_x), dtype=self.alines.dtype)
        data[:, idx[:, 1], idx[:, 0]] = self.alines.T
        pitch = float(self.lattice["pitch"])
        return GridDataset(data=data[:, 0, :] if n_y == 1 else data, dx=pitch, dt=self.dt, c=self.c,
                           dy=None if n_y == 1 else pitch, t0=self.t0, source=self.source,
                           meta=dict(self.meta), wavelengths=self.wavelengths)


Dataset = GridDataset | PointDataset


def p0_unit(ds: GridDataset | PointDataset) -> str:
    """The unit of a p0 reconstructed from ``ds``: ``"Pa"`` when the dataset is calibrated
    pressure (``meta["p0_unit"]``, from a scan whose instrument states its volts-to-pascal
    calibration: ``driver.scanfile.pressure_unit``), else ``"a.u."``."""
    return "Pa" if (ds.meta or {}).get("p0_unit") == "Pa" else "a.u."


def _positive(name: str, v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {v!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"{name} must be a positive finite number, got {v!r}")
    return f


def _grid_array(a: np.ndarray) -> np.ndarray:
    if a.dtype.kind not in "iuf":
        raise ValueError(f"array must hold real numbers, got dtype {a.dtype}")
    if a.ndim not in (2, 3):
        raise ValueError(f"array must be (n_t, n_x) or (n_t, n_y, n_x) (time first), got "
                         f"shape {a.shape}")
    if min(a.shape) < 2:
        raise ValueError(f"every axis needs at least 2 samples, got shape {a.shape}")
    if a.size > MAX_ELEMENTS:
        raise ValueError(f"array too large ({a.size} elements)")
    a = np.asarray(a, dtype=np.float32 if a.dtype.itemsize <= 4 else np.float64)
    if not np.isfinite(a).all():
        raise ValueError("array contains NaN or infinite values")
    return a


def detect_format(path: str | os.PathLike, _here: bool = False) -> str:
    """Guess the format of a file from its content; ValueError if none fits. A file a
    writer has open is opened in a bounded child (as in :func:`load_dataset`)."""
    if not _here:
        from service.storage.untrusted import read_bounded

        return read_bounded(detect_format, path, _here=True)
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head != b"\x89HDF\r\n\x1a\n":
        if head.lstrip().startswith(b"{"):
            raise ValueError("this is a plan (JSON), not data to reconstruct: scan it first "
                             "(`fpscan scan --plan ...`) and reconstruct the scan file")
        if head.startswith(b"\x89PNG"):
            raise ValueError("this is a PNG picture, not data to reconstruct")
        raise ValueError("file is neither HDF5 nor a NumPy .npy array")
    with _open_h5(path) as f:
        fmt = f.attrs.get("format")
        fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt or "")
        if fmt.startswith("fpscan-scan/"):  # /1 and /2
            return "fpscan"
        if f.attrs.get("format") == DATASET_FORMAT or f.attrs.get("layout") in ("grid", "points"):
            return "dataset"
        if fmt.startswith("fpscan-result/"):
            raise ValueError("this is a reconstruction result (a p0 volume), not data to reconstruct: "
                             "open it with h5py, or `fpscan export` it to OME-TIFF for ImageJ/napari")
        if "binary_time_series_data" in f:
            return "ipasc"
    return "kwave-hdf5"


def _open_h5(path: Path) -> h5py.File:
    """Open read-only (``driver.scanfile.open_readonly``: SWMR only for a file a writer
    has, or had, open); ValueError if it is not a readable HDF5 file."""
    from driver.scanfile import open_readonly

    try:
        return open_readonly(path)
    except ValueError:
        raise ValueError("file is not a readable HDF5 file (truncated or corrupt?)") from None


def load_dataset(path: str | os.PathLike, format: str | None = None, *, dt: float | None = None,
                 dx: float | None = None, dy: float | None = None, c: float | None = None,
                 key: str | None = None, max_bytes: int = MAX_ELEMENTS * 8,
                 force: bool = False, wavelength: int | None = None,
                 _here: bool = False) -> GridDataset | PointDataset:
    """Import a file for reconstruction (module docstring). ``wavelength``: which
    excitation wavelength of a multi-wavelength file (an index into its wavelengths;
    default None: the first, recorded in the dataset's ``meta["wavelength_index"]``); a
    file of one wavelength takes only None or 0 (``"all"``: :func:`load_wavelengths`).
    An index out of range is a ValueError naming the file's wavelengths. Explicit ``dt`` (s), ``dx``,
    ``dy`` (m) and ``c`` (m/s) override what the file says; they are what a person typed,
    so they must be plausible (``driver.units.check_plausible``: a unit mistake such as
    ``dt=20`` for 20 ns is named; ``force`` accepts an unusual ``c``). An HDF5 file is
    checked first (``service.storage.untrusted.check_hdf5``: no external storage,
    external links or virtual datasets, no dataset declaring more than ``max_bytes`` or
    more than it stores). A file HDF5 would open as an SWMR reader (a writer has it open)
    is read in a child process with a time limit
    (``service.storage.untrusted.read_bounded``: HDF5 can block on its damaged metadata for
    ever). Raises ValueError naming the fault, FileNotFoundError."""
    from driver.units import check_plausible
    from service.storage.untrusted import check_hdf5, is_hdf5, read_bounded

    if not _here:  # run here, or in the bounded child for a file a writer has open
        return read_bounded(load_dataset, path, format, dt=dt, dx=dx, dy=dy, c=c, key=key, max_bytes=max_bytes,
                            force=force, wavelength=wavelength, _here=True)

    num = (int, float)
    check_plausible(dt=dt if isinstance(dt, num) else None, dx=dx if isinstance(dx, num) else None,
                    dy=dy if isinstance(dy, num) else None,
                    sound_speed=c if isinstance(c, num) else None, force=force)
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    if format is not None and format not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    if format not in (None, "npy"):
        if not is_hdf5(path):
            raise ValueError(f"a {format} file must be HDF5 (no HDF5 signature at the start)")
        check_hdf5(path, max_bytes=max_bytes)
    elif format is None and is_hdf5(path):
        check_hdf5(path, max_bytes=max_bytes)
    fmt = format or detect_format(path)
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    choice = check_wavelength(wavelength, allow_all=False)  # 'all': load_wavelengths
    index = 0 if choice is None else int(choice)
    if fmt not in MULTI_WAVELENGTH_FORMATS and index != 0:
        raise ValueError(f"wavelength index {index} is out of range: a {fmt} file holds one wavelength's data")
    if fmt == "npy":
        return load_npy(path, dt=dt, dx=dx, dy=dy, c=c)
    if fmt == "kwave-hdf5":
        return load_kwave_hdf5(path, key=key, dt=dt, dx=dx, dy=dy, c=c)
    ds: GridDataset | PointDataset
    if fmt == "fpscan":
        ds = load_scan(path, wavelength_index=index)
    elif fmt == "dataset":
        ds = read_dataset(path)
    else:
        ds = load_ipasc(path, wavelength_index=index)
    if c is not None:
        ds.c = _positive("c", c)
    if dt is not None:
        ds.dt = _positive("dt", dt)
    return ds


def load_npy(path: str | os.PathLike, *, dt: float | None, dx: float | None,
             dy: float | None = None, c: float | None = None) -> GridDataset:
    """A ``.npy`` array in k-Wave layout; ``dt`` and ``dx`` required, ``c`` default 1500."""
    try:
        a = np.load(path, allow_pickle=False, mmap_mode="r")
    except (ValueError, OSError, EOFError):
        raise ValueError("file is not a NumPy .npy array (pickles are refused)") from None
    if not isinstance(a, np.ndarray):
        raise ValueError("file is not a single NumPy array")
    data = _grid_array(np.asarray(a))
    if dt is None or dx is None:
        raise ValueError("a .npy array needs dt (s) and dx (m)")
    return GridDataset(data=data, dx=_positive("dx", dx), dt=_positive("dt", dt),
                       c=_positive("c", c if c is not None else C_DEFAULT),
                       dy=_positive("dy", dy) if (dy is not None and data.ndim == 3) else
                       (_positive("dx", dx) if data.ndim == 3 else None),
                       source="npy")


def load_kwave_hdf5(path: str | os.PathLike, *, key: str | None = None, dt: float | None = None,
                    dx: float | None = None, dy: float | None = None,
                    c: float | None = None) -> GridDataset:
    """An HDF5 array in k-Wave layout (module docstring)."""
    f = _open_h5(Path(path))
    with f:
        if key is not None:
            if key not in f or not isinstance(f[key], h5py.Dataset):
                raise ValueError(f"no dataset {key!r} in the HDF5 file")
            ds = f[key]
        else:
            ds = None
            for k in ("sensor_data/clean", "sensor_data"):
                if k in f and isinstance(f[k], h5py.Dataset):
                    ds = f[k]
                    break
            if ds is None:
                found = []
                f.visititems(lambda n, o: found.append(o) if isinstance(o, h5py.Dataset)
                             and o.ndim in (2, 3) else None)
                if len(found) != 1:
                    raise ValueError(f"no 'sensor_data/clean' or 'sensor_data' dataset, and cannot tell "
                                     f"which dataset holds the data ({len(found)} 2-/3-D datasets); give key")
                ds = found[0]
        if ds.size > MAX_ELEMENTS:
            raise ValueError(f"array too large ({ds.size} elements)")
        data = _grid_array(ds[()])
        fa, da, name = dict(f.attrs), dict(ds.attrs), ds.name
    def get(name: str) -> Any:
        return kwave_layout.attribute(da, fa, name)

    kwave = kwave_layout.is_kwave_named(da, fa)
    lat_x, lat_y = kwave_layout.lateral_spacings(da, fa, data.ndim)
    dt = dt if dt is not None else get("dt_s")
    dx = dx if dx is not None else lat_x
    if dt is None:
        raise ValueError("dt is neither given nor in the file (attribute dt_s)")
    if dx is None:
        raise ValueError("the lateral spacing is neither given (dx) nor in the file")
    dx = _positive("dx", dx)
    if data.ndim == 3:
        dy = _positive("dy", dy if dy is not None else (lat_y if lat_y is not None else dx))
    else:
        dy = None
    c = c if c is not None else get("c_m_per_s")
    return GridDataset(data=data, dx=dx, dy=dy, dt=_positive("dt", dt),
                       c=_positive("c", c if c is not None else C_DEFAULT), source="kwave-hdf5",
                       meta={"key": name, "kwave_naming": kwave})


def lattice_axes(lattice: dict) -> tuple[np.ndarray, np.ndarray]:
    """The lattice's coordinate vectors ``(x, y)`` (m, centred; :func:`centred_axis`) of
    ``{"n_x", "n_y", "pitch"}``."""
    pitch = float(lattice["pitch"])
    return centred_axis(int(lattice["n_x"]), pitch), centred_axis(int(lattice.get("n_y", 1)), pitch)


def _check_index(index: int, wavelengths: Any, what: str) -> None:
    n = int(np.size(wavelengths))
    if not 0 <= index < max(n, 1):
        raise ValueError(f"wavelength index {index} is out of range: the {what} has {n} wavelength"
                         f"{'s' if n != 1 else ''} ({_nm(wavelengths)}), indices 0..{max(n, 1) - 1}")


def load_scan(path: str | os.PathLike, *, allow_empty: bool = False, wavelength_index: int = 0) -> PointDataset:
    """The completed points of a scan file at excitation wavelength ``wavelength_index``
    (default the first) as point data (DC-normalised pressure ``(n, n_t)`` float64, the
    plan's positions and weights, its lattice and indices; ``wavelengths``: the one
    wavelength read (m); ``meta["wavelengths"]`` all the scan's, ``meta["wavelength_index"]``
    the one read). Raises ValueError when no point is complete (unless ``allow_empty``),
    the plan is invalid or the wavelength index is out of range (naming the scan's
    wavelengths)."""
    from driver.plan import check_plan
    from driver.scanfile import pressure_unit, read_scan

    scan = read_scan(path)
    _check_index(wavelength_index, scan.wavelengths, "scan")
    scan = scan.at_wavelength(wavelength_index).completed_only() if wavelength_index else scan.completed_only()
    check_plan(scan.plan)  # its lattice becomes the reconstruction grid: bounded there
    if scan.n_points == 0 and not allow_empty:
        raise ValueError("the scan file has no completed A-lines")
    lat = scan.plan.get("lattice", {})
    positions = np.asarray(scan.positions, dtype=np.float64)
    two_d = positions.shape[1] == 1 or int(lat.get("n_y", 2)) == 1
    if lat:
        gx, gy = lattice_axes(lat)
        lattice = {"n_x": int(lat["n_x"]), "n_y": int(lat.get("n_y", 1)), "pitch": float(lat["pitch"])}
    else:
        gx = np.unique(positions[:, 0])
        gy = np.unique(positions[:, 1]) if positions.shape[1] > 1 else np.zeros(1)
        lattice = None
    all_w = np.ravel(np.asarray(scan.wavelengths, dtype=np.float64))
    wavelengths = (float(all_w[wavelength_index]),) if all_w.size else None
    return PointDataset(
        alines=scan.pressure, positions=positions[:, :1] if two_d else positions,
        weights=np.asarray(scan.weights, dtype=np.float64), dt=scan.dt, c=scan.sound_speed,
        grid=(gx,) if two_d else (gx, gy), source="fpscan",
        meta={"plan_id": scan.plan_id, "plan": scan.plan, "indices": scan.indices,
              "wavelengths": scan.wavelengths, "n_points_planned": int(scan.attrs["n_points"]),
              "wavelength_index": int(wavelength_index), "p0_unit": pressure_unit(scan.instrument)},
        indices=np.asarray(scan.indices, dtype=np.int64).reshape(-1, 2), lattice=lattice,
        wavelengths=wavelengths)


def load_ipasc(path: str | os.PathLike, *, wavelength_index: int = 0) -> PointDataset:
    """An IPASC file as point data (:func:`service.storage.ipasc.read_ipasc`) at excitation
    wavelength ``wavelength_index`` (default the first; ``wavelengths``: that one,
    ``meta["wavelengths"]`` all the file's). Raises ValueError, also for an index out of
    range (naming the file's wavelengths)."""
    from service.storage.ipasc import read_ipasc

    r = read_ipasc(path)
    if wavelength_index:
        _check_index(wavelength_index, [] if r["wavelengths"] is None else r["wavelengths"], "file")
        r = read_ipasc(path, wavelength_index=wavelength_index)
    plan, indices = r["plan"], r["indices"]
    lattice = None
    if isinstance(plan, dict) and isinstance(plan.get("lattice"), dict) and indices is not None:
        lat = plan["lattice"]
        lattice = {"n_x": int(lat["n_x"]), "n_y": int(lat.get("n_y", 1)), "pitch": float(lat["pitch"])}
        indices = np.asarray(indices, dtype=np.int64).reshape(-1, 2)
    wl = r["wavelengths"]
    return PointDataset(alines=r["alines"], positions=r["positions"], weights=r["weights"],
                        dt=r["dt"], c=r["c"], grid=r["grid"], source="ipasc",
                        meta={"uuid": r["uuid"], "plan": plan, "indices": r["indices"],
                              "wavelengths": wl, "wavelength_index": int(wavelength_index)},
                        indices=indices if lattice is not None else None, lattice=lattice,
                        wavelengths=(float(np.ravel(wl)[wavelength_index]),)
                        if wl is not None and np.size(wl) > wavelength_index else None)


def load_wavelengths(path: str | os.PathLike, format: str | None = None, *, wavelength: Any = None,
                     **load: Any) -> list[GridDataset | PointDataset]:
    """The datasets of ``path`` at the chosen excitation wavelength(s): ``wavelength`` an
    index or None (one dataset, :func:`load_dataset`) or ``"all"`` (one per wavelength of
    the file, in its order; a file of one wavelength gives one). ``load``: the other
    arguments of :func:`load_dataset`. Raises ValueError (a bad choice, an index out of
    range naming the file's wavelengths, what :func:`load_dataset` raises),
    FileNotFoundError."""
    choice = check_wavelength(wavelength)
    if not isinstance(choice, str):  # an index or None
        return [load_dataset(path, format, wavelength=choice, **load)]
    first = load_dataset(path, format, wavelength=0, **load)
    n = file_wavelengths(first).size
    return [first] + [load_dataset(path, format, wavelength=k, **load) for k in range(1, n)]


def write_dataset(path: str | os.PathLike, ds: GridDataset | PointDataset) -> None:
    """Write the canonical dataset file (format ``fpscan-dataset/1``), exactly (dtype kept).

    Layout ``grid``: ``/data`` ``(n_t, n_y, n_x)``/``(n_t, n_x)``; attributes ``dt`` (s),
    ``dx``, ``dy`` (3-D; m), ``c`` (m/s), ``t0`` (s). Layout ``points``: ``/alines``
    ``(n, n_t)``, ``/positions`` ``(n, d)`` m, ``/weights`` ``(n,)`` (if any), ``/grid_x``,
    ``/grid_y`` (3-D) m; attributes ``dt``, ``c``, ``t0``; a lattice adds ``/lattice``
    ``(n, 2)`` indices (i_x, i_y) and attributes ``lattice_shape`` ``(n_y, n_x)``, ``pitch``.
    Both: attribute ``format``, ``layout``, ``source``; ``wavelengths_m`` when known, and
    ``wavelength_index`` (into the source file's wavelengths) when it was chosen from a
    multi-wavelength file; ``p0_unit`` (``"Pa"`` for calibrated pressure, else ``"a.u."``:
    :func:`p0_unit`)."""
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": DATASET_FORMAT, "layout": ds.kind, "dt": float(ds.dt), "c": float(ds.c),
                        "t0": float(ds.t0), "source": ds.source})
        if ds.wavelengths is not None:
            f.attrs["wavelengths_m"] = np.asarray(ds.wavelengths, dtype=np.float64)
        if (ds.meta or {}).get("wavelength_index") is not None:
            f.attrs["wavelength_index"] = int(ds.meta["wavelength_index"])
        f.attrs["p0_unit"] = p0_unit(ds)
        if isinstance(ds, GridDataset):
            f.create_dataset("data", data=ds.data)
            f.attrs["dx"] = float(ds.dx)
            if ds.dy is not None and ds.data.ndim == 3:
                f.attrs["dy"] = float(ds.dy)
            return
        f.create_dataset("alines", data=np.asarray(ds.alines))
        f.create_dataset("positions", data=np.asarray(ds.positions, dtype=np.float64))
        if ds.weights is not None:
            f.create_dataset("weights", data=np.asarray(ds.weights, dtype=np.float64))
        f.create_dataset("grid_x", data=np.asarray(ds.grid[0], dtype=np.float64))
        if len(ds.grid) > 1:
            f.create_dataset("grid_y", data=np.asarray(ds.grid[1], dtype=np.float64))
        if ds.lattice is not None and ds.indices is not None:
            f.create_dataset("lattice", data=np.asarray(ds.indices, dtype=np.int64))
            f.attrs["lattice_shape"] = (int(ds.lattice.get("n_y", 1)), int(ds.lattice["n_x"]))
            f.attrs["pitch"] = float(ds.lattice["pitch"])


def read_dataset(path: str | os.PathLike) -> GridDataset | PointDataset:
    """Read a canonical dataset file (:func:`write_dataset`; also the layout without the
    ``format`` attribute that earlier versions wrote). Raises ValueError for a file that
    is not one."""
    def text(v: Any) -> str:
        return v.decode() if isinstance(v, bytes) else str(v)

    with _open_h5(Path(path)) as f:
        try:
            layout = text(f.attrs["layout"])
            dt, c, t0 = float(f.attrs["dt"]), float(f.attrs["c"]), float(f.attrs.get("t0", 0.0))
            wl = f.attrs.get("wavelengths_m")
            wavelengths = tuple(float(w) for w in np.ravel(wl)) if wl is not None and np.size(wl) else None
            source = text(f.attrs.get("source", "dataset"))
            meta: dict[str, Any] = ({"wavelength_index": int(f.attrs["wavelength_index"])}
                                    if "wavelength_index" in f.attrs else {})
            if text(f.attrs.get("p0_unit", "a.u.")) == "Pa":
                meta["p0_unit"] = "Pa"
            if layout == "grid":
                data = f["data"][()]
                dy = float(f.attrs["dy"]) if "dy" in f.attrs and data.ndim == 3 else None
                return GridDataset(data=data, dx=float(f.attrs["dx"]), dt=dt, c=c, dy=dy, t0=t0,
                                   source=source, wavelengths=wavelengths, meta=meta)
            if layout != "points":
                raise ValueError(f"unknown dataset layout {layout!r}")
            gx = f["grid_x"][()]
            grid = (gx, f["grid_y"][()]) if "grid_y" in f else (gx,)
            indices = lattice = None
            if "lattice" in f:
                n_y, n_x = (int(v) for v in f.attrs["lattice_shape"])
                lattice = {"n_x": n_x, "n_y": n_y, "pitch": float(f.attrs["pitch"])}
                indices = f["lattice"][()].astype(np.int64).reshape(-1, 2)
            return PointDataset(alines=f["alines"][()], positions=f["positions"][()],
                                weights=f["weights"][()] if "weights" in f else None, dt=dt, c=c,
                                grid=grid, t0=t0, source=source, indices=indices, lattice=lattice,
                                wavelengths=wavelengths, meta=meta)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a canonical dataset file ({exc})") from None


def dataset_nbytes(ds: GridDataset | PointDataset) -> int:
    """Bytes of the arrays :func:`write_dataset` writes for ``ds`` (the canonical file's
    size less its metadata)."""
    if isinstance(ds, GridDataset):
        return int(ds.data.nbytes)
    arrays = [ds.alines, ds.positions, ds.weights, ds.indices, *ds.grid]
    return int(sum(np.asarray(a).nbytes for a in arrays if a is not None))


HDF5_KEY_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-/.")


def import_dataset(src: str | os.PathLike, dest_dir: str | os.PathLike, fmt: str, *, dt, dx, dy, c, key,
                   max_bytes: int | None = None, force: bool = False, wavelength: int | None = None) -> dict:
    """Validate and convert an uploaded file with :func:`load_dataset` (all four formats)
    into ``dest_dir/dataset.h5`` (:func:`write_dataset`); returns the dataset's metadata
    (the API stores it in the job store). Run by ``POST /api/datasets`` in a bounded child
    process (``service.storage.untrusted.run_bounded``).
    ``max_bytes``: largest declared dataset of an HDF5 file
    (:func:`service.storage.untrusted.check_hdf5`, run before anything is read).
    ``force``: accept a ``c`` outside 1000-2000 m/s (as :func:`load_dataset`).
    ``wavelength``: which excitation wavelength of a multi-wavelength file to store (an
    index; None: the first; as :func:`load_dataset`, recorded in the metadata).
    Before the dataset file is written its bytes (:func:`dataset_nbytes`) are admitted
    (``service.storage.untrusted.request_admission``: the service's free-disk admission).
    Raises ``ValueError`` with the reason; ``service.storage.untrusted.NotAdmitted`` when
    the disk cannot take it."""
    if key is not None and (not key or len(key) > 200 or not set(key) <= HDF5_KEY_CHARS):
        raise ValueError("key must be an HDF5 dataset path of [A-Za-z0-9_-/.]")
    for name, value in (("dt", dt), ("dx", dx), ("dy", dy), ("c", c)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number")
    try:
        ds = load_dataset(src, fmt, dt=dt, dx=dx, dy=dy, c=c, key=key, force=force, wavelength=wavelength,
                          max_bytes=MAX_ELEMENTS * 8 if max_bytes is None else max_bytes)
    except (KeyError, TypeError, IndexError, OSError) as exc:
        raise ValueError(f"file is not a readable {fmt} dataset ({type(exc).__name__})") from None
    dest_dir = Path(dest_dir)
    if isinstance(ds, PointDataset) and ds.alines.shape[0] == 0:
        raise ValueError("the dataset holds no A-lines")
    from service.storage.untrusted import request_admission

    request_admission(dataset_nbytes(ds))  # the service's disk admission, before a byte is written
    write_dataset(dest_dir / "dataset.h5", ds)
    common = {"dt": ds.dt, "c": ds.c, "path": "dataset.h5", **wavelength_params(ds)}
    if isinstance(ds, GridDataset):
        return {"layout": "grid", "shape": list(ds.data.shape), "dx": ds.dx, **common}
    n_x, n_y = len(ds.grid[0]), len(ds.grid[1]) if len(ds.grid) > 1 else 1
    return {"layout": "points", "shape": list(ds.alines.shape), "n_x": n_x, "n_y": n_y,
            "full_lattice": ds.full_lattice,
            "dx": float(ds.grid[0][1] - ds.grid[0][0]) if len(ds.grid[0]) > 1 else None, **common}
