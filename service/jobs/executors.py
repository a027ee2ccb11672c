"""Where reconstructions run: a local process pool (default) or dask.distributed.

Both expose ``submit(fn, *args) -> future`` (the future has ``result(timeout)``; called
from a job thread, never from the event loop), ``run(fn, *args) -> result`` (blocking)
and ``close()``.

- :class:`LocalExecutor`: ``concurrent.futures.ProcessPoolExecutor`` with the ``spawn``
  start method (no fork of a threaded server), ``workers`` processes at the CPU priority
  increment ``nice`` (``Settings.worker_nice``; default 0, the server's own priority: the
  server stays responsive because its CPU work runs off the event loop), each warming
  its kernels when it starts (``warm``: :func:`start_worker`).
- :class:`DaskExecutor`: ``distributed.Client(address)``; works with any scheduler,
  e.g. a ``LocalCluster`` or a dask-jobqueue cluster. The workers must see the data
  directory (shared file system), since they read inputs and write results there.
"""
from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from fpscan.service.settings import Settings

__all__ = [
    "lower_priority", "start_worker", "stop_pool", "LocalExecutor", "WorkerDied", "DaskExecutor",
    "make_executor",
]


def _exit_with_parent(parent: int, period: float = 1.0) -> None:
    while True:
        time.sleep(period)
        if os.getppid() != parent:  # the server died (e.g. SIGKILL): do not linger
            os._exit(0)


def lower_priority(increment: int = 10, parent: int | None = None) -> None:
    """Worker initializer: run at a lower CPU priority, and exit when the server is gone.

    The lower priority (``os.nice``; ignored where not available or not permitted) keeps the
    server's event loop and serial threads responsive on a small machine. A daemon thread
    checks the parent every second and exits the worker when the server process is gone (a
    pool worker would otherwise wait forever on its queue after a crash of the server).

    Parameters
    ----------
    increment : int, optional
        The ``os.nice`` increment; default 10.
    parent : int or None, optional
        The server's pid, taken when the pool was made (the server may already be dead when
        a worker that was still starting gets here); default None: the current parent.
    """
    try:
        os.nice(increment)
    except (AttributeError, OSError):  # not on this platform / not permitted
        pass
    parent = os.getppid() if parent is None else parent
    if os.getppid() != parent:
        os._exit(0)
    threading.Thread(target=_exit_with_parent, args=(parent,), name="parent-watch", daemon=True).start()


