"""The job store's state transitions: a job's state, progress, lease and cancel request.

Each change is one transaction that records the job's event (:mod:`fpscan.service.jobs.store.events`).
A job re-queued after its run was cut off (a dead worker, a shutdown, a restart) starts its
timing anew: its ``started`` is cleared and set again when the next attempt starts, and the
cut-off attempt is kept in ``earlier_attempts`` (JSON list of ``{"attempt", "started",
"ended", "run_s", "reason"}``: wall times for display, ``run_s`` from the store's monotonic
time), so ``run_s`` counts the attempt that ended the job. Each moment is recorded on both
clocks (:mod:`fpscan.service.jobs.store.clock`): ``started``/``started_mono``,
``finished``/``finished_mono``.
"""
from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from typing import Any

from fpscan.service.jobs.store.clock import wall_time
from fpscan.service.jobs.store.jobs import JobRecords
from fpscan.service.jobs.store.schema import STATES, TERMINAL

__all__ = ["JobTransitions"]


def _cut_attempt(db: sqlite3.Connection, job_id: str, reason: str, now: tuple[float, float]) -> None:
    """Record a running job's current attempt as cut off (``earlier_attempts``: its number,
    start, end ``now`` (wall, store time), its ``run_s`` on the store's time and ``reason``) and
    clear ``started`` for the next one; inside a transaction."""
    row = db.execute("SELECT attempts, started, started_mono, earlier_attempts FROM jobs WHERE id = ?",
                     (job_id,)).fetchone()
    if row is None:
        return
    earlier = json.loads(row["earlier_attempts"] or "[]")
    wall, mono = now
    run_s = None if row["started_mono"] is None else max(0.0, mono - float(row["started_mono"]))
    earlier.append({"attempt": row["attempts"], "started": row["started"], "ended": wall, "run_s": run_s,
                    "reason": reason})
    db.execute("UPDATE jobs SET earlier_attempts = ?, started = NULL, started_mono = NULL WHERE id = ?",
               (json.dumps(earlier), job_id))


class JobTransitions(JobRecords):
    """The state transitions of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    def set_state(self, job_id: str, state: str, *, error: str | None = None,
                  result_path: str | None = None, only_from: Iterable[str] | None = None,
                  progress: dict | None = None) -> bool:
        """Move a job to ``state`` (optionally only from the states in ``only_from``),
        record the event; returns False if the job was not in an allowed state."""
        if state not in STATES:
            raise ValueError(f"unknown state {state!r}")
        now, mono = self._now()

        def work(db: sqlite3.Connection) -> bool:
            row = db.execute("SELECT state, progress FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None or (only_from is not None and row["state"] not in set(only_from)):
                return False
            sets: list[str] = ["state = ?"]
            args: list[object] = [state]
            if state == "running":
                sets += ["started = COALESCE(started, ?)", "started_mono = COALESCE(started_mono, ?)"]
                args += [now, mono]
            if state in TERMINAL:
                sets += ["finished = ?", "finished_mono = ?", "lease_owner = NULL", "lease_until = NULL"]
                args += [now, mono]
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
        """Merge ``progress`` into the job's progress and (optionally) emit an event; a report,
        not flushed to disk by itself (the next durable commit is)."""
        def work(db: sqlite3.Connection) -> None:
            row = db.execute("SELECT progress FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                return
            merged = {**json.loads(row["progress"]), **progress}
            db.execute("UPDATE jobs SET progress = ?, heartbeat = ? WHERE id = ?",
                       (json.dumps(merged), wall_time(), job_id))
            if event:
                self._event(db, job_id, "progress", merged)

        self._tx(work, durable=False)  # a report: flushed with the next durable commit
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
                db.execute("UPDATE jobs SET state = 'cancelled', finished = ?, finished_mono = ?, lease_owner = NULL,"
                           " lease_until = NULL WHERE id = ?", (*self._now(), job_id))
                self._event(db, job_id, "state", {"state": "cancelled"})
            return "ok"

        if self._tx(work) is None:
            return None
        return self.get(job_id)

    def claim(self, job_id: str, owner: str, lease_s: float) -> dict | None:
        """Lease a queued job for ``owner``: state running, attempts + 1; None if it was
        not queued (someone else took it or it was cancelled)."""
        now, mono = self._now()

        def work(db: sqlite3.Connection) -> dict[str, Any] | None:
            cur = db.execute(
                "UPDATE jobs SET state = 'running', lease_owner = ?, lease_until = ?, heartbeat = ?,"
                " attempts = attempts + 1, started = COALESCE(started, ?), started_mono = COALESCE(started_mono, ?)"
                " WHERE id = ? AND state = 'queued'",
                (owner, now + lease_s, now, now, mono, job_id))
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
            _cut_attempt(db, job_id, reason, self._now())
            db.execute("UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_until = NULL,"
                       " attempts = MAX(attempts - ?, 0) WHERE id = ?", (0 if count_attempt else 1, job_id))
            self._event(db, job_id, "state", {"state": "queued", "reason": reason})
            return True

        return bool(self._tx(work))

    def heartbeat(self, job_id: str, owner: str, lease_s: float) -> None:
        now = wall_time()
        def write() -> None:
            with self._lock, self._report():  # a report: flushed with the next durable commit
                self._cache.pop(job_id, None)
                self._db.execute("UPDATE jobs SET heartbeat = ?, lease_until = ? WHERE id = ? AND lease_owner = ?",
                                 (now, now + lease_s, job_id, owner))
        self._write(write)

    def recover(self, owner: str, max_attempts: int) -> dict[str, list[str]]:
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
                        db.execute("UPDATE jobs SET state = 'failed', error = ?, finished = ?, finished_mono = ?,"
                                   " lease_owner = NULL WHERE id = ?",
                                   (f"interrupted {row['attempts']} times", *self._now(), row["id"]))
                        self._event(db, row["id"], "state", {"state": "failed"})
                        out["failed"].append(row["id"])
                    else:
                        _cut_attempt(db, row["id"], "server restarted", self._now())
                        db.execute("UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_until = NULL"
                                   " WHERE id = ?", (row["id"],))
                        self._event(db, row["id"], "state", {"state": "queued", "reason": "server restarted"})
                        out["requeued"].append(row["id"])
                else:
                    prog = json.loads(db.execute("SELECT progress FROM jobs WHERE id = ?",
                                                 (row["id"],)).fetchone()[0])
                    prog["stage"] = "interrupted"
                    prog["eta_s"] = None  # stopped: no end to predict until it is resumed
                    _cut_attempt(db, row["id"], "server restarted", self._now())  # a resume starts the next
                    db.execute("UPDATE jobs SET state = 'paused', lease_owner = NULL, lease_until = NULL,"
                               " control = NULL, progress = ? WHERE id = ?", (json.dumps(prog), row["id"]))
                    self._event(db, row["id"], "state", {"state": "paused", "reason": "server restarted"})
                    out["paused"].append(row["id"])
            # A scan queued before the restart never started: leave it queued.
        self._tx(work)
        return out
