"""Dataset import for reconstruction: one uniform object from any supported input.

The input model (:class:`GridDataset`, :class:`PointDataset`, their validation) lives in
:mod:`fpscan.service.recon.dataset`; the formats (one module each: ``npy``, ``kwave-hdf5``,
``fpscan``, ``ipasc``, ``dataset``, ...) and their detection in :mod:`fpscan.service.formats`.
This module is the one loader of a file for reconstruction on top of them.

Inputs (``format``; ``None`` = detect from the content; ``fpscan.service.formats.names(input=True)``):
the fpscan scan file (its completed points → :class:`PointDataset`), an IPASC file
(→ :class:`PointDataset`), an HDF5 array in k-Wave layout (→ :class:`GridDataset`;
spacings from the arguments, then the file), a NumPy ``.npy`` array (``dt`` and ``dx``
required) and the canonical dataset file (``fpscan-dataset/1``, :func:`write_dataset`),
in which the server keeps every upload exactly. Each format's module documents its
layout.

Every reader of a file for reconstruction calls :func:`load_dataset` (the job worker, the
local ``fpscan recon``, the live preview, the experiments) and hands the result to
:func:`fpscan.service.pipeline.reconstruct`.

Multi-wavelength files (an fpscan scan or an IPASC file with several excitation
wavelengths) hold one data set per wavelength; a dataset is one of them, chosen with
``wavelength`` (an index into the file's wavelengths) in :func:`load_dataset`, or all of
them, one dataset each, with :func:`load_wavelengths` (``wavelength="all"``). Without a
choice the first wavelength (index 0) is read: documented, never silent: the dataset's
``wavelengths`` is that one wavelength, ``meta`` records ``wavelength_index`` and the
file's ``wavelengths``, and every reconstruction of it records ``wavelength_index`` and
``wavelength_nm`` in its params (:func:`wavelength_params`).
"""
from __future__ import annotations

import math
import numbers
import os
from pathlib import Path
from typing import Any

from fpscan.service import formats
from fpscan.service.formats.dataset import DATASET_FORMAT
from fpscan.service.formats.dataset import write as write_dataset
from fpscan.service.recon.dataset import (
    ALL_WAVELENGTHS,
    MAX_ELEMENTS,
    Dataset,
    GridDataset,
    PointDataset,
    check_dataset,
    check_wavelength,
    dataset_nbytes,
    file_wavelengths,
    lattice_axes,
    p0_unit,
    positive,
    wavelength_params,
)

__all__ = ["load_dataset", "load_wavelengths", "detect_format", "input_formats", "import_dataset",
           "read_dataset", "write_dataset", "load_scan", "GridDataset", "PointDataset", "Dataset",
           "DATASET_FORMAT", "MAX_ELEMENTS", "ALL_WAVELENGTHS", "check_wavelength", "dataset_nbytes",
           "file_wavelengths", "lattice_axes", "p0_unit", "wavelength_params"]


def input_formats() -> tuple[str, ...]:
    """The names of the formats a reconstruction reads.

    Returns
    -------
    tuple of str
        The input formats of ``fpscan.service.formats``, in registration order: the choices of
        :func:`load_dataset`'s ``format`` and ``fpscan recon --format``.
    """
    return formats.names(input=True)


def detect_format(path: str | os.PathLike) -> str:
    """The input format of a file, from its content.

    Detection is ``fpscan.service.formats.detect``'s: the file is opened once, HDF5 checked, a
    file a writer has open read in a bounded child.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    str
        The format's name (one of :func:`input_formats`).

    Raises
    ------
    ValueError
        If no format fits, or naming what the file is when it is not data to reconstruct (a
        plan, a result, a picture).
    """
    fmt = formats.FORMATS[formats.detect(path)]
    if fmt.refuse:
        raise ValueError(fmt.refuse)
    return fmt.name


