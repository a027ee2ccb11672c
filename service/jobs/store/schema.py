"""The job store's SQLite schema and the job record's states and kinds.

The tables: ``jobs`` (one row per job: kind, state, parameters and progress as JSON, the
unique ``Idempotency-Key``, the lease, attempts, result and error), ``events`` (each job's
state and progress events, numbered per job), ``plans``, ``datasets`` and ``config``
(key -> JSON value). A database of an earlier version gains the columns added since
(:data:`_ADDED_COLUMNS`) when it is opened (:func:`apply_schema`).
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


def apply_schema(db: sqlite3.Connection) -> None:
    """Put the database in WAL mode and create the tables that are missing; a database of an
    earlier version gains the columns added since.

    Parameters
    ----------
    db : sqlite3.Connection
        The store's connection (autocommit, ``sqlite3.Row`` rows), held under the store's lock.
    """
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("PRAGMA synchronous=NORMAL")
    db.executescript(_SCHEMA)
    have = {r["name"] for r in db.execute("PRAGMA table_info(jobs)").fetchall()}
    for column, definition in _ADDED_COLUMNS.items():  # a database of an earlier version
        if column not in have:
            db.execute(f"ALTER TABLE jobs ADD COLUMN {column} {definition}")
