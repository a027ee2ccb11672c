"""The reconstruction queue: admits queued jobs under the memory limit and runs them on
the executor, one thread per running job (the thread blocks on the executor, never the
event loop).

Memory admission (DESIGN §7): each job carries its peak-memory estimate (bytes); a job is
started only while the sum of the running jobs' estimates plus its own stays within
``settings.memory_limit`` (the first job in line always may start when nothing runs).
Jobs that can never fit are refused before they are queued (:func:`admit`).

Cancel is cooperative: a running job's result is discarded and the job ends
``cancelled``. Lease and heartbeat: the running thread renews the job's lease every
``settings.heartbeat_s``; after a restart, :meth:`JobStore.recover` re-queues jobs whose
owner is gone.
"""
from __future__ import annotations

import json
import logging
import shutil
import threading
import time
import uuid
from pathlib import Path

from service.jobs.lifecycle import apply_retention
from service.jobs.store import JobStore
from service.jobs.work import run_reconstruction

log = logging.getLogger("fpscan.jobs")


class AdmissionError(ValueError):
    """A job that can never fit in the memory limit."""


def estimate_memory(shape: dict, params: dict) -> int:
    """Peak memory (bytes) of a reconstruction. ``shape``: ``n_t`` and either ``n_x``
    (``n_y``) of the output grid, plus ``n_points`` for point inputs. Uses
    ``service.recon.estimate_peak_memory`` when it accepts these, else a conservative
    count: the mirrored, oversampled complex volume ``2 n_t × n_y × n_x`` (×upsample per
    lateral axis) held three times, plus the input."""
    n_t = int(shape["n_t"])
    n_x = int(shape["n_x"])
    n_y = int(shape.get("n_y", 1))
    up = int(params.get("upsample", 1) or 1)
    item = 8 if params.get("dtype", "float32") == "float32" else 16  # complex
    try:
        from service.recon import estimate_peak_memory

        value = estimate_peak_memory(n_t, n_x, n_y, n_z=params.get("n_z"), upsample=up,
                                     dtype=params.get("dtype", "float32"), method=params.get("method", "ner"),
                                     n_points=shape.get("n_points"))
        return int(value) + n_t * int(shape.get("n_points", n_x * n_y)) * 8  # + the input
    except ImportError:  # recon not installed: our own estimate
        pass
    lateral = n_x * up * (n_y * up if n_y > 1 else 1)
    volume = 2 * n_t * lateral * item
    inp = n_t * int(shape.get("n_points", n_x * n_y)) * 8
    return int(3 * volume + inp)


def admit(estimate: int, limit: int) -> None:
    """Raise :class:`AdmissionError` with the reason if ``estimate`` > ``limit`` bytes."""
    if estimate > limit:
        raise AdmissionError(f"reconstruction needs about {estimate / 2**30:.2f} GiB, more than the "
                             f"memory limit of {limit / 2**30:.2f} GiB; reduce the size or the upsampling")


