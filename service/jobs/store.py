"""The SQLite job store: the source of truth for jobs, plans and datasets.

One SQLite file in WAL mode (https://sqlite.org/wal.html). Every job row holds its kind
(``scan``/``recon``), state, progress (JSON), parameters (JSON), the unique
``Idempotency-Key``, lease owner/expiry and heartbeat, attempts, result path and error.
A per-job ``events`` table keeps the progress/state events with a sequence number, so the
Server-Sent Events stream can honour ``Last-Event-ID``.

A job re-queued after its run was cut off (a dead worker, a shutdown, a restart) starts its
timing anew: its ``started`` is cleared and set again when the next attempt starts, and the
cut-off attempt is kept in ``earlier_attempts`` (JSON list of ``{"attempt", "started",
"ended", "reason"}``), so ``run_s`` counts the attempt that ended the job (issue 60.8).

A job may carry the address of the client that submitted it (``params["client"]``);
:meth:`JobStore.create_job` refuses a new one (:class:`QueueFull`) while that client
already has ``max_queued`` jobs of the kind queued, counted in the transaction that would
insert it.

Thread-safe: one connection guarded by a lock (statements are short).
All times are UNIX seconds (float).

A full disk (SQLite's SQLITE_FULL, "database or disk is full") never strands a job's state:
the store keeps a reserve file beside the database (``<database>.reserve``,
:data:`DB_RESERVE_BYTES`, written at start-up) and, when a write finds the disk full, removes
it and writes again, so that the jobs' final states, cancels and deletions can still be
recorded while the rest of the server refuses new work; the reserve is written again once
the disk has room (:meth:`JobStore.problems` says while it is spent).
"""
from __future__ import annotations

import builtins
import copy
import json
import logging
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar, overload

from service.disk import is_disk_full
from service.names import person_names

__all__ = ["STATES", "TERMINAL", "ACTIVE", "KINDS", "DB_RESERVE_BYTES", "IdempotencyConflict", "QueueFull", "Jobs",
           "JobStore"]

log = logging.getLogger("fpscan.store")

_T = TypeVar("_T")

#: bytes of the reserve file kept beside the database for job states on a full disk (SQLite's
#: WAL grows by 4 MiB at most between checkpoints; each state or progress event adds a row)
DB_RESERVE_BYTES = 8 << 20
#: seconds between two looks, after a write, at whether a spent reserve can be written again
_RESERVE_RETRY_S = 5.0

