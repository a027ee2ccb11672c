"""The job store's SQLite schema and the job record's states and kinds.

The tables: ``jobs`` (one row per job: kind, state, parameters and progress as JSON, the
unique ``Idempotency-Key``, the lease, attempts, result and error), ``events`` (each job's
state and progress events, numbered per job), ``plans``, ``datasets`` (each with the store
times of its upload and latest use, ``created_mono`` and ``used_mono``) and ``config``
(key -> JSON value). A database of an earlier version gains the columns added since
(:data:`_ADDED_COLUMNS`, :data:`_ADDED_DATASET_COLUMNS`) when it is opened (:func:`apply_schema`).

A job's ``seq`` is the store's sequence: one more than the largest when it is inserted (in the
transaction that inserts it), so it orders the jobs as they were submitted, whatever the wall
clock did (the queue's order, "newest first"). Its ``*_mono`` columns are the store's
monotonic time of its moments (:mod:`fpscan.service.jobs.store.clock`), its durations' source.

Durability: WAL with ``synchronous=FULL``: the WAL is flushed (``fsync``) at every commit, so
a commit that returned survives a power cut (https://sqlite.org/pragma.html#pragma_synchronous:
with ``NORMAL`` the last transactions "might roll back following a power loss"); only a job's
progress reports and heartbeats are committed with ``NORMAL``
(:meth:`fpscan.service.jobs.store.base.StoreBase._report`).
"""
from __future__ import annotations

import sqlite3
from typing import Any

__all__ = ["STATES", "TERMINAL", "ACTIVE", "KINDS", "Jobs", "apply_schema"]

STATES = ("queued", "running", "paused", "succeeded", "failed", "cancelled")
TERMINAL = frozenset({"succeeded", "failed", "cancelled"})
ACTIVE = frozenset(STATES) - TERMINAL
KINDS = ("scan", "recon")

Jobs = list[dict[str, Any]]  # (``list`` is a method name inside JobStore)

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
    earlier_attempts TEXT NOT NULL DEFAULT '[]',
    seq INTEGER,
    created_mono REAL,
    started_mono REAL,
    finished_mono REAL
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
    created REAL NOT NULL,
    created_mono REAL,
    used_mono REAL
);
CREATE TABLE IF NOT EXISTS config (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""

_JOB_COLUMNS = ("id", "kind", "state", "params", "progress", "idempotency_key", "created", "started",
                "finished", "lease_owner", "lease_until", "heartbeat", "attempts", "result_path",
                "error", "memory_bytes", "cancel_requested", "control", "earlier_attempts", "seq", "created_mono",
                "started_mono", "finished_mono")
#: columns added after the first release, with their definitions (added to an older database at open)
_ADDED_COLUMNS = {"earlier_attempts": "TEXT NOT NULL DEFAULT '[]'", "seq": "INTEGER", "created_mono": "REAL",
                  "started_mono": "REAL", "finished_mono": "REAL"}
#: columns added to ``datasets`` after the first release: the store times of its upload and of its
#: latest use (retention by age counts from ``used_mono``)
_ADDED_DATASET_COLUMNS = {"created_mono": "REAL", "used_mono": "REAL"}
#: the indexes on added columns (made once they are there)
_INDEXES = """
CREATE INDEX IF NOT EXISTS jobs_seq ON jobs(seq);
CREATE INDEX IF NOT EXISTS jobs_queue ON jobs(state, kind, seq);
"""


def apply_schema(db: sqlite3.Connection) -> None:
    """Put the database in WAL mode and create the tables that are missing; a database of an
    earlier version gains the columns added since.

    Parameters
    ----------
    db : sqlite3.Connection
        The store's connection (autocommit, ``sqlite3.Row`` rows), held under the store's lock.
    """
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("PRAGMA synchronous=FULL")  # a returned commit survives a power cut (module docstring)
    db.executescript(_SCHEMA)
    have = {r["name"] for r in db.execute("PRAGMA table_info(jobs)").fetchall()}
    added = [column for column in _ADDED_COLUMNS if column not in have]
    if added:  # a database of an earlier version, in one transaction
        db.execute("BEGIN IMMEDIATE")
        try:
            for column in added:
                db.execute(f"ALTER TABLE jobs ADD COLUMN {column} {_ADDED_COLUMNS[column]}")
            # its jobs' sequence as they were inserted, their store times their wall times (the
            # best there is: the store's time starts from them, fpscan.service.jobs.store.clock)
            db.execute("UPDATE jobs SET seq = rowid WHERE seq IS NULL")
            for mono, wall in (("created_mono", "created"), ("started_mono", "started"),
                               ("finished_mono", "finished")):
                db.execute(f"UPDATE jobs SET {mono} = {wall} WHERE {mono} IS NULL AND {wall} IS NOT NULL")
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                db.execute("ROLLBACK")
            raise
    _add_dataset_times(db)
    db.executescript(_INDEXES)


def _add_dataset_times(db: sqlite3.Connection) -> None:
    """Give a database of an earlier version the datasets' store times, in one transaction:
    their wall times (the upload's ``created``, the latest use's ``last_used`` of its meta), the
    best there is, as the jobs' were (the store's time starts from them:
    :mod:`fpscan.service.jobs.store.clock`)."""
    have = {r["name"] for r in db.execute("PRAGMA table_info(datasets)").fetchall()}
    added = [column for column in _ADDED_DATASET_COLUMNS if column not in have]
    if not added:
        return
    db.execute("BEGIN IMMEDIATE")
    try:
        for column in added:
            db.execute(f"ALTER TABLE datasets ADD COLUMN {column} {_ADDED_DATASET_COLUMNS[column]}")
        db.execute("UPDATE datasets SET created_mono = created WHERE created_mono IS NULL")
        db.execute("UPDATE datasets SET used_mono = MAX(created, COALESCE(json_extract(meta, '$.last_used'), created))"
                   " WHERE used_mono IS NULL")
        db.execute("COMMIT")
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