def start_worker(increment: int = 0, parent: int | None = None, warm: bool = False) -> None:
    """Reconstruction worker initializer: lower the priority, then optionally warm up.

    With ``warm``, :func:`fpscan.service.jobs.work.warm_up` runs (imports, numba kernels, the result
    writer and its pictures; the k-Wave and model-based kernels in the background), so the
    first job costs what a later one costs. A failing warm-up is logged and ignored (the job
    then pays the cost itself).

    Parameters
    ----------
    increment : int, optional
        CPU priority increment for :func:`lower_priority`; default 0.
    parent : int or None, optional
        The server's pid (:func:`lower_priority`); default None: the current parent.
    warm : bool, optional
        Warm the kernels up; default False.
    """
    lower_priority(increment, parent)
    if warm:
        try:
            from fpscan.service.jobs.work import warm_up

            warm_up(full=True, rest_in_background=True)
        except Exception:  # a warm-up must never stop the worker
            import logging

            logging.getLogger("fpscan.worker").exception("worker warm-up failed")


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Shut a pool down now: pending work is cancelled and running workers terminated.

    A reconstruction in flight is lost; its job is re-queued at the next start. Each
    terminated worker is waited for up to 5 s.

    Parameters
    ----------
    pool : concurrent.futures.ProcessPoolExecutor
        The pool.
    """
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    for proc in processes:
        proc.join(timeout=5)


class LocalExecutor:
    """A pool of spawned worker processes that run reconstructions.

    ``submit(fn, *args)`` returns a future whose ``result(timeout)`` raises
    :class:`WorkerDied` when the worker died (a fresh pool is made for the next job);
    ``run(fn, *args)`` waits for the result; ``close()`` stops the pool (:func:`stop_pool`).

    Parameters
    ----------
    workers : int, optional
        The number of processes; default 1.
    nice : int, optional
        Their CPU priority increment (``os.nice``); default 0.
    warm : bool, optional
        Each warms its kernels as it starts (:func:`start_worker`); default False.

    Attributes
    ----------
    name : str
        ``"local"``.
    workers, nice : int
        As given.
    warm : bool
        As given.
    closed : bool
        True once :meth:`close` was called.
    """

    name = "local"

    def __init__(self, workers: int = 1, nice: int = 0, warm: bool = False):
        self.workers = int(workers)
        self.nice = int(nice)
        self.warm = bool(warm)
        self.closed = False
        self._starts: list | None = None
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=start_worker, initargs=(self.nice, os.getpid(), self.warm))

    def start_workers(self) -> list:
        """Start every worker process now rather than at the first job.

        They start in the background, so their warm-up runs before the first job. A second
        call returns the first call's futures.

        Returns
        -------
        list of concurrent.futures.Future
            One future per worker, returned at once; each one's result is the worker's pid.
        """
        from fpscan.service.jobs.work import worker_pid

        if self._starts is None:
            self._starts = [self._pool.submit(worker_pid) for _ in range(self.workers)]
        return self._starts

    def submit(self, fn: Callable[..., Any], *args: Any) -> _LocalFuture:
        try:
            return _LocalFuture(self, self._pool.submit(fn, *args))
        except BrokenProcessPool:
            self._pool = self._new_pool()
            return _LocalFuture(self, self._pool.submit(fn, *args))

    def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self.submit(fn, *args).result()

    def close(self) -> None:
        self.closed = True
        stop_pool(self._pool)


class WorkerDied(RuntimeError):
    """The process running a job died (killed by the OS, or by a shutdown).

    A ``RuntimeError``; the job may be run again.

    Attributes
    ----------
    args : tuple
        The message, ``("the reconstruction worker process died",)``.
    """


class _LocalFuture:
    """A pool future whose ``result`` turns a dead worker into ``RuntimeError`` (and
    gives the executor a fresh pool for the next job)."""

    def __init__(self, executor: LocalExecutor, future: Future[Any]) -> None:
        self._executor = executor
        self._future = future

    def result(self, timeout: float | None = None) -> Any:
        try:
            return self._future.result(timeout)
        except BrokenProcessPool:
            # A worker died (e.g. killed by the OS for memory): start a fresh pool, and
            # report the failure of this job.
            if not self._executor.closed:
                self._executor._pool = self._executor._new_pool()
            raise WorkerDied("the reconstruction worker process died") from None


class DaskExecutor:
    """A dask.distributed client connected to a scheduler: reconstructions run on its workers.

    The same ``submit`` / ``run`` / ``close`` as :class:`LocalExecutor`. The workers must see
    the data directory (shared file system).

    Parameters
    ----------
    address : str
        The scheduler's address (e.g. ``"tcp://host:8786"``); connecting waits up to 20 s.

    Attributes
    ----------
    name : str
        ``"dask"``.
    address : str
        As given.
    """

    name = "dask"

    def __init__(self, address: str):
        from distributed import Client

        self.address = address
        self._client = Client(address, set_as_default=False, timeout="20s")

    def submit(self, fn: Callable[..., Any], *args: Any) -> _DaskFuture:
        return _DaskFuture(self._client.submit(fn, *args, pure=False))

    def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self.submit(fn, *args).result()

    def close(self) -> None:
        self._client.close()


class _DaskFuture:
    """A dask future behind the same ``result(timeout)`` as the local one."""

    def __init__(self, future: Any) -> None:  # a distributed.Future
        self._future = future

    def result(self, timeout: float | None = None) -> Any:
        return self._future.result(timeout=timeout)  # raises the builtin TimeoutError


def make_executor(settings: Settings) -> LocalExecutor | DaskExecutor:
    """The executor the settings ask for.

    Parameters
    ----------
    settings : fpscan.service.settings.Settings
        Reads ``executor`` (``"dask"`` or ``"local"``), ``dask_scheduler``, ``workers``,
        ``worker_nice`` and ``warm_up``.

    Returns
    -------
    LocalExecutor or DaskExecutor
        A :class:`DaskExecutor` connected to ``dask_scheduler`` when ``executor`` is
        ``"dask"``, else a :class:`LocalExecutor`.
    """
    if settings.executor == "dask":
        return DaskExecutor(cast(str, settings.dask_scheduler))  # Settings requires one with executor dask
    return LocalExecutor(settings.workers, nice=settings.worker_nice, warm=settings.warm_up)
