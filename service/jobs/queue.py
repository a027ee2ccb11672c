"""The reconstruction queue: admits queued jobs under the memory limit and runs them on
the executor, one thread per running job (the thread blocks on the executor, never the
event loop).

Memory admission (docs/api.md): each job carries its peak-memory estimate (bytes); a job is
started only while the sum of the running jobs' estimates plus its own stays within
``settings.memory_limit`` (the first job in line always may start when nothing runs).
Jobs that can never fit are refused before they are queued (``fpscan.service.jobs.admission``).

Cancel is cooperative: the job thread creates the job's cancel file, the worker's
``should_stop`` sees it between steps of the reconstruction and stops
(``fpscan.service.pipeline.Cancelled``); a result that was finished anyway is discarded. The job
ends ``cancelled``. Lease and heartbeat: the running thread renews the job's lease every
``settings.heartbeat_s``; after a restart, :meth:`JobStore.recover` re-queues jobs whose
owner is gone.

A full disk fails a job, never strands it. Each job carries the bytes its
result needs (``params["result_bytes"]``, ``fpscan.service.jobs.admission.estimate_result_bytes``):

- a queued job whose result does not fit the free disk (less ``disk_reserve_bytes``, as for
  an upload) when its turn comes ends ``failed`` with "disk full: N bytes free, M needed"
  (the door refuses such a job with 507 up front);
- a running job's thread looks at the free disk every second until its worker writes: once
  the result no longer fits, the job ends ``failed`` with "disk full: N bytes free, M
  needed" at once, and its worker is stopped (cancel file) and its folder removed (the job
  database's reserve, while spent, does not count as free: it holds the jobs' states);
- a worker that meets ENOSPC while writing ends the job the same way;
- progress and heartbeats that cannot be written are skipped; a final state that cannot be
  written (the job database's disk full beyond its reserve, ``JobStore``) is retried every
  second until it is, and ``/api/health`` says so meanwhile; a job thread that fails in any
  other way still ends its job (``failed``, the dispatcher's ``orphaned`` hook).

A success is recorded once the result is on disk: its files, its folder and ``results/``
are flushed (``fpscan.service.disk.fsync_tree``) before the commit that says ``succeeded``.
"""
from __future__ import annotations

import logging
import os
import shutil
import sqlite3
import stat
import threading
import time
import uuid
from collections.abc import Callable, Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from fpscan.service.disk import durable_mkdir, free_bytes, fsync_tree, is_disk_full
from fpscan.service.jobs.dispatcher import SKIP, START, WAIT, Dispatcher, Loop, Verdict
from fpscan.service.jobs.executors import DaskExecutor, LocalExecutor, WorkerDied
from fpscan.service.jobs.lifecycle import apply_retention
from fpscan.service.jobs.store import JobStore
from fpscan.service.jobs.work import ProgressLog, run_reconstruction
from fpscan.service.pipeline import Cancelled
from fpscan.service.recon.methods import get as method_named
from fpscan.service.storage.usage import usage_for

__all__ = [
    "INCOMING", "DISK_LOOK_S", "RESERVE_LOOK_S", "DiskFull", "disk_full_reason", "remove_debris", "ReconQueue",
]

if TYPE_CHECKING:
    from fpscan.service.settings import Settings

log = logging.getLogger("fpscan.jobs")


class _Future(Protocol):
    """What an executor's ``submit`` returns (``fpscan.service.jobs.executors``)."""

    def result(self, timeout: float | None = None) -> Any: ...


#: the data folder's staging area of uploads: ``incoming/<dataset id>/`` until the upload is
#: stored and renamed to ``datasets/<dataset id>/`` (a refused or deduplicated upload leaves
#: ``datasets/`` untouched)
INCOMING = "incoming"


