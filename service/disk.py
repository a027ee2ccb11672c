"""The one test for a full disk, for every writer of the data folder (uploads, scan
files, results, the job database), and the one way a folder is put in place whole
(:func:`folder_replaced`: result folders, OME-Zarr exports)."""
from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["is_disk_full", "folder_replaced"]


@contextmanager
def folder_replaced(out: str | os.PathLike, tmp: str | os.PathLike) -> Iterator[Path]:
    """Write a folder as ``tmp`` (a sibling of ``out``, made by the body), then put it in
    place of ``out`` (an existing ``out`` folder removed first, ``os.replace``); on any
    error in the body or the move ``tmp`` is removed and the error raised. Yields ``tmp``."""
    out, tmp = Path(out), Path(tmp)
    try:
        yield tmp
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


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