def load_dataset(path: str | os.PathLike, format: str | None = None, *, dt: float | None = None,
                 dx: float | None = None, dy: float | None = None, sound_speed: float | None = None,
                 key: str | None = None, axes: str | None = None, max_bytes: int = MAX_ELEMENTS * 8,
                 force: bool = False, wavelength: int | None = None, c: float | None = None) -> GridDataset | PointDataset:
    """Import a file for reconstruction (module docstring).

    An HDF5 file is checked first, by the registry for every format
    (``fpscan.service.formats.open_source`` with ``fpscan.service.formats.untrusted.check_hdf5_file``: no
    external storage, external links or virtual datasets, no dataset declaring more than
    ``max_bytes`` or more than it stores). A file HDF5 would open as an SWMR reader (a
    writer has it open) is read in a child process with a time limit (the registry's
    ``fpscan.service.formats.untrusted.read_bounded``: HDF5 can block on its damaged metadata for
    ever).

    Parameters
    ----------
    path : str or os.PathLike
        The file to read.
    format : str or None, optional
        One of :func:`input_formats`; default None: detected from the content.
    dt : float or None, optional
        Sampling interval in s, overriding the file's (required for ``.npy``).
    dx, dy : float or None, optional
        Sensor spacing along x and y in m, overriding the file's (``dx`` required for ``.npy``).
    sound_speed : float or None, optional
        Speed of sound in m/s, overriding the file's.
    key : str or None, optional
        The HDF5 dataset path of the data, for formats that take one.
    axes : str or None, optional
        The order of a ``.npy`` array's axes (``"y,x,t"``, ``"t,y,x"``, ``"x,t"``, ``"t,x"``,
        ``"sensor,time"``); default None: time first where the shape shows it, else refused
        (``fpscan.service.formats.npy.time_axes``).
    max_bytes : int, optional
        Largest dataset an HDF5 file may declare, in bytes; default ``MAX_ELEMENTS * 8``.
    force : bool, optional
        Accept an unusual ``sound_speed`` (outside the plausible range for soft tissue); default False.
    wavelength : int or None, optional
        Which excitation wavelength of a multi-wavelength file (an index into its
        wavelengths); default None: the first, recorded in the dataset's
        ``meta["wavelength_index"]``. A file of one wavelength takes only None or 0 (for
        ``"all"`` use :func:`load_wavelengths`).
    c : float or None, optional
        An earlier release's name of ``sound_speed`` (a ``DeprecationWarning``).

    Returns
    -------
    GridDataset or PointDataset
        Grid data ``(n_t, n_x)`` or ``(n_t, n_y, n_x)``, or point data (A-lines ``(n, n_t)``
        at their positions).

    Raises
    ------
    ValueError
        Naming the fault: an unknown ``format``, ``"all"`` as ``wavelength``, an index out of
        range (naming the file's wavelengths), an implausible explicit ``dt``, ``dx``, ``dy``
        or ``sound_speed`` (``fpscan.driver.units.check_plausible``: a unit mistake such as ``dt=20`` for 20 ns
        is named), an unsafe or unreadable file, a file whose own speed of sound, sample interval,
        spacings, lattice or lateral shift are out of bounds
        (``fpscan.service.recon.dataset.check_dataset``), a ``.npy`` array whose time axis its shape
        does not show and ``axes`` does not say (naming the readings it could have).
    FileNotFoundError
        If ``path`` does not exist.

    Warns
    -----
    UserWarning
        A ``.npy`` array read time first without ``axes`` whose first axis is not clearly
        its longest.
    """
    choice = check_wavelength(wavelength, allow_all=False)  # 'all': load_wavelengths
    if c is not None:
        sound_speed = _old_speed_name(c, sound_speed)
    return _load(path, format, dt=dt, dx=dx, dy=dy, sound_speed=sound_speed, key=key, axes=axes, max_bytes=max_bytes,
                 force=force, wavelength_index=0 if choice is None else int(choice))


