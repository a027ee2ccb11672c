"""The one dispatch loop of the job runners: reconstructions (:mod:`fpscan.service.jobs.queue`),
scans (:mod:`fpscan.service.jobs.scan_manager`) and the live previews of scans (:mod:`fpscan.service.jobs.preview`).

:class:`Loop` is a background thread that calls its ``tick`` when woken (:meth:`Loop.wake`)
and at the latest every ``period`` seconds, logs whatever a tick raises and carries on, and
ends on :meth:`Loop.stop` (no tick runs once the stop is asked).

:class:`Dispatcher` is the loop whose tick starts the queued jobs of one kind of the job
store, oldest first. For each queued job its runner's ``admit(job, running)`` (``running``:
the dispatcher's job threads alive now, the ones it started in this tick included) answers

- :data:`START`: lease the job (:meth:`fpscan.service.jobs.store.JobStore.claim`, ``lease_s``) and
  run it in a thread of its own: ``launch(job)`` (called in the dispatcher's thread, right
  after the claim) gives the thread's name and body;
- :data:`SKIP`: leave it queued and look at the next one (a scan whose scanner is busy);
- :data:`WAIT`: leave it and every later job queued (FIFO: a reconstruction waiting for
  memory holds the ones behind it).

A job that another server claimed meanwhile (or that was cancelled) is passed over. When a
job's body ends, the dispatcher wakes (its memory or its scanner is free again). The body
keeps its lease alive itself (``JobStore.heartbeat``) and decides how the job ends.

Examples
--------
>>> import tempfile, threading
>>> from pathlib import Path
>>> from fpscan.service.jobs.store import JobStore
>>> store = JobStore(Path(tempfile.mkdtemp()) / "jobs.sqlite")
>>> job, _ = store.create_job("recon", {"method": "ner"})
>>> ran = threading.Event()
>>> def body(job):
...     store.set_state(job["id"], "succeeded", only_from=("running",))
...     ran.set()
>>> d = Dispatcher(store, "recon", owner="doc", lease_s=30.0, admit=lambda job, running: START,
...                launch=lambda job: (f"doc-{job['id'][:8]}", lambda: body(job)), name="doc-dispatcher")
>>> d.start(); d.wake()
>>> ran.wait(10)
True
>>> d.stop(); d.join()
>>> store.get(job["id"])["state"]
'succeeded'
>>> store.close()
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Literal

from fpscan.service.jobs.store import JobStore

__all__ = ["START", "SKIP", "WAIT", "Verdict", "Loop", "Dispatcher"]

_LOG = logging.getLogger("fpscan.jobs")

#: ``admit``'s answers: start the job now, pass over it, or hold it and every later one
START: Literal["start"] = "start"
SKIP: Literal["skip"] = "skip"
WAIT: Literal["wait"] = "wait"
Verdict = Literal["start", "skip", "wait"]


class Loop:
    """A daemon thread named ``name`` calling ``tick()`` on :meth:`wake` and at least every
    ``period`` seconds (s); what ``tick`` raises is logged (``log``) and the loop goes on.

    Parameters
    ----------
    name : str
        The thread's name, also in the log line of a failed tick.
    tick : callable
        ``tick()``, the work of one round.
    period : float
        The longest wait between two ticks (s), > 0.
    log : logging.Logger, optional
        Where a failed tick is logged (default ``fpscan.jobs``).

    Raises
    ------
    ValueError
        When ``period`` is not a positive number.
    """

    def __init__(self, name: str, tick: Callable[[], Any], *, period: float = 0.5,
                 log: logging.Logger | None = None) -> None:
        if not float(period) > 0:
            raise ValueError(f"a loop's period must be > 0 s, got {period!r}")
        self.name = name
        self.period = float(period)
        self._tick = tick
        self._log = log if log is not None else _LOG
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)

    def start(self) -> None:
        """Start the thread (the first tick comes after ``period`` s, or on :meth:`wake`)."""
        self._thread.start()

    def wake(self) -> None:
        """Tick now (soon: after the tick running, if one is)."""
        self._wake.set()

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the loop to end and wait up to ``timeout`` s for its thread (a tick running
        finishes first; none starts after)."""
        self._stop.set()
        self._wake.set()
        if self._thread.ident is not None:  # started
            self._thread.join(timeout=timeout)

    @property
    def stopping(self) -> bool:
        """True once :meth:`stop` was asked."""
        return self._stop.is_set()

    def wait_stop(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for a stop; True when it was asked."""
        return self._stop.wait(timeout)

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.period)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self._tick()
            except Exception:
                self._log.exception("%s error", self.name)


class Dispatcher(Loop):
    """The loop that starts queued jobs of ``kind`` (see the module doc).

    Parameters
    ----------
    store : JobStore
        The job store the jobs are read from and claimed in.
    kind : str
        The job kind dispatched (``"recon"``, ``"scan"``).
    owner : str
        The lease owner written by the claim (this server's runner).
    lease_s : float
        The lease a claim gives (s); the job's body renews it.
    admit : callable
        ``admit(job, running) -> START | SKIP | WAIT`` for each queued job, oldest first.
    launch : callable
        ``launch(job) -> (thread_name, body)`` for a claimed job (the store's row after the
        claim: state ``running``, ``attempts`` counted); ``body()`` runs in the job's thread.
    name : str
        The loop thread's name.
    period, log
        As for :class:`Loop`.
    orphaned : callable, optional
        ``orphaned(job_id, exc)``, called in the job's thread when its body raised: the body
        decides how its job ends, and this ends it when the body could not (a job is never
        left ``running`` without a thread).
    """

    def __init__(self, store: JobStore, kind: str, *, owner: str, lease_s: float,
                 admit: Callable[[dict, int], Verdict], launch: Callable[[dict], tuple[str, Callable[[], Any]]],
                 name: str, period: float = 0.5, log: logging.Logger | None = None,
                 orphaned: Callable[[str, BaseException], Any] | None = None) -> None:
        super().__init__(name, self.dispatch, period=period, log=log)
        self.store = store
        self.kind = kind
        self.owner = owner
        self.lease_s = float(lease_s)
        self._admit = admit
        self._launch = launch
        self._orphaned = orphaned
        self._threads: dict[str, threading.Thread] = {}
        self._lock = threading.Lock()

    def running(self) -> int:
        """The job threads alive now."""
        with self._lock:
            return sum(t.is_alive() for t in self._threads.values())

    def join(self, timeout: float = 10.0) -> None:
        """Wait (up to ``timeout`` s in all) for the job threads to end."""
        deadline = time.monotonic() + timeout
        with self._lock:
            threads = list(self._threads.values())
        for t in threads:
            t.join(max(0.0, deadline - time.monotonic()))

    def dispatch(self) -> None:
        """One round: start the queued jobs ``admit`` lets start (the loop's tick)."""
        with self._lock:
            for jid in [j for j, t in self._threads.items() if not t.is_alive()]:
                del self._threads[jid]
            busy = len(self._threads)
        for job in self.store.queued(self.kind):
            verdict = self._admit(job, busy)
            if verdict == WAIT:
                break
            if verdict != START:
                continue
            claimed = self.store.claim(job["id"], self.owner, lease_s=self.lease_s)
            if claimed is None:  # another server took it, or it was cancelled meanwhile
                continue
            thread_name, body = self._launch(claimed)
            t = threading.Thread(target=self._run, args=(claimed["id"], body), name=thread_name, daemon=True)
            with self._lock:
                self._threads[claimed["id"]] = t
            busy += 1
            t.start()

    def _run(self, job_id: str, body: Callable[[], Any]) -> None:
        try:
            body()
        except Exception as exc:  # a body decides how its job ends; this is a bug in it
            self._log.exception("%s: job=%s ended with an error", self.name, job_id)
            if self._orphaned is not None:
                try:
                    self._orphaned(job_id, exc)
                except Exception:  # logged; the restart's recovery is the last resort
                    self._log.exception("%s: job=%s could not be ended", self.name, job_id)
        finally:
            self.wake()  # its memory, its scanner are free again
