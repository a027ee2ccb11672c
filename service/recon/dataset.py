"""The input of every reconstruction: :class:`GridDataset` (data on a regular sensor grid)
and :class:`PointDataset` (A-lines at sensor points), with their validation.

The file formats that produce them live in :mod:`service.formats` (one module per format,
one registry); :func:`service.storage.datasets.load_dataset` is the one loader of a file
for reconstruction, :func:`service.pipeline.reconstruct` the one dispatch that consumes
them. A point dataset that covers its whole lattice turns into grid data with
:meth:`PointDataset.to_grid` (so grid methods work on a full-lattice scan everywhere);
grid data into point data with :meth:`GridDataset.to_points`. A dataset may carry the
excitation ``wavelengths`` (m) it was acquired at; one read from a multi-wavelength file
records ``meta["wavelength_index"]`` and the file's ``meta["wavelengths"]``.

Lateral grids are centred on the optical axis (docs/architecture.md):
``x_i = (i - (n_x - 1)/2)·dx``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from driver.physics.axes import centred_axis

__all__ = ["GridDataset", "PointDataset", "Dataset", "MAX_ELEMENTS", "ALL_WAVELENGTHS", "check_wavelength",
           "check_wavelength_index", "file_wavelengths", "wavelength_params", "p0_unit", "positive",
           "grid_array", "lattice_axes", "dataset_nbytes"]

MAX_ELEMENTS = 2 ** 31
#: ``wavelength="all"``: every wavelength of a multi-wavelength file, one dataset (one volume) each
ALL_WAVELENGTHS = "all"


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
    """Wavelengths (m) as text in nm: ``"532 nm, 1064 nm"``."""
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


def positive(name: str, v: Any) -> float:
    """``v`` as a positive finite float; ValueError naming ``name`` otherwise."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {v!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"{name} must be a positive finite number, got {v!r}")
    return f


def grid_array(a: np.ndarray) -> np.ndarray:
    """Grid data as read from a file, checked: real numbers, ``(n_t, n_x)`` or
    ``(n_t, n_y, n_x)`` (time first), at least 2 samples per axis, at most
    :data:`MAX_ELEMENTS`, all finite; returned as float32 (float64 for wider types).
    Raises ValueError naming the fault."""
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


def lattice_axes(lattice: dict) -> tuple[np.ndarray, np.ndarray]:
    """The lattice's coordinate vectors ``(x, y)`` (m, centred; :func:`centred_axis`) of
    ``{"n_x", "n_y", "pitch"}``."""
    pitch = float(lattice["pitch"])
    return centred_axis(int(lattice["n_x"]), pitch), centred_axis(int(lattice.get("n_y", 1)), pitch)


def check_wavelength_index(index: int, wavelengths: Any, what: str) -> None:
    """ValueError naming ``wavelengths`` (m) when ``index`` is not one of theirs (``what``:
    "scan", "file")."""
    n = int(np.size(wavelengths))
    if not 0 <= index < max(n, 1):
        raise ValueError(f"wavelength index {index} is out of range: the {what} has {n} wavelength"
                         f"{'s' if n != 1 else ''} ({_nm(wavelengths)}), indices 0..{max(n, 1) - 1}")


def dataset_nbytes(ds: GridDataset | PointDataset) -> int:
    """Bytes of the arrays :func:`write_dataset` writes for ``ds`` (the canonical file's
    size less its metadata)."""
    if isinstance(ds, GridDataset):
        return int(ds.data.nbytes)
    arrays = [ds.alines, ds.positions, ds.weights, ds.indices, *ds.grid]
    return int(sum(np.asarray(a).nbytes for a in arrays if a is not None))


HDF5_KEY_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-/.")