def remove_debris(data_dir: str | Path, older_than: float, known_datasets: Collection[str] | None = None) -> list[str]:
    """Remove what a crash leaves behind and nothing else can.

    That is: fpscan's temporary files and folders at any depth of ``results/`` and
    ``exports/`` (the names its writers give them, ``fpscan.service.disk.is_temp_name``: a
    result folder being written, ``results/<id>.tmp-<pid>-<ns>``; a file or an export's folder
    being written beside its target, ``.<name>.<pid>.<12 hex>.tmp``, also inside a result
    folder or inside another temporary folder), progress and cancel files
    (``results/.*.progress*``, ``results/.*.cancel``) and partial uploads (``incoming/<id>/``,
    where an upload is staged until it is stored, and ``datasets/<id>/`` still holding
    ``upload.bin``, as earlier versions staged them), and, given ``known_datasets``, a
    ``datasets/<id>/`` folder whose id the job store does not hold (the server stopped between
    the upload's move into place and its record's commit: an upload never acknowledged).
    Symbolic links are not followed. A path that is gone meanwhile or cannot be removed is
    skipped (no error).

    Parameters
    ----------
    data_dir : str or pathlib.Path
        The service's data folder.
    older_than : float
        UNIX time (s): only what was last modified before it goes (the start of this process).
    known_datasets : collection of str, optional
        The ids of the datasets the job store holds (None: dataset folders are judged by
        ``upload.bin`` alone).

    Returns
    -------
    list of str
        The names (last path component) of the files and folders removed.
    """
    from fpscan.service.disk import is_temp_name

    data_dir = Path(data_dir)
    candidates = []
    results = data_dir / "results"
    if results.is_dir():
        candidates += [p for p in results.iterdir() if p.name.startswith(".")
                       and (".progress" in p.name or p.name.endswith(".cancel"))]
    for top in (results, data_dir / "exports"):
        if top.is_dir() and not top.is_symlink():
            for folder, dirs, files in os.walk(top, onerror=lambda _: None):
                temps = [name for name in dirs if is_temp_name(name)]
                dirs[:] = [name for name in dirs if name not in temps]  # not walked: removed whole
                candidates += [Path(folder) / name for name in temps + files if is_temp_name(name)]
    datasets = data_dir / "datasets"
    if datasets.is_dir():
        candidates += [p for p in datasets.iterdir() if (p / "upload.bin").exists()
                       or (known_datasets is not None and p.is_dir() and not p.is_symlink()
                           and p.name not in known_datasets)]
    incoming = data_dir / INCOMING
    if incoming.is_dir():
        candidates += list(incoming.iterdir())
    removed = []
    for p in candidates:
        try:
            st = p.lstat()
            if st.st_mtime >= older_than:
                continue
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p.name)
        except OSError:  # gone meanwhile, or not ours to remove
            pass
    return removed


class DiskFull(Exception):
    """A running job's result no longer fits the free disk.

    Parameters
    ----------
    message : str
        The reason the job ends with (:func:`disk_full_reason`).
    """


#: seconds between two looks of a running job's thread at the free disk
DISK_LOOK_S = 1.0
#: seconds between two looks at whether the job database's spent reserve can be written again
RESERVE_LOOK_S = 2.0


def disk_full_reason(free: int | None, needed: int, reserve: int = 0) -> str:
    """The one-line reason a job ends with on a full disk: ``"disk full: N bytes free, M
    needed ..."``.

    Parameters
    ----------
    free : int or None
        Free bytes on the data folder's disk; None: unknown (said as "an unknown number of").
    needed : int
        Bytes the result needs (``params["result_bytes"]``).
    reserve : int, optional
        Bytes of those kept free (``disk_reserve_bytes``), named when not 0; default 0.

    Returns
    -------
    str
        The reason, ending with what to do (free space, then submit again).
    """
    shown = "an unknown number of" if free is None else str(int(free))
    kept = f" ({int(reserve)} of them kept in reserve, disk_reserve_bytes)" if reserve else ""
    return (f"disk full: {shown} bytes free{kept}, {int(needed)} needed for the result on the data folder's "
            "disk; free space, then submit the reconstruction again")


