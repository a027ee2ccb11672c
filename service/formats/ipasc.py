"""IPASC export and import of scan files, with plain h5py.

The IPASC data format (International Photoacoustic Standardisation Consortium; reference
implementation PACFISH, ``pacfish.iohandler``) is an HDF5 file with

- ``/binary_time_series_data``: ``[detectors, samples, wavelengths, measurements]``;
- ``/meta_data/<tag>``: acquisition metadata, every value a dataset, SI units (``None``
  would be the string ``"None"``; we write every tag with a value, so PACFISH's
  ``quality_check_pa_data`` -- completeness and consistency -- passes on our exports);
- ``/meta_data_device/general/<tag>`` and ``/meta_data_device/detectors/<id>/<tag>``
  (``<id>``: the detector's index, zero-padded to 10 digits as PACFISH's
  ``DeviceMetaDataCreator`` does; detector i is row i of the binary data).

Mapping of an fpscan scan (docs/file-formats.md has the full table): every *completed*
scan point is one detection element at ``[x, y, 0]`` m facing +z; one wavelength; one
measurement (the scan is a ``composite_scan``: its points were acquired one after the
other). The binary data is the DC-normalised pressure (``fpscan.driver.scanfile``). Things IPASC
has no tag for (area weights, lattice indices, the plan, per-A-line metadata) go into
extra ``/meta_data/fpscan_*`` datasets, which :func:`read_ipasc` uses when present and
other readers ignore.

In the registry of formats (``fpscan.service.formats``) this module is the ``ipasc`` format:
:func:`sniff`, :func:`load` (→ :class:`fpscan.service.recon.dataset.PointDataset`; it may hold
several excitation wavelengths: ``wavelength_index`` chooses one, default the first) and
:func:`export_scan`, its writer.
"""
from __future__ import annotations

import json
import math
import os
import uuid as _uuid
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt
from h5py import h5d, h5g, h5s, h5t

from fpscan.constants import C_DEFAULT
from fpscan.driver.scanfile import ScanData, read_scan
from fpscan.physics.axes import centred_axis
from fpscan.service.disk import file_replaced
from fpscan.service.formats.load_options import WavelengthChoice
from fpscan.service.formats.registry import Format, Source
from fpscan.service.recon.dataset import PointDataset, check_wavelength_index, positive

__all__ = ["DETECTOR_ID_WIDTH", "FORMAT", "export_scan", "import_ipasc", "load", "read_ipasc",
           "read_open_ipasc", "sniff", "write_ipasc"]

DETECTOR_ID_WIDTH = 10


class _SmallDatasets:
    """Creates the many tiny per-detector datasets with h5py's low-level API (about 4×
    faster than ``Group.create_dataset``); same on-disk result: float64 arrays/scalars and
    fixed-length, null-padded UTF-8 strings (what h5py writes for ``np.bytes_``)."""

    def __init__(self) -> None:
        self._f64 = h5t.IEEE_F64LE
        self._scalar = h5s.create(h5s.SCALAR)
        self._spaces: dict[Any, Any] = {}
        self._strtypes: dict[int, Any] = {}

    def vector(self, gid: Any, name: str, v: np.ndarray) -> None:
        v = np.ascontiguousarray(v, dtype="<f8")
        space = self._spaces.get(v.size)
        if space is None:
            space = self._spaces[v.size] = h5s.create_simple((v.size,))
        h5d.create(gid, name.encode(), self._f64, space).write(h5s.ALL, h5s.ALL, v)

    def matrix(self, gid: Any, name: str, v: np.ndarray) -> None:
        v = np.ascontiguousarray(v, dtype="<f8")
        space = self._spaces.get(v.shape)
        if space is None:
            space = self._spaces[v.shape] = h5s.create_simple(v.shape)
        h5d.create(gid, name.encode(), self._f64, space).write(h5s.ALL, h5s.ALL, v)

    def scalar(self, gid: Any, name: str, x: float) -> None:
        h5d.create(gid, name.encode(), self._f64, self._scalar).write(
            h5s.ALL, h5s.ALL, np.array(x, dtype="<f8"))

    def string(self, gid: Any, name: str, text: str) -> None:
        b = text.encode("utf-8")
        t = self._strtypes.get(len(b))
        if t is None:
            t = h5t.C_S1.copy()
            t.set_size(max(len(b), 1))
            t.set_strpad(h5t.STR_NULLPAD)
            t.set_cset(h5t.CSET_UTF8)
            self._strtypes[len(b)] = t
        h5d.create(gid, name.encode(), t, self._scalar).write(
            h5s.ALL, h5s.ALL, np.array(b, dtype=f"S{max(len(b), 1)}"), mtype=t)


