"""The one test for a full disk, for every writer of the data folder (uploads, scan
files, results, the job database), the one way a file or a folder is put in place
whole (:func:`file_replaced`: exports; :func:`folder_replaced`: result folders, OME-Zarr
exports), the names of the temporary files and folders they write meanwhile
(:func:`temp_sibling`, :func:`is_temp_name`: what the start-up sweep of crash debris removes),
and the one way stored data is made durable before it is acknowledged (:func:`fsync_tree`).

Acknowledged means on disk: a file a 2xx (or a job's recorded success) names is flushed
with its folder before the job store's commit that records it, in the order a power cut
needs: the file's data (``fsync`` of the file), then the folder entry naming it (``fsync``
of the folder, and of the folder above for a folder that was renamed into place), then the
commit (SQLite, ``synchronous=FULL``), then the answer. Renaming a file into place orders
nothing by itself: ext4 and XFS may persist the rename before the data (Pillai et al.,
"All File Systems Are Not Created Equal", OSDI 2014, the ALICE study; POSIX ``fsync``).

A full disk is an ``OSError`` with errno ENOSPC (or EDQUOT, a quota reached), or one whose
text says so (h5py's errors, SQLite's SQLITE_FULL). NumPy's ``ndarray.tofile`` (what tifffile
writes arrays with) raises an ``OSError`` without an errno: ``"Not enough free space to write
N bytes after offset M"`` when its ``fallocate`` of 16 MiB or more fails with ENOSPC (that
text is a full disk), and ``"N requested and M written"`` for any short ``fwrite`` (the C
errno is dropped; N and M count array elements; NumPy's ``convert.c``). The short write
alone does not say why, so the writers here tell it while the partial temporary still holds
its blocks: when the disk has fewer free bytes than the elements the write was short of
(each at least a byte), it was full, and the error is raised again as an ENOSPC ``OSError``
(:func:`file_replaced`, :func:`folder_replaced`). A free-space look after
the temporary is removed would not do: removing it frees the blocks the write filled.
"""
from __future__ import annotations

import errno
import os
import re
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["free_bytes", "is_disk_full", "file_replaced", "folder_replaced", "copy_replaced", "fsync_tree", "fsync_folder",
           "durable_mkdir", "remove_tree", "temp_sibling", "is_temp_name"]

#: NumPy's short write (``ndarray.tofile``; ``numpy/_core/src/multiarray/convert.c``): no errno
_SHORT_WRITE = re.compile(r"^(\d+) requested and (\d+) written$")
#: NumPy's failed ``fallocate`` before a write of 16 MiB or more (ENOSPC; no errno in the exception)
_NO_ROOM = "Not enough free space to write"
#: the temporary names fpscan's writers use in the data folder: ``.<name>.<pid>.<12 hex>.tmp``
#: (:func:`temp_sibling`), ``<name>.tmp-<pid>-<ns>`` (a result folder being written),
#: ``.<name>.tmp-<pid>`` (an unmixing file an earlier release was writing: its crash debris)
_TEMP_NAME = re.compile(r"^\..+\.\d+\.[0-9a-f]{12}\.tmp$|^.+\.tmp-\d+(-\d+)?$")


def free_bytes(path: str | os.PathLike) -> int | None:
    """The bytes free to an unprivileged writer on the file system holding ``path``
    (``statvfs``: ``f_bavail × f_frsize``, as ``shutil.disk_usage(path).free``), or None when
    they cannot be read (no such path, an I/O error): the one look at free space of every
    writer and report of the data folder.

    Parameters
    ----------
    path : str or os.PathLike
        A file or folder on that file system.

    Returns
    -------
    int or None
        The free bytes, or None.
    """
    try:
        st = os.statvfs(path)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def temp_sibling(out: str | os.PathLike) -> Path:
    """The temporary sibling a writer fills before renaming it over ``out``:
    ``.<name>.<pid>.<12 hex>.tmp`` beside it, unique per call (concurrent writers of one
    target never share it), a name :func:`is_temp_name` knows.

    Parameters
    ----------
    out : str or os.PathLike
        The file or folder to be put in place.

    Returns
    -------
    pathlib.Path
        The temporary path (not made here).
    """
    import uuid

    out = Path(out)
    return out.with_name(f".{out.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")


