"""The data folder's disk use by part, kept as counters (health's cost independent of
history).

``/api/health`` reports the bytes of the data folder by part (``scans``, ``results``,
``datasets``, ``exports``, ``other``). A walk of the folder per answer (or per change) cost
time linear in the files: health's p99 was 42 ms at 1860 files, 0.9-3.3 s at 9-11 thousand.
:class:`DiskUsage` answers from counters instead, in time independent of the folder:

- **Counters**, kept by whoever writes or removes a part's files, in the server process:
  a finished reconstruction adds its result folder (``fpscan.service.jobs.queue``), an upload its
  dataset folder, an export its file (the routes), a deletion or retention takes off what it
  freed (``fpscan.service.jobs.lifecycle``). :meth:`DiskUsage.add_path` measures a file or folder
  where it was written (a few ``lstat`` calls, in the writer's thread).
- **Growing files** (a scan file while its scan runs): :meth:`DiskUsage.growing` registers
  the file, whose size is read when an answer is made (one ``stat``); :meth:`DiskUsage.grown`
  adds its final size to its part.
- **The job database** (``jobs.sqlite`` and its WAL files) is ``stat``-ed when an answer is
  made; the free bytes come from ``statvfs``.
- **A walk checks the counters** (:meth:`DiskUsage.reconcile`, from
  :func:`fpscan.service.jobs.lifecycle.disk_usage`): at start-up before the server answers, then
  every ``period_s`` in a thread of its own (:meth:`DiskUsage.start_walks`), never per
  request. A counter that disagrees with the walk by more than :data:`DRIFT_BYTES` is logged
  and set to the walk's figure (changes made while the walk ran are kept on top of it).

One :class:`DiskUsage` per data folder in a process (:func:`usage_for`), so that the
lifecycle functions, the queue and the routes count into the one health reads.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["PARTS", "DRIFT_BYTES", "WALK_PERIOD_S", "DiskUsage", "usage_for", "part_of", "tree_bytes"]

log = logging.getLogger("fpscan.disk")

#: the parts of the data folder counted apart (the rest is ``other``)
PARTS = ("scans", "results", "datasets", "exports")
#: a counter further than this from the walk's figure is logged (and corrected)
DRIFT_BYTES = 1 << 20
#: seconds between two checking walks of the data folder (the default of ``start_walks``)
WALK_PERIOD_S = 600.0
#: the job database's files, stat-ed for every answer (not counted by a counter)
_DATABASE_SUFFIXES = ("", "-wal", "-shm", ".reserve")


def tree_bytes(path: str | os.PathLike) -> int:
    """Bytes of the files under ``path``, by ``lstat`` size.

    Parameters
    ----------
    path : str or os.PathLike
        A file, or a folder walked without following links.

    Returns
    -------
    int
        The file's size, or the sum of the sizes of the files under the folder, in bytes;
        0 if ``path`` is missing (files that vanish during the walk are skipped).
    """
    p = Path(path)
    try:
        st = p.lstat()
    except OSError:
        return 0
    if not p.is_dir() or p.is_symlink():
        return st.st_size
    total = 0
    for root, _dirs, files in os.walk(p):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def part_of(path: str | os.PathLike, data_dir: str | os.PathLike) -> str:
    """The part of the data folder that ``path`` lies in.

    Parameters
    ----------
    path : str or os.PathLike
        A file or folder (made absolute; links are not resolved).
    data_dir : str or os.PathLike
        The data folder.

    Returns
    -------
    str
        ``"scans"``, ``"results"``, ``"datasets"`` or ``"exports"`` (the first folder of
        ``path`` below ``data_dir``, one of :data:`PARTS`); ``"other"`` elsewhere in the data
        folder or outside it.
    """
    try:
        rel = Path(os.path.abspath(path)).relative_to(os.path.abspath(data_dir))
    except ValueError:
        return "other"
    first = rel.parts[0] if rel.parts else ""
    return first if first in PARTS else "other"


class DiskUsage:
    """Bytes of ``data_dir`` by part (module docstring), kept as counters. Thread-safe.

    Parameters
    ----------
    data_dir : str or os.PathLike
        The data folder whose parts (:data:`PARTS`, plus ``other``) are counted.
    database : str or os.PathLike or None, optional
        The job database's file (its WAL files beside it are counted with it, as ``other``,
        when it lies in the data folder itself); default ``data_dir / "jobs.sqlite"``.

    Attributes
    ----------
    data_dir : pathlib.Path
        The data folder.
    database : pathlib.Path
        The job database's file.
    walks : int
        The number of checking walks done (:meth:`reconcile`).
    last_walk_s : float or None
        Seconds the last checking walk took; None before the first.
    LIVE_TTL_S : float
        Seconds the live part of an answer (growing files, the database's files, the free
        bytes) is reused (class attribute, 1.0).
    """

    #: seconds the live part of an answer (growing files, the database's files, the free
    #: bytes: a system call each) is reused; the counters are always current
    LIVE_TTL_S = 1.0

    def __init__(self, data_dir: str | os.PathLike, database: str | os.PathLike | None = None) -> None:
        self.data_dir = Path(data_dir)
        self.database = Path(database) if database is not None else self.data_dir / "jobs.sqlite"
        self._live: tuple[float, dict[str, int], int | None] | None = None  # (when, bytes by part, free)
        self._lock = threading.Lock()
        self._counts = dict.fromkeys((*PARTS, "other"), 0)
        self._growing: dict[str, str] = {}  # path -> part
        self._changes: list[tuple[str, int]] | None = None  # (part, bytes) while a walk runs
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.walks = 0
        self.last_walk_s: float | None = None

    # -- counting (the writers) --------------------------------------------------------
    def add(self, part: str, nbytes: int) -> None:
        """Count ``nbytes`` in ``part``.

        Parameters
        ----------
        part : str
            One of :data:`PARTS` or ``"other"``; any other name counts as ``"other"``.
        nbytes : int
            Bytes written (negative: freed); a counter never goes below 0.
        """
        if part not in self._counts:
            part = "other"
        with self._lock:
            self._counts[part] = max(0, self._counts[part] + int(nbytes))
            if self._changes is not None:
                self._changes.append((part, int(nbytes)))

    def add_path(self, path: str | os.PathLike, *, removed: bool = False, nbytes: int | None = None) -> int:
        """Count the bytes of ``path`` in its part (:func:`part_of`), or take them off.

        Parameters
        ----------
        path : str or os.PathLike
            A file or folder of the data folder.
        removed : bool, optional
            Take the bytes off instead (measure before removing); default False.
        nbytes : int or None, optional
            The bytes, when known; default None: measured now (:func:`tree_bytes`).

        Returns
        -------
        int
            The bytes counted (or taken off), not negative.
        """
        n = tree_bytes(path) if nbytes is None else int(nbytes)
        self.add(part_of(path, self.data_dir), -n if removed else n)
        return n

    def growing(self, path: str | os.PathLike) -> None:
        """Register ``path`` as growing in place from now (a scan file being written).

        Its size is read for every answer until :meth:`grown`. Its bytes so far are taken
        off its part's counter meanwhile (they are in the file's size). A path already
        registered is left as it is.

        Parameters
        ----------
        path : str or os.PathLike
            The growing file.
        """
        key = os.path.abspath(path)
        part = part_of(key, self.data_dir)
        size = tree_bytes(key)
        with self._lock:
            if key in self._growing:
                return
            self._growing[key] = part
        self.add(part, -size)

    def grown(self, path: str | os.PathLike) -> None:
        """Register that ``path`` no longer grows: its size now is counted in its part.

        Parameters
        ----------
        path : str or os.PathLike
            A file registered with :meth:`growing` (anything else is ignored).
        """
        key = os.path.abspath(path)
        with self._lock:
            part = self._growing.pop(key, None)
        if part is not None:
            self.add(part, tree_bytes(key))

    # -- the answer (health) -------------------------------------------------------------
    def snapshot(self) -> dict:
        """The data folder's bytes by part, as health reports them.

        Returns
        -------
        dict
            ``{"total_bytes", "scans_bytes", "results_bytes", "datasets_bytes",
            "exports_bytes", "other_bytes", "free_bytes"}`` (int; ``free_bytes`` None when it
            cannot be read): the counters, plus the growing files' sizes, the job database's
            files and the file system's free bytes as read at most :attr:`LIVE_TTL_S` ago (a
            ``stat`` per growing file and database file, one ``statvfs``).
        """
        now = time.monotonic()
        live = self._live
        if live is None or now - live[0] >= self.LIVE_TTL_S:
            sizes, free = self._live_bytes(), self.free_bytes()
            live = self._live = (now, sizes, free)
        with self._lock:
            counts = dict(self._counts)
        for part, n in live[1].items():
            counts[part] = counts.get(part, 0) + n
        out: dict[str, int | None] = {f"{k}_bytes": v for k, v in counts.items()}
        out["total_bytes"] = sum(counts.values())
        out["free_bytes"] = live[2]
        return out

    def free_bytes(self) -> int | None:
        """Free bytes of the data folder's file system now.

        Returns
        -------
        int or None
            The free bytes (of the data folder's parent while the folder does not exist);
            None when they cannot be read.
        """
        from fpscan.service.disk import free_bytes

        return free_bytes(self.data_dir if self.data_dir.exists() else self.data_dir.parent)

    def _database_files(self) -> list[Path]:
        """The job database's files that lie in the data folder itself (``other``)."""
        try:
            inside = self.database.parent.resolve() == self.data_dir.resolve()
        except OSError:
            inside = False
        return [self.database.with_name(self.database.name + s) for s in _DATABASE_SUFFIXES] if inside else []

    def _live_bytes(self) -> dict[str, int]:
        """Bytes by part of the growing files and the job database's files, now."""
        with self._lock:
            growing = list(self._growing.items())
        live = dict.fromkeys(self._counts, 0)
        for path, part in growing:
            live[part] += tree_bytes(path)
        for db in self._database_files():
            try:
                live["other"] += db.stat().st_size
            except OSError:
                pass
        return live

    # -- the check ---------------------------------------------------------------------
    def reconcile(self, walk: Callable[[Path], dict]) -> dict:
        """Walk the data folder and set each counter to the walk's figure.

        Each counter becomes the walk's figure, less the growing files and the job database
        (read for each answer), plus the changes counted while the walk ran. A counter that
        was more than :data:`DRIFT_BYTES` off is logged (not on the first walk).

        Parameters
        ----------
        walk : callable
            ``walk(data_dir) -> dict``, the bytes by part as
            :func:`fpscan.service.jobs.lifecycle.disk_usage` returns them (``"scans_bytes"``, ...).

        Returns
        -------
        dict
            The walk's answer.

        Raises
        ------
        Exception
            Whatever ``walk`` raises (the counters are left as they were).
        """
        with self._lock:
            self._changes = []
        t0 = time.perf_counter()
        try:
            walked = walk(self.data_dir)
        except BaseException:
            with self._lock:
                self._changes = None
            raise
        live = self._live_bytes()
        with self._lock:
            changes, self._changes = self._changes or [], None
            for part in self._counts:
                truth = max(0, int(walked.get(f"{part}_bytes") or 0) - live[part])
                during = sum(n for p, n in changes if p == part)
                if self.walks and abs(self._counts[part] - during - truth) > DRIFT_BYTES:
                    log.warning("disk usage counter %s was %d bytes, the walk found %d: corrected", part,
                                self._counts[part] - during, truth)
                self._counts[part] = max(0, truth + during)
            self.walks += 1
        self.last_walk_s = time.perf_counter() - t0
        return walked

    def start_walks(self, walk: Callable[[Path], dict], period_s: float = WALK_PERIOD_S) -> None:
        """Check the counters periodically in a daemon thread of its own.

        The first check comes after one period (the caller walks once at start-up); a failed
        walk is logged and leaves the counters as they are; :meth:`stop` ends the thread. A
        second call while the thread runs does nothing.

        Parameters
        ----------
        walk : callable
            ``walk(data_dir) -> dict``, as for :meth:`reconcile`.
        period_s : float, optional
            Seconds between two walks; default :data:`WALK_PERIOD_S` (600 s).
        """
        if self._thread is not None:
            return

        def loop() -> None:
            while not self._stop.wait(period_s):
                try:
                    self.reconcile(walk)
                except Exception:  # a failed check leaves the counters as they are
                    log.exception("disk usage walk failed")

        self._stop.clear()
        self._thread = threading.Thread(target=loop, name="disk-usage-walk", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the checking walks' thread (after the walk running, if one is)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=5)


_USAGES: dict[str, DiskUsage] = {}
_USAGES_LOCK = threading.Lock()


def usage_for(data_dir: str | os.PathLike, database: str | os.PathLike | None = None) -> DiskUsage:
    """The process's one :class:`DiskUsage` of ``data_dir`` (made on first use).

    Parameters
    ----------
    data_dir : str or os.PathLike
        The data folder (keyed by its absolute path).
    database : str or os.PathLike or None, optional
        The job database's file; when given, it replaces the database of an existing
        :class:`DiskUsage`. Default None (``data_dir / "jobs.sqlite"`` for a new one).

    Returns
    -------
    DiskUsage
        The one counter set of ``data_dir`` in this process.
    """
    key = os.path.abspath(data_dir)
    with _USAGES_LOCK:
        found = _USAGES.get(key)
        if found is None:
            found = _USAGES[key] = DiskUsage(data_dir, database)
        elif database is not None:
            found.database = Path(database)
        return found
