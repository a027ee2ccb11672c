"""The one test for a full disk, for every writer of the data folder (uploads, scan
files, results, the job database), and the one way a file or a folder is put in place
whole (:func:`file_replaced`: exports; :func:`folder_replaced`: result folders, OME-Zarr
exports)."""
from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["is_disk_full", "file_replaced", "folder_replaced", "copy_replaced"]


@contextmanager
def file_replaced(out: str | os.PathLike) -> Iterator[Path]:
    """Write a file as a temporary sibling of ``out`` (unique per call: concurrent writers of
    one target never share it), then rename it over ``out`` (``os.replace``: a reader sees the
    old file or the whole new one); on any error the temporary file is removed and the error
    raised. ``out``'s folder is made if missing. Yields the temporary path.

    Parameters
    ----------
    out : str or os.PathLike
        The file to put in place.

    Returns
    -------
    contextlib.AbstractContextManager of pathlib.Path
        A context manager whose ``with`` value is the temporary path the body writes.

    Raises
    ------
    OSError
        The folder cannot be made, or the rename fails (and what the body raises).
    """
    import uuid

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        yield tmp
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def copy_replaced(src: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Copy the file ``src`` to ``out``, put in place whole (:func:`file_replaced`): the export
    of a file as itself (a result ``volume.h5``, a scan file).

    Parameters
    ----------
    src, out : str or os.PathLike

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    ValueError
        ``out`` is ``src`` itself.
    OSError
        As the copy.
    """
    out = Path(out)
    if out.exists() and out.resolve() == Path(src).resolve():
        raise ValueError("the export would overwrite its own source file")
    with file_replaced(out) as tmp:
        shutil.copyfile(src, tmp)
    return out


@contextmanager
def folder_replaced(out: str | os.PathLike, tmp: str | os.PathLike) -> Iterator[Path]:
    """Write a folder as ``tmp`` (a sibling of ``out``, made by the body), then put it in
    place of ``out`` (an existing ``out`` folder removed first, ``os.replace``); on any
    error in the body or the move ``tmp`` is removed and the error raised. Yields ``tmp``.

    Parameters
    ----------
    out : str or os.PathLike
        The folder to put in place.
    tmp : str or os.PathLike
        The temporary folder the body makes and fills (a sibling of ``out``, so that the
        rename stays on one file system).

    Returns
    -------
    contextlib.AbstractContextManager of pathlib.Path
        A context manager whose ``with`` value is ``tmp`` as a path.

    Raises
    ------
    OSError
        The old ``out`` cannot be removed or the rename fails (and what the body raises).
    """
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
    errors too, by their text) or SQLite's "database or disk is full" (SQLITE_FULL).

    Parameters
    ----------
    exc : BaseException or None
        The error; its chain (``__cause__``, else ``__context__``) is followed up to 8 links.

    Returns
    -------
    bool
        True for a full disk anywhere in that chain; False for None or any other error.
    """
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