class ReconQueue:
    """Background dispatcher of ``recon`` jobs (a :class:`fpscan.service.jobs.dispatcher.Dispatcher`
    admitting them under the memory limit, FIFO, and the free disk; module docstring).

    :meth:`start` starts the dispatcher and the watch of the job database's reserve,
    :meth:`stop` stops them; :meth:`join` waits for the job threads.

    Parameters
    ----------
    store : JobStore
        The job database the jobs are taken from and their states written to.
    executor : object
        Runs a job's ``run_reconstruction(spec)``: its ``submit`` returns a future
        (``fpscan.service.jobs.executors``; a dead worker raises ``WorkerDied``).
    settings : object
        The server's settings: ``data_dir``, ``memory_limit`` (bytes), ``workers``,
        ``executor`` (``"local"``: at most ``workers`` jobs run), ``heartbeat_s`` (s),
        ``disk_reserve_bytes``, ``time_limit_s`` (s), ``max_attempts`` and ``redact``.

    Attributes
    ----------
    store : JobStore
        As given.
    executor : object
        As given.
    settings : object
        As given.
    owner : str
        This server's name on the jobs it runs (``"srv-<12 hex digits>"``, the lease's owner).
    results_dir : pathlib.Path
        ``<data_dir>/results``, created if missing: one folder ``<job id>.<attempt>`` a result.
    """

    def __init__(self, store: JobStore, executor: LocalExecutor | DaskExecutor, settings: Settings) -> None:
        self.store = store
        self.executor = executor
        self.settings = settings
        self.owner = f"srv-{uuid.uuid4().hex[:12]}"
        self.results_dir = Path(settings.data_dir) / "results"
        durable_mkdir(self.results_dir)  # the folder a result's success names is on disk too
        self._problems: dict[str, str] = {}  # job id -> what keeps it from running or ending
        self._problems_lock = threading.Lock()
        self._dispatcher = Dispatcher(store, "recon", owner=self.owner, lease_s=settings.heartbeat_s * 5,
                                      admit=self._admit, launch=self._launch, name="recon-dispatcher", log=log,
                                      orphaned=self._orphaned)
        # the job database's reserve, spent on a full disk, written again once there is room
        self._reserve_watch = Loop("store-reserve", store.restore_reserve, period=RESERVE_LOOK_S, log=log)

    def start(self) -> None:
        self._dispatcher.start()
        self._reserve_watch.start()

    def stop(self) -> None:
        self._reserve_watch.stop(timeout=5)
        self._dispatcher.stop(timeout=5)

    def join(self, timeout: float = 10.0) -> None:
        """Wait (up to ``timeout`` s in all) for the job threads to finish: after the
        executor is closed, they re-queue their jobs (shutdown)."""
        self._dispatcher.join(timeout)

    def wake(self) -> None:
        self._dispatcher.wake()

    def running(self) -> int:
        return self._dispatcher.running()

    def problems(self) -> list[str]:
        """What keeps reconstructions from running or ending now, one line each (``/api/health``)."""
        with self._problems_lock:
            return [f"reconstruction {jid}: {why}" for jid, why in self._problems.items()]

    def _problem(self, jid: str, why: str | None) -> None:
        with self._problems_lock:
            if why is None:
                self._problems.pop(jid, None)
            else:
                self._problems[jid] = why

    def _free_bytes(self) -> int | None:
        """Free bytes of the results' disk for results: less the job database's reserve
        while it is spent (those bytes are the database's, for the jobs' states)."""
        free = free_bytes(self.results_dir)
        if free is None:
            return None
        return max(0, free - (self.store.reserve_bytes if self.store.reserve_spent is not None else 0))

    def _admit(self, job: dict, busy: int) -> Verdict:
        """Start ``job`` while the running jobs' memory estimates plus its own fit the limit
        (the first always may when nothing runs) and, on the local pool, a worker is free,
        else hold it and the jobs behind it (FIFO); a job whose result does not fit the free
        disk ends ``failed`` with the reason (never waiting without end)."""
        in_use = self.store.running_memory()
        if busy > 0 and in_use + job["memory_bytes"] > self.settings.memory_limit:
            return WAIT  # FIFO: wait for memory
        if busy >= max(self.settings.workers, 1) and self.settings.executor == "local":
            return WAIT
        needed = int(job["params"].get("result_bytes") or 0)
        free = self._free_bytes() if needed else None
        reserve = int(self.settings.disk_reserve_bytes)
        if free is not None and free - reserve < needed:
            why = disk_full_reason(free, needed, reserve)
            try:
                if self.store.set_state(job["id"], "failed", error=why, only_from=("queued",),
                                        progress={"stage": "failed"}):
                    log.warning("recon failed job=%s before it started: %s", job["id"], why)
            except sqlite3.Error as exc:  # the job database's disk too: the next round tries again
                log.warning("recon job=%s: its failure not written: %s", job["id"], exc)
            return SKIP
        return START

    def _launch(self, job: dict) -> tuple[str, Callable[[], None]]:
        return f"recon-{job['id'][:8]}", lambda: self._run(job)

    def _extras(self, job: dict) -> dict:
        """The worker spec's parts some jobs have: a multi-wavelength unmixing job's
        (``unmix``, ``inputs``, ``wavelengths``: fpscan.service.spectral) and a dense dataset sampled by
        a stored plan's mask (``plan``, its JSON: fpscan.service.subsample; None where it is gone)."""
        out = {key: job["params"][key] for key in ("unmix", "inputs", "wavelengths")
               if job["params"].get(key) is not None}
        plan_id = (job["params"]["input"] or {}).get("plan_id")
        if plan_id is not None:
            out["plan"] = self.store.get_plan_text(plan_id)
        return out

    def _run(self, job: dict) -> None:
        jid = job["id"]
        # one folder per attempt: a worker orphaned by a server crash may still finish the
        # previous attempt, and must not race with this one
        out_dir = self.results_dir / f"{jid}.{job['attempts']}"
        progress_path = self.results_dir / f".{jid}.{job['attempts']}.progress"
        cancel_path = self.results_dir / f".{jid}.{job['attempts']}.cancel"
        # the method's own options, as its model dumped them at submission
        params = {**job["params"]["params"], "method": job["params"]["method"]}
        if method_named(params["method"]).time_limited:  # the server's wall-time limit: the default and the most
            cap = float(self.settings.time_limit_s)
            params["time_limit"] = min(float(params.get("time_limit") or cap), cap)
        spec = {"input": job["params"]["input"], "params": params,
                "out_dir": str(out_dir), "input_id": job["params"].get("input_id", ""),
                "progress_path": str(progress_path), "memory_limit": int(self.settings.memory_limit),
                "memory_estimate": job["params"].get("memory_estimate"),  # made once, at submission
                "cancel_path": str(cancel_path)}
        spec.update(self._extras(job))
        needed = int(job["params"].get("result_bytes") or 0)
        self._progress(jid, {"fraction": 0.0, "stage": "starting"})
        log.info("recon start job=%s attempt=%s method=%s", jid, job["attempts"], spec["params"]["method"])
        t0 = time.perf_counter()
        future = None
        try:
            future = self.executor.submit(run_reconstruction, spec)
            summary = self._wait(jid, future, progress_path, cancel_path, needed)
        except Cancelled:
            shutil.rmtree(out_dir, ignore_errors=True)
            self._finish(jid, "cancelled")
            log.info("recon cancelled job=%s", jid)
            return
        except DiskFull as exc:  # ended at once; its worker stops at its next step, its folder goes
            self._finish(jid, "failed", error=str(exc))
            log.warning("recon failed job=%s: %s", jid, exc)
            self._drain(future, out_dir)
            return
        except ValueError as exc:
            self._finish(jid, "failed", error=self.settings.redact(str(exc)))
            log.info("recon failed job=%s reason=%s", jid, exc)
            return
        except WorkerDied as exc:
            if self._dispatcher.stopping:  # shutdown (SIGTERM) killed the worker: not the job's fault
                self._record(jid, lambda: self.store.requeue(jid, "server shutting down", count_attempt=False))
                log.info("recon requeued job=%s (shutdown)", jid)
            elif job["attempts"] < self.settings.max_attempts:
                self._record(jid, lambda: self.store.requeue(jid, "the worker process died"))
                log.warning("recon requeued job=%s (worker died, attempt %s)", jid, job["attempts"])
            else:
                self._finish(jid, "failed", error=f"{exc} ({job['attempts']} attempts)")
            return
        except Exception as exc:  # worker crash or bug: keep internals in the log only
            if is_disk_full(exc):  # the server's condition: say so (the input is intact)
                shutil.rmtree(out_dir, ignore_errors=True)
                log.warning("recon failed job=%s: disk full: %s", jid, exc)
                self._finish(jid, "failed", error=disk_full_reason(self._free_bytes(), needed))
                return
            log.exception("recon error job=%s", jid)
            self._finish(jid, "failed", error=f"reconstruction failed ({type(exc).__name__})")
            return
        finally:
            progress_path.unlink(missing_ok=True)
            cancel_path.unlink(missing_ok=True)
            self._dispatcher.wake()
        now = self.store.get(jid)
        if now is None or now["cancel_requested"]:  # cancelled (or deleted) meanwhile
            shutil.rmtree(out_dir, ignore_errors=True)
            self._finish(jid, "cancelled")
            return
        try:  # acknowledged means on disk: its files, its folder, results/, then the commit
            fsync_tree(out_dir)
        except OSError as exc:  # the disk lost the write (EIO): no success recorded for it
            shutil.rmtree(out_dir, ignore_errors=True)
            log.warning("recon failed job=%s: result not flushed to disk: %s", jid, exc)
            self._finish(jid, "failed", error=f"the result could not be flushed to disk ({exc.strerror or exc})")
            return
        usage_for(self.settings.data_dir).add_path(out_dir)  # /api/health's counters

        def succeed() -> None:  # one flush of the job database: the state's commit flushes the result's with it
            self.store.update_params(jid, {"result": summary}, durable=False)
            self.store.set_state(jid, "succeeded", result_path=str(out_dir), only_from=("running",),
                                 progress={"fraction": 1.0, "stage": "done",
                                           "points_done": summary.get("points_used"),
                                           "points_total": summary.get("points_used")})

        self._record(jid, succeed)
        log.info("recon done job=%s seconds=%.3f shape=%s%s", jid, time.perf_counter() - t0, summary.get("shape"),
                 f" {summary['outcome']}" if summary.get("outcome") else "")  # how an iterative method ended
        try:  # a new result: older ones beyond the retention policy go
            apply_retention(self.store, self.settings)
        except Exception:
            log.exception("retention failed after job=%s", jid)

    def _wait(self, jid: str, future: _Future, progress_path: Path, cancel_path: Path, needed: int = 0) -> dict:
        """The job's result; meanwhile renew its lease, turn the worker's stage reports
        (:func:`fpscan.service.jobs.work.report_stage`, read with :class:`ProgressLog`) into
        progress events, the last ones once the worker has returned, and, once the job's
        cancellation is requested, create ``cancel_path`` (the worker's ``should_stop``).
        Until the worker writes, look at the free disk every :data:`DISK_LOOK_S`: raise
        :class:`DiskFull` (the worker told to stop) once ``needed`` bytes no longer fit."""
        stages, beat, look = ProgressLog(progress_path), time.monotonic(), 0.0
        writing = False
        while True:
            try:
                result, done = future.result(timeout=0.25), True
            except TimeoutError:
                done = False
            for stage in stages.new():
                writing = writing or stage.get("stage") == "writing"
                self._progress(jid, stage)
            if done:
                return result
            if needed and not writing and time.monotonic() - look >= DISK_LOOK_S:
                look = time.monotonic()
                free = self._free_bytes()
                if free is not None and free < needed:
                    self._stop_worker(cancel_path)
                    raise DiskFull(disk_full_reason(free, needed))
            if not cancel_path.exists() and (self.store.get(jid) or {}).get("cancel_requested"):
                self._stop_worker(cancel_path)
            if time.monotonic() - beat > self.settings.heartbeat_s:
                beat = time.monotonic()
                try:
                    self.store.heartbeat(jid, self.owner, self.settings.heartbeat_s * 5)
                except sqlite3.Error as exc:  # the job database's disk: the lease waits for the next beat
                    log.warning("recon job=%s heartbeat not written: %s", jid, exc)

    @staticmethod
    def _stop_worker(cancel_path: Path) -> None:
        """Ask the worker to stop (its ``should_stop`` sees the file)."""
        try:
            cancel_path.touch()
        except OSError:  # best effort: the job then ends when its step returns
            pass

    def _drain(self, future: _Future | None, out_dir: Path) -> None:
        """Wait for a worker told to stop (a job already ended), then remove its folder."""
        if future is not None:
            try:
                future.result()
            except BaseException:  # the job has ended; how its worker stopped does not matter
                pass
        shutil.rmtree(out_dir, ignore_errors=True)

    def _progress(self, jid: str, progress: dict) -> None:
        """Record a progress event; one that cannot be written (the job database's disk
        full) is skipped: progress is best effort, the job's end is not."""
        try:
            self.store.update_progress(jid, progress)
        except sqlite3.Error as exc:
            log.warning("recon job=%s progress not written: %s", jid, exc)

    def _record(self, jid: str, write: Callable[[], object]) -> None:
        """``write()`` a job's state change, retried every second while the job database
        cannot write (its disk full beyond its reserve), said by :meth:`problems`
        meanwhile, until it is written or the server stops (a restart recovers the job)."""
        while True:
            try:
                write()
                self._problem(jid, None)
                return
            except sqlite3.Error as exc:
                self._problem(jid, f"its end cannot be recorded ({' '.join(str(exc).split())}); free space on "
                                   "the data folder's disk")
                log.warning("recon job=%s state not written, retrying: %s", jid, exc)
                if self._dispatcher.wait_stop(1.0):
                    return

    def _finish(self, jid: str, state: str, error: str | None = None) -> None:
        self._record(jid, lambda: self.store.set_state(jid, state, error=error, only_from=("running",),
                                                       progress={"stage": state}))

    def _orphaned(self, jid: str, exc: BaseException) -> None:
        """A job thread that failed outside its own handling: its job still ends (failed)."""
        self._finish(jid, "failed", error=f"reconstruction failed (internal error: {type(exc).__name__})")
