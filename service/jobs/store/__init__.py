"""The SQLite job store: the source of truth for jobs, plans and datasets.

One SQLite file in WAL mode (https://sqlite.org/wal.html). Every job row holds its kind
(``scan``/``recon``), state, progress (JSON), parameters (JSON), the unique
``Idempotency-Key``, lease owner/expiry and heartbeat, attempts, result path and error.
A per-job ``events`` table keeps the progress/state events with a sequence number, so the
Server-Sent Events stream can honour ``Last-Event-ID``.

A job re-queued after its run was cut off (a dead worker, a shutdown, a restart) starts its
timing anew: its ``started`` is cleared and set again when the next attempt starts, and the
cut-off attempt is kept in ``earlier_attempts`` (JSON list of ``{"attempt", "started",
"ended", "run_s", "reason"}``), so ``run_s`` counts the attempt that ended the job.

A job may carry the address of the client that submitted it (``params["client"]``);
:meth:`JobStore.create_job` refuses a new one (:class:`QueueFull`) while that client
already has ``max_queued`` jobs of the kind queued, counted in the transaction that would
insert it.

Thread-safe: one connection guarded by a lock (statements are short).
Times are UNIX seconds (float) on the wall clock, for display; a job's moments also carry the
store's monotonic time (``created_mono``, ``started_mono``, ``finished_mono``;
:mod:`fpscan.service.jobs.store.clock`), which its durations are taken from, and jobs are
listed in the store's sequence (``seq``), never by a wall time. Commits are durable
(``synchronous=FULL``): a commit that returned survives a power cut; a job's progress reports
and heartbeats alone are not flushed one by one (the next durable commit flushes them).

A full disk (SQLite's SQLITE_FULL, "database or disk is full") never strands a job's state:
the store keeps a reserve file beside the database (``<database>.reserve``,
:data:`DB_RESERVE_BYTES`, written at start-up) and, when a write finds the disk full, removes
it and writes again, so that the jobs' final states, cancels and deletions can still be
recorded while the rest of the server refuses new work; the reserve is written again once
the disk has room (:meth:`JobStore.problems` says while it is spent).

The store is one class composed of one part per record kind, over one connection and lock
(:class:`fpscan.service.jobs.store.base.StoreBase`, the transactions):

- :mod:`fpscan.service.jobs.store.jobs`: the job rows (create, read, list, delete);
- :mod:`fpscan.service.jobs.store.transitions`: their state changes, leases and restart recovery;
- :mod:`fpscan.service.jobs.store.events`: the jobs' events and the listeners that hear of them;
- :mod:`fpscan.service.jobs.store.plans`, :mod:`fpscan.service.jobs.store.datasets`: plans and datasets;
- :mod:`fpscan.service.jobs.store.config`: the service config (key -> JSON value);
- :mod:`fpscan.service.jobs.store.reserve`: the full disk's reserve;
- :mod:`fpscan.service.jobs.store.schema`: the tables, the job states and kinds;
- :mod:`fpscan.service.jobs.store.clock`: the wall clock and the store's monotonic time.
"""
from __future__ import annotations

from fpscan.service.jobs.store.config import ServiceConfig
from fpscan.service.jobs.store.datasets import DatasetRecords
from fpscan.service.jobs.store.jobs import IdempotencyConflict, QueueFull
from fpscan.service.jobs.store.plans import PlanRecords
from fpscan.service.jobs.store.reserve import DB_RESERVE_BYTES
from fpscan.service.jobs.store.schema import ACTIVE, KINDS, STATES, TERMINAL, Jobs
from fpscan.service.jobs.store.transitions import JobTransitions

__all__ = ["STATES", "TERMINAL", "ACTIVE", "KINDS", "DB_RESERVE_BYTES", "IdempotencyConflict", "QueueFull", "Jobs",
           "JobStore"]


class JobStore(JobTransitions, PlanRecords, DatasetRecords, ServiceConfig):
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