def _field_of_view(xy: np.ndarray, c: float, dt: float, n_t: int) -> np.ndarray:
    """``[x_min, x_max, y_min, y_max, z_min, z_max]`` m: the scanned area down to the depth
    the recording reaches (c·dt·(n_t − 1))."""
    return np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max(),
                     0.0, c * dt * (n_t - 1)])


def _instrument_id(instrument: dict) -> str:
    for key in ("unique_identifier", "serial", "idn", "IDN", "model"):
        if instrument.get(key):
            return str(instrument[key])
    return "fpscan FP scanner (unidentified)"


def export_scan(scan_path: str | os.PathLike, out_path: str | os.PathLike, *,
                dtype: npt.DTypeLike = np.float64, data_uuid: str | None = None) -> Path:
    """Export the completed A-lines of a scan file to an IPASC HDF5 file.

    Several excitation wavelengths make the binary data's wavelength axis (in the plan's
    order, ``acquisition_wavelengths``); only points complete at every wavelength are
    exported.

    Parameters
    ----------
    scan_path : str or os.PathLike
        An fpscan scan file (complete or partial; only completed points are exported, in scan
        order).
    out_path : str or os.PathLike
        The IPASC file, written to a temporary sibling, then renamed (its folder is created if
        missing).
    dtype : float32 or float64, optional
        Float type of the binary data (float64, the default, keeps the pressure bit-exact).
    data_uuid : str, optional
        The file's ``meta_data/uuid`` (default a new random UUID).

    Returns
    -------
    pathlib.Path
        ``out_path``.

    Raises
    ------
    ValueError
        No completed points (at every wavelength), or a dtype that is not float32/float64.
    FileNotFoundError
        ``scan_path`` does not exist.
    """
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    scan = read_scan(scan_path).completed_only(every_wavelength=True)
    if scan.n_points == 0:
        raise ValueError("the scan has no completed points (at every wavelength) to export")
    out_path = Path(out_path)
    # a temporary sibling unique per call (concurrent exports to one target never share it), renamed over out_path
    with file_replaced(out_path) as tmp, h5py.File(tmp, "w") as f:
        _write_ipasc(f, scan, dtype, data_uuid)
    return out_path


#: aliases used by callers
write_ipasc = export_scan

#: the HDF5 type of every string tag (variable-length UTF-8)
_UTF8 = h5py.string_dtype("utf-8")


def _put(group: h5py.Group, name: str, value: str | float | np.ndarray | None) -> None:
    """Write one tag as a dataset of ``group``: a string as variable-length UTF-8, None as
    the string ``"None"`` (IPASC's missing value), anything else as its numpy array."""
    if value is None:
        value = "None"
    if isinstance(value, str):
        group.create_dataset(name, data=value, dtype=_UTF8)
    else:
        group.create_dataset(name, data=value)


def _write_ipasc(f: h5py.File, scan: ScanData, dtype: np.dtype, data_uuid: str | None) -> None:
    """Write the completed scan ``scan`` into the new, empty file ``f`` in the order an export
    always has: the binary data ``[detectors, samples, wavelengths, measurements]`` as
    ``dtype``, ``/meta_data`` (the IPASC tags, then fpscan's extras) and
    ``/meta_data_device``. Detectors lie at the scan points' ``(x, y)`` (y = 0 m for a line
    scan) on z = 0."""
    pos = np.asarray(scan.positions, dtype=np.float64)
    xy = np.zeros((scan.n_points, 2))
    xy[:, :pos.shape[1]] = pos
    f.create_dataset("binary_time_series_data",
                     data=np.moveaxis(scan.pressure_all.astype(dtype), 0, -1)[..., None])
    m = f.create_group("meta_data")
    _put_acquisition(m, scan, dtype, data_uuid)
    roi = m.create_group("regions_of_interest")
    _put(roi, "scanned_volume", _field_of_view(xy, float(scan.sound_speed), float(scan.dt), scan.n_t))
    _put_fpscan_extras(m, scan, int(pos.shape[1]) + 1)
    _put_device(f.create_group("meta_data_device"), scan, xy)


