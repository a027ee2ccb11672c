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
  or our x in 2-D) and ``dz_m`` (our x); other files use ``dx_m``/``dy_m`` for our x/y.
  ``dt_s`` and ``c_m_per_s`` give dt and c.
- ``"npy"``: a NumPy ``.npy`` array in the same layout (loaded with
  ``allow_pickle=False``); ``dt`` and ``dx`` are required arguments.

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

FORMATS = ("fpscan", "ipasc", "kwave-hdf5", "npy")
MAX_ELEMENTS = 2 ** 31


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

    kind = "grid"

    @property
    def ndim(self) -> int:
        """2 (line sensor) or 3 (planar sensor)."""
        return self.data.ndim

    def axes(self) -> tuple[np.ndarray, ...]:
        """Lateral coordinate vectors: ``(x,)`` in 2-D, ``(x, y)`` in 3-D, m, centred."""
        n_x = self.data.shape[-1]
        x = (np.arange(n_x) - (n_x - 1) / 2.0) * self.dx
        if self.data.ndim == 2:
            return (x,)
        n_y = self.data.shape[1]
        return x, (np.arange(n_y) - (n_y - 1) / 2.0) * (self.dy or self.dx)


@dataclass
class PointDataset:
    """A-lines at arbitrary sensor positions. ``alines`` ``(n, n_t)``; ``positions``
    ``(n, 2)`` (x, y) m or ``(n, 1)`` in 2-D; ``weights`` ``(n,)`` area weights or None
    (then the reconstruction computes Voronoi weights); ``dt`` s; ``c`` m/s; ``grid``: the
    regular lateral vectors ``(x,)``/``(x, y)`` to reconstruct on; ``t0`` s; ``source``;
    ``meta`` (plan, lattice indices, wavelengths, ...)."""

    alines: np.ndarray
    positions: np.ndarray
    weights: np.ndarray | None
    dt: float
    c: float
    grid: tuple
    t0: float = 0.0
    source: str = ""
    meta: dict = field(default_factory=dict)

    kind = "points"

    @property
    def ndim(self) -> int:
        return 3 if self.positions.shape[1] == 2 else 2


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


def detect_format(path: str | os.PathLike) -> str:
    """Guess the format of a file from its content; ValueError if none fits."""
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head != b"\x89HDF\r\n\x1a\n":
        raise ValueError("file is neither HDF5 nor a NumPy .npy array")
    with _open_h5(path) as f:
        if str(f.attrs.get("format", "")).startswith("fpscan-scan/"):  # /1 and /2
            return "fpscan"
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
                 key: str | None = None, max_bytes: int = MAX_ELEMENTS * 8) -> GridDataset | PointDataset:
    """Import a file for reconstruction (module docstring). Explicit ``dt`` (s), ``dx``,
    ``dy`` (m) and ``c`` (m/s) override what the file says. An HDF5 file is checked
    first (``service.storage.untrusted.check_hdf5``: no external storage, external links
    or virtual datasets, no dataset declaring more than ``max_bytes`` or more than it
    stores). Raises ValueError naming the fault, FileNotFoundError."""
    from service.storage.untrusted import check_hdf5, is_hdf5

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
    if fmt == "npy":
        return load_npy(path, dt=dt, dx=dx, dy=dy, c=c)
    if fmt == "kwave-hdf5":
        return load_kwave_hdf5(path, key=key, dt=dt, dx=dx, dy=dy, c=c)
    if fmt == "fpscan":
        ds = load_scan(path)
    else:
        ds = load_ipasc(path)
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
                       c=_positive("c", c if c is not None else 1500.0),
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
                    raise ValueError(f"cannot tell which dataset holds the data ({len(found)} "
                                     "2-/3-D datasets); give key")
                ds = found[0]
        if ds.size > MAX_ELEMENTS:
            raise ValueError(f"array too large ({ds.size} elements)")
        data = _grid_array(ds[()])
        fa, da, name = dict(f.attrs), dict(ds.attrs), ds.name
    get = lambda name: da.get(name, fa.get(name))  # noqa: E731
    kwave = "kwave_DataOrder" in da or "kwave_commit" in fa
    if kwave:
        lat_x = get("dz_m") if data.ndim == 3 else get("dy_m")
        lat_y = get("dy_m") if data.ndim == 3 else None
    else:
        lat_x, lat_y = get("dx_m"), get("dy_m")
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
                       c=_positive("c", c if c is not None else 1500.0), source="kwave-hdf5",
                       meta={"key": name, "kwave_naming": kwave})


def _lattice_axes(lattice: dict) -> tuple[np.ndarray, np.ndarray]:
    n_x, n_y, pitch = int(lattice["n_x"]), int(lattice.get("n_y", 1)), float(lattice["pitch"])
    return ((np.arange(n_x) - (n_x - 1) / 2.0) * pitch,
            (np.arange(n_y) - (n_y - 1) / 2.0) * pitch)


def load_scan(path: str | os.PathLike) -> PointDataset:
    """The completed points of a scan file as point data (DC-normalised pressure)."""
    from driver.plan import check_plan
    from driver.scanfile import read_scan

    scan = read_scan(path).completed_only()
    check_plan(scan.plan)  # its lattice becomes the reconstruction grid: bounded there
    if scan.n_points == 0:
        raise ValueError("the scan file has no completed A-lines")
    lat = scan.plan.get("lattice", {})
    positions = np.asarray(scan.positions, dtype=np.float64)
    two_d = positions.shape[1] == 1 or int(lat.get("n_y", 2)) == 1
    if lat:
        gx, gy = _lattice_axes(lat)
    else:
        gx = np.unique(positions[:, 0])
        gy = np.unique(positions[:, 1]) if positions.shape[1] > 1 else np.zeros(1)
    return PointDataset(
        alines=scan.pressure, positions=positions[:, :1] if two_d else positions,
        weights=np.asarray(scan.weights, dtype=np.float64), dt=scan.dt, c=scan.sound_speed,
        grid=(gx,) if two_d else (gx, gy), source="fpscan",
        meta={"plan_id": scan.plan_id, "plan": scan.plan, "indices": scan.indices,
              "wavelengths": scan.wavelengths, "n_points_planned": int(scan.attrs["n_points"])})


def load_ipasc(path: str | os.PathLike) -> PointDataset:
    """An IPASC file as point data (:func:`service.storage.ipasc.read_ipasc`)."""
    from service.storage.ipasc import read_ipasc

    r = read_ipasc(path)
    return PointDataset(alines=r["alines"], positions=r["positions"], weights=r["weights"],
                        dt=r["dt"], c=r["c"], grid=r["grid"], source="ipasc",
                        meta={"uuid": r["uuid"], "plan": r["plan"], "indices": r["indices"],
                              "wavelengths": r["wavelengths"]})
