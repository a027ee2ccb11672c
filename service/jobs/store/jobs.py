"""The job store's job records: creating a job, reading and listing jobs, deleting them.

A job row holds its kind (``scan``/``recon``), state, progress (JSON), parameters (JSON),
the unique ``Idempotency-Key``, lease owner/expiry and heartbeat, attempts, result path and
error; its state changes are :mod:`fpscan.service.jobs.store.transitions`'. A job may carry the
address of the client that submitted it (``params["client"]``): :meth:`JobRecords.create_job`
refuses a new one (:class:`QueueFull`) while that client already has ``max_queued`` jobs of
the kind queued, counted in the transaction that would insert it. Read jobs are cached in
memory until the next write (:meth:`JobRecords.peek` reads the cache alone).

Jobs are listed in the store's sequence (``seq``, the order they were submitted in), never by
a wall time: a wall clock set back would put the newest job last and let a new job jump the
queue. A job's moments carry the wall time (display) and the store's monotonic time
(``*_mono``, :mod:`fpscan.service.jobs.store.clock`: durations).
"""
from __future__ import annotations

import copy
import json
import sqlite3
import uuid
from collections.abc import Iterable
from typing import Any, overload

from fpscan.service.jobs.store.events import EventLog
from fpscan.service.jobs.store.schema import ACTIVE, KINDS, TERMINAL, Jobs
from fpscan.service.names import current_names

__all__ = ["IdempotencyConflict", "QueueFull", "JobRecords"]


class IdempotencyConflict(ValueError):
    """The Idempotency-Key is already used by a job with different parameters.

    A ``ValueError``.

    Attributes
    ----------
    args : tuple
        The message.
    """


class QueueFull(ValueError):
    """A client already has as many jobs queued as it may (``max_queued`` of
    :meth:`JobStore.create_job`).

    A ``ValueError``.

    Parameters
    ----------
    client : str
        The client's address.
    queued : int
        Its jobs of the kind queued now.
    limit : int
        The most it may have.

    Attributes
    ----------
    client, queued, limit
        As given.
    """

    def __init__(self, client: str, queued: int, limit: int) -> None:
        super().__init__(f"client {client} has {queued} jobs queued, the most it may have ({limit})")
        self.client, self.queued, self.limit = client, queued, limit


