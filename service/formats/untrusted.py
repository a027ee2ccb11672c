"""Files from users (uploads, CLI arguments): checked before anything is read, and read
in bounded time.

HDF5 files are checked before anything is read by the one vetting step of
:mod:`fpscan.driver.hdf5_checks` (no external links, external storage or virtual datasets, no
dataset declaring more than ``max_bytes`` or more than it stores; re-exported here):
:func:`check_hdf5_file` on a file open, ``fpscan.driver.scanfile.open_checked`` to open and check one.

How much an import may *write* is admitted separately (:func:`request_admission`: the
service checks the decoded bytes against the free disk less what imports in flight have
reserved, before the dataset file is written).

The HDF5 library can block while holding the GIL (a damaged file opened as an SWMR reader
retries forever), so the service runs the whole import in a child process with a time
limit and an address-space limit: :func:`run_bounded`. An upload's import decodes at most
:func:`hdf5_limit` bytes (every array it reads, through every compressed layer, sized
before it is decoded) in a child capped at :func:`import_memory_limit`. The child dies with
the process that asked for it (:func:`run_bounded`: no orphans after a crash or a
``kill -9`` of the server). The library and the CLI read a user's file in their own
process, except a file HDF5 would open as an SWMR reader (its superblock says a writer has,
or had, it open: :func:`writer_flagged`): :func:`read_bounded` reads that one in the same
bounded child.
"""
from __future__ import annotations

import errno
import multiprocessing
import os
import queue as _queue
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fpscan.driver.hdf5_checks import HDF5_SIGNATURE, MAX_RATIO, SMALL_BYTES, check_hdf5_file, is_hdf5

__all__ = ["HDF5_SIGNATURE", "SMALL_BYTES", "MAX_RATIO", "STARTUP_S", "CHILD_NICE", "CHILD_PRELOAD", "READ_TIMEOUT_S",
           "IMPORT_MEMORY_FLOOR", "is_hdf5", "check_hdf5_file", "NotAdmitted", "request_admission", "DiskAdmission",
           "run_bounded", "writer_flagged", "read_bounded", "hdf5_limit", "import_memory_limit"]

#: Longest wait for a child process of :func:`run_bounded` to start (s).
STARTUP_S = 120.0
#: CPU priority (``nice`` increment) of the reading child: below the server's event loop,
#: so that a burst of uploads being vetted does not slow every other request (health
#: included), beside the live-preview worker (+5)
CHILD_NICE = 5


class NotAdmitted(Exception):
    """The service cannot take what an import would write (not enough free disk, counting the
    imports in flight): the server's condition, not the file's fault (HTTP 507).

    Parameters
    ----------
    reason : str
        Why: the bytes asked for, the room left and what to do.
    """


#: In a child of :func:`run_bounded` given ``admit``: (request queue, answer queue).
_ADMISSION: tuple[Any, Any] | None = None


def request_admission(nbytes: int) -> None:
    """Ask to write ``nbytes`` (the decoded dataset) before writing it.

    In a child of :func:`run_bounded` called with ``admit``, the parent answers
    (``DiskAdmission``: free space less what imports in flight reserved); elsewhere (a local
    read) nothing is asked.

    Parameters
    ----------
    nbytes : int
        The bytes the import will write.

    Raises
    ------
    NotAdmitted
        With the reason, when refused.
    """
    if _ADMISSION is None:
        return
    requests, answers = _ADMISSION
    requests.put(("admit", int(nbytes)))
    refused = answers.get()
    if refused:
        raise NotAdmitted(refused)