def _put_acquisition(m: h5py.Group, scan: ScanData, dtype: np.dtype, data_uuid: str | None) -> None:
    """The IPASC acquisition tags of ``/meta_data``: the binary data's description (one
    measurement per wavelength set, a ``composite_scan``), sampling rate (Hz), sound speed
    (m/s), wavelengths (m), pose, timestamps (s), pulse energies (J) and the acquisition
    chain as recorded (no gain, no time-gain compensation, no filter)."""
    n, n_t, meta = scan.n_points, scan.n_t, scan.meta
    c, dt = float(scan.sound_speed), float(scan.dt)
    # binary data [detectors, samples, wavelengths, measurements]
    n_wl, n_meas = scan.n_wavelengths, 1
    fs = 1.0 / dt
    _put(m, "uuid", data_uuid or str(_uuid.uuid4()))
    _put(m, "encoding", "raw")
    # "none", not "None": PACFISH reads the string "None" back as a missing value
    _put(m, "compression", "none")
    _put(m, "data_type", dtype.name)
    _put(m, "dimensionality", "time")
    _put(m, "sizes", np.array([n, n_t, n_wl, n_meas], dtype=np.int64))
    _put(m, "ad_sampling_rate", fs)
    _put(m, "speed_of_sound", c)
    _put(m, "acquisition_wavelengths",
         np.asarray(scan.wavelengths, dtype=np.float64) if len(scan.wavelengths) else None)
    # one pose per measurement as a (2, 3) block [[x, y, z] m, [rx, ry, rz] rad]
    # (the reference pose: detector positions are absolute). A (1, 6) array would
    # be squeezed to (6,) by PACFISH's reader and then fail its own 2-D check.
    _put(m, "measurement_spatial_poses", np.zeros((2 * n_meas, 3)))
    _put(m, "measurement_timestamps", np.full(n_meas, float(meta["timestamp_s"].min())))
    _put(m, "pulse_energy", scan.meta_all["pulse_energy_j"].mean(axis=1))
    _put(m, "measurements_per_image", n_meas)
    _put(m, "scanning_method", "composite_scan")
    _put(m, "photoacoustic_imaging_device_reference", _instrument_id(scan.instrument))
    # acquisition chain as recorded: the pressure is DC-normalised, no further gain,
    # no time-gain compensation, no frequency filter (pass band [0, Nyquist] Hz)
    _put(m, "time_gain_compensation", np.ones(n_t))
    _put(m, "overall_gain", 1.0)
    _put(m, "element_dependent_gain", np.ones(n))
    _put(m, "frequency_domain_filter", np.array([0.0, fs / 2.0]))
    # not measured by the scanner: NaN K unless the instrument reports it
    _put(m, "temperature_control", np.full(
        n_meas, float(scan.instrument.get("temperature_k", float("nan")))))
    _put(m, "acoustic_coupling_agent", str(scan.instrument.get("acoustic_coupling_agent", "water")))


def _put_fpscan_extras(m: h5py.Group, scan: ScanData, spatial_dimensions: int) -> None:
    """Write fpscan's own ``/meta_data/fpscan_*`` datasets (not IPASC tags; :func:`read_ipasc`
    uses them): the plan, software version, the pressure's definition, the exact dt (s),
    area weights, lattice indices, ``spatial_dimensions`` (2 for a line scan, 3 for an area)
    and the per-A-line metadata, ``(n,)`` for one wavelength, ``(n_wavelengths, n)`` for
    several."""
    _put(m, "fpscan_plan_json", json.dumps(scan.plan, sort_keys=True, separators=(",", ":")))
    _put(m, "fpscan_plan_id", scan.plan_id)
    _put(m, "fpscan_software_version", scan.software_version)
    _put(m, "fpscan_pressure", "(sample*scale + offset)/dc_level per A-line")
    _put(m, "fpscan_dt_s", float(scan.dt))
    _put(m, "fpscan_weights", np.asarray(scan.weights, dtype=np.float64))
    _put(m, "fpscan_lattice_indices", np.asarray(scan.indices, dtype=np.int64))
    _put(m, "fpscan_spatial_dimensions", spatial_dimensions)
    for key in ("point_index", "timestamp_s", "bias_wavelength_m", "dc_level",
                "pulse_energy_j", "pulse_number", "boot_id", "run_id",
                "excitation_wavelength_m"):
        _put(m, f"fpscan_{key}", np.asarray(scan.meta[key] if scan.n_wavelengths == 1
                                            else scan.meta_all[key]))