STATES = ("queued", "running", "paused", "succeeded", "failed", "cancelled")
TERMINAL = frozenset({"succeeded", "failed", "cancelled"})
ACTIVE = frozenset(STATES) - TERMINAL
KINDS = ("scan", "recon")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    kind TEXT NOT NULL,
    state TEXT NOT NULL,
    params TEXT NOT NULL,
    progress TEXT NOT NULL,
    idempotency_key TEXT UNIQUE,
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    lease_owner TEXT,
    lease_until REAL,
    heartbeat REAL,
    attempts INTEGER NOT NULL DEFAULT 0,
    result_path TEXT,
    error TEXT,
    memory_bytes INTEGER NOT NULL DEFAULT 0,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    control TEXT,
    earlier_attempts TEXT NOT NULL DEFAULT '[]'
);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state, kind, created);
CREATE TABLE IF NOT EXISTS events (
    job_id TEXT NOT NULL,
    seq INTEGER NOT NULL,
    event TEXT NOT NULL,
    data TEXT NOT NULL,
    created REAL NOT NULL,
    PRIMARY KEY (job_id, seq)
);
CREATE TABLE IF NOT EXISTS plans (
    id TEXT PRIMARY KEY,
    body TEXT NOT NULL,
    summary TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS datasets (
    id TEXT PRIMARY KEY,
    meta TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS config (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""

_JOB_COLUMNS = ("id", "kind", "state", "params", "progress", "idempotency_key", "created", "started",
                "finished", "lease_owner", "lease_until", "heartbeat", "attempts", "result_path",
                "error", "memory_bytes", "cancel_requested", "control", "earlier_attempts")
#: columns added after the first release, with their definitions (added to an older database at open)
_ADDED_COLUMNS = {"earlier_attempts": "TEXT NOT NULL DEFAULT '[]'"}


def _cut_attempt(db: sqlite3.Connection, job_id: str, reason: str) -> None:
    """Record a running job's current attempt as cut off (``earlier_attempts``: its number,
    start, end now and ``reason``) and clear ``started`` for the next one; inside a
    transaction."""
    row = db.execute("SELECT attempts, started, earlier_attempts FROM jobs WHERE id = ?", (job_id,)).fetchone()
    if row is None:
        return
    earlier = json.loads(row["earlier_attempts"] or "[]")
    earlier.append({"attempt": row["attempts"], "started": row["started"], "ended": time.time(), "reason": reason})
    db.execute("UPDATE jobs SET earlier_attempts = ?, started = NULL WHERE id = ?", (json.dumps(earlier), job_id))


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


Jobs = list[dict[str, Any]]  # (``list`` is a method name inside JobStore)


class JobStore:
    """Jobs, their events, plans and datasets in one SQLite file (WAL).

    Parameters
    ----------
    path : str or pathlib.Path
        The database file (parent folders are created).
    reserve_bytes : int, optional
        The reserve kept beside it for a full disk (module docstring; 0: none); default
        :data:`DB_RESERVE_BYTES` (8 MiB).

    Attributes
    ----------
    path : pathlib.Path
        The database file.
    reserve_path : pathlib.Path
        The reserve file, ``<database>.reserve``.
    reserve_bytes : int
        The reserve's size in bytes.
    reserve_spent : float or None
        When the reserve was given up (UNIX s), None while it is kept.
    """

    def __init__(self, path: str | Path, reserve_bytes: int = DB_RESERVE_BYTES):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.reserve_path = self.path.with_name(self.path.name + ".reserve")
        self.reserve_bytes = int(reserve_bytes)
        self.reserve_spent: float | None = None  # when the reserve was given up (time.time()), None: kept
        self._reserve_look = 0.0  # time.monotonic() of the last look at writing it again
        self._reserve_lock = threading.Lock()  # spending and writing it again never cross
        self._reserve_seen = False  # the reserve file was in place once (written here or by another store)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, timeout=30.0,
                                   isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._cache: dict[str, dict] = {}  # job id -> row; every write to a job drops its entry
        self._listeners: list[Callable[[str], None]] = []
        self._touched: list[str] = []  # the jobs the current transaction recorded events of
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            have = {r["name"] for r in self._db.execute("PRAGMA table_info(jobs)").fetchall()}
            for column, definition in _ADDED_COLUMNS.items():  # a database of an earlier version
                if column not in have:
                    self._db.execute(f"ALTER TABLE jobs ADD COLUMN {column} {definition}")
        self._reserve_seen = self._write_reserve()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- a full disk ------------------------------------------------------------------
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
        try:
            import shutil

            room = shutil.disk_usage(self.path.parent).free >= 2 * self.reserve_bytes + (1 << 20)
        except OSError:
            room = False
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

    def problems(self) -> builtins.list[str]:
        """One line while the reserve is spent (the disk filled), else none (``/api/health``)."""
        if self.reserve_spent is None:
            return []
        return [f"the job database's disk filled at {time.strftime('%H:%M:%S', time.localtime(self.reserve_spent))}: "
                f"its reserve of {self.reserve_bytes} bytes is spent on job states; free space on the data folder's disk"]

    # -- helpers -----------------------------------------------------------------
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
        job["params"] = json.loads(job["params"])
        job["progress"] = json.loads(job["progress"])
        job["control"] = job["control"]
        job["cancel_requested"] = bool(job["cancel_requested"])
        job["earlier_attempts"] = json.loads(job.get("earlier_attempts") or "[]")
        return job

    def _event(self, db: sqlite3.Connection, job_id: str, event: str, data: dict) -> int:
        self._touched.append(job_id)  # inside `_tx`: its listeners hear of it after the commit
        seq = db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM events WHERE job_id = ?", (job_id,)).fetchone()[0]
        db.execute("INSERT INTO events (job_id, seq, event, data, created) VALUES (?, ?, ?, ?, ?)",
                   (job_id, seq, event, json.dumps(data), time.time()))
        return seq

    # -- jobs ----------------------------------------------------------------------
    def create_job(self, kind: str, params: dict, *, idempotency_key: str | None = None,
                   memory_bytes: int = 0, progress: dict | None = None,
                   max_queued: int | None = None) -> tuple[dict, bool]:
        """Insert a queued job; returns ``(job, created)``. With an ``idempotency_key``
        already used by a job of the same kind and parameters, returns that job and
        ``created=False``; with different ones raises :class:`IdempotencyConflict`. With
        ``max_queued`` and ``params["client"]``, raises :class:`QueueFull` while that client
        has ``max_queued`` jobs of ``kind`` queued (a repeated idempotent request is answered
        all the same)."""
        if kind not in KINDS:
            raise ValueError(f"unknown job kind {kind!r}")
        job_id = uuid.uuid4().hex
        now = time.time()
        progress = progress or {"fraction": 0.0, "stage": "queued"}

        def work(db: sqlite3.Connection) -> tuple[dict[str, Any], bool]:
            if idempotency_key is not None:
                row = db.execute("SELECT * FROM jobs WHERE idempotency_key = ?", (idempotency_key,)).fetchone()
                if row is not None:
                    old = self._row(row)
                    # the same request from another address of the client is the same request
                    asked = {k: v for k, v in json.loads(json.dumps(params)).items() if k != "client"}
                    before = person_names(old["params"])  # a job an older server stored with c
                    if old["kind"] != kind or {k: before.get(k) for k in asked} != person_names(asked):
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
                "INSERT INTO jobs (id, kind, state, params, progress, idempotency_key, created, memory_bytes)"
                " VALUES (?, ?, 'queued', ?, ?, ?, ?, ?)",
                (job_id, kind, json.dumps(params), json.dumps(progress), idempotency_key, now, int(memory_bytes)))
            self._event(db, job_id, "state", {"state": "queued"})
            return self._row(db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()), True

        return self._tx(work)

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

    def list(self, *, state: str | None = None, kind: str | None = None, limit: int = 1000) -> Jobs:
        sql = "SELECT * FROM jobs WHERE 1=1"
        args: list[Any] = []
        if state is not None:
            sql += " AND state = ?"
            args.append(state)
        if kind is not None:
            sql += " AND kind = ?"
            args.append(kind)
        sql += " ORDER BY created DESC LIMIT ?"
        args.append(int(limit))
        with self._lock:
            return [self._row(r) for r in self._db.execute(sql, args).fetchall()]

    def set_state(self, job_id: str, state: str, *, error: str | None = None,
                  result_path: str | None = None, only_from: Iterable[str] | None = None,
                  progress: dict | None = None) -> bool:
        """Move a job to ``state`` (optionally only from the states in ``only_from``),
        record the event; returns False if the job was not in an allowed state."""
        if state not in STATES:
            raise ValueError(f"unknown state {state!r}")
        now = time.time()

        def work(db: sqlite3.Connection) -> bool:
            row = db.execute("SELECT state, progress FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None or (only_from is not None and row["state"] not in set(only_from)):
                return False
            sets: list[str] = ["state = ?"]
            args: list[object] = [state]
            if state == "running":
                sets.append("started = COALESCE(started, ?)")
                args.append(now)
            if state in TERMINAL:
                sets += ["finished = ?", "lease_owner = NULL", "lease_until = NULL"]
                args.append(now)
            if error is not None:
                sets.append("error = ?")
                args.append(error)
            if result_path is not None:
                sets.append("result_path = ?")
                args.append(result_path)
            if progress is not None:
                merged = {**json.loads(row["progress"]), **progress}
                sets.append("progress = ?")
                args.append(json.dumps(merged))
            db.execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id = ?", (*args, job_id))
            data = {"state": state}
            if error is not None:
                data["error"] = error
            self._event(db, job_id, "state", data)
            return True

        return self._tx(work)

    def update_progress(self, job_id: str, progress: dict, *, event: bool = True) -> None:
        """Merge ``progress`` into the job's progress and (optionally) emit an event."""
        def work(db: sqlite3.Connection) -> None:
            row = db.execute("SELECT progress FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                return
            merged = {**json.loads(row["progress"]), **progress}
            db.execute("UPDATE jobs SET progress = ?, heartbeat = ? WHERE id = ?",
                       (json.dumps(merged), time.time(), job_id))
            if event:
                self._event(db, job_id, "progress", merged)

        self._tx(work)

    def update_params(self, job_id: str, params: dict) -> None:
        """Merge ``params`` into the job's parameters (e.g. the scan file name)."""
        def work(db: sqlite3.Connection) -> None:
            row = db.execute("SELECT params FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is not None:
                merged = {**json.loads(row["params"]), **params}
                db.execute("UPDATE jobs SET params = ? WHERE id = ?", (json.dumps(merged), job_id))
        self._tx(work)

    def request_cancel(self, job_id: str) -> dict | None:
        """Flag a job for cooperative cancel; a queued or paused job is cancelled at once."""
        def work(db: sqlite3.Connection) -> str | None:
            row = db.execute("SELECT state FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                return None
            if row["state"] in TERMINAL:
                return "terminal"
            db.execute("UPDATE jobs SET cancel_requested = 1 WHERE id = ?", (job_id,))
            if row["state"] in ("queued", "paused"):
                db.execute("UPDATE jobs SET state = 'cancelled', finished = ?, lease_owner = NULL,"
                           " lease_until = NULL WHERE id = ?", (time.time(), job_id))
                self._event(db, job_id, "state", {"state": "cancelled"})
            return "ok"

        if self._tx(work) is None:
            return None
        return self.get(job_id)

    def claim(self, job_id: str, owner: str, lease_s: float) -> dict | None:
        """Lease a queued job for ``owner``: state running, attempts + 1; None if it was
        not queued (someone else took it or it was cancelled)."""
        now = time.time()

        def work(db: sqlite3.Connection) -> dict[str, Any] | None:
            cur = db.execute(
                "UPDATE jobs SET state = 'running', lease_owner = ?, lease_until = ?, heartbeat = ?,"
                " attempts = attempts + 1, started = COALESCE(started, ?) WHERE id = ? AND state = 'queued'",
                (owner, now + lease_s, now, now, job_id))
            if cur.rowcount != 1:
                return None
            self._event(db, job_id, "state", {"state": "running"})
            return self._row(db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone())

        return self._tx(work)

    def clear_cancel(self, job_id: str) -> None:
        """Forget a cancel request (a job that resumes: the request was for the run that
        was stuck, not for the new one)."""
        self._tx(lambda db: db.execute("UPDATE jobs SET cancel_requested = 0 WHERE id = ?", (job_id,)))

    def requeue(self, job_id: str, reason: str, *, count_attempt: bool = True) -> bool:
        """A running job back to ``queued`` (its worker died or the server is shutting
        down); ``count_attempt=False`` gives the attempt back (a shutdown is not the job's
        fault). The attempt cut off goes to ``earlier_attempts`` and ``started`` is
        cleared: the next attempt's timing starts anew. Returns False if the job was not
        running."""
        def work(db: sqlite3.Connection) -> bool:
            if db.execute("SELECT 1 FROM jobs WHERE id = ? AND state = 'running'", (job_id,)).fetchone() is None:
                return False
            _cut_attempt(db, job_id, reason)
            db.execute("UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_until = NULL,"
                       " attempts = MAX(attempts - ?, 0) WHERE id = ?", (0 if count_attempt else 1, job_id))
            self._event(db, job_id, "state", {"state": "queued", "reason": reason})
            return True

        return bool(self._tx(work))

    def heartbeat(self, job_id: str, owner: str, lease_s: float) -> None:
        now = time.time()
        def write() -> None:
            with self._lock:
                self._cache.pop(job_id, None)
                self._db.execute("UPDATE jobs SET heartbeat = ?, lease_until = ? WHERE id = ? AND lease_owner = ?",
                                 (now, now + lease_s, job_id, owner))
        self._write(write)

    def recover(self, owner: str, max_attempts: int) -> dict[str, builtins.list[str]]:
        """Restart recovery for a new server instance ``owner``: running reconstructions
        not leased by ``owner`` are re-queued (or failed after ``max_attempts``); running
        scans become ``paused`` (resumable from their scan file). Returns the ids."""
        out: dict[str, list[str]] = {"requeued": [], "failed": [], "paused": []}

        def work(db: sqlite3.Connection) -> None:
            rows = db.execute("SELECT id, kind, attempts FROM jobs WHERE state = 'running'"
                              " AND (lease_owner IS NULL OR lease_owner != ?)", (owner,)).fetchall()
            for row in rows:
                if row["kind"] == "recon":
                    if row["attempts"] >= max_attempts:
                        db.execute("UPDATE jobs SET state = 'failed', error = ?, finished = ?,"
                                   " lease_owner = NULL WHERE id = ?",
                                   (f"interrupted {row['attempts']} times", time.time(), row["id"]))
                        self._event(db, row["id"], "state", {"state": "failed"})
                        out["failed"].append(row["id"])
                    else:
                        _cut_attempt(db, row["id"], "server restarted")
                        db.execute("UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_until = NULL"
                                   " WHERE id = ?", (row["id"],))
                        self._event(db, row["id"], "state", {"state": "queued", "reason": "server restarted"})
                        out["requeued"].append(row["id"])
                else:
                    prog = json.loads(db.execute("SELECT progress FROM jobs WHERE id = ?",
                                                 (row["id"],)).fetchone()[0])
                    prog["stage"] = "interrupted"
                    db.execute("UPDATE jobs SET state = 'paused', lease_owner = NULL, lease_until = NULL,"
                               " control = NULL, progress = ? WHERE id = ?", (json.dumps(prog), row["id"]))
                    self._event(db, row["id"], "state", {"state": "paused", "reason": "server restarted"})
                    out["paused"].append(row["id"])
            # A scan queued before the restart never started: leave it queued.
        self._tx(work)
        return out

    def events_after(self, job_id: str, after: int, limit: int = 500) -> Jobs:
        with self._lock:
            rows = self._db.execute(
                "SELECT seq, event, data FROM events WHERE job_id = ? AND seq > ? ORDER BY seq LIMIT ?",
                (job_id, int(after), int(limit))).fetchall()
        return [{"seq": r["seq"], "event": r["event"], "data": r["data"]} for r in rows]

    def running_memory(self) -> int:
        with self._lock:
            return int(self._db.execute(
                "SELECT COALESCE(SUM(memory_bytes), 0) FROM jobs WHERE state = 'running' AND kind = 'recon'"
            ).fetchone()[0])

    def queued(self, kind: str) -> Jobs:
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                "SELECT * FROM jobs WHERE state = 'queued' AND kind = ? ORDER BY created", (kind,)).fetchall()]

    # -- plans and datasets --------------------------------------------------------
    def put_plan(self, plan_id: str, body: dict, summary: dict) -> None:
        self.put_plan_text(plan_id, json.dumps(body), summary)

    def put_plan_text(self, plan_id: str, text: str, summary: dict) -> None:
        """Store a plan already serialized (``text``: its JSON), as :meth:`put_plan` does."""
        def write() -> None:
            with self._lock:
                self._db.execute("INSERT OR IGNORE INTO plans (id, body, summary, created) VALUES (?, ?, ?, ?)",
                                 (plan_id, text, json.dumps(summary), time.time()))
        self._write(write)

    def get_plan_text(self, plan_id: str) -> str | None:
        """The plan's JSON as stored (ready to serve, not parsed); None when there is none."""
        with self._lock:
            row = self._db.execute("SELECT body FROM plans WHERE id = ?", (plan_id,)).fetchone()
        return None if row is None else row["body"]

    def get_plan_summary(self, plan_id: str) -> dict | None:
        """The plan's stored summary alone (its points are not read); None when there is none."""
        with self._lock:
            row = self._db.execute("SELECT summary FROM plans WHERE id = ?", (plan_id,)).fetchone()
        return None if row is None else json.loads(row["summary"])

    def get_plan(self, plan_id: str) -> tuple[dict, dict] | None:
        with self._lock:
            row = self._db.execute("SELECT body, summary FROM plans WHERE id = ?", (plan_id,)).fetchone()
        return None if row is None else (json.loads(row["body"]), json.loads(row["summary"]))

    def list_plans(self, limit: int = 1000) -> Jobs:
        with self._lock:
            rows = self._db.execute("SELECT summary FROM plans ORDER BY created DESC LIMIT ?", (limit,)).fetchall()
        return [json.loads(r["summary"]) for r in rows]

    def put_dataset(self, dataset_id: str, meta: dict) -> None:
        def write() -> None:
            with self._lock:
                self._db.execute("INSERT INTO datasets (id, meta, created) VALUES (?, ?, ?)",
                                 (dataset_id, json.dumps(meta), time.time()))
        self._write(write)

    def get_dataset(self, dataset_id: str) -> dict | None:
        with self._lock:
            row = self._db.execute("SELECT meta FROM datasets WHERE id = ?", (dataset_id,)).fetchone()
        return None if row is None else json.loads(row["meta"])

    def list_datasets(self) -> Jobs:
        """Every stored dataset as ``{"id", "meta", "created"}``, oldest first."""
        with self._lock:
            rows = self._db.execute("SELECT id, meta, created FROM datasets ORDER BY created, id").fetchall()
        return [{"id": r["id"], "meta": json.loads(r["meta"]), "created": r["created"]} for r in rows]

    def touch_dataset(self, dataset_id: str) -> None:
        """Record that ``dataset_id`` was asked for again (its meta's ``last_used``, UNIX s):
        retention by age counts from then."""
        def write() -> None:
            with self._lock:
                self._db.execute("UPDATE datasets SET meta = json_set(meta, '$.last_used', ?) WHERE id = ?",
                                 (time.time(), dataset_id))
        self._write(write)

    def find_datasets(self, dedup_key: str) -> builtins.list[str]:
        """The ids of the datasets stored under ``dedup_key`` (their meta's), oldest first."""
        with self._lock:
            rows = self._db.execute("SELECT id FROM datasets WHERE json_extract(meta, '$.dedup_key') = ? "
                                    "ORDER BY created, id", (dedup_key,)).fetchall()
        return [str(r["id"]) for r in rows]

    # -- deletion and configuration (service.jobs.lifecycle owns the rules) ----------
    def active_jobs(self) -> Jobs:
        """Jobs that are queued, running or paused (they may still read their inputs)."""
        marks = ",".join("?" * len(ACTIVE))
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                f"SELECT * FROM jobs WHERE state IN ({marks})", tuple(sorted(ACTIVE))).fetchall()]

    def finished_jobs(self, kind: str) -> Jobs:
        """Terminal jobs of ``kind``, oldest finished first."""
        marks = ",".join("?" * len(TERMINAL))
        with self._lock:
            return [self._row(r) for r in self._db.execute(
                f"SELECT * FROM jobs WHERE kind = ? AND state IN ({marks}) ORDER BY finished, created",
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

    def delete_plan(self, plan_id: str) -> bool:
        def write() -> bool:
            with self._lock:
                return self._db.execute("DELETE FROM plans WHERE id = ?", (plan_id,)).rowcount == 1
        return bool(self._write(write))

    def delete_dataset(self, dataset_id: str) -> bool:
        def write() -> bool:
            with self._lock:
                return self._db.execute("DELETE FROM datasets WHERE id = ?", (dataset_id,)).rowcount == 1
        return bool(self._write(write))

    def get_config(self, key: str) -> Any:
        """A stored configuration value (JSON), or None."""
        with self._lock:
            row = self._db.execute("SELECT value FROM config WHERE key = ?", (key,)).fetchone()
        return None if row is None else json.loads(row["value"])

    def set_config(self, key: str, value: Any) -> None:
        def write() -> None:
            with self._lock:
                self._db.execute("INSERT INTO config (key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE"
                                 " SET value = excluded.value", (key, json.dumps(value)))
        self._write(write)
