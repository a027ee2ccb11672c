"""The one test for a full disk, for every writer of the data folder (uploads, scan
files, results, the job database)."""
from __future__ import annotations

__all__ = ["is_disk_full"]


def is_disk_full(exc: BaseException | None) -> bool:
    """True when ``exc`` (or what caused it) is a full disk: ``OSError`` ENOSPC (h5py's
    errors too, by their text) or SQLite's "database or disk is full" (SQLITE_FULL)."""
    import errno
    import sqlite3

    for _ in range(8):
        if exc is None:
            return False
        if isinstance(exc, OSError) and (exc.errno == errno.ENOSPC or "No space left on device" in str(exc)):
            return True
        if isinstance(exc, sqlite3.OperationalError) and "disk is full" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False