def _put_device(dev: h5py.Group, scan: ScanData, xy: np.ndarray) -> None:
    """``/meta_data_device``: the general tags (the instrument, the field of view in m,
    one detector per scan point at ``xy`` ``(n, 2)`` m, no illuminators) and one group per
    detector, named by its zero-padded index."""
    n_t, c, dt = scan.n_t, float(scan.sound_speed), float(scan.dt)
    g = dev.create_group("general")
    _put(g, "unique_identifier", _instrument_id(scan.instrument))
    _put(g, "field_of_view", _field_of_view(xy, c, dt, n_t))
    _put(g, "num_detectors", scan.n_points)
    _put(g, "num_illuminators", 0)
    dev.create_group("illuminators")
    _put_detectors(dev.create_group("detectors"), scan, xy, fs=1.0 / dt)


def _put_detectors(dets: h5py.Group, scan: ScanData, xy: np.ndarray, fs: float) -> None:
    """One group per detector under ``dets``: the FP interrogation spot at scan point i, at
    ``[x, y, 0]`` m facing +z, with its geometry, frequency response (flat up to the
    Nyquist frequency ``fs``/2 Hz) and angular response (flat over the half space)."""
    # the FP interrogation spot: a point-like element (radius 0 m unless the
    # instrument reports its spot radius), modelled flat in frequency up to Nyquist
    # and omnidirectional over the half space it faces -- documented assumptions,
    # the same model the reconstruction uses
    spot = float(scan.instrument.get("spot_radius_m") or 0.0)
    frequency_response = np.array([[0.0, fs / 2.0], [1.0, 1.0]])
    angular_response = np.array([[0.0, math.pi / 2.0], [1.0, 1.0]])
    w = _SmallDatasets()
    orientation = np.array([0.0, 0.0, 1.0])
    point_index = scan.meta["point_index"]
    for i in range(scan.n_points):
        gid = h5g.create(dets.id, str(i).zfill(DETECTOR_ID_WIDTH).encode())
        w.string(gid, "detection_element", f"FP interrogation spot at scan point {int(point_index[i])}")
        w.vector(gid, "detector_position", np.array([xy[i, 0], xy[i, 1], 0.0]))
        w.vector(gid, "detector_orientation", orientation)
        w.string(gid, "detector_geometry_type", "CIRCULAR")
        w.scalar(gid, "detector_geometry", spot)
        w.matrix(gid, "frequency_response", frequency_response)
        w.matrix(gid, "angular_response", angular_response)


def _value(ds: h5py.Dataset) -> Any:
    v = ds[()]
    if isinstance(v, bytes):
        v = v.decode("utf-8")
    if isinstance(v, str) and v == "None":
        return None
    return v


def _regular_axis(coords: np.ndarray, name: str) -> np.ndarray:
    """A regular vector spanning ``coords`` at their smallest spacing (foreign files)."""
    u = np.unique(np.round(coords, 12))
    if len(u) == 1:
        return u
    step = float(np.min(np.diff(u)))
    n = int(round((u[-1] - u[0]) / step)) + 1
    if n > 8192:
        raise ValueError(f"detector {name} coordinates do not lie on a regular lattice "
                         f"(would need {n} grid points)")
    return u[0] + step * np.arange(n)


