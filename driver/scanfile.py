"""The scan file: one HDF5 file per acquisition, written as A-lines arrive.

Layout (``format`` attribute ``fpscan-scan/2``; full description in docs/file-formats.md;
``fpscan-scan/1`` files, one wavelength without the first axis, are still read):

=====================  ==========================  =========================================
path                   shape, dtype                meaning
=====================  ==========================  =========================================
``/alines``            (n_w, n_points, n_t) int16  samples as received; [w, k] = point k at
                                                   excitation wavelength w
``/aline_meta``        (n_w, n_points) compound    per-A-line metadata (``META_DTYPE``)
``/completed``         (n_w, n_points) uint8       1 once A-line [w, k] is on disk (the record)
``/positions``         (n_points, d) float64       sensor (x[, y]) in m, d = 2 (1 for 2-D)
``/indices``           (n_points, 2) int32         lattice (i_x, i_y)
``/weights``           (n_points,) float64         area weights (m², or m in 2-D)
``/plan_json``         scalar UTF-8 string         the plan JSON (docs/architecture.md)
root attributes                                    ``plan_id``, ``n_points``, ``n_t``,
                                                   ``dt_s``, ``sound_speed`` (m/s),
                                                   ``wavelengths_m`` (n_w,),
                                                   ``n_wavelengths``, ``wavelength_order``,
                                                   ``acquisition_json``,
                                                   ``instrument_json``,
                                                   ``software_version``, ``created_utc``
=====================  ==========================  =========================================

Crash safety and SWMR. The file is created with ``libver='latest'`` and every dataset is
chunked with *early allocation*, so all file space and all HDF5 metadata exist before
the first A-line; the writer then switches to SWMR mode (readers may open the file with
``swmr=True`` while it is written) and renames the finished skeleton into place. After
that the writer never changes HDF5 metadata: :meth:`ScanFile.append` writes three whole
chunks with ``H5Dwrite_chunk`` (h5py ``write_direct_chunk``), in this order — the A-line's
samples, the metadata chunk holding its record, the ``completed`` chunk holding its flag.
Each is a ``pwrite`` into the already allocated place, done before ``append`` returns, so a
point marked complete always has its samples and metadata on disk before its flag.

Durability policy (``durable`` argument):

- ``"process"`` (default): ``append`` returning means the A-line has been handed to the
  operating system. It survives a crash or ``SIGKILL`` of the writing process (tested),
  not a power cut or kernel crash.
- ``"fsync"``: additionally ``fsync`` after every append: survives power loss, at the
  cost of one disk flush per A-line (use with slow PRFs only).

A killed writer leaves the superblock's "open for SWMR write" flags set; HDF5 then refuses
a normal open. :meth:`ScanFile.open_append` clears them (what ``h5clear -s`` does) after
taking the writer lock. :func:`read_scan` opens a file whose flags say it is (or was)
open for writing as an SWMR reader, any other file normally (HDF5's SWMR reader would
retry a truncated file's missing metadata forever), after checking the superblock's
checksum and stored end of file against the file's size. The writer lock is an exclusive
``flock`` on the sidecar file ``<path>.lock`` (removed on close); it dies with the
process, so a stale lock file never blocks a resume.

DC-normalised pressure (the ``pressure`` view of :class:`ScanData`): the FP sensor's AC
output is pressure × sensitivity × DC level, so for A-line k

    pressure[w, k, n] = (alines[w, k, n] · scale[w, k] + offset[w, k]) / dc_level[w, k]

(docs/protocol.md A-line frame; units Pa when scale/offset are in V and the sensitivity is
V/(Pa·V), otherwise relative). Rows of A-lines not yet complete are NaN. Whether that
calibration holds is the instrument's statement: ``instrument_json`` with
``"pressure_unit": "Pa"`` (:func:`pressure_unit`); without it the pressure, and every p0
reconstructed from it, is in arbitrary units ("a.u.").
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import errno
import fcntl
import json
import math
import numbers
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from h5py import h5d, h5p, h5s, h5t

from fpscan.constants import C_DEFAULT
from fpscan.driver.hdf5_checks import HDF5_SIGNATURE, check_hdf5_file
from fpscan.driver.plan import canonical_json, check_plan, wavelength_order

__all__ = [
    "FORMAT", "FORMAT_1", "META_KEYS", "META_DTYPE", "META_CHUNK", "COMPLETED_CHUNK", "DURABLE_POLICIES",
    "open_readonly", "open_checked", "ScanFile", "ScanData", "PRESSURE_UNITS", "pressure_unit", "completed_count",
    "read_scan", "read_open_scan", "FORMAT_FAMILY", "superblock_open_for_write", "Repaired", "repair"]

FORMAT = "fpscan-scan/2"
#: the single-wavelength layout of fpscan ≤ 0.x, still read by read_scan
FORMAT_1 = "fpscan-scan/1"
#: the ``format`` attribute's prefix of every scan-file version (detection:
#: ``fpscan.service.formats.scan.sniff``; a version this module does not read is refused by it)
FORMAT_FAMILY = "fpscan-scan/"
#: the speed of sound's root attribute (m/s): the name a person reads (as the plan's
#: ``acquisition.sound_speed`` and ``fpscan.service.names``); files of an older fpscan say
#: ``sound_speed_m_per_s`` (:data:`_SPEED_BEFORE`), still read
_SPEED = "sound_speed"
_SPEED_BEFORE = "sound_speed_m_per_s"

META_KEYS = ("run_id", "boot_id", "point_index", "pulse_number", "timestamp_s",
             "bias_wavelength_m", "dc_level", "pulse_energy_j", "dt_s", "scale", "offset",
             "wavelength_index", "excitation_wavelength_m")
#: keys append() requires; ``point_index``, ``wavelength_index`` (default 0) and
#: ``excitation_wavelength_m`` (default: the plan's wavelength) may be omitted
_META_REQUIRED = frozenset(META_KEYS) - {"point_index", "wavelength_index",
                                          "excitation_wavelength_m"}
_META_KEY_SET = frozenset(META_KEYS)
_FLOAT_KEYS = ("timestamp_s", "bias_wavelength_m", "dc_level", "pulse_energy_j", "dt_s",
               "scale", "offset")  # META_DTYPE order after the four integers
#: Per-A-line metadata record, little-endian, as stored in ``/aline_meta``.
META_DTYPE = np.dtype([
    ("run_id", "<u8"), ("boot_id", "<u8"), ("point_index", "<i8"), ("pulse_number", "<u8"),
    ("timestamp_s", "<f8"), ("bias_wavelength_m", "<f8"), ("dc_level", "<f8"),
    ("pulse_energy_j", "<f8"), ("dt_s", "<f8"), ("scale", "<f8"), ("offset", "<f8"),
    ("wavelength_index", "<i8"), ("excitation_wavelength_m", "<f8"),
])
META_CHUNK = 64        # records per /aline_meta chunk (6.7 kB)
COMPLETED_CHUNK = 4096  # flags per /completed chunk (4 kB)
DURABLE_POLICIES = ("process", "fsync")


@dataclass(frozen=True)
class _PlanArrays:
    n_points: int
    n_t: int
    dt: float
    sound_speed: float
    wavelengths: np.ndarray
    order: str
    positions: np.ndarray
    indices: np.ndarray
    weights: np.ndarray


def _check_plan(plan: Any) -> _PlanArrays:
    """Validate a plan dict with ``fpscan.driver.plan.check_plan`` (docs/architecture.md "Plan
    JSON"; ValueError names the fault) and return its arrays."""
    check_plan(plan)
    acq, pts = plan["acquisition"], plan["points"]
    pos = np.asarray(pts["positions"], dtype=np.float64)
    return _PlanArrays(pos.shape[0], int(acq["n_t"]), float(acq["dt"]),
                       float(acq.get("sound_speed", C_DEFAULT)),
                       np.asarray(acq["wavelengths"], dtype=np.float64).reshape(-1),
                       wavelength_order(acq), pos,
                       np.asarray(pts["indices"], dtype=np.int64).astype(np.int32),
                       np.asarray(pts["weights"], dtype=np.float64))


# --- superblock status flags (what `h5clear -s` does) ------------------------------------

def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF


def _lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``, as HDF5's ``H5_checksum_lookup3``."""
    m = 0xFFFFFFFF
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & m
    i = 0
    while length > 12:
        a = (a + int.from_bytes(data[i:i + 4], "little")) & m
        b = (b + int.from_bytes(data[i + 4:i + 8], "little")) & m
        c = (c + int.from_bytes(data[i + 8:i + 12], "little")) & m
        a = (a - c) & m; a ^= _rot(c, 4); c = (c + b) & m
        b = (b - a) & m; b ^= _rot(a, 6); a = (a + c) & m
        c = (c - b) & m; c ^= _rot(b, 8); b = (b + a) & m
        a = (a - c) & m; a ^= _rot(c, 16); c = (c + b) & m
        b = (b - a) & m; b ^= _rot(a, 19); a = (a + c) & m
        c = (c - b) & m; c ^= _rot(b, 4); b = (b + a) & m
        i += 12
        length -= 12
    if length == 0:
        return c
    tail = data[i:] + bytes(12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & m
    b = (b + int.from_bytes(tail[4:8], "little")) & m
    c = (c + int.from_bytes(tail[8:12], "little")) & m
    c ^= b; c = (c - _rot(b, 14)) & m
    a ^= c; a = (a - _rot(c, 11)) & m
    b ^= a; b = (b - _rot(a, 25)) & m
    c ^= b; c = (c - _rot(b, 16)) & m
    a ^= c; a = (a - _rot(c, 4)) & m
    b ^= a; b = (b - _rot(a, 14)) & m
    c ^= b; c = (c - _rot(b, 24)) & m
    return c




def _clear_status_flags(path: Path) -> bool:
    """Clear the superblock's file-consistency flags left by a killed writer.

    Only for superblock versions 2/3 (``libver='latest'``) at offset 0; the superblock
    checksum is verified before and rewritten after. Returns True if flags were cleared.
    Raises ValueError if the file is not such an HDF5 file.
    """
    with open(path, "r+b") as fh:
        head = fh.read(12)
        if len(head) < 12 or head[:8] != HDF5_SIGNATURE:
            raise ValueError(f"{path} is not an HDF5 file with a superblock at offset 0")
        version, size_off = head[8], head[9]
        if version not in (2, 3):
            raise ValueError(f"{path}: superblock version {version} is not a scan file's (3)")
        n = 12 + 4 * size_off
        fh.seek(0)
        block = fh.read(n + 4)
        if len(block) != n + 4:
            raise ValueError(f"{path}: truncated superblock")
        stored = int.from_bytes(block[n:n + 4], "little")
        if _lookup3(block[:n]) != stored:
            raise ValueError(f"{path}: superblock checksum mismatch (not a valid HDF5 file)")
        if block[11] == 0:
            return False
        new = bytearray(block[:n])
        new[11] = 0
        fh.seek(0)
        fh.write(bytes(new) + _lookup3(bytes(new)).to_bytes(4, "little"))
        fh.flush()
        os.fsync(fh.fileno())
    return True


_DEFERRED_SIGNALS = ("SIGINT", "SIGTERM")


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back while the block runs, then deliver them.

    In the main thread (the only one whose signal handlers Python runs) each of the two
    signals gets a handler that only records it; on leaving, the previous handlers are put
    back and every recorded signal is raised again (``signal.raise_signal``), so its own
    handler (``KeyboardInterrupt``, a program's handler, or the default action) acts after
    the block. Elsewhere a plain block.
    """
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    before: dict[int, Any] = {}

    def record(signum: int, frame: object) -> None:
        if signum not in pending:
            pending.append(signum)

    try:
        for name in _DEFERRED_SIGNALS:
            signum = getattr(signal, name)
            before[signum] = signal.signal(signum, record)
        yield
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        for signum in pending:
            signal.raise_signal(signum)


# --- writer lock ------------------------------------------------------------------------

def _lock_path(path: Path) -> Path:
    return path.with_name(path.name + ".lock")


def _acquire_lock(path: Path) -> int:
    """Exclusive non-blocking flock on ``<path>.lock``; ValueError if another writer has it."""
    lp = _lock_path(path)
    while True:
        fd = os.open(lp, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise ValueError(f"{path} is being written by another process "
                                 f"(lock {lp} is held)") from None
            raise
        try:  # the holder may have unlinked the lock file between our open and flock
            if os.fstat(fd).st_ino == os.stat(lp).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)


def _release_lock(path: Path, fd: int) -> None:
    try:
        os.unlink(_lock_path(path))
    except FileNotFoundError:
        pass
    os.close(fd)


_TRANSIENT = ("unable to lock file", "not already open for SWMR writing")


def _open_h5(path: Path, timeout: float, **kwargs: Any) -> h5py.File:
    """``h5py.File(path, **kwargs)``, retried for up to ``timeout`` s while another process
    briefly holds HDF5's file lock (an SWMR reader, or a writer reopening the file)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return h5py.File(path, **kwargs)
        except OSError as exc:
            transient = any(t in str(exc) for t in _TRANSIENT)
            if not transient or time.monotonic() >= deadline:
                raise
        time.sleep(0.02)


def superblock_open_for_write(path: str | os.PathLike) -> bool:
    """Check an HDF5 file's superblock before HDF5 sees the file, and say whether a writer
    has it open.

    A version 2/3 superblock at offset 0 (what ``libver='latest'`` writes) must have a valid
    checksum (HDF5's Jenkins lookup3) and a stored end-of-file address within the file's size.
    Other superblock versions are left to HDF5's own checks.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    bool
        True when the superblock's file-consistency flags say a writer has (or had, if it was
        killed) the file open for SWMR writing (:func:`open_readonly` then opens it as an SWMR
        reader); False when they do not, and for superblock versions other than 2 and 3.

    Raises
    ------
    ValueError
        Not an HDF5 file with its signature at offset 0; a truncated or corrupt superblock (bad
        checksum, an offset size other than 2, 4 or 8); a file shorter than its stored end.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(12)
        if len(head) < 12 or head[:8] != HDF5_SIGNATURE:
            raise ValueError(f"{path} is not an HDF5 file")
        version, size_off = head[8], head[9]
        if version not in (2, 3):
            return False
        if size_off not in (2, 4, 8):
            raise ValueError(f"{path}: corrupt HDF5 superblock")
        n = 12 + 4 * size_off
        fh.seek(0)
        block = fh.read(n + 4)
        size = os.fstat(fh.fileno()).st_size
    if len(block) != n + 4 or _lookup3(block[:n]) != int.from_bytes(block[n:n + 4], "little"):
        raise ValueError(f"{path}: corrupt or truncated HDF5 superblock")
    eof = int.from_bytes(block[12 + 2 * size_off:12 + 3 * size_off], "little")
    if eof > size:
        raise ValueError(f"{path} is truncated ({size} of {eof} bytes)")
    return block[11] != 0


def open_readonly(path: str | os.PathLike, timeout: float = 5.0) -> h5py.File:
    """Open an HDF5 file (a scan file or any other) read-only. A file a writer has open
    (or left open when killed) is opened as an SWMR reader; any other without SWMR:
    HDF5's SWMR reader retries unreadable metadata (of a truncated or corrupt file)
    without end, holding the GIL, where a normal open reports the damage. ``timeout``:
    retries while a writer holds the file lock (s). Raises ValueError.

    Parameters
    ----------
    path : str or os.PathLike
        The HDF5 file.
    timeout : float, optional
        Seconds to retry while a writer holds the file lock (default 5).

    Returns
    -------
    h5py.File
        The file, open read-only (the caller closes it).

    Raises
    ------
    ValueError
        A corrupt or truncated superblock, or a file HDF5 cannot open.
    """
    path = Path(path)
    live = superblock_open_for_write(path)
    kwargs: dict[str, Any] = {"libver": "latest", "swmr": True} if live else {}
    try:
        return _open_h5(path, timeout, mode="r", **kwargs)
    except OSError as exc:
        raise ValueError(f"{path} cannot be opened as an HDF5 scan file: {exc}") from None


def _make_dataset(parent: h5py.Group, name: str, shape: tuple, dtype: np.dtype,
                  chunks: tuple) -> h5py.Dataset:
    """Chunked dataset with all chunks allocated at creation and never filled."""
    dcpl = h5p.create(h5p.DATASET_CREATE)
    dcpl.set_chunk(chunks)
    dcpl.set_alloc_time(h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5d.FILL_TIME_NEVER)
    tid = h5t.py_create(np.dtype(dtype), logical=True)
    dsid = h5d.create(parent.id, name.encode(), tid, h5s.create_simple(shape), dcpl=dcpl)
    return h5py.Dataset(dsid)



@contextmanager
def open_checked(path: str | os.PathLike, *, max_bytes: int) -> Iterator[Any]:
    """An HDF5 file opened read-only (``fpscan.driver.scanfile.open_readonly``: without SWMR unless a
    writer has it) and checked (:func:`check_hdf5_file`) before the caller reads anything;
    closed on leaving.

    Parameters
    ----------
    path : str or os.PathLike
    max_bytes : int
        The most bytes any one dataset may declare.

    Returns
    -------
    context manager of h5py.File
        Entered, the file, read-only (``with open_checked(path, max_bytes=n) as f``).

    Raises
    ------
    ValueError
        Not a readable HDF5 file (truncated or corrupt), or refused by :func:`check_hdf5_file`
        (the reason names the file's own objects only).
    """
    try:
        f = open_readonly(path)
    except Exception:  # ValueError from the checks; damaged files can reach other paths
        raise ValueError("not a readable HDF5 file (truncated or corrupt)") from None
    with f:
        check_hdf5_file(f, max_bytes=max_bytes)
        yield f


class ScanFile:
    """Writer of one scan file (see the module docstring for layout and guarantees).

    Create with :meth:`create` or resume with :meth:`open_append`; then :meth:`append`
    each A-line as it arrives; :meth:`close` (or use as a context manager). One writer per
    file (enforced by a lock); any number of SWMR readers (:func:`read_scan`).

    Parameters
    ----------
    path : Path
        The scan file (the constructor is internal: :meth:`create`, :meth:`open_append`).
    h5 : h5py.File
        The file, open for SWMR writing.
    lock_fd : int
        The descriptor holding the writer lock.
    durable : str
        ``"process"`` or ``"fsync"`` (module docstring).

    Attributes
    ----------
    plan_id : str
        The plan's id.
    n_points : int
        Points of the plan.
    n_t : int
        Samples per A-line.
    wavelengths : ndarray ``(n_wavelengths,)`` float64
        Excitation wavelengths, m.
    n_wavelengths : int
        Number of excitation wavelengths.
    wavelength_order : str
        ``"per_point"`` or ``"per_pass"``.
    """

    def __init__(self, path: Path, h5: h5py.File, lock_fd: int, durable: str) -> None:
        self._path = path
        self._f = h5
        self._lock_fd = lock_fd
        self._durable = durable
        self._mutex = threading.Lock()
        self._alines = h5["alines"]
        self._meta_ds = h5["aline_meta"]
        self._completed_ds = h5["completed"]
        self._alines_id = self._alines.id
        self._meta_id = self._meta_ds.id
        self._done_id = self._completed_ds.id
        self._meta_chunk = self._meta_ds.chunks[1]
        self._done_chunk = self._completed_ds.chunks[1]
        self.plan_id: str = str(h5.attrs["plan_id"])
        self.n_points: int = int(h5.attrs["n_points"])
        self.n_t: int = int(h5.attrs["n_t"])
        self.wavelengths = np.asarray(h5.attrs["wavelengths_m"], dtype=np.float64).reshape(-1)
        self.n_wavelengths: int = int(h5.attrs["n_wavelengths"])
        self.wavelength_order: str = str(h5.attrs["wavelength_order"])
        n_w, n = self.n_wavelengths, self.n_points
        pad_m = -(-n // META_CHUNK) * META_CHUNK
        pad_c = -(-n // COMPLETED_CHUNK) * COMPLETED_CHUNK
        self._meta = np.zeros((n_w, pad_m), META_DTYPE)
        self._done = np.zeros((n_w, pad_c), np.uint8)
        if n:
            self._done[:, :n] = self._completed_ds[()]
            self._meta[:, :n] = self._meta_ds[()]
            # rows never written hold whatever the disk held: zero them in memory
            self._meta[:, :n][self._done[:, :n] == 0] = np.zeros((), META_DTYPE)
        self._sync_fd = os.open(path, os.O_RDONLY) if durable == "fsync" else None
        self._writing: tuple[int, int] | None = None  # the A-line an append is writing
        self._closed = False

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | os.PathLike, plan: dict, *, instrument: dict,
               software_version: str, durable: str = "process") -> ScanFile:
        """Create a new scan file for ``plan`` and open it for appending.

        ``plan``: the plan JSON dict (docs/architecture.md); its ``id`` is checked against
        its content. ``instrument``: JSON-serialisable identity of the scanner (e.g. the
        ``*IDN?`` fields). ``durable``: ``"process"`` or ``"fsync"`` (module docstring).
        Raises ValueError (bad plan/arguments), FileExistsError (path exists: use
        :meth:`open_append`).
        """
        path = Path(path)
        pa = _check_plan(plan)
        if durable not in DURABLE_POLICIES:
            raise ValueError(f"durable must be one of {DURABLE_POLICIES}, got {durable!r}")
        if not isinstance(instrument, dict):
            raise ValueError(f"instrument must be a dict, got {type(instrument).__name__}")
        if not isinstance(software_version, str):
            raise ValueError("software_version must be a string")
        try:
            instrument_json = canonical_json(instrument)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"instrument is not JSON-serialisable: {exc}") from None
        if path.exists():
            raise FileExistsError(f"{path} exists; use ScanFile.open_append to resume")
        lock_fd = _acquire_lock(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        renamed = False
        try:
            if path.exists():
                raise FileExistsError(f"{path} exists; use ScanFile.open_append to resume")
            f = h5py.File(tmp, "w", libver="latest")
            try:
                n, n_t = pa.n_points, pa.n_t
                n_w = len(pa.wavelengths)
                _make_dataset(f, "alines", (n_w, n, n_t), np.dtype("<i2"), (1, 1, n_t))
                _make_dataset(f, "aline_meta", (n_w, n), META_DTYPE, (1, min(META_CHUNK, n)))
                _make_dataset(f, "completed", (n_w, n), np.dtype("u1"),
                              (1, min(COMPLETED_CHUNK, n)))
                f.create_dataset("positions", data=pa.positions)
                f.create_dataset("indices", data=pa.indices)
                f.create_dataset("weights", data=pa.weights)
                f.create_dataset("plan_json", data=canonical_json(plan),
                                 dtype=h5py.string_dtype("utf-8"))
                a = f.attrs
                a["format"] = FORMAT
                a["plan_id"] = plan["id"]
                a["n_points"] = n
                a["n_t"] = n_t
                a["dt_s"] = pa.dt
                a[_SPEED] = pa.sound_speed
                a["wavelengths_m"] = pa.wavelengths
                a["n_wavelengths"] = n_w
                a["wavelength_order"] = pa.order
                a["acquisition_json"] = canonical_json(plan["acquisition"])
                a["instrument_json"] = instrument_json
                a["software_version"] = software_version
                a["created_utc"] = _dt.datetime.now(_dt.UTC).isoformat()
                # zero the flags (early allocation with FILL_TIME_NEVER leaves them undefined)
                zeros = np.zeros(min(COMPLETED_CHUNK, n), np.uint8)
                for w in range(n_w):
                    for start in range(0, n, COMPLETED_CHUNK):
                        f["completed"].id.write_direct_chunk((w, start), zeros)
                f.swmr_mode = True  # flushes all metadata; from here on only raw writes
            except BaseException:
                f.close()
                raise
            os.replace(tmp, path)
            renamed = True
            if durable == "fsync":  # the new directory entry must survive a power cut too
                os.fsync(f.id.get_vfd_handle())
                dir_fd = os.open(path.parent, os.O_RDONLY)
                try:
                    os.fsync(dir_fd)
                finally:
                    os.close(dir_fd)
            return cls(path, f, lock_fd, durable)
        except BaseException:
            if renamed:  # the file is in place and valid (resumable); just close it
                try:
                    f.close()
                except Exception:  # already failing; keep the first error
                    pass
            tmp.unlink(missing_ok=True)
            _release_lock(path, lock_fd)
            raise

    @classmethod
    def open_append(cls, path: str | os.PathLike, plan: dict | None = None, *,
                    durable: str = "process", timeout: float = 10.0) -> ScanFile:
        """Reopen an existing scan file (interrupted or not) to continue appending.

        If ``plan`` is given, its id must equal the file's plan id (ValueError otherwise).
        Clears the superblock flags a killed writer left behind, and zeroes the samples and
        metadata of the A-lines it had not marked complete (:func:`repair`). Waits up to ``timeout`` s
        while readers hold HDF5's file lock. Raises FileNotFoundError, ValueError (not a
        scan file, plan mismatch, another writer holds the lock, file still locked).
        """
        path = Path(path)
        if durable not in DURABLE_POLICIES:
            raise ValueError(f"durable must be one of {DURABLE_POLICIES}, got {durable!r}")
        if not path.is_file():
            raise FileNotFoundError(f"no scan file at {path}")
        lock_fd = _acquire_lock(path)
        try:
            was_open = _clear_status_flags(path)
            try:
                f = _open_h5(path, timeout, mode="r+", libver="latest")
            except OSError as exc:
                raise ValueError(f"{path} cannot be opened as HDF5: {exc}") from None
            try:
                if f.attrs.get("format") == FORMAT_1:
                    raise ValueError(f"{path} is an {FORMAT_1} file (an older fpscan's single-"
                                     f"wavelength layout): it can be read, not resumed")
                if f.attrs.get("format") != FORMAT:
                    raise ValueError(f"{path} is not an {FORMAT} file")
                if plan is not None:
                    pid = plan.get("id") if isinstance(plan, dict) else None
                    if pid != f.attrs["plan_id"]:
                        raise ValueError(f"plan {pid!r} does not match the scan file's plan "
                                         f"{f.attrs['plan_id']!r}")
                if was_open:  # its writer died: drop the A-line it had not marked complete
                    _zero_incomplete(f, np.asarray(f["completed"][()], dtype=bool))
                f.swmr_mode = True
                return cls(path, f, lock_fd, durable)
            except BaseException:
                f.close()
                raise
        except BaseException:
            _release_lock(path, lock_fd)
            raise

    # -- properties -----------------------------------------------------------------------
    @property
    def path(self) -> Path:
        return self._path

    @property
    def plan(self) -> dict:
        """The plan dict stored in the file."""
        return json.loads(self._f["plan_json"][()].decode())

    def completed(self) -> np.ndarray:
        """``(n_points,)`` bool: points complete at every wavelength (a copy)."""
        return np.asarray(self._done[:, :self.n_points].all(axis=0))

    def completed_by_wavelength(self) -> np.ndarray:
        """``(n_wavelengths, n_points)`` bool: the record of completed A-lines (a copy)."""
        return self._done[:, :self.n_points].astype(bool)

    def n_completed(self) -> int:
        """Points complete at every wavelength."""
        return int(self.completed().sum())

    # -- writing --------------------------------------------------------------------------
    def append(self, point_index: int, samples: np.ndarray, meta: dict) -> bool:
        """Store the A-line of point ``point_index`` at wavelength ``meta["wavelength_index"]``
        (default 0); False if that A-line is already complete.

        ``samples``: int16 array ``(n_t,)`` as received. ``meta``: dict with the keys
        ``META_KEYS``, of which ``point_index`` (if present it must equal the argument),
        ``wavelength_index`` (0 ≤ w < n_wavelengths; default 0) and
        ``excitation_wavelength_m`` (default: the plan's wavelength w) may be omitted;
        ``dc_level`` must be finite and > 0, ``scale``/``offset`` finite.
        When it returns True the A-line is durable under the file's policy.
        Raises ValueError on bad input (nothing is written then), RuntimeError if closed.
        """
        if self._closed:
            raise RuntimeError("scan file is closed")
        if isinstance(point_index, bool) or not isinstance(point_index, numbers.Integral):
            raise ValueError(f"point_index must be an integer, got {point_index!r}")
        k = int(point_index)
        if not 0 <= k < self.n_points:
            raise ValueError(f"point_index {k} out of range [0, {self.n_points})")
        if not isinstance(samples, np.ndarray):
            raise ValueError(f"samples must be a numpy int16 array, got {type(samples).__name__}")
        if samples.dtype.kind != "i" or samples.dtype.itemsize != 2:
            raise ValueError(f"samples must be int16, got {samples.dtype}")
        if samples.shape != (self.n_t,):
            raise ValueError(f"samples must have shape ({self.n_t},), got {samples.shape}")
        rec = self._meta_record(k, meta)
        w = rec[11]
        with self._mutex:
            if self._done[w, k]:
                return False
            self._writing = (w, k)  # until the flag is on disk (close() undoes a broken append)
            data = np.ascontiguousarray(samples, dtype="<i2")
            self._alines_id.write_direct_chunk((w, k, 0), data)
            m0 = k - k % META_CHUNK
            self._meta[w, k] = rec
            self._meta_id.write_direct_chunk((w, m0), self._meta[w, m0:m0 + self._meta_chunk])
            c0 = k - k % COMPLETED_CHUNK
            self._done[w, k] = 1
            try:
                self._done_id.write_direct_chunk((w, c0),
                                                 self._done[w, c0:c0 + self._done_chunk])
            except BaseException:
                self._done[w, k] = 0
                raise
            self._writing = None
            if self._sync_fd is not None:
                os.fsync(self._sync_fd)
        return True

    def _unwrite(self, w: int, k: int) -> None:
        """Undo an append that an exception (a ``KeyboardInterrupt`` between its writes)
        broke off: A-line ``[w, k]`` is written back as never written (zero samples, a zero
        metadata record, its flag as the in-memory record says, which the failed append
        left 0), so the file holds exactly the A-lines whose ``append`` returned."""
        self._done[w, k] = 0
        self._alines_id.write_direct_chunk((w, k, 0), np.zeros(self.n_t, "<i2"))
        m0 = k - k % META_CHUNK
        self._meta[w, k] = np.zeros((), META_DTYPE)
        self._meta_id.write_direct_chunk((w, m0), self._meta[w, m0:m0 + self._meta_chunk])
        c0 = k - k % COMPLETED_CHUNK
        self._done_id.write_direct_chunk((w, c0), self._done[w, c0:c0 + self._done_chunk])
        self._writing = None

    @staticmethod
    def _uint(key: str, v: Any) -> int:
        if type(v) is not int:  # fast path for plain ints; numpy integers are fine too
            if isinstance(v, bool) or not isinstance(v, numbers.Integral):
                raise ValueError(f"meta[{key!r}] must be a non-negative integer, got {v!r}")
            v = int(v)
        if not 0 <= v < 18446744073709551616:
            raise ValueError(f"meta[{key!r}] must be a non-negative integer < 2**64, got {v!r}")
        return v

    def _meta_record(self, k: int, meta: Any) -> tuple:
        """Validated metadata as a tuple in ``META_DTYPE`` field order."""
        if not isinstance(meta, dict):
            raise ValueError(f"meta must be a dict, got {type(meta).__name__}")
        if not (_META_KEY_SET.issuperset(meta) and _META_REQUIRED.issubset(meta)):
            unknown = set(meta) - _META_KEY_SET
            if unknown:
                raise ValueError(f"unknown A-line metadata keys: {sorted(unknown)}")
            missing = [key for key in META_KEYS if key not in meta and key in _META_REQUIRED]
            raise ValueError(f"A-line metadata missing keys: {missing}")
        try:
            floats = [float(meta[key]) for key in _FLOAT_KEYS]
        except (TypeError, ValueError):
            for key in _FLOAT_KEYS:
                try:
                    float(meta[key])
                except (TypeError, ValueError):
                    raise ValueError(f"meta[{key!r}] must be a number, got {meta[key]!r}") \
                        from None
            raise
        timestamp, bias, dc, energy, dt, scale, offset = floats
        pi = self._uint("point_index", meta.get("point_index", k))
        if pi != k:
            raise ValueError(f"meta point_index {pi} != point_index {k}")
        if not (dc > 0 and math.isfinite(dc)):
            raise ValueError(f"meta dc_level must be finite and > 0, got {dc}")
        if not math.isfinite(scale):
            raise ValueError(f"meta['scale'] must be finite, got {scale}")
        if not math.isfinite(offset):
            raise ValueError(f"meta['offset'] must be finite, got {offset}")
        w, wavelength = self._wavelength_of(meta)
        return (self._uint("run_id", meta["run_id"]), self._uint("boot_id", meta["boot_id"]),
                pi, self._uint("pulse_number", meta["pulse_number"]),
                timestamp, bias, dc, energy, dt, scale, offset, w, wavelength)

    def _wavelength_of(self, meta: dict) -> tuple[int, float]:
        w = self._uint("wavelength_index", meta.get("wavelength_index", 0))
        if w >= self.n_wavelengths:
            raise ValueError(f"meta wavelength_index {w} out of range "
                             f"[0, {self.n_wavelengths})")
        if "excitation_wavelength_m" not in meta:
            return w, float(self.wavelengths[w])
        try:
            wavelength = float(meta["excitation_wavelength_m"])
        except (TypeError, ValueError):
            raise ValueError(f"meta['excitation_wavelength_m'] must be a number, got "
                             f"{meta['excitation_wavelength_m']!r}") from None
        if not (math.isfinite(wavelength) and wavelength >= 0):  # 0: not reported
            raise ValueError(f"meta excitation_wavelength_m must be finite and >= 0 m, got "
                             f"{wavelength}")
        return w, wavelength

    def flush(self) -> None:
        """Flush HDF5 buffers (nothing is buffered after append) and fsync the file."""
        if self._closed:
            return
        with self._mutex:
            self._f.flush()
            fd = self._f.id.get_vfd_handle()
            os.fsync(fd)

    def close(self) -> None:
        """Flush, close the HDF5 file (clearing its open-for-write flags) and the lock.

        Not interrupted by SIGINT or SIGTERM when called from the main thread: a signal that
        arrives meanwhile is delivered once the file is closed (:func:`_signals_deferred`),
        so a Ctrl-C or a ``kill`` never leaves the file open for writing.
        """
        if self._closed:
            return
        with _signals_deferred():
            try:
                with self._mutex:
                    if self._writing is not None:
                        self._unwrite(*self._writing)
                self.flush()
            finally:
                self._closed = True
                try:
                    self._f.close()
                finally:
                    if self._sync_fd is not None:
                        os.close(self._sync_fd)
                    _release_lock(self._path, self._lock_fd)

    def __enter__(self) -> ScanFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"{self.n_completed()}/{self.n_points} done"
        return f"ScanFile({str(self._path)!r}, plan {self.plan_id[:12]}, {state})"


@dataclass
class ScanData:
    """Everything in a scan file, read at one instant (:func:`read_scan`).

    Arrays are indexed by point index k (scan order). The per-A-line arrays are views at
    one excitation wavelength, ``wavelength_index`` (default 0), so a single-wavelength
    user reads exactly what a one-wavelength file holds; the ``*_all`` arrays hold every
    wavelength (first axis w, the index into ``wavelengths``). Rows of A-lines whose
    completion flag is False hold no data: ``alines`` 0, metadata 0, ``pressure`` NaN.

    Attributes
    ----------
    path : Path
        The file read.
    plan : dict
        The plan JSON stored in the file.
    plan_id : str
        The plan's id.
    n_points : int
        Points (rows of the per-point arrays).
    n_t : int
        Samples per A-line.
    dt : float
        Sample interval, s (from the plan's acquisition).
    sound_speed : float
        m/s (from the plan's acquisition).
    wavelengths : ndarray ``(n_wavelengths,)`` float64
        Excitation wavelengths, m.
    alines : ndarray ``(n_points, n_t)`` int16
        The samples as received, at ``wavelength_index``.
    scale, offset, dc_level : ndarray ``(n_points,)`` float64
        From the metadata, at ``wavelength_index``.
    pressure : ndarray ``(n_points, n_t)`` float
        DC-normalised ``(alines·scale + offset) / dc_level`` (module docstring).
    positions : ndarray ``(n_points, 2)``
        (x, y) in m (2-D plans: ``(n_points, 1)``).
    indices : ndarray ``(n_points, 2)``
        Lattice indices (i_x, i_y).
    weights : ndarray ``(n_points,)``
        The plan's sensor weights (areas, m²; m on a line lattice).
    completed : ndarray ``(n_points,)`` bool
        The completion record at ``wavelength_index``.
    meta : dict
        Key → ``(n_points,)`` array for every key of ``META_KEYS``.
    acquisition : dict
        The plan's acquisition object.
    instrument : dict
        The scanner's identity (``instrument_json``; :func:`pressure_unit`).
    software_version : str
        The fpscan version that wrote the file.
    created_utc : str
        Creation time, ISO 8601 (UTC).
    attrs : dict
        Every file attribute (bytes decoded).
    n_wavelengths : int
        Number of excitation wavelengths.
    wavelength_index : int
        The wavelength the per-A-line views show (index into ``wavelengths``).
    wavelength_order : str
        ``"per_point"`` or ``"per_pass"``.
    alines_all : ndarray ``(n_wavelengths, n_points, n_t)`` int16
        Samples at every wavelength.
    pressure_all : ndarray ``(n_wavelengths, n_points, n_t)`` float
        Pressure at every wavelength.
    completed_all : ndarray ``(n_wavelengths, n_points)`` bool
        The completion record at every wavelength.
    meta_all : dict
        Key → ``(n_wavelengths, n_points)`` array.
    """

    path: Path
    plan: dict
    plan_id: str
    n_points: int
    n_t: int
    dt: float
    sound_speed: float
    wavelengths: np.ndarray
    alines: np.ndarray
    scale: np.ndarray
    offset: np.ndarray
    dc_level: np.ndarray
    pressure: np.ndarray
    positions: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    completed: np.ndarray
    meta: dict
    acquisition: dict
    instrument: dict
    software_version: str
    created_utc: str
    attrs: dict = field(default_factory=dict)
    n_wavelengths: int = 1
    wavelength_index: int = 0
    wavelength_order: str = "per_point"
    alines_all: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), np.int16))
    pressure_all: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    completed_all: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    meta_all: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        """One line: the file, its plan, points measured of planned, samples, dt and wavelengths
        (never the arrays)."""
        from fpscan.wire.brief import one_line

        wl = ", ".join(f"{w * 1e9:g}" for w in np.atleast_1d(self.wavelengths)[:4])
        more = ", ..." if np.size(self.wavelengths) > 4 else ""
        return one_line(f"ScanData({self.path.name!r}: plan {self.plan_id[:12]}, {int(np.count_nonzero(self.completed))} of "
                        f"{self.n_points} points, n_t {self.n_t} x dt {self.dt * 1e9:.4g} ns, wavelengths {wl}{more} nm)")

    def at_wavelength(self, index: int) -> ScanData:
        """The same data with the per-A-line views at wavelength ``index`` (views, no copy).
        Raises ``ValueError`` if ``index`` is not in ``[0, n_wavelengths)``."""
        if isinstance(index, bool) or not isinstance(index, numbers.Integral) or \
                not 0 <= index < self.n_wavelengths:
            raise ValueError(f"wavelength index must be an integer in [0, {self.n_wavelengths})"
                             f" (the scan's {self.n_wavelengths} wavelengths), got {index!r}")
        w = int(index)
        meta = {k: v[w] for k, v in self.meta_all.items()}
        return dataclasses.replace(
            self, wavelength_index=w, alines=self.alines_all[w], pressure=self.pressure_all[w],
            completed=self.completed_all[w], meta=meta, scale=meta["scale"],
            offset=meta["offset"], dc_level=meta["dc_level"])

    def completed_only(self, *, every_wavelength: bool = False) -> ScanData:
        """A copy restricted to the points complete at ``wavelength_index`` (or, with
        ``every_wavelength``, at every wavelength); rows kept in scan order, the ``*_all``
        arrays restricted to the same points."""
        sel = np.flatnonzero(self.completed_all.all(axis=0) if every_wavelength
                             else self.completed)
        return dataclasses.replace(
            self, n_points=len(sel), alines=self.alines[sel], scale=self.scale[sel],
            offset=self.offset[sel], dc_level=self.dc_level[sel],
            pressure=self.pressure[sel], positions=self.positions[sel],
            indices=self.indices[sel], weights=self.weights[sel],
            completed=self.completed[sel], meta={k: v[sel] for k, v in self.meta.items()},
            alines_all=self.alines_all[:, sel], pressure_all=self.pressure_all[:, sel],
            completed_all=self.completed_all[:, sel],
            meta_all={k: v[:, sel] for k, v in self.meta_all.items()},
            attrs=dict(self.attrs, subset_of_n_points=self.n_points))


def _check_layout(f: h5py.File, path: Path, attrs: dict, wavelengths: np.ndarray, *, version_1: bool) -> None:
    """Refuse a scan file whose datasets disagree with its own ``n_points``, ``n_t`` and
    wavelengths (the module docstring's layout), before any of them is read: an A-line record
    shorter or longer than ``n_t``, or one array with fewer points than the others, would
    otherwise read as a different scan or fail deep inside the reader. Raises ValueError
    naming the dataset, the shape it has and the shape the attributes ask."""
    stated = attrs.get("n_points"), attrs.get("n_t")
    if not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and int(v) >= 1 for v in stated):
        raise ValueError(f"{path}: n_points ({stated[0]!r}) and n_t ({stated[1]!r}) must be positive integers")
    n, n_t = (int(v) for v in stated if v is not None)
    n_w = 1 if version_1 else wavelengths.size
    lead = () if version_1 else (n_w,)
    want = {"alines": (*lead, n, n_t), "aline_meta": (*lead, n), "completed": (*lead, n),
            "weights": (n,)}
    for name in (*want, "positions", "indices", "plan_json"):
        if not isinstance(f.get(name), h5py.Dataset):
            raise ValueError(f"{path} has no dataset /{name}: not a complete scan file")
    for name, shape in want.items():
        if f[name].shape != shape:
            raise ValueError(f"{path}: /{name} has shape {f[name].shape}, but the file's n_points = {n}, "
                             f"n_t = {n_t} and {n_w} wavelength(s) ask {shape}")
    if f["positions"].ndim != 2 or f["positions"].shape[0] != n or f["positions"].shape[1] not in (1, 2):
        raise ValueError(f"{path}: /positions has shape {f['positions'].shape}, not ({n}, 1 or 2)")
    if f["indices"].shape != (n, 2):
        raise ValueError(f"{path}: /indices has shape {f['indices'].shape}, not ({n}, 2)")
    if not version_1 and attrs.get("n_wavelengths", n_w) != n_w:
        raise ValueError(f"{path}: n_wavelengths = {attrs['n_wavelengths']!r}, but wavelengths_m holds {n_w}")


def _read_v1(f: h5py.File, wavelengths: np.ndarray) -> tuple:
    """An ``fpscan-scan/1`` file's record, samples and metadata in the version-2 shapes."""
    done = f["completed"][()].astype(bool)[None]
    old = f["aline_meta"][()]
    alines = f["alines"][()][None]
    meta_arr = np.zeros((1, old.shape[0]), META_DTYPE)
    for name in old.dtype.names:
        meta_arr[0][name] = old[name]
    meta_arr["excitation_wavelength_m"] = wavelengths[0] if wavelengths.size else np.nan
    return done, meta_arr, alines


#: the units of the DC-normalised pressure: calibrated (volts → Pa) or arbitrary
PRESSURE_UNITS = ("Pa", "a.u.")


def pressure_unit(instrument: dict | None) -> str:
    """The unit of a scan's DC-normalised pressure: ``"Pa"`` when the instrument dict (the
    scan file's ``instrument_json``) states the volts-to-pascal calibration with
    ``"pressure_unit": "Pa"`` (``scale``/``offset`` give volts and the sensitivity is
    1 V/(Pa·V): module docstring), else ``"a.u."`` (arbitrary units, proportional to
    pressure). Raises ValueError for a ``pressure_unit`` other than those two.

    Parameters
    ----------
    instrument : dict or None
        The scan file's instrument dict (None: none stated).

    Returns
    -------
    str
        ``"Pa"`` or ``"a.u."``.

    Raises
    ------
    ValueError
        A ``pressure_unit`` other than those of ``PRESSURE_UNITS``.
    """
    unit = (instrument or {}).get("pressure_unit", "a.u.")
    if unit not in PRESSURE_UNITS:
        raise ValueError(f"instrument pressure_unit must be one of {', '.join(PRESSURE_UNITS)}, got {unit!r}")
    return str(unit)


def completed_count(path: str | os.PathLike, *, timeout: float = 5.0) -> int:
    """The number of points complete at every wavelength in a scan file (complete,
    partial or left open by a killed writer), reading only its completion record.
    Raises FileNotFoundError, ValueError (not a scan file).

    Parameters
    ----------
    path : str or os.PathLike
        The scan file.
    timeout : float, optional
        Seconds to retry while a writer holds the file lock (default 5).

    Returns
    -------
    int
        Points complete at every wavelength.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Not a scan file (or not a readable HDF5 file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no scan file at {path}")
    with open_readonly(path, timeout) as f:
        fmt = f.attrs.get("format")
        if fmt not in (FORMAT, FORMAT_1):
            raise ValueError(f"{path} is not an {FORMAT} (or {FORMAT_1}) file")
        done = np.asarray(f["completed"][()], dtype=bool)
    return int(np.count_nonzero(done if done.ndim == 1 else done.all(axis=0)))


@dataclass(frozen=True)
class Repaired:
    """What :func:`repair` found and did.

    Attributes
    ----------
    was_open : bool
        The superblock said a writer had the file open (a writer killed, or a power cut):
        its flags were cleared.
    n_points : int
        Points of the plan.
    points_done : int
        Points complete at every wavelength (the record's count, unchanged by the repair).
    alines_done : int
        A-lines (point, wavelength) complete.
    alines_cleared : int
        A-lines not marked complete whose samples or metadata were on disk (written by a
        writer that died before it marked them complete): zeroed, as a never-written A-line.
    """

    was_open: bool
    n_points: int
    points_done: int
    alines_done: int
    alines_cleared: int


def repair(path: str | os.PathLike, *, timeout: float = 10.0) -> Repaired:
    """Close a scan file that its writer left open (``SIGKILL``, a crash, a power cut), so
    that any HDF5 reader opens it: ``h5py.File(path, "r")`` included.

    Takes the writer lock (a file being written is refused), checks the superblock
    (checksum, stored end of file against the file's size) and that it is a scan file, clears
    the superblock's open-for-write flags (what ``h5clear -s`` does), then opens it for
    writing without SWMR and makes its content the record's: the samples and metadata of
    every A-line not marked complete in ``/completed`` are zeroed (at most the A-line being
    written when the writer died has any), the record itself is left as it is. Closing the
    file then leaves its flags clear. A file closed cleanly is checked the same way and left
    with the same content; resuming the scan (:meth:`ScanFile.open_append`) does all of this
    too.

    Parameters
    ----------
    path : str or os.PathLike
        The scan file.
    timeout : float, optional
        Seconds to retry while a reader holds HDF5's file lock (default 10).

    Returns
    -------
    Repaired
        What was found and done.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Not a scan file, a corrupt or truncated HDF5 file, or a file another process is writing.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no scan file at {path}")
    lock_fd = _acquire_lock(path)
    try:
        with open_readonly(path, timeout) as f:  # a scan file? (as an SWMR reader if left open)
            fmt = f.attrs.get("format")
        if fmt not in (FORMAT, FORMAT_1):
            raise ValueError(f"{path} is not an {FORMAT} (or {FORMAT_1}) file")
        was_open = _clear_status_flags(path)
        try:
            f = _open_h5(path, timeout, mode="r+", libver="latest")
        except OSError as exc:
            raise ValueError(f"{path} cannot be opened as HDF5: {exc}") from None
        with f:
            done = np.asarray(f["completed"][()], dtype=bool)
            if done.ndim == 1:  # fpscan-scan/1: one wavelength, no first axis
                done = done[None]
            cleared = _zero_incomplete(f, done)
            n = int(f.attrs["n_points"])
        return Repaired(was_open, n, int(done.all(axis=0).sum()), int(done.sum()), cleared)
    finally:
        _release_lock(path, lock_fd)


def _zero_incomplete(f: h5py.File, done: np.ndarray) -> int:
    """Zero the samples and metadata of the A-lines not marked complete that hold any (read
    a block of points at a time); their count. ``done``: ``(n_wavelengths, n_points)``."""
    one = f["alines"].ndim == 2  # fpscan-scan/1: one wavelength, no first axis
    alines, meta = f["alines"], f["aline_meta"]
    zero_rec = np.zeros((), meta.dtype)
    cleared = 0
    block = 256
    for w in range(done.shape[0]):
        for lo in range(0, done.shape[1], block):
            hi = min(lo + block, done.shape[1])
            todo = np.flatnonzero(~done[w, lo:hi])
            if not todo.size:
                continue
            at: Any = (slice(lo, hi),) if one else (w, slice(lo, hi))
            rows = np.asarray(meta[at])
            samples = np.asarray(alines[at])
            for r in todo:
                stray_meta = rows[r].tobytes() != zero_rec.tobytes()
                stray_samples = bool(samples[r].any())
                if not (stray_meta or stray_samples):
                    continue
                k = lo + int(r)
                row: Any = (k,) if one else (w, k)
                if stray_meta:
                    meta[row] = zero_rec
                if stray_samples:
                    alines[row] = np.zeros(samples.shape[-1], alines.dtype)
                cleared += 1
    return cleared


def read_scan(path: str | os.PathLike, *, dtype: Any = np.float64,
              timeout: float = 5.0, wavelength_index: int = 0) -> ScanData:
    """Read a scan file, complete or still being written (SWMR reader).

    Reads ``fpscan-scan/2`` files and the single-wavelength ``fpscan-scan/1`` layout.
    ``dtype``: float type of the ``pressure`` view (float64 or float32). ``timeout``: how
    long to retry while a writer is (re)opening the file and holds its lock.
    ``wavelength_index``: the wavelength the per-A-line views show (``ScanData``).
    The completion record is read first, so every A-line it marks complete has its
    samples and metadata present. Raises FileNotFoundError, ValueError (not a scan file,
    wavelength index out of range).

    Parameters
    ----------
    path : str or os.PathLike
        The scan file.
    dtype : numpy float dtype, optional
        Float type of the ``pressure`` views (default float64; float32 halves their memory).
    timeout : float, optional
        Seconds to retry while a writer holds the file lock (default 5).
    wavelength_index : int, optional
        The wavelength the per-A-line views show (default 0).

    Returns
    -------
    ScanData
        Everything in the file, read at one instant.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        ``dtype`` not a float type, not a scan file, or ``wavelength_index`` out of range.
    """
    path = Path(path)
    if np.dtype(dtype).kind != "f":
        raise ValueError(f"dtype must be a float type, got {np.dtype(dtype)}")
    if not path.is_file():
        raise FileNotFoundError(f"no scan file at {path}")
    with open_readonly(path, timeout) as f:
        return read_open_scan(f, path, dtype=dtype, wavelength_index=wavelength_index)


def read_open_scan(f: h5py.File, path: str | os.PathLike, *, dtype: Any = np.float64,
                   wavelength_index: int = 0) -> ScanData:
    """:func:`read_scan` of a scan file already open (``open_readonly``), ``path`` its
    name (for messages and ``ScanData.path``): so a caller that opened the file once (the
    registry of formats, ``fpscan.service.formats``) reads it without opening it again. The speed
    of sound is the attribute ``sound_speed``, or ``sound_speed_m_per_s`` in a file an older
    fpscan wrote. Raises ValueError (not a scan file, wavelength index out of range).

    Parameters
    ----------
    f : h5py.File
        The scan file, open read-only.
    path : str or os.PathLike
        Its name.
    dtype : numpy float dtype, optional
        Float type of the ``pressure`` views (default float64).
    wavelength_index : int, optional
        The wavelength the per-A-line views show (default 0).

    Returns
    -------
    ScanData
        Everything in the file.

    Raises
    ------
    ValueError
        ``dtype`` not a float type, not a scan file, or ``wavelength_index`` out of range.
    """
    path = Path(path)
    dtype = np.dtype(dtype)
    if dtype.kind != "f":
        raise ValueError(f"dtype must be a float type, got {dtype}")
    fmt = f.attrs.get("format")
    if fmt not in (FORMAT, FORMAT_1):
        raise ValueError(f"{path} is not an {FORMAT} (or {FORMAT_1}) file")
    attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    wavelengths = np.asarray(attrs["wavelengths_m"], dtype=np.float64).reshape(-1)
    _check_layout(f, path, attrs, wavelengths, version_1=fmt == FORMAT_1)
    if fmt == FORMAT_1:
        done, meta_arr, alines = _read_v1(f, wavelengths)
    else:
        done = f["completed"][()].astype(bool)
        meta_arr = f["aline_meta"][()]
        alines = f["alines"][()]
    plan = json.loads(f["plan_json"][()].decode())
    positions = f["positions"][()]
    indices = f["indices"][()]
    weights = f["weights"][()]
    alines[~done] = 0
    meta_arr[~done] = np.zeros((), META_DTYPE)
    meta_all = {k: np.ascontiguousarray(meta_arr[k]) for k in META_KEYS}
    scale, offset, dc = meta_all["scale"], meta_all["offset"], meta_all["dc_level"]
    pressure = alines.astype(dtype)
    pressure *= scale.astype(dtype)[..., None]
    pressure += offset.astype(dtype)[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        pressure /= dc.astype(dtype)[..., None]
    pressure[~done] = np.nan
    acquisition = json.loads(attrs["acquisition_json"])
    data = ScanData(
        path=path, plan=plan, plan_id=str(attrs["plan_id"]), n_points=int(attrs["n_points"]),
        n_t=int(attrs["n_t"]), dt=float(attrs["dt_s"]),
        sound_speed=float(attrs[_SPEED] if _SPEED in attrs else attrs[_SPEED_BEFORE]), wavelengths=wavelengths,
        alines=alines[0], scale=scale[0], offset=offset[0], dc_level=dc[0],
        pressure=pressure[0], positions=positions, indices=indices, weights=weights,
        completed=done[0], meta={k: v[0] for k, v in meta_all.items()},
        acquisition=acquisition, instrument=json.loads(attrs["instrument_json"]),
        software_version=str(attrs["software_version"]), created_utc=str(attrs["created_utc"]),
        attrs=attrs, n_wavelengths=done.shape[0],
        wavelength_order=str(attrs.get("wavelength_order", "per_point")),
        alines_all=alines, pressure_all=pressure, completed_all=done, meta_all=meta_all)
    return data.at_wavelength(wavelength_index) if wavelength_index != 0 else data
