"""The job store's job events: each job's state and progress events, numbered per job.

An event is recorded inside the transaction that changes the job (:meth:`EventLog._event`),
with the next sequence number of that job, so the Server-Sent Events stream can honour
``Last-Event-ID`` (:meth:`EventLog.events_after`). The listeners (:meth:`EventLog.add_listener`)
hear of the job once the transaction is committed.
"""
from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable

from fpscan.service.jobs.store.base import StoreBase
from fpscan.service.jobs.store.clock import wall_time
from fpscan.service.jobs.store.schema import Jobs

__all__ = ["EventLog"]


class EventLog(StoreBase):
    """The events part of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    def add_listener(self, fn: Callable[[str], None]) -> None:
        """Call ``fn(job_id)`` after each committed transaction that recorded an event of
        that job (a state change, progress) or deleted it, in the thread that made the change,
        outside the store's lock; an exception of ``fn`` is logged and ignored. The events
        endpoint's streams wait on it (they never poll)."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[str], None]) -> None:
        """Stop calling ``fn`` (:meth:`add_listener`); a function not added is ignored."""
        if fn in self._listeners:
            self._listeners.remove(fn)

    def _event(self, db: sqlite3.Connection, job_id: str, event: str, data: dict) -> int:
        self._touched.append(job_id)  # inside `_tx`: its listeners hear of it after the commit
        seq = db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM events WHERE job_id = ?", (job_id,)).fetchone()[0]
        db.execute("INSERT INTO events (job_id, seq, event, data, created) VALUES (?, ?, ?, ?, ?)",
                   (job_id, seq, event, json.dumps(data), wall_time()))
        return seq

    def events_after(self, job_id: str, after: int, limit: int = 500) -> Jobs:
        with self._lock:
            rows = self._db.execute(
                "SELECT seq, event, data FROM events WHERE job_id = ? AND seq > ? ORDER BY seq LIMIT ?",
                (job_id, int(after), int(limit))).fetchall()
        return [{"seq": r["seq"], "event": r["event"], "data": r["data"]} for r in rows]