def _old_speed_name(c: float, sound_speed: float | None) -> float:
    """``c``, an earlier release's name of ``sound_speed``: warned, and refused beside it."""
    import warnings

    if sound_speed is not None:
        raise ValueError("give sound_speed or its deprecated name c, not both")
    warnings.warn("c is deprecated: use sound_speed= (c is refused from the next release)", DeprecationWarning,
                  stacklevel=3)
    return c


def _load(path: str | os.PathLike, format: str | None, *, dt: float | None, dx: float | None, dy: float | None,
          sound_speed: float | None, key: str | None, max_bytes: int, force: bool, axes: str | None = None,
          **which: Any) -> Any:
    """:func:`load_dataset`'s checks and the registry's load; ``which``:
    ``wavelength_index`` (one dataset) or ``all_wavelengths=True`` (a list). The load options
    given (``dt``, ``dx``, ``dy``, ``key``, ``axes``) must be the format's own
    (``fpscan.service.formats.load_options.check_load_options``: a ValueError naming the ones it takes)."""
    from fpscan.driver.units import check_plausible

    num = numbers.Real  # numpy's scalars too (np.float32(20.0) is as much a unit mistake as 20.0)
    check_plausible(dt=dt if isinstance(dt, num) else None, dx=dx if isinstance(dx, num) else None,
                    dy=dy if isinstance(dy, num) else None,
                    sound_speed=sound_speed if isinstance(sound_speed, num) else None, force=force)
    from fpscan.service.formats.load_options import check_load_options

    choices = input_formats()
    if format is not None and format not in choices:
        raise ValueError(f"format must be one of {', '.join(choices)}, got {format!r}")
    asked = {"dt": dt, "dx": dx, "dy": dy, "key": key, "axes": axes}  # the load options (the format's own model)
    if format is not None:
        asked = {**asked, **check_load_options(format, asked)}  # axes in its canonical form
    if axes is not None:  # only to a format that may take it (a plugin's load need not know the name)
        which = {**which, "axes": asked["axes"]}
    name, loaded = formats.load(path, format, max_bytes=max_bytes, choices=choices, dt=dt, dx=dx, dy=dy,
                                sound_speed=sound_speed, key=key, **which)
    if format is None:  # detected from the content: its options, now that it is known
        check_load_options(name, asked)
    for ds in loaded if isinstance(loaded, list) else [loaded]:
        if sound_speed is not None:
            ds.sound_speed = positive("sound_speed", sound_speed)
        if dt is not None:
            ds.dt = positive("dt", dt)
        check_dataset(ds)  # the file's own numbers are as hostile as typed ones
    return loaded


def load_scan(path: str | os.PathLike, *, allow_empty: bool = False, wavelength_index: int = 0) -> PointDataset:
    """The completed points of the service's own scan file, as point data.

    The file may still be being written; it is read in this process
    (``fpscan.service.formats.scan.load``: the live preview).

    Parameters
    ----------
    path : str or os.PathLike
        The scan file.
    allow_empty : bool, optional
        Accept a scan with no completed point too; default False.
    wavelength_index : int, optional
        Which excitation wavelength of the scan (an index into its wavelengths); default 0.

    Returns
    -------
    PointDataset
        The completed A-lines ``(n, n_t)`` at their positions.

    Raises
    ------
    ValueError
        If the file is not a readable scan file (or has no completed point, unless
        ``allow_empty``).
    FileNotFoundError
        If ``path`` does not exist.
    """
    return check_dataset(formats.load(path, "fpscan", bounded=False, allow_empty=allow_empty,
                                      wavelength_index=wavelength_index)[1])


def read_dataset(path: str | os.PathLike) -> GridDataset | PointDataset:
    """Read a canonical dataset file (``fpscan.service.formats.dataset``).

    Parameters
    ----------
    path : str or os.PathLike
        The dataset file (``fpscan-dataset/1``).

    Returns
    -------
    GridDataset or PointDataset
        The dataset as it was stored.

    Raises
    ------
    ValueError
        For a file that is not a canonical dataset file.
    FileNotFoundError
        If ``path`` does not exist.
    """
    return check_dataset(formats.load(path, "dataset")[1])