class DiskAdmission:
    """Free-space admission of uploads and imports that run at once.

    An import asks before it writes (:func:`request_admission`), and an upload's body before
    it is spooled (``fpscan.service.api.spool``); each is admitted when its bytes fit the free
    space of ``folder``'s file system less ``reserve_bytes`` (left for the job database,
    scans and results) less what the uploads and imports in flight were admitted for; its
    reservation lasts until :meth:`release`. So uploads at once cannot together fill the
    disk. Thread-safe.

    Parameters
    ----------
    folder : str or os.PathLike
        A folder on the file system the imports write to (the data folder).
    reserve_bytes : int
        Bytes always left free.

    Attributes
    ----------
    folder : pathlib.Path
        As given.
    reserve_bytes : int
        As given.
    """

    def __init__(self, folder: str | os.PathLike, reserve_bytes: int):
        import threading

        self.folder = Path(folder)
        self.reserve_bytes = int(reserve_bytes)
        self._lock = threading.Lock()
        self._reserved: dict[str, int] = {}

    def reserved(self) -> int:
        """Bytes admitted to imports still in flight."""
        with self._lock:
            return sum(self._reserved.values())

    def reserve(self, key: str, nbytes: int, what: str | None = None) -> str | None:
        """Admit ``nbytes`` for ``key`` (None) or say why not (the reason).

        Parameters
        ----------
        key : str
            The reservation's name (:meth:`release` ends it; a second ``reserve`` replaces it).
        nbytes : int
            The bytes to be written.
        what : str or None, optional
            The reason's start, what needs the bytes (e.g. "the upload holds 5 bytes");
            default None: "the dataset decodes to ``nbytes`` bytes".

        Returns
        -------
        str or None
            None when admitted; else why not (the bytes asked for, the room left, what to do).
            Free bytes that cannot be read count as none.
        """
        from fpscan.service.disk import free_bytes

        with self._lock:
            free = free_bytes(self.folder) or 0
            others = sum(v for k, v in self._reserved.items() if k != key)
            room = free - others - self.reserve_bytes
            if nbytes > room:
                return (f"{what or f'the dataset decodes to {nbytes} bytes'} but the data folder's disk can take "
                        f"{max(room, 0)} more ({free} free, {others} reserved by uploads, imports and exports in "
                        f"progress, {self.reserve_bytes} kept free); free space or retry later")
            self._reserved[key] = int(nbytes)
            return None

    def release(self, key: str) -> None:
        with self._lock:
            self._reserved.pop(key, None)


def _child(conn: Any, fn: Callable, args: tuple, kwargs: dict, memory_bytes: int | None = None) -> None:
    try:
        conn.put(("ok", fn(*args, **kwargs)))
    except NotAdmitted as exc:
        conn.put(("notadmitted", str(exc)))
    except ValueError as exc:
        conn.put(("value", str(exc)))
    except FileNotFoundError as exc:
        conn.put(("value", f"file not found: {exc.filename or exc}"))
    except MemoryError:
        limit = f" of {memory_bytes} bytes" if memory_bytes else ""
        conn.put(("value", f"the file needs more memory than the import's limit{limit} allows"))
    except OSError as exc:
        from fpscan.service.disk import is_disk_full

        if is_disk_full(exc):  # not the file's fault
            conn.put(("nospace", str(exc)))
        else:
            conn.put(("value", f"file is not a readable dataset ({type(exc).__name__})"))
    except Exception as exc:  # a damaged file can raise anything from the HDF5 layer
        conn.put(("value", f"file is not a readable dataset ({type(exc).__name__})"))


#: what the fork server imports once, so that a reading child starts without imports
CHILD_PRELOAD = ["fpscan.service.formats.untrusted", "fpscan.service.formats", "fpscan.service.storage.loader", "fpscan.driver.scanfile"]


def _child_context() -> Any:
    """Where :func:`run_bounded`'s children come from: forked from a fork server that has
    imported :data:`CHILD_PRELOAD` (one interpreter start per process, not one per file:
    a spawned child spent 0.3-0.5 s of CPU on its imports, for each upload a server
    reads, refused ones included); a fresh spawned interpreter where the platform has no
    fork server. A fork server's children share no threads or open files with the caller."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(CHILD_PRELOAD)
    return ctx


def _fork_server_pid(ctx: Any) -> int | None:
    """The pid of ``ctx``'s fork server, started if it is not running (None: not a fork
    server's context, or not known on this Python)."""
    if ctx.get_start_method() != "forkserver":
        return None
    from multiprocessing import forkserver

    forkserver.ensure_running()
    return getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", None)


#: Linux ``prctl`` option: the signal a process gets when its parent ends (``<sys/prctl.h>``)
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int | None) -> None:
    """In a child of :func:`run_bounded` (forked by the fork server, pid ``parent``): end with
    the caller. A fork server's children hold the write end of its "alive" pipe; the server
    leaves when every holder has closed it (Python's ``multiprocessing.forkserver``): this
    child closes its copy (it starts no processes), so the caller's is the last one and the
    fork server leaves when the caller does, however the caller ends (``kill -9``
    included); and it asks Linux for SIGKILL when its parent, the fork server's one thread,
    ends (``prctl(PR_SET_PDEATHSIG)``, prctl(2)) -- no Python code has to run for it, so a
    child stuck in the HDF5 library holding the GIL ends too. Once both are gone nothing
    holds the resource tracker's pipe and it leaves as well. Checked after the request:
    a parent already gone (it left before the request took) ends this child at once."""
    if parent is None:
        return
    from multiprocessing import forkserver

    server = getattr(forkserver, "_forkserver", None)
    alive = getattr(server, "_forkserver_alive_fd", None)
    if alive is not None:
        try:
            os.close(alive)
        except OSError:
            pass
        server._forkserver_alive_fd = None  # type: ignore[union-attr]
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
            return
    except (OSError, AttributeError):  # not Linux
        return
    if os.getppid() != parent:
        os._exit(1)


