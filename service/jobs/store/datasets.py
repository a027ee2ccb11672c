"""The job store's datasets: each imported dataset's metadata (JSON) under its id.

A dataset's ``dedup_key`` finds an upload already stored (:meth:`DatasetRecords.find_datasets`)
and its ``last_used`` (:meth:`DatasetRecords.touch_dataset`) is where retention by age counts
from.
"""
from __future__ import annotations

import json

from fpscan.service.jobs.store.base import StoreBase
from fpscan.service.jobs.store.clock import wall_time
from fpscan.service.jobs.store.schema import Jobs
from fpscan.service.names import current_names

__all__ = ["DatasetRecords"]


class DatasetRecords(StoreBase):
    """The datasets of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    def put_dataset(self, dataset_id: str, meta: dict) -> None:
        def write() -> None:
            with self._lock:
                self._db.execute("INSERT INTO datasets (id, meta, created) VALUES (?, ?, ?)",
                                 (dataset_id, json.dumps(meta), wall_time()))
        self._write(write)

    def get_dataset(self, dataset_id: str) -> dict | None:
        with self._lock:
            row = self._db.execute("SELECT meta FROM datasets WHERE id = ?", (dataset_id,)).fetchone()
        return None if row is None else current_names(json.loads(row["meta"]))  # an earlier release's c too

    def list_datasets(self) -> Jobs:
        """Every stored dataset as ``{"id", "meta", "created"}``, oldest first (the order they
        were stored in, SQLite's ``rowid``: whatever the wall clock did)."""
        with self._lock:
            rows = self._db.execute("SELECT id, meta, created FROM datasets ORDER BY rowid").fetchall()
        return [{"id": r["id"], "meta": current_names(json.loads(r["meta"])), "created": r["created"]} for r in rows]

    def touch_dataset(self, dataset_id: str) -> None:
        """Record that ``dataset_id`` was asked for again (its meta's ``last_used``, UNIX s):
        retention by age counts from then."""
        def write() -> None:
            with self._lock:
                self._db.execute("UPDATE datasets SET meta = json_set(meta, '$.last_used', ?) WHERE id = ?",
                                 (wall_time(), dataset_id))
        self._write(write)

    def find_datasets(self, dedup_key: str) -> list[str]:
        """The ids of the datasets stored under ``dedup_key`` (their meta's), oldest first (as stored)."""
        with self._lock:
            rows = self._db.execute("SELECT id FROM datasets WHERE json_extract(meta, '$.dedup_key') = ? "
                                    "ORDER BY rowid", (dedup_key,)).fetchall()
        return [str(r["id"]) for r in rows]
    def delete_dataset(self, dataset_id: str) -> bool:
        def write() -> bool:
            with self._lock:
                return self._db.execute("DELETE FROM datasets WHERE id = ?", (dataset_id,)).rowcount == 1
        return bool(self._write(write))