class ReconQueue:
    """Background dispatcher of ``recon`` jobs."""

    def __init__(self, store: JobStore, executor, settings):
        self.store = store
        self.executor = executor
        self.settings = settings
        self.owner = f"srv-{uuid.uuid4().hex[:12]}"
        self.results_dir = Path(settings.data_dir) / "results"
        self.results_dir.mkdir(parents=True, exist_ok=True)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads: dict[str, threading.Thread] = {}
        self._lock = threading.Lock()
        self._dispatcher = threading.Thread(target=self._loop, name="recon-dispatcher", daemon=True)

    def start(self) -> None:
        self._dispatcher.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        self._dispatcher.join(timeout=5)

    def wake(self) -> None:
        self._wake.set()

    def running(self) -> int:
        with self._lock:
            return sum(t.is_alive() for t in self._threads.values())

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            try:
                self._dispatch()
            except Exception:
                log.exception("recon dispatcher error")

    def _dispatch(self) -> None:
        with self._lock:
            for jid in [j for j, t in self._threads.items() if not t.is_alive()]:
                del self._threads[jid]
            busy = len(self._threads)
        for job in self.store.queued("recon"):
            in_use = self.store.running_memory()
            if busy > 0 and in_use + job["memory_bytes"] > self.settings.memory_limit:
                break  # FIFO: wait for memory
            if busy >= max(self.settings.workers, 1) and self.settings.executor == "local":
                break
            claimed = self.store.claim(job["id"], self.owner, lease_s=self.settings.heartbeat_s * 5)
            if claimed is None:
                continue
            t = threading.Thread(target=self._run, args=(claimed,), name=f"recon-{job['id'][:8]}", daemon=True)
            with self._lock:
                self._threads[job["id"]] = t
            busy += 1
            t.start()

    def _run(self, job: dict) -> None:
        jid = job["id"]
        # one folder per attempt: a worker orphaned by a server crash may still finish the
        # previous attempt, and must not race with this one
        out_dir = self.results_dir / f"{jid}.{job['attempts']}"
        progress_path = self.results_dir / f".{jid}.{job['attempts']}.progress"
        spec = {"input": job["params"]["input"], "params": {**job["params"]["params"], "method": job["params"]["method"]},
                "out_dir": str(out_dir), "input_id": job["params"].get("input_id", ""),
                "progress_path": str(progress_path)}
        self.store.update_progress(jid, {"fraction": 0.0, "stage": "starting"})
        log.info("recon start job=%s attempt=%s method=%s", jid, job["attempts"], spec["params"]["method"])
        t0 = time.perf_counter()
        try:
            summary = self._wait(jid, self.executor.submit(run_reconstruction, spec), progress_path)
        except ValueError as exc:
            self._finish(jid, "failed", error=self.settings.redact(str(exc)))
            log.info("recon failed job=%s reason=%s", jid, exc)
            return
        except Exception as exc:  # worker crash or bug: keep internals in the log only
            log.exception("recon error job=%s", jid)
            self._finish(jid, "failed", error=f"reconstruction failed ({type(exc).__name__})")
            return
        finally:
            progress_path.unlink(missing_ok=True)
            self._wake.set()
        if self.store.get(jid)["cancel_requested"]:
            shutil.rmtree(out_dir, ignore_errors=True)
            self._finish(jid, "cancelled")
            return
        self.store.update_params(jid, {"result": summary})
        self.store.set_state(jid, "succeeded", result_path=str(out_dir), only_from=("running",),
                             progress={"fraction": 1.0, "stage": "done",
                                       "points_done": summary.get("points_used"),
                                       "points_total": summary.get("points_used")})
        log.info("recon done job=%s seconds=%.3f shape=%s", jid, time.perf_counter() - t0, summary.get("shape"))
        try:  # a new result: older ones beyond the retention policy go
            apply_retention(self.store, self.settings)
        except Exception:
            log.exception("retention failed after job=%s", jid)

    def _wait(self, jid: str, future, progress_path: Path):
        """The job's result; meanwhile renew its lease and turn the worker's stage
        reports (:func:`service.jobs.work.report_stage`) into progress events."""
        last, beat = None, time.monotonic()
        while True:
            try:
                return future.result(timeout=0.25)
            except TimeoutError:
                pass
            try:
                stage = json.loads(progress_path.read_text())
            except (OSError, ValueError):
                stage = None
            if stage and stage != last:
                last = stage
                self.store.update_progress(jid, stage)
            if time.monotonic() - beat > self.settings.heartbeat_s:
                beat = time.monotonic()
                self.store.heartbeat(jid, self.owner, self.settings.heartbeat_s * 5)

    def _finish(self, jid: str, state: str, error: str | None = None) -> None:
        self.store.set_state(jid, state, error=error, only_from=("running",),
                             progress={"stage": state})
