"""The job store's connection: one SQLite file in WAL mode, one lock, and its transactions.

Every record kind of :class:`fpscan.service.jobs.store.JobStore` (jobs, their events, plans,
datasets, the service config) reads and writes through :class:`StoreBase`: one connection
guarded by one lock (statements are short), its clock (:mod:`fpscan.service.jobs.store.clock`:
wall time for display, the store's monotonic time for durations); a write goes through the full-disk reserve
(:class:`fpscan.service.jobs.store.reserve.DiskReserve`), and a transaction (:meth:`StoreBase._tx`,
``BEGIN IMMEDIATE``) is all or nothing: its listeners hear of the jobs it recorded events of
only once it is committed.

A commit is durable (``synchronous=FULL``: the WAL flushed before the commit returns), so
whatever an answer acknowledges survives a power cut; a report (a job's progress, a
heartbeat: :meth:`StoreBase._report`) is not flushed by itself, the next durable commit
flushes it.
"""
from __future__ import annotations

import contextlib
import logging
import sqlite3
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from fpscan.service.jobs.store.clock import StoreClock
from fpscan.service.jobs.store.reserve import DB_RESERVE_BYTES, DiskReserve
from fpscan.service.jobs.store.schema import apply_schema

__all__ = ["StoreBase"]

log = logging.getLogger("fpscan.store")

_T = TypeVar("_T")


class StoreBase(DiskReserve):
    """The connection, lock and transactions the record kinds of the job store share.

    Parameters
    ----------
    path : str or pathlib.Path
        The database file (parent folders are created).
    reserve_bytes : int, optional
        The reserve kept beside it for a full disk (0: none); default
        :data:`fpscan.service.jobs.store.reserve.DB_RESERVE_BYTES` (8 MiB).

    Attributes
    ----------
    path : pathlib.Path
        The database file.
    """

    def __init__(self, path: str | Path, reserve_bytes: int = DB_RESERVE_BYTES):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._init_reserve(reserve_bytes)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, timeout=30.0,
                                   isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._cache: dict[str, dict] = {}  # job id -> row; every write to a job drops its entry
        self._listeners: list[Callable[[str], None]] = []
        self._touched: list[str] = []  # the jobs the current transaction recorded events of
        with self._lock:
            apply_schema(self._db)
            self._clock = StoreClock.open(self._db)
        self._reserve_seen = self._write_reserve()

    def monotonic(self) -> float:
        """The store's time now, s: monotonic, shared by every store of the database on this
        machine (:mod:`fpscan.service.jobs.store.clock`); a job's ``*_mono`` times are on it,
        so ``store.monotonic() - job["started_mono"]`` is how long it has run."""
        return self._clock.monotonic()

    def _now(self) -> tuple[float, float]:
        """``(wall, store)``: the wall time (UNIX s, for display) and the store's time (s, for
        durations) of this moment."""
        return self._clock.now()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _tx(self, fn: Callable[[sqlite3.Connection], _T], *, durable: bool = True) -> _T:
        """``fn(db)`` in one transaction (``BEGIN IMMEDIATE``), committed durably unless
        ``durable`` is False (:meth:`_report`)."""
        return self._write(lambda: self._tx_once(fn, durable))

    @contextmanager
    def _report(self) -> Iterator[None]:
        """Under the store's lock: the commits inside it are a report (a job's progress, a
        heartbeat), acknowledged to no one, so not flushed one by one (``synchronous=NORMAL``:
        a power cut may lose the last reports, never a commit before them, nor break the
        database); the next durable commit flushes them with it (the WAL is written in order).
        A transaction still open at the end (its ROLLBACK failed in :meth:`_tx_once`) is rolled back
        first: SQLite refuses to change the safety level inside one ("Safety level may not be
        changed inside a transaction"), which would mask the block's own error (a full disk no
        longer recognised as one) and leave the connection at ``NORMAL``.
        Source: https://sqlite.org/pragma.html#pragma_synchronous, https://sqlite.org/wal.html."""
        self._db.execute("PRAGMA synchronous=NORMAL")
        try:
            yield
        finally:
            if self._db.in_transaction:
                with contextlib.suppress(sqlite3.Error):  # the block's own error is the one raised
                    self._db.execute("ROLLBACK")
            self._db.execute("PRAGMA synchronous=FULL")

    def _tx_once(self, fn: Callable[[sqlite3.Connection], _T], durable: bool = True) -> _T:
        with self._lock, (contextlib.nullcontext() if durable else self._report()):
            self._cache.clear()
            self._touched = []
            self._db.execute("BEGIN IMMEDIATE")
            try:
                out = fn(self._db)
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:  # SQLite rolls back by itself on some errors (SQLITE_FULL)
                    try:
                        self._db.execute("ROLLBACK")
                    except sqlite3.Error:
                        pass
                self._touched = []
                raise
            touched, self._touched = list(dict.fromkeys(self._touched)), []
        for job_id in touched:
            for listener in list(self._listeners):
                try:
                    listener(job_id)
                except Exception:  # a listener never undoes a committed change
                    log.exception("job event listener failed")
        return out

