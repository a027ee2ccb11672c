"""The one test for a full disk, for every writer of the data folder (uploads, scan
files, results, the job database), the one way a file or a folder is put in place
whole (:func:`file_replaced`: exports; :func:`folder_replaced`: result folders, OME-Zarr
exports), and the one way stored data is made durable before it is acknowledged
(:func:`fsync_tree`).

Acknowledged means on disk: a file a 2xx (or a job's recorded success) names is flushed
with its folder before the job store's commit that records it, in the order a power cut
needs: the file's data (``fsync`` of the file), then the folder entry naming it (``fsync``
of the folder, and of the folder above for a folder that was renamed into place), then the
commit (SQLite, ``synchronous=FULL``), then the answer. Renaming a file into place orders
nothing by itself: ext4 and XFS may persist the rename before the data (Pillai et al.,
"All File Systems Are Not Created Equal", OSDI 2014, the ALICE study; POSIX ``fsync``).
"""
from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["is_disk_full", "file_replaced", "folder_replaced", "copy_replaced", "fsync_tree", "fsync_folder",
           "durable_mkdir"]


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


def fsync_folder(folder: str | os.PathLike) -> None:
    """Flush a folder's entries to disk (``fsync`` of the folder itself): the names created,
    renamed into it or removed from it survive a power cut.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder.

    Raises
    ------
    OSError
        It cannot be opened or flushed (EIO: the disk lost the write).
    """
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def durable_mkdir(folder: str | os.PathLike) -> Path:
    """Make ``folder`` (and its missing parents) and flush the folder above each one made, so
    that the folders the data's files are put in survive a power cut too (a folder that was
    there is left as it is).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder (``datasets/``, ``results/``, ``scans/`` of the data folder).

    Returns
    -------
    pathlib.Path
        ``folder``.

    Raises
    ------
    OSError
        It cannot be made or flushed.
    """
    folder = Path(folder)
    missing = []
    here = folder
    while not here.is_dir():
        missing.append(here)
        if here.parent == here:
            break
        here = here.parent
    folder.mkdir(parents=True, exist_ok=True)
    for made in reversed(missing):  # the outermost first: each entry after the folder above it exists
        fsync_folder(made.parent)
    return folder


def fsync_tree(path: str | os.PathLike, *, parent: bool = True) -> None:
    """Flush ``path`` to disk before it is acknowledged (module docstring): a file, or every
    file of a folder and then the folder (its subfolders first, each after its files), then,
    with ``parent``, the folder that names ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The file or folder just written (and renamed into place).
    parent : bool, optional
        Also flush the folder holding ``path`` (its entry naming ``path``); default True.

    Raises
    ------
    OSError
        A file or folder cannot be opened or flushed (EIO: the disk lost the write).
    """
    path = Path(path)
    if path.is_dir():
        for here, _dirs, files in os.walk(path, topdown=False):  # files, then their folder; the root last
            for name in sorted(files):
                _fsync_file(Path(here) / name)
            fsync_folder(here)
    else:
        _fsync_file(path)
    if parent:
        fsync_folder(path.parent)


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


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
