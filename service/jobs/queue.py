"""The reconstruction queue: admits queued jobs under the memory limit and runs them on
the executor, one thread per running job (the thread blocks on the executor, never the
event loop).

Memory admission (DESIGN §7): each job carries its peak-memory estimate (bytes); a job is
started only while the sum of the running jobs' estimates plus its own stays within
``settings.memory_limit`` (the first job in line always may start when nothing runs).
Jobs that can never fit are refused before they are queued (``service.jobs.admission``).

Cancel is cooperative: the job thread creates the job's cancel file, the worker's
``should_stop`` sees it between steps of the reconstruction and stops
(``service.pipeline.Cancelled``); a result that was finished anyway is discarded. The job
ends ``cancelled``. Lease and heartbeat: the running thread renews the job's lease every
``settings.heartbeat_s``; after a restart, :meth:`JobStore.recover` re-queues jobs whose
owner is gone.
"""
from __future__ import annotations

import logging
import shutil
import time
import uuid
from collections.abc import Callable
from pathlib import Path

from service.disk import is_disk_full
from service.jobs.dispatcher import START, WAIT, Dispatcher, Verdict
from service.jobs.executors import WorkerDied
from service.jobs.lifecycle import apply_retention
from service.jobs.store import JobStore
from service.jobs.work import ProgressLog, run_reconstruction
from service.names import code_names, person_names
from service.pipeline import Cancelled

__all__ = [
    "INCOMING", "remove_debris", "ReconQueue",
]

log = logging.getLogger("fpscan.jobs")


#: the data folder's staging area of uploads: ``incoming/<dataset id>/`` until the upload is
#: stored and renamed to ``datasets/<dataset id>/`` (a refused or deduplicated upload leaves
#: ``datasets/`` untouched)
INCOMING = "incoming"


def remove_debris(data_dir: str | Path, older_than: float) -> list[str]:
    """Remove what a crash leaves behind and nothing else can: temporary result folders
    (``results/*.tmp-*``), progress and cancel files (``results/.*.progress*``,
    ``results/.*.cancel``) and partial uploads (``incoming/<id>/``, where an upload is
    staged until it is stored, and ``datasets/<id>/`` still holding ``upload.bin``, as
    earlier versions staged them), if last modified before ``older_than`` (UNIX time:
    the start of this process). Returns the names removed."""
    data_dir = Path(data_dir)
    candidates = []
    results = data_dir / "results"
    if results.is_dir():
        candidates += [p for p in results.iterdir() if ".tmp-" in p.name
                       or (p.name.startswith(".") and (".progress" in p.name or p.name.endswith(".cancel")))]
    datasets = data_dir / "datasets"
    if datasets.is_dir():
        candidates += [p for p in datasets.iterdir() if (p / "upload.bin").exists()]
    incoming = data_dir / INCOMING
    if incoming.is_dir():
        candidates += list(incoming.iterdir())
    removed = []
    for p in candidates:
        try:
            if p.stat().st_mtime >= older_than:
                continue
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p.name)
        except OSError:  # gone meanwhile, or not ours to remove
            pass
    return removed