class JobRecords(EventLog):
    """The job rows of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    @staticmethod
    @overload
    def _row(row: sqlite3.Row) -> dict[str, Any]: ...
    @staticmethod
    @overload
    def _row(row: None) -> None: ...
    @staticmethod
    def _row(row: sqlite3.Row | None) -> dict[str, Any] | None:
        if row is None:
            return None
        job = dict(row)
        job["params"] = current_names(json.loads(job["params"]))  # an earlier release's c: sound_speed
        job["progress"] = json.loads(job["progress"])
        job["control"] = job["control"]
        job["cancel_requested"] = bool(job["cancel_requested"])
        job["earlier_attempts"] = json.loads(job.get("earlier_attempts") or "[]")
        return job
    def create_job(self, kind: str, params: dict, *, idempotency_key: str | None = None,
                   memory_bytes: int = 0, progress: dict | None = None,
                   max_queued: int | None = None, request_keys: Iterable[str] | None = None) -> tuple[dict, bool]:
        """Insert a queued job; returns ``(job, created)``. With an ``idempotency_key``
        already used by a job of the same kind and request, returns that job and
        ``created=False``; with a different request raises :class:`IdempotencyConflict`. The
        request is ``params`` but ``client``, or only its ``request_keys`` where given (what the
        client asked, not what the server worked out from it: a path, an estimate, which a
        restart with other settings may spell differently). With ``max_queued`` and
        ``params["client"]``, raises :class:`QueueFull` while that client has ``max_queued``
        jobs of ``kind`` queued (a repeated idempotent request is answered all the same)."""
        if kind not in KINDS:
            raise ValueError(f"unknown job kind {kind!r}")
        job_id = uuid.uuid4().hex
        now, mono = self._now()
        progress = progress or {"fraction": 0.0, "stage": "queued"}

        def work(db: sqlite3.Connection) -> tuple[dict[str, Any], bool]:
            if idempotency_key is not None:
                row = db.execute("SELECT * FROM jobs WHERE idempotency_key = ?", (idempotency_key,)).fetchone()
                if row is not None:
                    old = self._row(row)
                    # the same request from another address of the client is the same request
                    keys = set(params) - {"client"} if request_keys is None else set(request_keys)
                    asked = {k: v for k, v in json.loads(json.dumps(params)).items() if k in keys}
                    before = old["params"]
                    if old["kind"] != kind or {k: before.get(k) for k in asked} != asked:
                        raise IdempotencyConflict(
                            "Idempotency-Key already used for a different request")
                    return old, False
            client = params.get("client")
            if max_queued is not None and client is not None:
                queued = db.execute("SELECT COUNT(*) FROM jobs WHERE state = 'queued' AND kind = ? AND"
                                    " json_extract(params, '$.client') = ?", (kind, client)).fetchone()[0]
                if queued >= max_queued:
                    raise QueueFull(str(client), int(queued), int(max_queued))
            db.execute(
                "INSERT INTO jobs (id, kind, state, params, progress, idempotency_key, created, created_mono,"
                " memory_bytes, seq) VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?,"
                " (SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs))",
                (job_id, kind, json.dumps(params), json.dumps(progress), idempotency_key, now, mono,
                 int(memory_bytes)))
            self._event(db, job_id, "state", {"state": "queued"})
            return self._row(db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()), True

        return self._tx(work)

    def find_repeat(self, idempotency_key: str, kind: str, request: dict) -> dict | None:
        """The job an earlier request with ``idempotency_key`` created, when it is of ``kind``
        and each item of ``request`` equals its parameter of that name; else None (the key is
        unused, or the request differs: :meth:`create_job` then decides, with its conflict).

        A route asks this before it looks up the request's inputs or admits it: a client's
        retry of a request already answered gets its job, even where an input has been deleted
        since or the disk has filled (draft-ietf-httpapi-idempotency-key-header: a repeat is
        answered as the first request was)."""
        with self._lock:
            row = self._db.execute("SELECT * FROM jobs WHERE idempotency_key = ?", (idempotency_key,)).fetchone()
        job = self._row(row)
        if job is None or job["kind"] != kind:
            return None
        asked = json.loads(json.dumps(request))
        return job if all(job["params"].get(k) == v for k, v in asked.items()) else None

    def get(self, job_id: str) -> dict | None:
        with self._lock:
            hit = self._cache.get(job_id)
            if hit is not None:
                return copy.deepcopy(hit)
            job = self._row(self._db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone())
            if job is not None:
                self._cache[job_id] = copy.deepcopy(job)
            return job

    def resolve(self, prefix: str) -> list[str]:
        """The ids of the jobs whose id starts with ``prefix`` (a short id as the CLI and the
        web page show it; lowercase hex), at most 2 (enough to tell unique from ambiguous)."""
        p = prefix.lower()
        if not p or any(ch not in "0123456789abcdef" for ch in p):
            return []
        with self._lock:
            rows = self._db.execute("SELECT id FROM jobs WHERE id >= ? AND id < ? ORDER BY id LIMIT 2",
                                    (p, p + "g")).fetchall()
        return [r["id"] for r in rows]

    def peek(self, job_id: str) -> dict | None:
        """The job from the in-memory cache (no database access, no lock: cached rows are
        never mutated, only replaced), or None when it is not cached; for the event loop's
        fast path. The caller must not modify the returned dict."""
        return self._cache.get(job_id)

    def list(self, *, state: str | None = None, kind: str | None = None, limit: int = 1000,
             before: str | None = None, scan_job_id: str | None = None) -> Jobs:
        """The jobs (of ``state`` and ``kind`` when given), newest first: in the store's
        sequence, the last submitted first (module docstring), at most ``limit``; ``before``
        (a job's id): only those submitted before it (the next page of a listing that ended
        at it); ``scan_job_id``: only the reconstructions of that scan job. A ``before`` that
        names no job gives none."""
        sql = "SELECT * FROM jobs WHERE 1=1"
        args: list[Any] = []
        for clause, value in (("state = ?", state), ("kind = ?", kind),
                              ("seq < (SELECT seq FROM jobs WHERE id = ?)", before),
                              ("json_extract(params, '$.scan_job_id') = ?", scan_job_id)):
            if value is not None:
                sql += f" AND {clause}"
                args.append(value)
        sql += " ORDER BY seq DESC LIMIT ?"
        args.append(int(limit))
        with self._lock:
            return [self._row(r) for r in self._db.execute(sql, args).fetchall()]
    def update_params(self, job_id: str, params: dict, *, durable: bool = True) -> None:
        """Merge ``params`` into the job's parameters (e.g. the scan file name); not flushed by
        itself where not ``durable`` (a write the next durable commit, e.g. its state's, flushes
        with it: the WAL is written in order)."""
        def work(db: sqlite3.Connection) -> None:
            row = db.execute("SELECT params FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is not None:
                merged = {**json.loads(row["params"]), **params}
                db.execute("UPDATE jobs SET params = ? WHERE id = ?", (json.dumps(merged), job_id))
        self._tx(work, durable=durable)
    def running_memory(self) -> int:
        with self._lock:
            return int(self._db.execute(
                "SELECT COALESCE(SUM(memory_bytes), 0) FROM jobs WHERE state = 'running' AND kind = 'recon'"
            ).fetchone()[0])

    def queued(self, kind: str) -> Jobs:
        """The queued jobs of ``kind``, first submitted first (the store's sequence)."""
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                "SELECT * FROM jobs WHERE state = 'queued' AND kind = ? ORDER BY seq", (kind,)).fetchall()]
    def active_jobs(self) -> Jobs:
        """Jobs that are queued, running or paused (they may still read their inputs)."""
        marks = ",".join("?" * len(ACTIVE))
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                f"SELECT * FROM jobs WHERE state IN ({marks})", tuple(sorted(ACTIVE))).fetchall()]

    def finished_jobs(self, kind: str) -> Jobs:
        """Terminal jobs of ``kind``, oldest finished first (by the store's time)."""
        marks = ",".join("?" * len(TERMINAL))
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                f"SELECT * FROM jobs WHERE kind = ? AND state IN ({marks}) ORDER BY finished_mono, seq",
                (kind, *sorted(TERMINAL))).fetchall()]

    def delete_job(self, job_id: str, *, only_terminal: bool = True) -> bool:
        """Remove a job's row and its events; with ``only_terminal`` only when it is in a
        final state. Returns whether a row was removed."""
        def work(db: sqlite3.Connection) -> bool:
            sql = "DELETE FROM jobs WHERE id = ?"
            args: tuple = (job_id,)
            if only_terminal:
                marks = ",".join("?" * len(TERMINAL))
                sql += f" AND state IN ({marks})"
                args = (job_id, *sorted(TERMINAL))
            if db.execute(sql, args).rowcount != 1:
                return False
            db.execute("DELETE FROM events WHERE job_id = ?", (job_id,))
            self._touched.append(job_id)  # its listeners hear of it (an events stream ends)
            return True
        return self._tx(work)
