"""The job store's plans: each stored plan's JSON as given and its summary.

A plan is stored once under its id (a second put of the same id is ignored) and served as
stored (:meth:`PlanRecords.get_plan_text`: not parsed again).
"""
from __future__ import annotations

import json

from fpscan.service.jobs.store.base import StoreBase
from fpscan.service.jobs.store.clock import wall_time
from fpscan.service.jobs.store.schema import Jobs

__all__ = ["PlanRecords"]


class PlanRecords(StoreBase):
    """The plans of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    def put_plan(self, plan_id: str, body: dict, summary: dict) -> None:
        self.put_plan_text(plan_id, json.dumps(body), summary)

    def put_plan_text(self, plan_id: str, text: str, summary: dict) -> None:
        """Store a plan already serialized (``text``: its JSON), as :meth:`put_plan` does."""
        def write() -> None:
            with self._lock:
                self._db.execute("INSERT OR IGNORE INTO plans (id, body, summary, created) VALUES (?, ?, ?, ?)",
                                 (plan_id, text, json.dumps(summary), wall_time()))
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
        """The stored plans' summaries, newest first (the order they were stored in, SQLite's
        ``rowid``: whatever the wall clock did), at most ``limit``."""
        with self._lock:
            rows = self._db.execute("SELECT summary FROM plans ORDER BY rowid DESC LIMIT ?", (limit,)).fetchall()
        return [json.loads(r["summary"]) for r in rows]

    def delete_plan(self, plan_id: str) -> bool:
        def write() -> bool:
            with self._lock:
                return self._db.execute("DELETE FROM plans WHERE id = ?", (plan_id,)).rowcount == 1
        return bool(self._write(write))