def _child_nice() -> int | None:
    """The niceness of a reading child: the caller's + ``CHILD_NICE`` (at most 19); None where
    the platform has no priorities."""
    try:
        return min(os.getpriority(os.PRIO_PROCESS, 0) + CHILD_NICE, 19)
    except (AttributeError, OSError):
        return None


def _set_nice(pid: int, nice: int | None) -> None:
    """Set process ``pid``'s (0: this one's) niceness to ``nice`` where it can (None: nothing;
    a child already gone, or a value below the current one without privileges: left as is)."""
    if nice is None:
        return
    try:
        os.setpriority(os.PRIO_PROCESS, pid, nice)
    except (AttributeError, OSError):
        pass


def run_bounded(fn: Callable, *args: Any, timeout: float, memory_bytes: int | None = None,
                what: str = "the file", admit: Callable[[int], str | None] | None = None, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` in a child process, killed when it takes too long.

    The child (:func:`_child_context`) runs at CPU priority + ``CHILD_NICE`` and is killed
    when it has not returned ``timeout`` s after it started (imports done; the start itself is
    bounded by :data:`STARTUP_S`). ``fn`` and its arguments and result must be picklable. It
    ends with the caller (a fork server's child on Linux: :func:`_die_with_parent`), so a
    caller killed meanwhile leaves no process behind: not the child, not the fork server,
    not multiprocessing's resource tracker.

    Parameters
    ----------
    fn : callable
        The function to run.
    *args
        Its positional arguments.
    timeout : float
        Time limit in s, from the child's start.
    memory_bytes : int, optional
        Address-space limit of the child (``RLIMIT_AS``), so a file that expands past it fails
        there with MemoryError (a ValueError saying so here), not in the caller.
    what : str, optional
        What is read, for the messages (default ``"the file"``).
    admit : callable, optional
        Answers the child's :func:`request_admission` (bytes -> None to admit, else the
        reason); without it the child's requests are admitted unasked.
    **kwargs
        Its keyword arguments.

    Returns
    -------
    object
        What ``fn`` returns.

    Raises
    ------
    ValueError
        With the reason for any failure of ``fn``, and for a child that times out or dies.
    NotAdmitted
        ``admit`` refused.
    OSError
        ENOSPC: the disk it writes to is full (the server's condition, not the file's).
    """
    ctx = _child_context()
    q = ctx.Queue()
    answers = ctx.Queue() if admit is not None else None
    # an Event, not a queue message: a queue's message is written by a feeder thread, which
    # never runs while the child's main thread blocks in HDF5 holding the GIL
    ready = ctx.Event()
    nice = _child_nice()
    proc = ctx.Process(target=_bounded_entry, args=(q, ready, fn, args, kwargs, memory_bytes, answers, nice,
                                                    _fork_server_pid(ctx)),
                       daemon=True)
    proc.start()
    if proc.pid is not None:  # from here too, not only in the child: a spawned child's start is costly
        _set_nice(proc.pid, nice)
    # the time limit starts when the child has imported what it runs (interpreter start-up
    # on a busy machine is not the file's fault), bounded separately by STARTUP_S
    deadline = time.monotonic() + STARTUP_S
    started = False
    try:
        while True:
            if not started and ready.is_set():
                started, deadline = True, time.monotonic() + timeout
            try:
                kind, value = q.get(timeout=0.05)
                if kind == "admit" and answers is not None and admit is not None:
                    answers.put(admit(int(value)))
                    continue
                break
            except _queue.Empty:
                pass
            if not proc.is_alive():
                try:
                    kind, value = q.get(timeout=0.5)  # the result may still be in the pipe
                except _queue.Empty:
                    kind, value = "value", f"reading {what} failed (the reader process died)"
                break
            if time.monotonic() > deadline:
                kind, value = "value", f"{what} could not be read within {timeout:g} s (truncated or corrupt?)"
                break
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(5)
        q.close()
        if answers is not None:
            answers.close()
    if kind == "ok":
        return value
    if kind == "notadmitted":
        raise NotAdmitted(value)
    if kind == "nospace":
        raise OSError(errno.ENOSPC, "No space left on device (writing the imported dataset)")
    raise ValueError(value)


def _bounded_entry(q: Any, ready: Any, fn: Callable, args: tuple, kwargs: dict, memory_bytes: int | None,
                   answers: Any = None, nice: int | None = None, fork_server: int | None = None) -> None:
    """The child's start: bound to its parent's life (:func:`_die_with_parent`; its parent
    the fork server ``fork_server``), its niceness ``nice`` (absolute, the same value the
    parent sets from outside: a forked child can run ``fn`` before the parent's setpriority
    reaches it), its address-space limit, then ``fn`` (:func:`_child`)."""
    global _ADMISSION
    _die_with_parent(fork_server)
    _set_nice(0, nice)
    if answers is not None:
        _ADMISSION = (q, answers)
    ready.set()
    if memory_bytes:
        try:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        except (ImportError, ValueError, OSError):  # not on this platform
            pass
    _child(q, fn, args, kwargs, memory_bytes)


#: Time limit (s) of :func:`read_bounded` (the service's upload limit is its own setting).
READ_TIMEOUT_S = 60.0


def writer_flagged(path: str | os.PathLike) -> bool:
    """True for an HDF5 file whose superblock says a writer has (or had, if killed) it open for
    SWMR writing.

    ``fpscan.driver.scanfile.open_readonly`` opens such a file as an SWMR reader, which HDF5 can
    block in for ever on damaged metadata.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    bool
        False for anything else, a file that is not HDF5 or a damaged superblock included
        (those are refused by the readers).
    """
    from fpscan.driver.scanfile import superblock_open_for_write

    try:
        return is_hdf5(path) and superblock_open_for_write(path)
    except (OSError, ValueError):
        return False


def read_bounded(fn: Callable, path: str | os.PathLike, *args: Any, timeout: float | None = None,
                 **kwargs: Any) -> Any:
    """``fn(path, *args, **kwargs)``, in a bounded child process where HDF5 could block.

    In this process, or, for a file HDF5 would open as an SWMR reader (:func:`writer_flagged`),
    in a child process killed after ``timeout`` s (:func:`run_bounded`: the result must be
    picklable). The child is spawned: a script calling this at import time needs the
    ``if __name__ == "__main__":`` guard of ``multiprocessing``.

    Parameters
    ----------
    fn : callable
        The reader, ``fn(path, *args, **kwargs)``.
    path : str or os.PathLike
        The file.
    *args
        More positional arguments for ``fn``.
    timeout : float, optional
        Time limit of the child, s (default ``FPSCAN_IMPORT_TIMEOUT_S`` or
        :data:`READ_TIMEOUT_S`, 60 s).
    **kwargs
        Keyword arguments for ``fn``.

    Returns
    -------
    object
        What ``fn`` returns.

    Raises
    ------
    ValueError
        In the child: the reason ``fn`` failed, also for a read that did not end in time.
    Exception
        In this process: what ``fn`` raises.
    """
    if not writer_flagged(path) or multiprocessing.current_process().daemon:  # a bounded child already
        return fn(path, *args, **kwargs)
    if timeout is None:
        timeout = float(os.environ.get("FPSCAN_IMPORT_TIMEOUT_S") or READ_TIMEOUT_S)
    return run_bounded(fn, path, *args, timeout=timeout, what=f"{Path(path).name} (open by a writer)", **kwargs)


#: The least address space an import child is given (bytes): forked from the fork server, its
#: interpreter and libraries (numpy, scipy, h5py) map 0.18 GB before it reads a byte (measured;
#: OpenBLAS's threads are shut down before a fork, so this does not grow with the cores)
IMPORT_MEMORY_FLOOR = 1 << 30


def hdf5_limit(upload_limit: int, memory_limit: int) -> int:
    """The decode budget of an upload's import (bytes).

    An HDF5 file's datasets may declare at most this, any one and all together (each link
    counted: ``check_hdf5_file``), and a MAT-file's variables may take at most this decoded,
    every field of a struct or cell, nested or not, sized before it is decoded
    (``fpscan.service.formats.kwave_mat``). It must fit the upload limit uncompressed ×4
    (compressed files) and half the memory limit (the import converts samples to float).

    Parameters
    ----------
    upload_limit : int
        The largest accepted upload, bytes.
    memory_limit : int
        Bytes available to reconstructions at once.

    Returns
    -------
    int
        ``min(4 upload_limit, memory_limit // 2)``.
    """
    return int(min(4 * upload_limit, memory_limit // 2))


def import_memory_limit(memory_limit: int) -> int:
    """The address-space limit (``RLIMIT_AS``, bytes) of an upload's import child: the
    memory limit itself, at least :data:`IMPORT_MEMORY_FLOOR`.

    The child decodes at most :func:`hdf5_limit` (at most half of this) and converts it to
    float; a file that needs more fails there with MemoryError and is refused with the
    reason. ``import_workers`` children at once take at most that many times this.

    Parameters
    ----------
    memory_limit : int
        Bytes available to reconstructions at once (``Settings.memory_limit``).

    Returns
    -------
    int
        ``max(memory_limit, IMPORT_MEMORY_FLOOR)``.
    """
    return int(max(memory_limit, IMPORT_MEMORY_FLOOR))