def read_ipasc(path: str | os.PathLike, *, wavelength_index: int = 0,
               measurement_index: int = 0) -> dict:
    """Read an IPASC file as point data for reconstruction.

    Parameters
    ----------
    path : str or os.PathLike
        The IPASC HDF5 file.
    wavelength_index : int, optional
        Index into the binary data's wavelength axis (default 0).
    measurement_index : int, optional
        Index into its measurement axis (default 0).

    Returns
    -------
    dict
        ``alines`` ``(n, n_t)`` float64 (detector i = row i), ``positions`` ``(n, 2)`` (x, y) m
        (``(n, 1)`` for an fpscan 2-D export), ``weights`` ``(n,)`` or None (fpscan exports
        carry the plan's weights), ``dt`` s (1/``ad_sampling_rate``), ``c`` m/s
        (``speed_of_sound``, 1500 if absent), ``wavelengths`` (m), ``grid`` (regular lateral
        coordinate vectors: the plan's lattice, else spanned by the detector positions),
        ``uuid``, ``plan`` (dict or None), ``indices`` (lattice indices or None), ``z_plane``
        (the detectors' z, m).

    Raises
    ------
    ValueError
        Naming the fault: not HDF5, not IPASC, inconsistent sizes, an index out of range,
        non-planar detectors, non-finite data.
    FileNotFoundError
        No file at ``path``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no IPASC file at {path}")
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise ValueError(f"{path} is not an HDF5 file") from None
    with f:
        return read_open_ipasc(f, wavelength_index=wavelength_index, measurement_index=measurement_index)


def read_open_ipasc(f: h5py.File, *, wavelength_index: int = 0, measurement_index: int = 0) -> dict:
    """:func:`read_ipasc` of an IPASC file already open.

    The registry of formats (``fpscan.service.formats``) opens a file once and reads it here.

    Parameters
    ----------
    f : h5py.File
        The open, read-only file.
    wavelength_index, measurement_index : int, optional
        As :func:`read_ipasc`.

    Returns
    -------
    dict
        As :func:`read_ipasc`.

    Raises
    ------
    ValueError
        As :func:`read_ipasc`.
    """
    raw = _binary_data(f, wavelength_index, measurement_index)
    n_det = raw.shape[0]
    m = {k: _value(v) for k, v in f["meta_data"].items() if isinstance(v, h5py.Dataset)}
    sizes = m.get("sizes")
    if sizes is not None and list(np.ravel(sizes)) != list(raw.shape):
        raise ValueError(f"meta_data/sizes {list(np.ravel(sizes))} != binary data shape "
                         f"{list(raw.shape)}")
    fs = _sampling_rate(m)
    c = _speed_of_sound(m)
    wl = m.get("acquisition_wavelengths")
    wavelengths = np.ravel(np.asarray(wl, dtype=np.float64)) if wl is not None else np.zeros(0)
    pos3 = _detector_positions(f, n_det)
    alines = np.asarray(raw[:, :, wavelength_index, measurement_index], dtype=np.float64)
    if not np.isfinite(alines).all():
        raise ValueError("binary data contains NaN or infinite values")
    dt = 1.0 / fs
    dt_exact = m.get("fpscan_dt_s")
    if dt_exact is not None and abs(float(dt_exact) * fs - 1.0) < 1e-9:
        dt = float(dt_exact)  # the exact sample interval 1/ad_sampling_rate was derived from
    plan = _plan(m)
    weights = m.get("fpscan_weights")
    if weights is not None:
        weights = np.ravel(np.asarray(weights, dtype=np.float64))
        if weights.shape != (n_det,):
            raise ValueError(f"fpscan_weights has {weights.size} values for {n_det} detectors")
    indices = m.get("fpscan_lattice_indices")
    two_d = int(m.get("fpscan_spatial_dimensions") or 3) == 2
    lattice = _plan_lattice(plan)
    if lattice is not None:
        n_x, n_y, pitch = lattice["n_x"], lattice["n_y"], lattice["pitch"]
        gx, gy = centred_axis(n_x, pitch), centred_axis(n_y, pitch)
    else:
        gx = _regular_axis(pos3[:, 0], "x")
        gy = _regular_axis(pos3[:, 1], "y")
        two_d = two_d or len(gy) == 1
    positions = pos3[:, :1].copy() if two_d else pos3[:, :2].copy()
    return {
        "alines": alines, "positions": positions, "weights": weights, "dt": dt, "c": c,
        "wavelengths": wavelengths, "grid": (gx,) if two_d else (gx, gy),
        "uuid": m.get("uuid"), "plan": plan,
        "indices": np.asarray(indices) if indices is not None else None,
        "z_plane": float(pos3[0, 2]),
    }


def _binary_data(f: h5py.File, wavelength_index: int, measurement_index: int) -> Any:
    """``/binary_time_series_data`` (not read), checked: 4-D [detectors, samples,
    wavelengths, measurements], real numbers, the indices within it."""
    if "binary_time_series_data" not in f or "meta_data" not in f:
        raise ValueError("not an IPASC file: /binary_time_series_data or /meta_data missing")
    raw = f["binary_time_series_data"]
    if raw.ndim != 4:
        raise ValueError(f"binary_time_series_data must be 4-D [detectors, samples, "
                         f"wavelengths, measurements], got shape {raw.shape}")
    _, _, n_wl, n_meas = raw.shape
    if not 0 <= wavelength_index < n_wl:
        raise ValueError(f"wavelength_index {wavelength_index} out of range [0, {n_wl})")
    if not 0 <= measurement_index < n_meas:
        raise ValueError(f"measurement_index {measurement_index} out of range [0, {n_meas})")
    if raw.dtype.kind not in "iuf":
        raise ValueError(f"binary data must be real numbers, got {raw.dtype}")
    return raw


def _sampling_rate(m: dict) -> float:
    """``meta_data/ad_sampling_rate`` (Hz), finite and > 0."""
    fs_value = m.get("ad_sampling_rate")
    try:
        if fs_value is None:
            raise TypeError
        fs = float(fs_value)
    except (TypeError, ValueError):
        raise ValueError(f"meta_data/ad_sampling_rate missing or not a number: {fs_value!r}") from None
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"meta_data/ad_sampling_rate must be > 0 Hz, got {fs}")
    return fs


def _speed_of_sound(m: dict) -> float:
    """``meta_data/speed_of_sound`` (m/s; ``C_DEFAULT`` if absent): one value (a
    homogeneous medium), finite and > 0."""
    c = m.get("speed_of_sound")
    if c is None:
        c = C_DEFAULT
    c_arr = np.ravel(np.asarray(c, dtype=np.float64))
    if c_arr.size == 0 or not np.all(c_arr == c_arr[0]):
        raise ValueError("a spatially varying speed_of_sound is not supported (homogeneous "
                         "medium only)")
    c = float(c_arr[0])
    if not (math.isfinite(c) and c > 0):
        raise ValueError(f"speed_of_sound must be > 0 m/s, got {c}")
    return c


def _detector_positions(f: h5py.File, n_det: int) -> np.ndarray:
    """``(n_det, 3)`` detector positions (m) from ``/meta_data_device/detectors/<id>``
    (ids sorted: detector i is row i of the binary data), finite, on one plane z = const."""
    dets = f.get("meta_data_device/detectors")
    if not isinstance(dets, h5py.Group):
        raise ValueError("not an IPASC file: /meta_data_device/detectors missing")
    ids = sorted(dets.keys())
    if len(ids) != n_det:
        raise ValueError(f"{len(ids)} detectors described but the binary data has {n_det}")
    pos3 = np.empty((n_det, 3))
    buf = np.empty(3, dtype="<f8")
    for i, key in enumerate(ids):
        try:  # low-level open/read: ~5x faster than dets[key]["detector_position"][()]
            dsid = h5d.open(dets.id, f"{key}/detector_position".encode())
        except KeyError:
            raise ValueError(f"detector {key} has no detector_position") from None
        if dsid.get_space().get_simple_extent_npoints() != 3 or \
                dsid.get_type().get_class() not in (h5t.FLOAT, h5t.INTEGER):
            raise ValueError(f"detector {key}: detector_position must be 3 numbers")
        dsid.read(h5s.ALL, h5s.ALL, buf)
        pos3[i] = buf
    if not np.isfinite(pos3).all():
        raise ValueError("detector positions must be finite")
    if np.ptp(pos3[:, 2]) > 1e-9:
        raise ValueError("detectors are not on one plane z = const (planar sensors only)")
    return pos3


def _plan(m: dict) -> dict | None:
    """The plan JSON fpscan exported in ``meta_data/fpscan_plan_json``, None when absent or
    unreadable."""
    if isinstance(m.get("fpscan_plan_json"), str):
        try:
            plan = json.loads(m["fpscan_plan_json"])
        except json.JSONDecodeError:
            return None
        return plan if isinstance(plan, dict) else None
    return None


def _plan_lattice(plan: dict | None) -> dict | None:
    """The lattice ``{"n_x", "n_y", "pitch"}`` (pitch in m) of the exported plan, checked before
    anything is sized from it: integers of at least 1, at most
    `fpscan.driver.plan.MAX_LATTICE_POINTS` points, a positive finite pitch; None without one."""
    from fpscan.driver.plan import MAX_LATTICE_POINTS

    lat = plan.get("lattice") if plan is not None else None
    if lat is None:
        return None
    if not isinstance(lat, dict):
        raise ValueError("fpscan_plan_json's lattice must be an object {n_x, n_y, pitch}")
    sizes = [lat.get("n_x"), lat.get("n_y", 1)]
    if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in sizes) \
            or sizes[0] * sizes[1] > MAX_LATTICE_POINTS:
        raise ValueError(f"fpscan_plan_json's lattice must have 1 to {MAX_LATTICE_POINTS} points (integers n_x, "
                         f"n_y), got {sizes[0]!r} x {sizes[1]!r}")
    return {"n_x": sizes[0], "n_y": sizes[1], "pitch": positive("fpscan_plan_json's lattice pitch", lat.get("pitch"))}


import_ipasc = read_ipasc


def sniff(source: Source) -> bool:
    """True for an HDF5 file with IPASC's ``/binary_time_series_data``.

    Parameters
    ----------
    source : Source
        The opened HDF5 file.

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return "binary_time_series_data" in source.h5


