"""The job store's reserve for a full disk: a file beside the database whose bytes are given
back when a write finds the disk full, so that the jobs' states can still be written.

The reserve is ``<database>.reserve`` (:data:`DB_RESERVE_BYTES`, written at start-up). When a
write meets SQLite's SQLITE_FULL ("database or disk is full"), :meth:`DiskReserve._write`
removes it and writes again; the reserve is written again once the disk has room for twice
it (:meth:`DiskReserve.restore_reserve`, looked at after writes and by the server's periodic
look), and :meth:`DiskReserve.problems` says while it is spent. The server's API and each
worker open their own store on one database and share the one reserve file.
"""
from __future__ import annotations

import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from fpscan.service.disk import free_bytes, is_disk_full

__all__ = ["DB_RESERVE_BYTES", "DiskReserve"]

log = logging.getLogger("fpscan.store")

_T = TypeVar("_T")

#: bytes of the reserve file kept beside the database for job states on a full disk (SQLite's
#: WAL grows by 4 MiB at most between checkpoints; each state or progress event adds a row)
DB_RESERVE_BYTES = 8 << 20
#: seconds between two looks, after a write, at whether a spent reserve can be written again
_RESERVE_RETRY_S = 5.0


class DiskReserve:
    """The reserve part of :class:`fpscan.service.jobs.store.JobStore` (module docstring): every write
    of the store goes through :meth:`_write`.

    Attributes
    ----------
    path : pathlib.Path
        The database file (set by the store).
    reserve_path : pathlib.Path
        The reserve file, ``<database>.reserve``.
    reserve_bytes : int
        The reserve's size in bytes (0: none).
    reserve_spent : float or None
        When the reserve was given up (UNIX s), None while it is kept.
    """

    path: Path

    def _init_reserve(self, reserve_bytes: int) -> None:
        """Set the reserve's attributes (nothing written yet: :meth:`_write_reserve`)."""
        self.reserve_path = self.path.with_name(self.path.name + ".reserve")
        self.reserve_bytes = int(reserve_bytes)
        self.reserve_spent: float | None = None  # when the reserve was given up (time.time()), None: kept
        self._reserve_look = 0.0  # time.monotonic() of the last look at writing it again
        self._reserve_lock = threading.Lock()  # spending and writing it again never cross
        self._reserve_seen = False  # the reserve file was in place once (written here or by another store)

    def _write_reserve(self) -> bool:
        """Write the reserve file (all of it: its blocks allocated); True when it is there."""
        if self.reserve_bytes <= 0:
            return True
        try:
            if self.reserve_path.exists() and self.reserve_path.stat().st_size >= self.reserve_bytes:
                return True
            fd = os.open(self.reserve_path, os.O_WRONLY | os.O_CREAT, 0o600)
            try:
                try:
                    os.posix_fallocate(fd, 0, self.reserve_bytes)
                except (AttributeError, OSError) as exc:  # no fallocate here: write zeros
                    if is_disk_full(exc):
                        raise
                    block = bytes(1 << 20)
                    for start in range(0, self.reserve_bytes, len(block)):
                        os.pwrite(fd, block[:self.reserve_bytes - start], start)
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            self.reserve_path.unlink(missing_ok=True)
            log.warning("job store reserve %s not written: %s", self.reserve_path, exc)
            return False
        return True

    def _spend_reserve(self) -> bool:
        """Give the reserve's bytes back to the disk. True when a write is worth trying once
        more: this store gave them up now, or another store on the same database gave them up
        before (the server's API and each worker open their own, and share the one reserve
        file: when a worker met the full disk first, the API's cancel found the file gone, and
        was refused while the bytes it had held lay free); this store then counts the reserve
        as spent too (`problems`, and the free bytes the server reports). False when there is
        none to give: ``reserve_bytes`` 0, or a reserve that was never in place (a disk too
        small for it at start-up)."""
        with self._reserve_lock:
            if self.reserve_bytes <= 0:
                return False
            if not self.reserve_path.exists():
                if not self._reserve_seen:  # never written: nothing was given up
                    return False
                if self.reserve_spent is None:  # given up by another store on this database
                    self.reserve_spent = time.time()
                return True
            self.reserve_path.unlink(missing_ok=True)
            self.reserve_spent = time.time()
        log.warning("job store: the disk is full; its reserve of %d bytes was given up for job states",
                    self.reserve_bytes)
        return True

    def _after_write(self) -> None:
        """After a write: a spent reserve is written again once the disk has room for twice it;
        a reserve this store could not write at start-up counts as in place once another store
        on the database has written it (each looked at most every few seconds)."""
        if time.monotonic() - self._reserve_look < _RESERVE_RETRY_S:
            return
        if self.reserve_spent is None:
            if not self._reserve_seen:
                self._reserve_look = time.monotonic()
                self._reserve_seen = self.reserve_path.exists()
            return
        self.restore_reserve()

    def restore_reserve(self) -> bool:
        """Write a spent reserve again if the disk has room for twice it (a server's
        periodic look, and after writes); True when the reserve is in place."""
        if self.reserve_spent is None:
            return True
        self._reserve_look = time.monotonic()
        free = free_bytes(self.path.parent)
        room = free is not None and free >= 2 * self.reserve_bytes + (1 << 20)
        with self._reserve_lock:
            if room and self.reserve_spent is not None and self._write_reserve():
                log.info("job store: the disk has room again; its reserve is back")
                self.reserve_spent = None
                self._reserve_seen = True
            return self.reserve_spent is None

    def _write(self, call: Callable[[], _T]) -> _T:
        """``call()`` (a write); on a full disk the reserve is given up and ``call`` tried once more."""
        try:
            out = call()
        except sqlite3.OperationalError as exc:
            if not is_disk_full(exc) or not self._spend_reserve():
                raise
            out = call()
        self._after_write()
        return out

    def problems(self) -> list[str]:
        """One line while the reserve is spent (the disk filled), else none (``/api/health``)."""
        if self.reserve_spent is None:
            return []
        return [f"the job database's disk filled at {time.strftime('%H:%M:%S', time.localtime(self.reserve_spent))}: "
                f"its reserve of {self.reserve_bytes} bytes is spent on job states; free space on the data folder's disk"]
