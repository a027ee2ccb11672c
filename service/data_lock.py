"""One server per data folder and per job database, and a port checked before anything starts.

Two ``fpscan serve`` on one data folder would share one job store: the second one's
start-up recovery marks the first one's running scan ``paused`` (and re-queues its
reconstructions) while it goes on, and both dispatch the same queue. So a server takes an
exclusive lock on a file in its data folder (:data:`LOCK_FILE`) before anything reads or
changes the store, as Jupyter Server and PostgreSQL (``postmaster.pid``) refuse a second
server on one data directory, and holds it for its lifetime. The job database may live
outside the data folder (``FPSCAN_DB_PATH``): two servers with folders of their own would
still share it, so the server also locks the file beside the database,
``<database>.lock`` (:func:`lock_job_store`), wherever it lives.

The lock is a POSIX record lock (``fcntl.lockf``): the kernel releases it when the process
ends, however it ends (a SIGKILL or a power cut leaves no stale lock to clean up by hand),
and it is per process, so the server's worker processes (spawned, the file not inherited)
never hold it. The lock file holds the holder's PID as text, read back for the refusal's
one line; the file itself stays (its content, not its existence, is no lock).

:func:`check_port` binds the address the server is about to listen on and lets go of it:
a port already taken is one line, before the data folder is touched.
"""
from __future__ import annotations

import contextlib
import errno
import os
import socket
from pathlib import Path

__all__ = ["LOCK_FILE", "DataFolderInUse", "JobStoreInUse", "PortInUse", "DataFolderLock", "lock_data_folder",
           "lock_job_store", "job_store_lock_path", "check_port"]

#: the lock file in the data folder
LOCK_FILE = "fpscan.lock"


class DataFolderInUse(RuntimeError):
    """Another live process holds the data folder's lock (the message names its PID).

    Parameters
    ----------
    message : str
        One line naming the folder and the holder (``"pid 1234"`` or ``"another process"``).
    """


class JobStoreInUse(DataFolderInUse):
    """Another live process holds the job database's lock (:func:`lock_job_store`; the
    message names its PID and the lock file). A :class:`DataFolderInUse`.

    Parameters
    ----------
    message : str
        One line naming the database, its lock file and the holder (``"pid 1234"`` or
        ``"another process"``).
    """


class PortInUse(RuntimeError):
    """The address and port a server would listen on are taken (or not available).

    Parameters
    ----------
    message : str
        One line naming the address (``host:port``, ``[host]:port`` for IPv6) and the reason.
    """


class DataFolderLock:
    """The held lock of one data folder (:func:`lock_data_folder`) or job database
    (:func:`lock_job_store`); :meth:`release` (or the process's end) lets it go. Also a
    context manager: leaving the ``with`` block releases it.

    Parameters
    ----------
    path : pathlib.Path
        The lock file (:data:`LOCK_FILE` in the data folder, or ``<database>.lock``).
    fd : int
        Its open file descriptor, which holds the record lock (``fcntl.lockf``).

    Attributes
    ----------
    path : pathlib.Path
        The lock file.
    held : bool
        True until :meth:`release`.
    """

    def __init__(self, path: Path, fd: int) -> None:
        self.path, self._fd = path, fd

    @property
    def held(self) -> bool:
        return self._fd >= 0

    def release(self) -> None:
        """Let the lock go (closing the file releases the process's record lock)."""
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)

    def __enter__(self) -> DataFolderLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(path: Path) -> str:
    """The holder as the lock file names it: ``"pid 1234"``, else ``"another process"``."""
    try:
        text = path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        return "another process"
    return f"pid {text}" if text.isdigit() else "another process"


def _take(path: Path) -> DataFolderLock | None:
    """The exclusive record lock of the file ``path`` (created if missing) for this process,
    its PID written in it; None when another process holds it."""
    import fcntl

    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EACCES, errno.EAGAIN):
            return None
        raise
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    except OSError:  # the PID is for the message only: the lock holds without it
        pass
    return DataFolderLock(path, fd)