def _wavelengths(f: Any) -> np.ndarray:
    """The file's ``meta_data/acquisition_wavelengths`` (m), empty when absent (no data read)."""
    ds = f.get("meta_data/acquisition_wavelengths")
    try:
        return np.ravel(np.asarray(ds[()], dtype=np.float64)) if ds is not None else np.zeros(0)
    except (TypeError, ValueError):
        return np.zeros(0)


def load(source: Source, *, wavelength_index: int = 0, all_wavelengths: bool = False,
         **_: Any) -> PointDataset | list[PointDataset]:
    """The file as point data (:func:`read_open_ipasc`) at one excitation wavelength, or at all.

    Parameters
    ----------
    source : Source
        The opened HDF5 file.
    wavelength_index : int, optional
        The excitation wavelength to read (default 0); the dataset's ``wavelengths`` is that
        one, its ``meta["wavelengths"]`` all the file's.
    all_wavelengths : bool, optional
        Read every wavelength the file records, from the one open file.
    **_
        Other loading options, ignored.

    Returns
    -------
    PointDataset or list of PointDataset
        The dataset; with ``all_wavelengths`` a list, one per wavelength.

    Raises
    ------
    ValueError
        What :func:`read_open_ipasc` refuses, and an index out of range (naming the file's
        wavelengths).
    """
    if all_wavelengths:
        return [_dataset(source, k) for k in range(max(1, _wavelengths(source.h5).size))]
    return _dataset(source, wavelength_index)