def load_wavelengths(path: str | os.PathLike, format: str | None = None, *, wavelength: Any = None,
                     **load: Any) -> list[GridDataset | PointDataset]:
    """The datasets of ``path`` at the chosen excitation wavelength(s).

    Parameters
    ----------
    path : str or os.PathLike
        The file to read.
    format : str or None, optional
        One of :func:`input_formats`; default None: detected from the content.
    wavelength : int or None or "all", optional
        An index into the file's wavelengths or None (one dataset, :func:`load_dataset`), or
        ``"all"`` (one per wavelength of the file, in its order, read from one open of the
        file; a file of one wavelength gives one). Default None: the first.
    **load
        The other arguments of :func:`load_dataset` (``dt``, ``dx``, ``dy``, ``sound_speed``, ``key``,
        ``axes``, ``max_bytes``, ``force``).

    Returns
    -------
    list of GridDataset or PointDataset
        One dataset per chosen wavelength.

    Raises
    ------
    ValueError
        A bad choice, an index out of range (naming the file's wavelengths), or what
        :func:`load_dataset` raises.
    FileNotFoundError
        If ``path`` does not exist.
    """
    choice = check_wavelength(wavelength)
    if not isinstance(choice, str):  # an index or None
        return [load_dataset(path, format, wavelength=choice, **load)]
    if load.get("c") is not None:
        load = {**load, "sound_speed": _old_speed_name(load["c"], load.get("sound_speed"))}
    load.pop("c", None)
    options = {"dt": None, "dx": None, "dy": None, "sound_speed": None, "key": None, "axes": None,
               "max_bytes": MAX_ELEMENTS * 8,
               "force": False, **load}
    return list(_load(path, format, all_wavelengths=True, **options))


HDF5_KEY_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-/.")


