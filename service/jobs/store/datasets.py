"""The job store's datasets: each imported dataset's metadata (JSON) under its id.

A dataset's ``dedup_key`` finds an upload already stored (:meth:`DatasetRecords.find_datasets`)
and its ``used_mono`` (the store's time of its upload or latest use,
:meth:`DatasetRecords.touch_dataset`; :mod:`fpscan.service.jobs.store.clock`) is where retention
by age counts from, whatever the wall clock did; its ``created`` and meta's ``last_used`` are the
wall times of those moments, for display.
"""
from __future__ import annotations

import json

from fpscan.service.jobs.store.base import StoreBase
from fpscan.service.jobs.store.schema import Jobs
from fpscan.service.names import current_names

__all__ = ["DatasetRecords"]


class DatasetRecords(StoreBase):
    """The datasets of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

    def put_dataset(self, dataset_id: str, meta: dict) -> None:
        """Store ``dataset_id``'s ``meta``, uploaded now (its wall and store times).

        ``meta`` is written as strict JSON (RFC 8259: no NaN or infinity, which SQLite's JSON
        functions refuse on every later query of the table): a ValueError before anything is stored.
        """
        text = json.dumps(meta, allow_nan=False)

        def write() -> None:
            with self._lock:
                wall, mono = self._now()
                self._db.execute("INSERT INTO datasets (id, meta, created, created_mono, used_mono) "
                                 "VALUES (?, ?, ?, ?, ?)", (dataset_id, text, wall, mono, mono))
        self._write(write)

    def get_dataset(self, dataset_id: str) -> dict | None:
        with self._lock:
            row = self._db.execute("SELECT meta FROM datasets WHERE id = ?", (dataset_id,)).fetchone()
        return None if row is None else current_names(json.loads(row["meta"]))  # an earlier release's c too

    def list_datasets(self) -> Jobs:
        """Every stored dataset as ``{"id", "meta", "created", "used_mono"}`` (``created``: the
        upload's wall time, UNIX s; ``used_mono``: the store time of its upload or latest use, s),
        oldest first (the order they were stored in, SQLite's ``rowid``: whatever the wall clock did)."""
        with self._lock:
            rows = self._db.execute("SELECT id, meta, created, used_mono FROM datasets ORDER BY rowid").fetchall()
        return [{"id": r["id"], "meta": current_names(json.loads(r["meta"])), "created": r["created"],
                 "used_mono": r["used_mono"] if r["used_mono"] is not None else r["created"]} for r in rows]

    def touch_dataset(self, dataset_id: str) -> None:
        """Record that ``dataset_id`` was asked for again (its ``used_mono``, the store's time, and
        its meta's ``last_used``, the wall time, UNIX s): retention by age counts from then."""
        def write() -> None:
            with self._lock:
                wall, mono = self._now()
                self._db.execute("UPDATE datasets SET meta = json_set(meta, '$.last_used', ?), used_mono = ? "
                                 "WHERE id = ?", (wall, mono, dataset_id))
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
