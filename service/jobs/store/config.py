"""The job store's service config: configuration values the server keeps (key -> JSON value).

:mod:`fpscan.service.jobs.lifecycle` owns the rules that use them.
"""
from __future__ import annotations

import json
from typing import Any

from fpscan.service.jobs.store.base import StoreBase

__all__ = ["ServiceConfig"]


class ServiceConfig(StoreBase):
    """The configuration values of :class:`fpscan.service.jobs.store.JobStore` (module docstring).

    A mixin of :class:`fpscan.service.jobs.store.JobStore`: made as :class:`~fpscan.service.jobs.store.base.StoreBase` is.
    """

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
