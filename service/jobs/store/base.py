"""The job store's connection: one SQLite file in WAL mode, one lock, and its transactions.

Every record kind of :class:`fpscan.service.jobs.store.JobStore` (jobs, their events, plans,
datasets, the service config) reads and writes through :class:`StoreBase`: one connection
guarded by one lock (statements are short); a write goes through the full-disk reserve
(:class:`fpscan.service.jobs.store.reserve.DiskReserve`), and a transaction (:meth:`StoreBase._tx`,
``BEGIN IMMEDIATE``) is all or nothing: its listeners hear of the jobs it recorded events of
only once it is committed.
"""
from __future__ import annotations

import logging
import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

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
        self._reserve_seen = self._write_reserve()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _tx(self, fn: Callable[[sqlite3.Connection], _T]) -> _T:
        return self._write(lambda: self._tx_once(fn))

    def _tx_once(self, fn: Callable[[sqlite3.Connection], _T]) -> _T:
        with self._lock:
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