class ReconQueue:
    """Background dispatcher of ``recon`` jobs (a :class:`service.jobs.dispatcher.Dispatcher`
    admitting them under the memory limit, FIFO)."""

    def __init__(self, store: JobStore, executor, settings):
        self.store = store
        self.executor = executor
        self.settings = settings
        self.owner = f"srv-{uuid.uuid4().hex[:12]}"
        self.results_dir = Path(settings.data_dir) / "results"
        self.results_dir.mkdir(parents=True, exist_ok=True)
        self._dispatcher = Dispatcher(store, "recon", owner=self.owner, lease_s=settings.heartbeat_s * 5,
                                      admit=self._admit, launch=self._launch, name="recon-dispatcher", log=log)

    def start(self) -> None:
        self._dispatcher.start()

    def stop(self) -> None:
        self._dispatcher.stop(timeout=5)

    def join(self, timeout: float = 10.0) -> None:
        """Wait (up to ``timeout`` s in all) for the job threads to finish: after the
        executor is closed, they re-queue their jobs (shutdown)."""
        self._dispatcher.join(timeout)

    def wake(self) -> None:
        self._dispatcher.wake()

    def running(self) -> int:
        return self._dispatcher.running()

    def _admit(self, job: dict, busy: int) -> Verdict:
        """Start ``job`` while the running jobs' memory estimates plus its own fit the limit
        (the first always may when nothing runs) and, on the local pool, a worker is free;
        else hold it and the jobs behind it (FIFO)."""
        in_use = self.store.running_memory()
        if busy > 0 and in_use + job["memory_bytes"] > self.settings.memory_limit:
            return WAIT  # FIFO: wait for memory
        if busy >= max(self.settings.workers, 1) and self.settings.executor == "local":
            return WAIT
        return START

    def _launch(self, job: dict) -> tuple[str, Callable[[], None]]:
        return f"recon-{job['id'][:8]}", lambda: self._run(job)

    def _run(self, job: dict) -> None:
        jid = job["id"]
        # one folder per attempt: a worker orphaned by a server crash may still finish the
        # previous attempt, and must not race with this one
        out_dir = self.results_dir / f"{jid}.{job['attempts']}"
        progress_path = self.results_dir / f".{jid}.{job['attempts']}.progress"
        cancel_path = self.results_dir / f".{jid}.{job['attempts']}.cancel"
        # stored as a person reads them (sound_speed; an older server's c too): the library's names here
        params = {**code_names(job["params"]["params"]), "method": job["params"]["method"]}
        if params["method"] == "tv":  # the operator's wall-time limit: the default, and the most one may ask
            cap = float(self.settings.tv_time_limit_s)
            params["time_limit"] = min(float(params.get("time_limit") or cap), cap)
        spec = {"input": job["params"]["input"], "params": params,
                "out_dir": str(out_dir), "input_id": job["params"].get("input_id", ""),
                "progress_path": str(progress_path), "memory_limit": int(self.settings.memory_limit),
                "memory_estimate": job["params"].get("memory_estimate"),  # made once, at submission
                "cancel_path": str(cancel_path)}
        for key in ("unmix", "inputs", "wavelengths"):  # a multi-wavelength unmixing job (service.spectral)
            if job["params"].get(key) is not None:
                spec[key] = job["params"][key]
        self.store.update_progress(jid, {"fraction": 0.0, "stage": "starting"})
        log.info("recon start job=%s attempt=%s method=%s", jid, job["attempts"], spec["params"]["method"])
        t0 = time.perf_counter()
        try:
            summary = self._wait(jid, self.executor.submit(run_reconstruction, spec), progress_path, cancel_path)
        except Cancelled:
            shutil.rmtree(out_dir, ignore_errors=True)
            self._finish(jid, "cancelled")
            log.info("recon cancelled job=%s", jid)
            return
        except ValueError as exc:
            self._finish(jid, "failed", error=self.settings.redact(str(exc)))
            log.info("recon failed job=%s reason=%s", jid, exc)
            return
        except WorkerDied as exc:
            if self._dispatcher.stopping:  # shutdown (SIGTERM) killed the worker: not the job's fault
                self.store.requeue(jid, "server shutting down", count_attempt=False)
                log.info("recon requeued job=%s (shutdown)", jid)
            elif job["attempts"] < self.settings.max_attempts:
                self.store.requeue(jid, "the worker process died")
                log.warning("recon requeued job=%s (worker died, attempt %s)", jid, job["attempts"])
            else:
                self._finish(jid, "failed", error=f"{exc} ({job['attempts']} attempts)")
            return
        except Exception as exc:  # worker crash or bug: keep internals in the log only
            if is_disk_full(exc):  # the server's condition: say so (the input is intact)
                log.warning("recon failed job=%s: disk full: %s", jid, exc)
                self._finish(jid, "failed", error="the data folder's disk is full (no room for the result); "
                                                  "free space, then submit the reconstruction again")
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
        self.store.update_params(jid, {"result": person_names(summary)})
        self.store.set_state(jid, "succeeded", result_path=str(out_dir), only_from=("running",),
                             progress={"fraction": 1.0, "stage": "done",
                                       "points_done": summary.get("points_used"),
                                       "points_total": summary.get("points_used")})
        log.info("recon done job=%s seconds=%.3f shape=%s%s", jid, time.perf_counter() - t0, summary.get("shape"),
                 f" {summary['outcome']}" if summary.get("outcome") else "")  # how an iterative method ended
        try:  # a new result: older ones beyond the retention policy go
            apply_retention(self.store, self.settings)
        except Exception:
            log.exception("retention failed after job=%s", jid)

    def _wait(self, jid: str, future, progress_path: Path, cancel_path: Path):
        """The job's result; meanwhile renew its lease, turn the worker's stage reports
        (:func:`service.jobs.work.report_stage`, read with :class:`ProgressLog`) into
        progress events, the last ones once the worker has returned, and, once the job's
        cancellation is requested, create ``cancel_path`` (the worker's ``should_stop``)."""
        stages, beat = ProgressLog(progress_path), time.monotonic()
        while True:
            try:
                result, done = future.result(timeout=0.25), True
            except TimeoutError:
                done = False
            for stage in stages.new():
                self.store.update_progress(jid, stage)
            if done:
                return result
            if not cancel_path.exists() and (self.store.get(jid) or {}).get("cancel_requested"):
                try:
                    cancel_path.touch()
                except OSError:  # best effort: the job then ends when its step returns
                    pass
            if time.monotonic() - beat > self.settings.heartbeat_s:
                beat = time.monotonic()
                self.store.heartbeat(jid, self.owner, self.settings.heartbeat_s * 5)

    def _finish(self, jid: str, state: str, error: str | None = None) -> None:
        self.store.set_state(jid, state, error=error, only_from=("running",),
                             progress={"stage": state})