def import_dataset(src: str | os.PathLike, dest_dir: str | os.PathLike, fmt: str, *, dt: float | None,
                   dx: float | None, dy: float | None, sound_speed: float | None, key: str | None,
                   axes: str | None = None, max_bytes: int | None = None, force: bool = False,
                   wavelength: int | None = None) -> dict:
    """Validate and convert an uploaded file into ``dest_dir/dataset.h5``.

    The file is read with :func:`load_dataset` (every input format) and written with
    :func:`write_dataset`. Run by ``POST /api/datasets`` in a bounded child process
    (``fpscan.service.formats.untrusted.run_bounded``). Before the dataset file is written its
    bytes (:func:`dataset_nbytes`) are admitted
    (``fpscan.service.formats.untrusted.request_admission``: the service's free-disk admission).

    Parameters
    ----------
    src : str or os.PathLike
        The uploaded file.
    dest_dir : str or os.PathLike
        The dataset's folder (``dataset.h5`` is written in it).
    fmt : str or None
        The input format (one of :func:`input_formats`; None: detected).
    dt : float or None
        Sampling interval in s, overriding the file's.
    dx, dy : float or None
        Sensor spacing along x and y in m, overriding the file's.
    sound_speed : float or None
        Speed of sound in m/s, overriding the file's.
    key : str or None
        The HDF5 dataset path of the data (at most 200 characters of ``[A-Za-z0-9_-/.]``).
    axes : str or None, optional
        The order of a ``.npy`` array's axes (as :func:`load_dataset`); default None.
    max_bytes : int or None, optional
        Largest declared dataset of an HDF5 file in bytes (``fpscan.driver.hdf5_checks.check_hdf5_file``,
        run before anything is read); default None: ``MAX_ELEMENTS * 8``.
    force : bool, optional
        Accept a ``sound_speed`` outside ``fpscan.constants.C_PLAUSIBLE`` (m/s; as :func:`load_dataset`);
        default False.
    wavelength : int or None, optional
        Which excitation wavelength of a multi-wavelength file to store (an index; None: the
        first; as :func:`load_dataset`, recorded in the metadata).

    Returns
    -------
    dict
        The dataset's metadata, which the API stores in the job store: ``layout``
        (``"grid"`` or ``"points"``), ``shape``, ``dx``, ``dt``, ``sound_speed``, ``t0``, ``path``
        (``"dataset.h5"``), the wavelength's params and ``record_facts`` (what the record holds
        above its noise, ``fpscan.service.recon.tv.grid.record_facts``: the memory admission sizes a tv
        job on the grid tv will choose from them), with ``sensor_bandwidth_hz`` where the file
        declares one; for points also ``n_x``, ``n_y`` and ``full_lattice``.

    Raises
    ------
    ValueError
        With the reason: a bad ``key``, a ``dt``, ``dx``, ``dy`` or ``c`` that is not a
        positive finite number, a file that is not a readable dataset of ``fmt``, a point
        dataset with no A-lines, or what :func:`load_dataset` raises.
    fpscan.service.formats.untrusted.NotAdmitted
        When the disk cannot take the dataset.
    """
    if key is not None and (not key or len(key) > 200 or not set(key) <= HDF5_KEY_CHARS):
        raise ValueError("key must be an HDF5 dataset path of [A-Za-z0-9_-/.]")
    for name, value in (("dt", dt), ("dx", dx), ("dy", dy), ("sound_speed", sound_speed)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number")
    try:
        ds = load_dataset(src, fmt, dt=dt, dx=dx, dy=dy, sound_speed=sound_speed, key=key, axes=axes, force=force,
                          wavelength=wavelength,
                          max_bytes=MAX_ELEMENTS * 8 if max_bytes is None else max_bytes)
    except (KeyError, TypeError, IndexError, OSError) as exc:
        raise ValueError(f"file is not a readable {fmt} dataset ({type(exc).__name__})") from None
    dest_dir = Path(dest_dir)
    if isinstance(ds, PointDataset) and ds.alines.shape[0] == 0:
        raise ValueError("the dataset holds no A-lines")
    from fpscan.service.formats.untrusted import request_admission

    request_admission(dataset_nbytes(ds))  # the service's disk admission, before a byte is written
    write_dataset(dest_dir / "dataset.h5", ds)
    common = {"dt": ds.dt, "sound_speed": ds.sound_speed, "t0": float(ds.t0 or 0.0), "path": "dataset.h5", **wavelength_params(ds),
              **_record_facts(ds)}
    if isinstance(ds, GridDataset):
        return {"layout": "grid", "shape": list(ds.data.shape), "dx": ds.dx, **common}
    n_x, n_y = len(ds.grid[0]), len(ds.grid[1]) if len(ds.grid) > 1 else 1
    return {"layout": "points", "shape": list(ds.alines.shape), "n_x": n_x, "n_y": n_y,
            "full_lattice": ds.full_lattice,
            "dx": float(ds.grid[0][1] - ds.grid[0][0]) if len(ds.grid[0]) > 1 else None, **common}


def _record_facts(ds: GridDataset | PointDataset) -> dict:
    """``record_facts`` of a dataset's record (``fpscan.service.recon.tv.grid.record_facts``: its noise
    σ and the samples up to its last echo; in blocks, without a float64
    copy of the data) and the sensor bandwidth its metadata declares, for the stored record."""
    from fpscan.service.recon.methods.tv import BANDWIDTH_KEY, declared_bandwidth
    from fpscan.service.recon.tv.grid import record_facts

    data, time_axis = (ds.data, 0) if isinstance(ds, GridDataset) else (ds.alines, 1)
    out: dict[str, Any] = {}
    if data.shape[time_axis] >= 2:  # a single sample holds no record to cut
        out["record_facts"] = record_facts(data, ds.dt, time_axis).as_dict()
    bandwidth = declared_bandwidth(ds.meta)
    if bandwidth is not None:
        out[BANDWIDTH_KEY] = bandwidth
    return out
