"""The input of every reconstruction: :class:`GridDataset` (data on a regular sensor grid)
and :class:`PointDataset` (A-lines at sensor points), with their validation.

The file formats that produce them live in :mod:`fpscan.service.formats` (one module per format,
one registry); :func:`fpscan.service.storage.loader.load_dataset` is the one loader of a file
for reconstruction, :func:`fpscan.service.pipeline.reconstruct` the one dispatch that consumes
them. A point dataset that covers its whole lattice turns into grid data with
:meth:`PointDataset.to_grid` (so grid methods work on a full-lattice scan everywhere);
grid data into point data with :meth:`GridDataset.to_points`. A dataset may carry the
excitation ``wavelengths`` (m) it was acquired at; one read from a multi-wavelength file
records ``meta["wavelength_index"]`` and the file's ``meta["wavelengths"]``.

Lateral grids are centred on the optical axis (docs/architecture.md):
``x_i = (i - (n_x - 1)/2)·dx``; a dataset whose file gives its own sensor coordinates, or
follows k-Wave's ``kWaveGrid`` (``(i - floor(N/2))·dx``), carries the difference as
``lateral_shift`` (m), which :func:`fpscan.service.pipeline.reconstruct` adds to the image's
lateral coordinates (docs/file-formats.md "Lateral coordinates").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from fpscan.physics.axes import centred_axis

__all__ = ["GridDataset", "PointDataset", "Dataset", "MAX_ELEMENTS", "ALL_WAVELENGTHS", "check_wavelength",
           "check_wavelength_index", "file_wavelengths", "wavelength_params", "p0_unit", "positive",
           "grid_array", "lattice_axes", "dataset_nbytes", "lateral_shift_of", "check_dataset"]

MAX_ELEMENTS = 2 ** 31
#: ``wavelength="all"``: every wavelength of a multi-wavelength file, one dataset (one volume) each
ALL_WAVELENGTHS = "all"


def check_wavelength(wavelength: Any, *, allow_all: bool = True) -> int | str | None:
    """A wavelength choice as given, checked.

    Parameters
    ----------
    wavelength : None, int or str
        None (the default: the first wavelength), an index >= 0 (an int, or its decimal text
        as a command line gives it) or ``"all"`` (case-insensitive).
    allow_all : bool, optional
        Whether ``"all"`` is accepted (default True).

    Returns
    -------
    int, str or None
        The index, ``"all"`` or None.

    Raises
    ------
    ValueError
        Anything else, naming the choice.

    Examples
    --------
    >>> from fpscan.service.recon.dataset import check_wavelength
    >>> check_wavelength(None), check_wavelength("2"), check_wavelength("All"), check_wavelength(1)
    (None, 2, 'all', 1)
    >>> check_wavelength(-1)
    Traceback (most recent call last):
    ...
    ValueError: wavelength must be an index >= 0 into the file's wavelengths or 'all', got -1
    """
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
    """The excitation wavelengths of the file a dataset was read from.

    All of them, not only the one the dataset holds (``meta["wavelengths"]``, else the
    dataset's own).

    Parameters
    ----------
    ds : GridDataset or PointDataset

    Returns
    -------
    ndarray, shape ``(n_w,)``
        Wavelengths in m; empty when the file records none.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset, file_wavelengths
    >>> ds = GridDataset(np.zeros((64, 4)), dx=1e-4, dt=2e-8, sound_speed=1500.0, wavelengths=(7.5e-7,),
    ...                  meta={"wavelength_index": 1, "wavelengths": [5.32e-7, 7.5e-7]})
    >>> file_wavelengths(ds)  # m
    array([5.32e-07, 7.50e-07])
    >>> file_wavelengths(GridDataset(np.zeros((64, 4)), 1e-4, 2e-8, 1500.0)).size
    0
    """
    w = (ds.meta or {}).get("wavelengths")
    if w is None:
        w = ds.wavelengths
    return np.asarray([] if w is None else w, dtype=np.float64).reshape(-1)


def wavelength_params(ds: GridDataset | PointDataset) -> dict:
    """What a reconstruction of a dataset records about its wavelength.

    Parameters
    ----------
    ds : GridDataset or PointDataset

    Returns
    -------
    dict
        ``wavelength_index`` (into the file's wavelengths, when read from a multi-wavelength
        file) and ``wavelength_nm`` (when ``ds`` holds one known wavelength's data); ``{}``
        otherwise.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset, wavelength_params
    >>> ds = GridDataset(np.zeros((64, 4)), dx=1e-4, dt=2e-8, sound_speed=1500.0, wavelengths=(7.5e-7,),
    ...                  meta={"wavelength_index": 1, "wavelengths": [5.32e-7, 7.5e-7]})
    >>> wavelength_params(ds)
    {'wavelength_index': 1, 'wavelength_nm': 750.0}
    >>> wavelength_params(GridDataset(np.zeros((64, 4)), 1e-4, 2e-8, 1500.0))
    {}
    """
    out: dict = {}
    if (ds.meta or {}).get("wavelength_index") is not None:
        out["wavelength_index"] = int(ds.meta["wavelength_index"])
    w = np.asarray([] if ds.wavelengths is None else ds.wavelengths, dtype=np.float64).reshape(-1)
    if w.size == 1:
        out["wavelength_nm"] = round(float(w[0]) * 1e9, 6)
    return out


@dataclass
class GridDataset:
    """Data on a regular sensor line or plane: the input of the grid methods.

    Parameters
    ----------
    data, dx, dt, sound_speed, dy, t0, source, meta, wavelengths, lateral_shift
        As the attributes below (``c``, an earlier release's name of ``sound_speed``, is
        accepted with a ``DeprecationWarning``).

    Attributes
    ----------
    data : ndarray, shape ``(n_t, n_x)`` or ``(n_t, n_y, n_x)``
        Time first (k-Wave's 'ty' / 'tyz' order), Pa (or the instrument's unit).
    dx : float
        Lateral spacing along x, m.
    dt : float
        Sample interval, s.
    sound_speed : float
        Speed of sound, m/s (k-Wave's ``medium.sound_speed``).
    dy : float or None
        Spacing along y, m (None in 2-D, or dy = dx).
    t0 : float
        Time of sample 0, s.
    source : str
        The format it was read from.
    meta : dict
        Anything else (``p0_unit``, ``wavelength_index``, ...).
    wavelengths : tuple of float or None
        Excitation wavelength(s) of these data, m.
    lateral_shift : tuple of float or None
        ``(x,)`` or ``(x, y)``, m: the data's own lateral coordinates minus the centred ones of
        :meth:`axes` (the file's sensor coordinates, or k-Wave's ``kWaveGrid`` origin); the
        reconstruction's ``x``/``y`` are shifted by it. None: the centred convention.
    kind : str
        ``"grid"``.
    ndim : int
        2 (line sensor) or 3 (planar sensor).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> ds = GridDataset(np.zeros((64, 3, 4), np.float32), dx=1e-4, dt=2e-8, sound_speed=1500.0)
    >>> ds.ndim, [a.round(6).tolist() for a in ds.axes()]  # (x, y) in m, centred
    (3, [[-0.00015, -5e-05, 5e-05, 0.00015], [-0.0001, 0.0, 0.0001]])
    >>> pts = ds.to_points()  # every grid point a sensor
    >>> pts.alines.shape, pts.positions.shape  # (n_y n_x, n_t), (n, 2) (x, y) in m
    ((12, 64), (12, 2))
    """

    data: np.ndarray
    dx: float
    dt: float
    sound_speed: float
    dy: float | None = None
    t0: float = 0.0
    source: str = ""
    meta: dict = field(default_factory=dict)
    wavelengths: tuple[float, ...] | None = None
    lateral_shift: tuple[float, ...] | None = None

    kind = "grid"

    def __repr__(self) -> str:
        """One line: the source, shape and axes, spacings, dt and the speed of sound (never the array).

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon.dataset import GridDataset
        >>> GridDataset(np.zeros((64, 3, 4), np.float32), dx=1e-4, dt=2e-8, sound_speed=1500.0)
        GridDataset((64, 3, 4) float32 (n_t, n_y, n_x), dx 100 µm, dy 100 µm, dt 20 ns, sound_speed 1500 m/s)
        """
        axes = "(n_t, n_x)" if self.data.ndim == 2 else "(n_t, n_y, n_x)"
        dy = f", dy {(self.dy or self.dx) * 1e6:.4g} µm" if self.data.ndim == 3 else ""
        src = f"{self.source}: " if self.source else ""
        return (f"GridDataset({src}{tuple(self.data.shape)} {self.data.dtype} {axes}, dx {self.dx * 1e6:.4g} µm{dy}, "
                f"dt {self.dt * 1e9:.4g} ns, sound_speed {self.sound_speed:g} m/s)")

    @property
    def ndim(self) -> int:
        """2 (line sensor) or 3 (planar sensor)."""
        return self.data.ndim

    def axes(self) -> tuple[np.ndarray, ...]:
        """Lateral coordinate vectors, centred on the optical axis.

        Returns
        -------
        tuple of ndarray
            ``(x,)`` in 2-D, ``(x, y)`` in 3-D; shapes ``(n_x,)``, ``(n_y,)``; m.

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon.dataset import GridDataset
        >>> [a.shape for a in GridDataset(np.zeros((8, 3, 4)), 1e-4, 2e-8, 1500.0).axes()]
        [(4,), (3,)]
        """
        x = centred_axis(self.data.shape[-1], self.dx)
        if self.data.ndim == 2:
            return (x,)
        return x, centred_axis(self.data.shape[1], self.dy or self.dx)

    def to_points(self) -> PointDataset:
        """Every grid point as a sensor.

        Returns
        -------
        PointDataset
            ``alines`` ``(n_y·n_x, n_t)`` in C order of ``(n_y, n_x)``, positions ``(n, 2)``
            (x, y) in m (``(n, 1)`` in 2-D), no weights (the reconstruction then uses clipped
            Voronoi areas, here the grid cells), ``grid`` = :meth:`axes`.

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon.dataset import GridDataset
        >>> pts = GridDataset(np.zeros((8, 5)), 1e-4, 2e-8, 1500.0).to_points()
        >>> pts.alines.shape, pts.positions.shape, pts.weights
        ((5, 8), (5, 1), None)
        """
        axes = self.axes()
        if self.data.ndim == 2:
            alines, positions = self.data.T, axes[0][:, None]
        else:
            yy, xx = np.meshgrid(axes[1], axes[0], indexing="ij")
            alines = self.data.reshape(self.data.shape[0], -1).T
            positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
        return PointDataset(alines=alines, positions=positions, weights=None, dt=self.dt, sound_speed=self.sound_speed,
                            grid=axes, t0=self.t0, source=self.source, meta=dict(self.meta),
                            wavelengths=self.wavelengths, lateral_shift=self.lateral_shift)


@dataclass
class PointDataset:
    """A-lines at arbitrary sensor positions: the input of NEDNER (and, on a full lattice, of
    the grid methods via :meth:`to_grid`).

    Parameters
    ----------
    alines, positions, weights, dt, sound_speed, grid, t0, source, meta, indices, lattice, wavelengths, lateral_shift
        As the attributes below (``c``, an earlier release's name of ``sound_speed``, is
        accepted with a ``DeprecationWarning``).

    Attributes
    ----------
    alines : ndarray, shape ``(n, n_t)``
        One A-line per sensor, Pa (or the instrument's unit).
    positions : ndarray, shape ``(n, 2)`` or ``(n, 1)``
        Sensor positions (x, y), or x in 2-D, m.
    weights : ndarray, shape ``(n,)``, or None
        Area weights, m² (m in 2-D); None: the reconstruction computes clipped Voronoi areas.
    dt : float
        Sample interval, s.
    sound_speed : float
        Speed of sound, m/s (k-Wave's ``medium.sound_speed``).
    grid : tuple of ndarray
        The regular lateral vectors ``(x,)`` or ``(x, y)`` to reconstruct on, m.
    t0 : float
        Time of sample 0, s.
    source : str
        The format it was read from.
    meta : dict
        Plan, calibration, ...
    indices : ndarray of int, shape ``(n, 2)``, or None
        Lattice indices (i_x, i_y) when the points come from a scanner lattice.
    lattice : dict or None
        ``{"n_x", "n_y", "pitch"}`` (pitch in m) of that lattice.
    wavelengths : tuple of float or None
        Excitation wavelength(s), m.
    lateral_shift : tuple of float or None
        ``(x,)`` or ``(x, y)``, m, added to the reconstruction's lateral coordinates (as
        :class:`GridDataset`'s; ``positions`` and ``grid`` stay in the centred frame).
    kind : str
        ``"points"``.
    ndim : int
        2 (positions ``(n, 1)``) or 3.
    full_lattice : bool
        True when the points are every point of their lattice, exactly once.

    Raises
    ------
    ValueError
        :meth:`to_grid` on data not on a full lattice.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import PointDataset
    >>> ds = PointDataset(alines=np.ones((3, 64)), positions=np.array([[-1e-4], [0.0], [1e-4]]),
    ...                   weights=None, dt=2e-8, sound_speed=1500.0, grid=(np.array([-1e-4, 0.0, 1e-4]),),
    ...                   indices=np.array([[0, 0], [1, 0], [2, 0]]),
    ...                   lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
    >>> ds.ndim, ds.full_lattice
    (2, True)
    >>> grid = ds.to_grid()  # (n_t, n_x) on a line lattice
    >>> grid.data.shape, grid.dx
    ((64, 3), 0.0001)
    """

    alines: np.ndarray
    positions: np.ndarray
    weights: np.ndarray | None
    dt: float
    sound_speed: float
    grid: tuple
    t0: float = 0.0
    source: str = ""
    meta: dict = field(default_factory=dict)
    indices: np.ndarray | None = None
    lattice: dict | None = None
    wavelengths: tuple[float, ...] | None = None
    lateral_shift: tuple[float, ...] | None = None

    kind = "points"

    def __repr__(self) -> str:
        """One line: the source, points × samples, the lattice, weights, dt and the speed of sound (never the arrays).

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon.dataset import PointDataset
        >>> PointDataset(alines=np.ones((3, 64)), positions=np.array([[-1e-4], [0.0], [1e-4]]),
        ...              weights=None, dt=2e-8, sound_speed=1500.0, grid=(np.array([-1e-4, 0.0, 1e-4]),),
        ...              indices=np.array([[0, 0], [1, 0], [2, 0]]), lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        PointDataset(3 points x 64 samples float64, lattice 3x1 at 100 µm, Voronoi weights, dt 20 ns, sound_speed 1500 m/s)
        """
        n, n_t = self.alines.shape
        lat = self.lattice
        where = (f", lattice {lat['n_x']}x{lat.get('n_y', 1)} at {float(lat['pitch']) * 1e6:.4g} µm"
                 if lat else "")
        weights = "weighted" if self.weights is not None else "Voronoi weights"
        src = f"{self.source}: " if self.source else ""
        return (f"PointDataset({src}{n} points x {n_t} samples {self.alines.dtype}{where}, {weights}, "
                f"dt {self.dt * 1e9:.4g} ns, sound_speed {self.sound_speed:g} m/s)")

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
        """The A-lines of a full-lattice dataset as grid data.

        Returns
        -------
        GridDataset
            ``(n_t, n_y, n_x)`` (``(n_t, n_x)`` for a line lattice), ``dx = dy`` = the lattice
            pitch (m), same dtype.

        Raises
        ------
        ValueError
            The data are not on a lattice, or lattice points are missing.

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon.dataset import PointDataset
        >>> ds = PointDataset(alines=np.ones((2, 8)), positions=np.array([[-5e-5], [5e-5]]), weights=None,
        ...                   dt=2e-8, sound_speed=1500.0, grid=(np.array([-5e-5, 5e-5]),),
        ...                   indices=np.array([[0, 0], [1, 0]]), lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        >>> ds.to_grid()
        Traceback (most recent call last):
        ...
        ValueError: this method needs every lattice point; 1 of 3 are missing (use 'nedner' for a sensor mask)
        """
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
        return GridDataset(data=data[:, 0, :] if n_y == 1 else data, dx=pitch, dt=self.dt, sound_speed=self.sound_speed,
                           dy=None if n_y == 1 else pitch, t0=self.t0, source=self.source,
                           meta=dict(self.meta), wavelengths=self.wavelengths, lateral_shift=self.lateral_shift)


def _accepting_old_speed_name(cls: type) -> None:
    """Let ``cls`` (a dataset dataclass) take ``c=`` in its constructor and read and set ``.c``, an
    earlier release's name of ``sound_speed``, each with a ``DeprecationWarning`` naming it."""
    import functools
    import warnings

    init = vars(cls)["__init__"]  # the dataclass's own

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, c: Any = None, **kw: Any) -> None:
        if c is not None:
            if "sound_speed" in kw or len(args) > 3 + (cls is PointDataset):
                raise ValueError("give sound_speed or its deprecated name c, not both")
            warnings.warn(f"{cls.__name__}(c=...) is deprecated: use sound_speed= (c is refused from the next "
                          "release)", DeprecationWarning, stacklevel=2)
            kw["sound_speed"] = c
        init(self, *args, **kw)

    def get(self: Any) -> float:
        warnings.warn(f"{cls.__name__}.c is deprecated: use .sound_speed", DeprecationWarning, stacklevel=2)
        return float(self.sound_speed)

    def set_(self: Any, value: float) -> None:
        warnings.warn(f"{cls.__name__}.c is deprecated: use .sound_speed", DeprecationWarning, stacklevel=2)
        self.sound_speed = value

    cls.__init__ = __init__  # type: ignore[misc]
    cls.c = property(get, set_, doc="Deprecated name of ``sound_speed`` (m/s).")  # type: ignore[attr-defined]


_accepting_old_speed_name(GridDataset)
_accepting_old_speed_name(PointDataset)

Dataset = GridDataset | PointDataset
#: either kind of dataset, as given (`check_dataset` returns what it is given)
AnyDataset = TypeVar("AnyDataset", GridDataset, PointDataset)


def p0_unit(ds: GridDataset | PointDataset) -> str:
    """The unit of a p0 reconstructed from a dataset.

    Parameters
    ----------
    ds : GridDataset or PointDataset

    Returns
    -------
    str
        ``"Pa"`` when the dataset is calibrated pressure (``meta["p0_unit"]``, from a scan
        whose instrument states its volts-to-pascal calibration:
        ``fpscan.driver.scanfile.pressure_unit``), else ``"a.u."``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset, p0_unit
    >>> p0_unit(GridDataset(np.zeros((4, 4)), 1e-4, 1e-8, 1500.0))
    'a.u.'
    >>> p0_unit(GridDataset(np.zeros((4, 4)), 1e-4, 1e-8, 1500.0, meta={"p0_unit": "Pa"}))
    'Pa'
    """
    return "Pa" if (ds.meta or {}).get("p0_unit") == "Pa" else "a.u."


def positive(name: str, v: Any) -> float:
    """``v`` as a positive finite float.

    Parameters
    ----------
    name : str
        The quantity's name, used in the error message.
    v : float or anything ``float()`` takes

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Not a number, non-finite or <= 0, naming ``name``.

    Examples
    --------
    >>> from fpscan.service.recon.dataset import positive
    >>> positive("c", "1500")  # m/s
    1500.0
    >>> positive("c", 0)
    Traceback (most recent call last):
    ...
    ValueError: c must be a positive finite number, got 0
    """
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {v!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"{name} must be a positive finite number, got {v!r}")
    return f


def check_dataset(ds: AnyDataset) -> AnyDataset:
    """The numbers a dataset carries beside its samples, checked before anything is computed
    from them: what every file reader's dataset must hold
    (`fpscan.service.storage.loader.load_dataset`) and every reconstruction's input
    (`fpscan.service.pipeline.reconstruct`).

    - ``sound_speed`` within ``fpscan.constants.C_LIMITS`` (100-10 000 m/s, the bound an explicit
      speed keeps even with ``force``: a file may hold another medium, not another unit);
    - ``dt`` and the lateral spacings (``dx``, ``dy``; a point dataset's lattice pitch and the
      steps of its ``grid``) within the plausible ranges of typed values
      (`fpscan.driver.units.check_plausible`: 0.1 ns-1 µs, 1 µm-10 mm, the unit mistake named);
    - ``t0`` finite, and ``lateral_shift`` None or one finite value per lateral axis;
    - the samples (grid ``data``, or the A-lines where there are any) real and finite
      (`fpscan.service.recon.checks.finite_array`);
    - a point dataset's ``positions`` ``(n, 1)`` or ``(n, 2)`` and finite, one per A-line, its
      ``weights`` None or ``(n,)`` finite and >= 0, its ``lattice`` at most
      `fpscan.driver.plan.MAX_LATTICE_POINTS` points, and its ``indices`` ``(n, 2)`` integers
      inside it.

    Parameters
    ----------
    ds : GridDataset or PointDataset

    Returns
    -------
    GridDataset or PointDataset
        ``ds`` itself (its own type).

    Raises
    ------
    ValueError
        The first number out of its bounds, named (``fpscan.driver.units.ImplausibleValue`` for
        a spacing or sample interval out of its range).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset, check_dataset
    >>> check_dataset(GridDataset(np.zeros((8, 4)), dx=1e-4, dt=2e-8, sound_speed=1500.0)).dx
    0.0001
    >>> check_dataset(GridDataset(np.zeros((8, 4)), dx=1e-4, dt=2e-8, sound_speed=1.5))
    Traceback (most recent call last):
    ...
    ValueError: the dataset's sound_speed must be within 100-10000 m/s, got 1.5
    """
    from fpscan.constants import C_LIMITS
    from fpscan.driver.units import check_plausible
    from fpscan.service.recon.checks import finite_array

    c = _number("sound_speed", ds.sound_speed)
    if not C_LIMITS[0] < c <= C_LIMITS[1]:
        raise ValueError(f"the dataset's sound_speed must be within {C_LIMITS[0]:g}-{C_LIMITS[1]:g} m/s, got {c:g}")
    _number("t0", ds.t0)
    spacings: dict[str, float] = {"dt": _number("dt", ds.dt)}
    if isinstance(ds, GridDataset):
        spacings["dx"] = _number("dx", ds.dx)
        lateral = finite_array("the dataset's data", ds.data, (2, 3)).ndim - 1
        if ds.dy is not None:
            spacings["dy"] = _number("dy", ds.dy)
    else:
        lateral = _check_points(ds, spacings)
    check_plausible(dt=spacings["dt"], dx=spacings.get("dx"), dy=spacings.get("dy"), pitch=spacings.get("pitch"))
    shift = ds.lateral_shift
    if shift is not None:
        values = [_number("lateral_shift", v) for v in np.ravel(np.asarray(shift, dtype=object))]
        if not 1 <= len(values) <= max(1, lateral):
            raise ValueError(f"the dataset's lateral_shift must have one value per lateral axis (x or x, y), "
                             f"got {len(values)}")
    return ds


def _number(name: str, v: Any) -> float:
    """`check_dataset`: the dataset's ``name`` as a finite float (a ValueError naming it)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ValueError(f"the dataset's {name} must be a real number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise ValueError(f"the dataset's {name} must be finite, got {f}")
    return f


def _check_points(ds: PointDataset, spacings: dict[str, float]) -> int:
    """`check_dataset` of a point dataset's arrays: its lateral dimensions (1 or 2); its grid
    steps and lattice pitch go into ``spacings`` (``dx``, ``dy``, ``pitch``) for the range check."""
    from fpscan.driver.plan import MAX_LATTICE_POINTS
    from fpscan.service.recon.checks import finite_array

    n = np.shape(ds.alines)[0]
    pos = np.asarray(ds.positions)
    if pos.ndim != 2 or pos.shape[1] not in (1, 2) or pos.shape[0] != n:
        raise ValueError(f"the dataset's positions must be (n, 1) or (n, 2), one per A-line ({n}), "
                         f"got shape {pos.shape}")
    if pos.dtype.kind not in "iuf" or not np.isfinite(pos).all():
        raise ValueError("the dataset's positions must be finite real numbers")
    if np.size(ds.alines):
        finite_array("the dataset's A-lines", ds.alines, (2,))
    if ds.weights is not None:
        w = np.asarray(ds.weights)
        if w.shape != (n,):
            raise ValueError(f"the dataset's weights must have shape ({n},), one per A-line, got {w.shape}")
        if w.dtype.kind not in "iuf" or not np.isfinite(w).all() or (w < 0).any():
            raise ValueError("the dataset's weights must be finite numbers >= 0 (m², m on a line)")
    for name, axis in zip(("dx", "dy"), ds.grid):
        steps = np.diff(np.asarray(axis, dtype=np.float64).reshape(-1))
        if steps.size:
            spacings[name] = _number(f"grid step along {name[1]}", steps[0])
    if ds.lattice is None:
        return pos.shape[1]
    n_x, n_y = (int(_number(f"lattice {k}", ds.lattice.get(k, 1))) for k in ("n_x", "n_y"))
    if n_x < 1 or n_y < 1 or n_x * n_y > MAX_LATTICE_POINTS:
        raise ValueError(f"the dataset's lattice must have 1 to {MAX_LATTICE_POINTS} points, got {n_x} x {n_y}")
    spacings["pitch"] = _number("lattice pitch", ds.lattice.get("pitch"))
    if ds.indices is not None:
        idx = np.asarray(ds.indices)
        if idx.dtype.kind not in "iu" or idx.shape != (n, 2):
            raise ValueError(f"the dataset's lattice indices must be ({n}, 2) integers, got {idx.dtype} {idx.shape}")
        if idx.size and (idx.min() < 0 or idx[:, 0].max() >= n_x or idx[:, 1].max() >= n_y):
            raise ValueError(f"the dataset's lattice indices must lie inside its {n_x} x {n_y} lattice")
    return pos.shape[1]


def grid_array(a: np.ndarray) -> np.ndarray:
    """Grid data as read from a file, checked.

    Parameters
    ----------
    a : ndarray, shape ``(n_t, n_x)`` or ``(n_t, n_y, n_x)``
        Time first; real numbers; at least 2 samples per axis, at most :data:`MAX_ELEMENTS`.

    Returns
    -------
    ndarray
        float32 (float64 for wider types), same shape.

    Raises
    ------
    ValueError
        Naming the fault: non-real dtype, wrong number of dimensions, an axis under 2
        samples, too many elements, NaN or infinities.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import grid_array
    >>> grid_array(np.zeros((4, 3), np.int16)).dtype, grid_array(np.zeros((4, 3))).dtype
    (dtype('float32'), dtype('float64'))
    >>> grid_array(np.zeros(4))
    Traceback (most recent call last):
    ...
    ValueError: array must be (n_t, n_x) or (n_t, n_y, n_x) (time first), got shape (4,)
    """
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
    """The coordinate vectors of a scanner lattice.

    Parameters
    ----------
    lattice : dict
        ``{"n_x", "n_y", "pitch"}`` (pitch in m; ``n_y`` default 1).

    Returns
    -------
    tuple of ndarray
        ``(x, y)``, shapes ``(n_x,)`` and ``(n_y,)``, m, centred on the optical axis
        (:func:`fpscan.physics.axes.centred_axis`).

    Examples
    --------
    >>> from fpscan.service.recon.dataset import lattice_axes
    >>> x, y = lattice_axes({"n_x": 3, "n_y": 2, "pitch": 1e-4})
    >>> x.round(6).tolist(), y.round(6).tolist()
    ([-0.0001, 0.0, 0.0001], [-5e-05, 5e-05])
    """
    pitch = float(lattice["pitch"])
    return centred_axis(int(lattice["n_x"]), pitch), centred_axis(int(lattice.get("n_y", 1)), pitch)


def lateral_shift_of(shape: tuple[int, ...], spacings: tuple[float, ...], coordinates: tuple[Any, ...] = (),
                     *, kwave_grid: bool = False) -> tuple[float, ...] | None:
    """The ``lateral_shift`` of grid data (:class:`GridDataset`): its own lateral coordinates
    minus the centred ones, ``(i - (n - 1)/2)·d``.

    Per lateral axis (x, then y): the coordinates the file gives, checked to be a regular
    grid at the spacing; else, for k-Wave's grid (``kwave_grid``), ``kWaveGrid``'s own
    ``(i - floor(n/2))·d`` (``x_vec``/``y_vec``: a shift of -d/2 on an even axis, none on an
    odd one); else the centred axis (no shift).

    Parameters
    ----------
    shape : tuple of int
        The data's shape, ``(n_t, n_x)`` or ``(n_t, n_y, n_x)``.
    spacings : tuple of float
        ``(dx,)`` or ``(dx, dy)``, m.
    coordinates : tuple of array_like or None, optional
        ``(x,)`` or ``(x, y)``: each axis's sensor coordinates, m, shape ``(n,)``, or None
        where the file gives none.
    kwave_grid : bool, optional
        Whether an axis without coordinates follows k-Wave's ``kWaveGrid``.

    Returns
    -------
    tuple of float or None
        ``(sx,)`` or ``(sx, sy)``, m; None when every shift is 0.

    Raises
    ------
    ValueError
        Coordinates of the wrong length, not increasing at the spacing (to 1e-6 of it), or
        not finite, naming the axis.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import lateral_shift_of
    >>> [round(v * 1e6, 6) for v in lateral_shift_of((10, 4, 4), (1e-4, 1e-4), kwave_grid=True)]  # µm
    [-50.0, -50.0]
    >>> lateral_shift_of((10, 3), (1e-4,), kwave_grid=True) is None  # odd: the same
    True
    >>> [round(v * 1e6, 6) for v in lateral_shift_of((10, 3), (1e-4,), (np.array([0.0, 1e-4, 2e-4]),))]  # µm
    [100.0]
    >>> lateral_shift_of((10, 3), (1e-4,), (np.array([0.0, 2e-4, 4e-4]),))
    Traceback (most recent call last):
    ...
    ValueError: the sensor x coordinates are not a regular grid at the spacing 0.0001 m (steps 0.0002 to 0.0002 m)
    """
    sizes = (shape[-1],) if len(shape) == 2 else (shape[-1], shape[1])
    out = []
    for k, n in enumerate(sizes):
        d = float(spacings[k])
        given = coordinates[k] if k < len(coordinates) else None
        centred0 = -(n - 1) / 2.0 * d
        if given is not None:
            c = np.asarray(given, dtype=np.float64).reshape(-1)
            name = "xy"[k]
            if c.size != n:
                raise ValueError(f"the file's {c.size} sensor {name} coordinates do not match the data's {n} "
                                 f"sensors along {name}")
            steps = np.diff(c)
            if not np.isfinite(c).all() or (steps.size and np.abs(steps - d).max() > 1e-6 * d):
                raise ValueError(f"the sensor {name} coordinates are not a regular grid at the spacing {d:g} m "
                                 f"(steps {steps.min():g} to {steps.max():g} m)")
            out.append(float(np.mean(c - centred_axis(n, d))))
        elif kwave_grid:
            out.append(-(n // 2) * d - centred0)
        else:
            out.append(0.0)
    return tuple(out) if any(out) else None


def check_wavelength_index(index: int, wavelengths: Any, what: str) -> None:
    """Refuse an index that is not one of a file's wavelengths.

    Parameters
    ----------
    index : int
        The wavelength index asked for.
    wavelengths : array_like
        The file's wavelengths, m.
    what : str
        What holds them (``"scan"``, ``"file"``), named in the message.

    Raises
    ------
    ValueError
        ``index`` out of range, naming the wavelengths in nm.

    Examples
    --------
    >>> from fpscan.service.recon.dataset import check_wavelength_index
    >>> check_wavelength_index(1, [7.5e-7, 8.5e-7], "scan")
    >>> check_wavelength_index(2, [7.5e-7, 8.5e-7], "scan")
    Traceback (most recent call last):
    ...
    ValueError: wavelength index 2 is out of range: the scan has 2 wavelengths (750 nm, 850 nm), indices 0..1
    """
    n = int(np.size(wavelengths))
    if not 0 <= index < max(n, 1):
        raise ValueError(f"wavelength index {index} is out of range: the {what} has {n} wavelength"
                         f"{'s' if n != 1 else ''} ({_nm(wavelengths)}), indices 0..{max(n, 1) - 1}")


def dataset_nbytes(ds: GridDataset | PointDataset) -> int:
    """Bytes of the arrays :func:`write_dataset` writes for a dataset.

    The canonical file's size less its metadata.

    Parameters
    ----------
    ds : GridDataset or PointDataset

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset, dataset_nbytes
    >>> ds = GridDataset(np.zeros((64, 3, 4), np.float32), dx=1e-4, dt=2e-8, sound_speed=1500.0)
    >>> dataset_nbytes(ds)  # 64 x 3 x 4 float32
    3072
    >>> dataset_nbytes(ds.to_points())  # + positions (12, 2) and the grid vectors, float64
    3320
    """
    if isinstance(ds, GridDataset):
        return int(ds.data.nbytes)
    arrays = [ds.alines, ds.positions, ds.weights, ds.indices, *ds.grid]
    return int(sum(np.asarray(a).nbytes for a in arrays if a is not None))


HDF5_KEY_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-/.")