def lock_data_folder(data_dir: str | os.PathLike) -> DataFolderLock:
    """Take the exclusive lock of ``data_dir`` (created if missing) for this process.

    Parameters
    ----------
    data_dir : path
        The server's data folder (its job store, plans, scans and results).

    Returns
    -------
    DataFolderLock
        Held until :meth:`DataFolderLock.release` or the process's end; the lock file
        (:data:`LOCK_FILE`) then holds this process's PID.

    Raises
    ------
    DataFolderInUse
        Another live process holds it: one line naming the folder and that process's PID.
    OSError
        The folder or its lock file cannot be created or opened (permissions, a full disk).

    Examples
    --------
    >>> import tempfile
    >>> from fpscan.service.data_lock import lock_data_folder
    >>> folder = tempfile.mkdtemp()
    >>> with lock_data_folder(folder) as lock:
    ...     lock.held
    True
    """
    folder = Path(data_dir)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_FILE
    lock = _take(path)
    if lock is None:
        raise DataFolderInUse(f"the data folder {folder} is in use by another fpscan server "
                              f"({_holder(path)}); stop that one, or give this one another --data-dir")
    return lock


def job_store_lock_path(database: str | os.PathLike) -> Path:
    """The lock file of a job database: ``<database>.lock`` beside it.

    Parameters
    ----------
    database : path
        The SQLite job database (``Settings.database``).

    Returns
    -------
    pathlib.Path
        ``<database>.lock``.
    """
    db = Path(database)
    return db.with_name(db.name + ".lock")


def lock_job_store(database: str | os.PathLike) -> DataFolderLock:
    """Take the exclusive lock of the job database ``database`` for this process: the file
    ``<database>.lock`` beside it (:func:`job_store_lock_path`; its folder created if
    missing), wherever the database lives, so that two servers never share one job store
    even with data folders of their own (``FPSCAN_DB_PATH``). The server takes it with the
    data folder's (:func:`lock_data_folder`), before anything reads the store.

    Parameters
    ----------
    database : path
        The SQLite job database (``Settings.database``).

    Returns
    -------
    DataFolderLock
        Held until :meth:`DataFolderLock.release` or the process's end; the lock file then
        holds this process's PID.

    Raises
    ------
    JobStoreInUse
        Another live process holds it: one line naming the database, the lock file and that
        process's PID.
    OSError
        The folder or the lock file cannot be created or opened.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from fpscan.service.data_lock import lock_job_store
    >>> with lock_job_store(Path(tempfile.mkdtemp()) / "jobs.sqlite") as lock:
    ...     lock.path.name
    'jobs.sqlite.lock'
    """
    db = Path(database)
    db.parent.mkdir(parents=True, exist_ok=True)
    path = job_store_lock_path(db)
    lock = _take(path)
    if lock is None:
        raise JobStoreInUse(f"the job database {db} is in use by another fpscan server ({_holder(path)}, "
                            f"lock {path}); stop that one, or give this one another FPSCAN_DB_PATH")
    return lock


def check_port(host: str, port: int) -> None:
    """Refuse now a ``host``:``port`` the server could not listen on: bind it as uvicorn
    does (``SO_REUSEADDR``; IPv6 for an address with ``:``) and let go of it at once.
    Port 0 (any free port) always passes.

    Parameters
    ----------
    host : str
        The address to listen on (a name, an IPv4 address, or an IPv6 address without
        brackets).
    port : int
        The TCP port, 0-65535.

    Raises
    ------
    PortInUse
        One line naming the address: taken by another program, or not an address of this
        machine.
    """
    if int(port) == 0:
        return
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with contextlib.closing(socket.socket(family, socket.SOCK_STREAM)) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, int(port)))
        except OSError as exc:
            where = f"[{host}]:{port}" if family == socket.AF_INET6 else f"{host}:{port}"
            if exc.errno == errno.EADDRINUSE:
                raise PortInUse(f"port {port} is in use ({where}): another server listens there; stop it or "
                                "choose another --port") from None
            raise PortInUse(f"cannot listen on {where}: {exc.strerror or exc}") from None
