"""Scan jobs: drive the configured scanners with the host driver, one thread per port.

A scan job owns its serial port exclusively while it runs. The
:class:`ScanManager` starts queued scan jobs when their scanner is free; each runs
``fpscan.driver.acquire.acquire`` in its own thread (serial I/O never touches the event loop),
writing the job's scan file (``<data_dir>/scans/<job_id>.h5``, a server-chosen name).
Progress (points done, rate, ETA, faults recovered) goes to the job store (and so to the
SSE stream) about twice a second; the live preview (:mod:`fpscan.service.jobs.preview`) follows the
scan file. The queued scans are started by the jobs' one dispatcher
(:class:`fpscan.service.jobs.dispatcher.Dispatcher`): a scan starts when its scanner is free.

Controls: ``pause``/``resume``/``abort`` call the open ``fpscan.driver.host.Scanner`` from the
request thread (the driver queues them for its scan loop). A scan interrupted by a server
restart is ``paused`` (stage ``interrupted``); ``resume`` re-queues it and the driver
continues from the scan file's record of completed points, so no A-line is lost or
acquired twice. A scan paused by a full disk resumes by itself once its scan file fits the
free disk again (and at least ``DISK_FREED_BYTES`` more are free than when it stopped),
looked at every second.
"""
from __future__ import annotations

import errno
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from fpscan.service.disk import durable_mkdir, free_bytes, fsync_tree, is_disk_full
from fpscan.service.jobs.dispatcher import SKIP, START, Dispatcher, Loop, Verdict
from fpscan.service.jobs.preview import PreviewManager, PreviewState
from fpscan.service.jobs.store import TERMINAL, JobStore
from fpscan.service.storage.usage import usage_for

if TYPE_CHECKING:
    from fpscan.driver.host import Scanner, ScanProgress, ScanResult
    from fpscan.service.settings import Settings

log = logging.getLogger("fpscan.scans")


#: Free space (bytes) that must come back on the data folder's disk, beyond what was free
#: when a full disk stopped a scan, before ``/api/health`` stops calling the disk full.
DISK_FREED_BYTES = 1 << 20
#: Seconds between two looks of a running scan at whether the rest of its file fits the disk.
DISK_LOOK_S = 1.0
#: Longest reason kept for an interrupted scan (HDF5's write errors run to many lines).
REASON_CHARS = 300


def _one_line(text: str) -> str:
    """``text`` on one line (whitespace folded), cut to ``REASON_CHARS``."""
    text = " ".join(text.split())
    return text if len(text) <= REASON_CHARS else text[:REASON_CHARS - 1] + "…"


def _missing_device(port: str) -> bool:
    """True for a device path (not a pyserial URL) that does not exist."""
    return "://" not in port and not Path(port).exists()


class _NoRoom(OSError):
    """The rest of a scan file no longer fits its disk (``ScanManager._room_watch``)."""


class _Run:
    def __init__(self, job_id: str, scanner_id: str):
        self.job_id = job_id
        self.scanner_id = scanner_id
        self.scanner: Scanner | None = None  # once open
        self.pending: list[str] = []  # controls asked before the scanner was open
        self.lock = threading.Lock()