def _dataset(source: Source, wavelength_index: int) -> PointDataset:
    """The dataset of one wavelength of the open IPASC file."""
    if wavelength_index:
        check_wavelength_index(wavelength_index, _wavelengths(source.h5), "file")
    r = read_open_ipasc(source.h5, wavelength_index=wavelength_index)
    plan, indices = r["plan"], r["indices"]
    lattice = _plan_lattice(plan) if indices is not None else None
    if lattice is not None:
        indices = np.asarray(indices, dtype=np.int64).reshape(-1, 2)
    wl = r["wavelengths"]
    return PointDataset(alines=r["alines"], positions=r["positions"], weights=r["weights"],
                        dt=r["dt"], sound_speed=r["c"], grid=r["grid"], source="ipasc",
                        meta={"uuid": r["uuid"], "plan": plan, "indices": r["indices"],
                              "wavelengths": wl, "wavelength_index": int(wavelength_index)},
                        indices=indices if lattice is not None else None, lattice=lattice,
                        wavelengths=(float(np.ravel(wl)[wavelength_index]),)
                        if wl is not None and np.size(wl) > wavelength_index else None)


FORMAT = Format(rank=50, name="ipasc", title="IPASC HDF5", container="hdf5", sniff=sniff, load=load, write=export_scan,
                input=True, upload=True, wavelengths=True, order=50, noun="an IPASC file", options=WavelengthChoice,
                export_from="fpscan", export=export_scan, suffix="_ipasc.h5", media_type="application/x-hdf5")