def is_temp_name(name: str) -> bool:
    """Whether ``name`` (a last path component) is one of the temporary names fpscan's
    writers use in the data folder (:func:`temp_sibling`'s, a result folder's
    ``<name>.tmp-<pid>-<ns>``, and ``.<name>.tmp-<pid>``, an unmixing file's in an earlier
    release): what a crash leaves behind.

    Parameters
    ----------
    name : str

    Returns
    -------
    bool

    Examples
    --------
    >>> is_temp_name("..volume.ome.zarr.zip.4242.0123456789ab.tmp"), is_temp_name("volume.h5")
    (True, False)
    >>> is_temp_name("job1.tmp-4242-123456789"), is_temp_name("notes.tmp")
    (True, False)
    """
    return bool(_TEMP_NAME.match(name))


def _as_disk_full(exc: BaseException, where: Path) -> BaseException:
    """``exc`` itself, or, for NumPy's short write (no errno) while the disk at ``where`` has
    fewer free bytes than the elements the write was short of, an ENOSPC ``OSError`` saying
    so (module docstring); call it while the partial temporary still holds its blocks."""
    if not isinstance(exc, OSError) or exc.errno is not None:
        return exc
    short = _SHORT_WRITE.match(str(exc))
    if short is None:
        return exc
    free = free_bytes(where)
    missing = int(short.group(1)) - int(short.group(2))
    if free is None or free >= missing:
        return exc
    full = OSError(errno.ENOSPC, f"No space left on device ({type(exc).__name__}: {exc})")
    full.__cause__ = exc
    return full


@contextmanager
def file_replaced(out: str | os.PathLike) -> Iterator[Path]:
    """Write a file as a temporary sibling of ``out`` (:func:`temp_sibling`: unique per call,
    concurrent writers of one target never share it), then rename it over ``out``
    (``os.replace``: a reader sees the old file or the whole new one); on any error the
    temporary file is removed and the error raised (NumPy's short write on a full disk as an
    ENOSPC ``OSError``: module docstring). ``out``'s folder is made if missing. Yields the
    temporary path.

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
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(out)
    try:
        yield tmp
        os.replace(tmp, out)
    except BaseException as exc:
        full = _as_disk_full(exc, out.parent)
        tmp.unlink(missing_ok=True)
        if full is not exc:
            raise full from exc
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
    error in the body or the move ``tmp`` is removed (every file in it, however deep) and the
    error raised (NumPy's short write on a full disk as an ENOSPC ``OSError``: module
    docstring). Yields ``tmp``.

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
    except BaseException as exc:
        full = _as_disk_full(exc, tmp.parent)
        remove_tree(tmp)
        if full is not exc:
            raise full from exc
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


def remove_tree(folder: str | os.PathLike) -> None:
    """Remove ``folder`` and everything in it, however deep, if it is there; a file that
    another thread of the writer adds while the tree is removed (a write in flight when the
    writer failed) is removed by a second pass. Errors are not raised (what stays is crash
    debris for the start-up sweep).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder (a temporary one a writer filled).
    """
    for _ in range(3):
        shutil.rmtree(folder, ignore_errors=True)
        if not os.path.lexists(folder):
            return


def is_disk_full(exc: BaseException | None) -> bool:
    """True when ``exc`` (or what caused it) is a full disk: ``OSError`` ENOSPC or EDQUOT
    (h5py's errors too, by their text; NumPy's failed ``fallocate``, by its text: module
    docstring) or SQLite's "database or disk is full" (SQLITE_FULL).

    Parameters
    ----------
    exc : BaseException or None
        The error; its chain (``__cause__``, else ``__context__``) is followed up to 8 links.

    Returns
    -------
    bool
        True for a full disk anywhere in that chain; False for None or any other error.
    """
    import sqlite3

    for _ in range(8):
        if exc is None:
            return False
        if isinstance(exc, OSError) and (exc.errno in (errno.ENOSPC, errno.EDQUOT) or any(
                text in str(exc) for text in ("No space left on device", "Disk quota exceeded", _NO_ROOM))):
            return True
        if isinstance(exc, sqlite3.OperationalError) and "disk is full" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False