class ScanManager:
    """Runs scan jobs on the scanners of ``settings.devices`` (module docstring).

    :meth:`start` starts the live previews, the dispatcher and the full-disk watch;
    :meth:`stop` pauses the running scans (they stay resumable) and stops them. The controls
    :meth:`pause`, :meth:`resume`, :meth:`abort` and :meth:`cancel` are called from request
    threads (``pause`` and ``resume`` raise ValueError for a job that cannot take them).

    Parameters
    ----------
    store : JobStore
        The job store.
    settings : fpscan.service.settings.Settings
        The service settings: ``devices`` (scanner id -> serial port), ``data_dir``,
        ``preview_interval_s``, ...

    Attributes
    ----------
    store : JobStore
        As given.
    settings : fpscan.service.settings.Settings
        As given.
    owner : str
        This manager's lease owner name in the store (``scan-<hex>``).
    scans_dir : pathlib.Path
        ``<data_dir>/scans``, where the scan files are written (created).
    previews : PreviewManager
        The live previews of the running scans.

    Raises
    ------
    ImportError
        When the scanner driver (``fpscan.driver.acquire``) cannot be imported: no scanning.
    """

    def __init__(self, store: JobStore, settings: Settings) -> None:
        import fpscan.driver.acquire  # noqa: F401  (ImportError: no driver → no scanning)

        self.store = store
        self.settings = settings
        self.owner = f"scan-{uuid.uuid4().hex[:12]}"
        self.scans_dir = Path(settings.data_dir) / "scans"
        durable_mkdir(self.scans_dir)  # the folder a scan's success names is on disk too
        self.previews = PreviewManager(settings.preview_interval_s, warm=settings.warm_up)
        self._runs: dict[str, _Run] = {}     # scanner_id -> active run
        self._problems: dict[str, str] = {}  # job id -> why it is interrupted (full disk, ...)
        self._free_at_interrupt: dict[str, int] = {}  # job id -> free bytes when a full disk stopped it
        self._identity: dict[str, str] = {}
        self._lock = threading.Lock()
        self._dispatcher = Dispatcher(store, "scan", owner=self.owner, lease_s=60.0, admit=self._admit,
                                      launch=self._launch, name="scan-dispatcher", log=log)
        self._disk_watch = Loop("scan-disk-watch", self._resume_when_room, period=1.0, log=log)

    # -- lifecycle -----------------------------------------------------------------
    def start(self) -> None:
        self.previews.start()
        self._dispatcher.start()
        self._disk_watch.start()

    def stop(self) -> None:
        self._disk_watch.stop(timeout=5)
        self._dispatcher.stop(timeout=5)  # no scan starts after this
        with self._lock:
            runs = list(self._runs.values())
        for run in runs:  # leave the devices idle; the jobs stay resumable
            with run.lock:
                if run.scanner is not None:
                    try:
                        run.scanner.pause()
                    except Exception:
                        pass
        self.previews.stop()

    def wake(self) -> None:
        self._dispatcher.wake()

    # -- queries ---------------------------------------------------------------------
    def scanners(self) -> list[dict]:
        out = []
        with self._lock:
            for sid, port in self.settings.devices.items():
                run = self._runs.get(sid)
                status = "busy" if run else ("unreachable" if _missing_device(port) else "idle")
                out.append({"id": sid, "port": port, "status": status,
                            "job_id": run.job_id if run else None, "identity": self._identity.get(sid)})
        return out

    def problems(self) -> list[str]:
        """What keeps scans from running now (a full disk, a lost device): one line each,
        for ``/api/health``. A full disk is judged now, not when the scan stopped: once at
        least ``DISK_FREED_BYTES`` more are free on the data folder's disk than then, the line
        says the space is back and the scan waits for a resume (no stale "disk is full")."""
        with self._lock:
            items = list(self._problems.items())
            free_then = dict(self._free_at_interrupt)
        out = []
        for jid, why in items:
            if jid in free_then and ("disk full" in why or "disk is full" in why):
                free_now = free_bytes(self.settings.data_dir)
                if free_now is not None and free_now >= free_then[jid] + DISK_FREED_BYTES:
                    why = "paused by a full disk; space has been freed since: resume it"
            out.append(f"scan {jid}: {why}")
        return out

    def preview(self, job_id: str) -> PreviewState | None:
        return self.previews.get(job_id)

    def _run_of(self, job_id: str) -> _Run | None:
        with self._lock:
            for run in self._runs.values():
                if run.job_id == job_id:
                    return run
        return None

    # -- controls (called from request threads) -------------------------------------
    def _send(self, run: _Run, what: str) -> None:
        from fpscan.driver.host import DriverError

        with run.lock:
            if run.scanner is None or run.pending:
                run.pending.append(what)
                return
            try:
                getattr(run.scanner, what)()
            except DriverError as exc:
                raise ValueError(f"scanner refused {what}: {exc}") from None

    def pause(self, job_id: str) -> None:
        job = self.store.get(job_id)
        if job is None:
            raise ValueError(f"no scan job {job_id}")
        run = self._run_of(job_id)
        if job["state"] == "paused":
            return
        if job["state"] == "queued":
            raise ValueError("scan has not started; cancel it instead")
        if run is None:
            raise ValueError("scan is not running")
        self._send(run, "pause")
        self.store.set_state(job_id, "paused", only_from=("running",), progress={"stage": "paused"})

    def resume(self, job_id: str) -> None:
        job = self.store.get(job_id)
        if job is None:
            raise ValueError(f"no scan job {job_id}")
        if job["state"] in ("running", "queued"):
            return
        run = self._run_of(job_id)
        if run is not None:  # paused in this process: the scanner is waiting
            self._send(run, "resume")
            self.store.set_state(job_id, "running", only_from=("paused",), progress={"stage": "acquiring"})
            return
        # interrupted (restart, lost device, full disk): acquire the missing points in a
        # new run; a cancel asked while it was stuck no longer applies
        if self.store.set_state(job_id, "queued", only_from=("paused",),
                                progress={"stage": "resuming", "reason": None}):
            self.store.clear_cancel(job_id)
            with self._lock:
                self._problems.pop(job_id, None)
                self._free_at_interrupt.pop(job_id, None)
        self.wake()

    def abort(self, job_id: str) -> None:
        run = self._run_of(job_id)
        self.store.request_cancel(job_id)
        if run is not None:
            self._send(run, "abort")

    def cancel(self, job_id: str) -> None:
        """After the store marked a cancel: stop the scanner if the scan is live."""
        run = self._run_of(job_id)
        if run is not None:
            self._send(run, "abort")

    # -- dispatching ---------------------------------------------------------------------
    def _admit(self, job: dict, busy: int) -> Verdict:
        """Start a scan when its scanner is configured and free; else pass over it."""
        sid = job["params"].get("scanner_id")
        with self._lock:
            if sid in self._runs or sid not in self.settings.devices:
                return SKIP
        return START

    def _launch(self, job: dict) -> tuple[str, Callable[[], None]]:
        """The scanner is this job's from now on (controls find its run)."""
        sid = job["params"].get("scanner_id")
        run = _Run(job["id"], sid)
        with self._lock:
            self._runs[sid] = run
        return f"scan-{sid}", lambda: self._execute(job, run)

    def _execute(self, job: dict, run: _Run) -> None:
        jid = job["id"]
        scan_path = Path(job["params"].get("scan_path") or self.scans_dir / f"{jid}.h5")
        usage = usage_for(self.settings.data_dir)
        usage.growing(scan_path)  # /api/health reads its size while it grows
        try:
            self._acquire(job, run)
        except Exception as exc:  # never let a scan thread die silently, nor a job stay running
            log.exception("scan job=%s crashed", jid)
            self._interrupt(jid, f"scan stopped ({type(exc).__name__}: {self.settings.redact(str(exc))})")
        finally:
            usage.grown(scan_path)
            with self._lock:
                self._runs.pop(run.scanner_id, None)
            self.previews.untrack(jid)  # (the dispatcher wakes when this returns)

    def _interrupt(self, jid: str, why: str) -> None:
        """The job to ``paused`` with stage ``interrupted`` and ``why`` (resumable from its
        scan file with ``/resume``: the points on disk are kept). While the job store
        itself cannot write (its disk is full too), retried every second, the reason shown
        by ``/api/health`` meanwhile, so the job never stays ``running``."""
        import sqlite3

        why = _one_line(why)
        free = free_bytes(self.settings.data_dir)
        with self._lock:
            self._problems[jid] = why
            if free is not None:
                self._free_at_interrupt[jid] = free
        while True:
            try:
                self.store.set_state(jid, "paused", only_from=("running", "queued"),
                                     progress={"stage": "interrupted", "reason": why})
                log.warning("scan job=%s interrupted: %s", jid, why)
                with self._lock:  # the job store writes again: its own error is no problem any more
                    if jid in self._problems:
                        self._problems[jid] = why
                return
            except sqlite3.Error as exc:
                with self._lock:
                    self._problems[jid] = f"{why}; job store: {_one_line(str(exc))}"
                if self._dispatcher.wait_stop(1.0):
                    return

    def _resume_when_room(self) -> None:
        """Resume the scans a full disk paused once their scan file fits again (the disk
        watch's tick): its remaining A-lines fit the free disk (:meth:`_disk_shortfall`) and
        at least ``DISK_FREED_BYTES`` more are free than when it stopped."""
        with self._lock:
            waiting = [(jid, free) for jid, free in self._free_at_interrupt.items()
                       if "disk full" in self._problems.get(jid, "") or "disk is full" in self._problems.get(jid, "")]
        for jid, free_then in waiting:
            job = self.store.get(jid)
            if job is None or job["state"] in TERMINAL:  # cancelled or deleted meanwhile
                with self._lock:
                    self._problems.pop(jid, None)
                    self._free_at_interrupt.pop(jid, None)
                continue
            if job["state"] != "paused":  # still being interrupted (its pause not yet written)
                continue
            found = self.store.get_plan(job["params"]["plan_id"])
            if found is None:
                continue
            scan_path = Path(job["params"].get("scan_path") or self.scans_dir / f"{jid}.h5")
            free_now = free_bytes(self.settings.data_dir)
            if free_now is None:
                continue
            if free_now >= free_then + DISK_FREED_BYTES and self._disk_shortfall(found[0], scan_path) is None:
                log.info("scan job=%s: the disk has room again (%d bytes free); resuming", jid, free_now)
                self.resume(jid)

    def _disk_shortfall(self, plan: dict, scan_path: Path) -> str | None:
        """The reason a scan file cannot be completed on its disk (free space below what
        its remaining A-lines need: ``n_points × (2 n_t × n_wavelengths + 128)`` bytes
        less what the file has allocated), or None. The job database's reserve, while it
        is spent (a full disk), does not count as free: it holds the jobs' states."""
        acq = plan["acquisition"]
        n = len(plan["points"]["indices"])
        need = n * (2 * int(acq["n_t"]) * max(1, len(acq.get("wavelengths") or [1])) + 128) + (1 << 20)
        try:
            have = scan_path.stat().st_blocks * 512 if scan_path.exists() else 0
        except OSError:
            return None
        free = free_bytes(scan_path.parent)
        if free is None:
            return None
        if self.store.reserve_spent is not None:
            free = max(0, free - self.store.reserve_bytes)
        if need - have > free:
            return (f"disk full: the scan file needs {need - have} more bytes, {free} are free on the data "
                    "folder's disk; free space, then resume")
        return None

    def _room_watch(self, plan: dict, scan_path: Path) -> Callable[[ScanProgress], None]:
        """A check for the scan's progress reports: every :data:`DISK_LOOK_S`, the rest of the
        scan file must still fit the disk (:meth:`_disk_shortfall`), else it raises
        :class:`_NoRoom` (an ENOSPC ``OSError``): the scan stops as a full disk would stop it,
        before it takes the bytes the job database holds for the jobs' states."""
        last = [time.monotonic()]

        def check(p: ScanProgress) -> None:
            now = time.monotonic()
            if now - last[0] < DISK_LOOK_S or p.state in ("done", "aborted"):
                return
            last[0] = now
            short = self._disk_shortfall(plan, scan_path)
            if short:
                raise _NoRoom(errno.ENOSPC, short)

        return check

    def _acquire_or_interrupt(self, jid: str, run_acquire: Callable[[], ScanResult]) -> ScanResult | None:
        """``run_acquire()``'s result; None when the scan stopped: a bad plan or file fails
        the job, a lost device, a device fault or a disk error pauses it (``_interrupt``:
        resumable)."""
        from fpscan.driver.host import DeviceFault, DriverError

        try:
            return run_acquire()
        except ValueError as exc:  # the plan or the scan file does not fit: not resumable
            log.warning("scan job=%s failed: %s", jid, exc)
            self.store.set_state(jid, "failed", error=self.settings.redact(str(exc)),
                                 only_from=("running", "paused"))
        except _NoRoom as exc:  # the rest of the file no longer fits: resumable, and by itself
            self._interrupt(jid, exc.strerror or "disk full")
        except OSError as exc:  # the disk (ENOSPC, EIO): the points on disk stay resumable
            why = "disk full" if is_disk_full(exc) else "scan file write failed"
            self._interrupt(jid, f"{why}: {self.settings.redact(str(exc))}; free space, then resume")
        except DeviceFault as exc:  # the device sent what no plan allows: it was stopped
            self._interrupt(jid, f"device fault: {self.settings.redact(exc.reason)}; the scanner was "
                                 "stopped, resume to acquire the rest")
        except DriverError as exc:  # the device went away or stopped answering
            self._interrupt(jid, f"device lost: {self.settings.redact(str(exc))}; resume when it is back")
        return None

    def _connect(self, jid: str, port: str, resumed: bool) -> Scanner | None:
        """An open ``fpscan.driver.host.Scanner`` on ``port``, or None: the job failed (nothing
        acquired yet) or, with points on disk, paused until the device is back."""
        from fpscan.driver.host import DriverError, Scanner

        try:
            return Scanner(port)
        except DriverError as exc:
            if resumed:
                self._interrupt(jid, f"device lost: {self.settings.redact(str(exc))}; resume when it is back")
            else:
                self.store.set_state(jid, "failed", error=str(exc), only_from=("running",))
            return None

    def _acquire(self, job: dict, run: _Run) -> None:
        """Acquire the scan of ``job`` on its scanner into its scan file (a resumed scan
        continues the file): the job ends ``succeeded``, ``cancelled`` or ``failed``, or is
        paused (``_interrupt``) when its plan's rest does not fit the disk, the device is
        lost or the file cannot be written."""
        from fpscan.driver.acquire import acquire

        jid = job["id"]
        port = self.settings.devices[run.scanner_id]
        found = self.store.get_plan(job["params"]["plan_id"])
        if found is None:
            self.store.set_state(jid, "failed", error="the plan of this scan is gone", only_from=("running",))
            return
        plan = found[0]
        scan_path = Path(job["params"].get("scan_path") or self.scans_dir / f"{jid}.h5")
        resumed = scan_path.exists()
        short = self._disk_shortfall(plan, scan_path)
        if short:
            self._interrupt(jid, short)
            return
        self.store.update_progress(jid, {"stage": "connecting", "points_total": len(plan["points"]["indices"])})
        scanner = self._connect(jid, port, resumed)
        if scanner is None:
            return
        try:
            self._note_identity(run.scanner_id, scanner)
            with run.lock:
                pending = list(run.pending)
            self.previews.track(jid, str(scan_path),
                                wavelength_index=int(job["params"].get("preview_wavelength", 0)))
            progress = self._progress_reporter(jid, run, scanner, self._room_watch(plan, scan_path))
            self.store.update_progress(jid, {"stage": "resuming" if resumed else "acquiring"})
            if "abort" in pending:  # a control that came before the port was open
                self.store.set_state(jid, "cancelled", only_from=("running", "paused"))
                return
            result = self._acquire_or_interrupt(jid, lambda: acquire(port, plan, scan_path, progress=progress,
                                                                      scanner=scanner))
            if result is None:
                return
        finally:
            with run.lock:
                run.scanner = None
            try:
                scanner.close()
            except Exception:
                pass
        self._finish(jid, result, scan_path)

    def _note_identity(self, scanner_id: str, scanner: Scanner) -> None:
        """Keep what the scanner says it is (``identify``; :meth:`scanners` shows it); a
        scanner that does not say is left as it was."""
        from fpscan.driver.host import DriverError

        try:
            ident = scanner.identify()
            self._identity[scanner_id] = " ".join(str(v) for v in ident.values()) \
                if isinstance(ident, dict) else str(ident)
        except DriverError:
            pass

    def _progress_reporter(self, jid: str, run: _Run, scanner: Scanner,
                           room: Callable[[ScanProgress], None]) -> Callable[[ScanProgress], None]:
        """The scan's progress callback: ``room`` checks the disk; the first report hands the
        controls to the open scanner (the ones asked before are sent then); the live preview
        hears of each report; the job store gets the progress and a heartbeat at most every
        0.5 s, and the last report."""
        last = {"t": 0.0}

        def progress(p: ScanProgress) -> None:
            now = time.monotonic()
            room(p)
            if run.scanner is None or run.pending:
                with run.lock:  # scanning now: controls go straight to the driver
                    run.scanner = scanner
                    todo, run.pending = run.pending, []
                for what in todo:
                    getattr(scanner, what)()
            self.previews.note_progress(jid, p.alines_done)
            if now - last["t"] < 0.5 and p.state not in ("done", "aborted"):
                return
            last["t"] = now
            eta = p.eta_s if math.isfinite(p.eta_s) else None
            stage = {"running": "acquiring"}.get(p.state, p.state)
            self.store.update_progress(jid, {
                "fraction": p.alines_done / max(p.n_alines, 1), "stage": stage,
                "points_done": p.points_done, "points_total": p.n_points,
                "alines_done": p.alines_done, "alines_total": p.n_alines,
                "rate_per_s": p.rate, "eta_s": eta, "faults_recovered": p.faults_recovered})
            self.store.heartbeat(jid, self.owner, 60.0)

        return progress

    def _finish(self, jid: str, result: ScanResult, scan_path: Path) -> None:
        """The job's final state from the acquisition's ``result``: ``cancelled`` when it was
        aborted or a cancel was asked, ``succeeded`` when every point is on disk, else
        ``failed``; the final progress with it. The scan file and the folder naming it are
        flushed to disk first (``fpscan.service.disk.fsync_tree``): the points the final
        state counts survive a power cut."""
        try:
            fsync_tree(scan_path)
        except OSError as exc:  # the disk lost the write: the points are not all on disk
            self._interrupt(jid, f"scan file not flushed to disk: {self.settings.redact(str(exc))}; resume to "
                                 "measure the points it lost")
            return
        final = {"fraction": result.points_done / max(result.n_points, 1), "points_done": result.points_done,
                 "points_total": result.n_points, "faults_recovered": sum(result.faults.values())
                 if isinstance(result.faults, dict) else None,
                 "acquisition_s": result.acquisition_s}
        self.previews.untrack(jid)  # the last refresh shows every point before the job ends
        current = self.store.get(jid)
        if result.aborted or (current and current["cancel_requested"]):
            self.store.set_state(jid, "cancelled", only_from=("running", "paused"), progress={**final, "stage": "aborted"})
        elif result.complete:
            self.store.set_state(jid, "succeeded", only_from=("running", "paused"), progress={**final, "stage": "done"})
        else:
            self.store.set_state(jid, "failed", error=f"scan ended with {result.points_done} of "
                                 f"{result.n_points} points", only_from=("running", "paused"), progress=final)
        log.info("scan done job=%s points=%d/%d seconds=%.2f", jid, result.points_done, result.n_points,
                 result.elapsed_s)


__all__ = ["TERMINAL", "ScanManager"]
