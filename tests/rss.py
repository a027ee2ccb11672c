"""Resident memory of the processes a test starts, read from Linux's ``/proc`` (proc(5):
``/proc/PID/status``'s ``VmRSS``, the resident set now, and ``VmHWM``, its peak; writing ``5`` to
``/proc/PID/clear_refs`` resets that peak to the resident set now).

- ``resident(pid)``: a process's resident set (bytes); ``resident()`` this process's own. A child
  started as ``python -c`` with ``cwd=ROOT`` reports its own with ``from tests.rss import resident``.
- ``session_processes(sid)``: the processes of a session (a server started by
  ``fpscan.clients.processes.start_service`` leads its own; every process it starts stays in it).
- ``RssWatch``: a thread that records the resident-set growth of one process, or of every process
  of a session, over a base while a block runs, and that can end a process at a bound (a test of a
  memory bound fails instead of taking the machine's memory) and say so (``check``).
"""
from __future__ import annotations

import os
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: a child that reports its own resident set needs neither
    import psutil

#: the folder that holds the package ``tests`` (the repository's root)
ROOT = Path(__file__).resolve().parents[1]

MB = 2**20


def _status(pid: int | str) -> dict[str, int]:
    """``VmRSS`` and ``VmHWM`` (bytes) and ``PPid`` of ``/proc/PID/status``; a zombie has no
    ``Vm*`` lines. Raises ``OSError`` once the process is gone."""
    out = {}
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith(("VmRSS:", "VmHWM:", "PPid:")):
                key, value = line.split(":", 1)
                out[key] = int(value.split()[0]) * (1 if key == "PPid" else 1024)  # Vm*: kB
    return out


def resident(pid: int | str = "self") -> int:
    """The resident set of process ``pid`` (this one by default) now, in bytes (``VmRSS``).
    Raises ``OSError`` once the process is gone, ``KeyError`` for a zombie."""
    return _status(pid)["VmRSS"]


def session_processes(sid: int) -> list[psutil.Process]:
    """The processes of session ``sid`` (psutil objects): a server started by
    ``start_service`` leads its own session, and every process it starts stays in it, also
    once the server is gone and they are the init process's children."""
    import psutil

    out = []
    for p in psutil.process_iter():
        try:
            if os.getsid(p.pid) == sid:
                out.append(p)
        except (ProcessLookupError, PermissionError):
            pass
    return out


class RssWatch:
    """The largest resident-set growth of process ``pid``, or of every process of session
    ``session``, while it runs (``with RssWatch(pid) as watch: ...; watch.growth``; or
    ``start()`` and ``stop()``).

    A thread samples every ``period_s`` each process's peak resident set (``VmHWM``, reset to
    the resident set at the start: a peak between two samples is not missed while the process
    lives). A process there at the start grows from its resident set then (``base=`` gives the
    watched process's own instead, e.g. what it reported itself before the work began); one
    started meanwhile (a child of the session) from its parent's. ``peaks`` (pid -> bytes),
    ``growth`` (bytes, the largest); ``base`` and ``peak`` are the watched process's (the
    session's leader's).

    With ``limit`` (bytes), a process whose growth passes it is killed (SIGKILL) at once and
    the watch ends; ``over`` is then its peak resident set (0 while none was), ``check()`` fails
    the test saying so. A watched process (``pid``) that is gone ends the watch."""

    def __init__(self, pid: int | None = None, *, session: int | None = None, base: int | None = None,
                 limit: int | None = None, period_s: float = 0.02, what: str = "the process") -> None:
        if (pid is None) == (session is None):
            raise ValueError("watch one process (pid) or one session (session)")
        self.pid = pid if pid is not None else session
        self.session, self.limit, self.period_s, self.what = session, limit, period_s, what
        self.bases: dict[int, int] = {}
        self.parents: dict[int, int] = {}
        self.peaks: dict[int, int] = {}
        self._own_base = base
        self._hwm: set[int] = set()  # the processes whose VmHWM was reset at the start
        self.growth = self.over = self.over_base = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="RssWatch")

    @property
    def base(self) -> int:
        return self.bases.get(self.pid, 0)

    @property
    def peak(self) -> int:
        return self.peaks.get(self.pid, self.base)

    def _pids(self) -> list[int]:
        return [self.pid] if self.session is None else [p.pid for p in session_processes(self.session)]

    def start(self) -> RssWatch:
        for pid in self._pids():
            try:
                with open(f"/proc/{pid}/clear_refs", "w") as fh:
                    fh.write("5")  # reset the peak resident set (VmHWM) to the resident set now
                self._hwm.add(pid)
            except OSError:  # not ours to reset: its resident set alone counts
                pass
            try:
                self.bases[pid] = resident(pid)
            except (OSError, KeyError):
                pass
        if self._own_base is not None:
            self.bases[self.pid] = self._own_base
        self._thread.start()
        return self

    def _base_of(self, pid: int) -> int:
        """A process's base: its own, else its nearest watched ancestor's (a process forked
        meanwhile starts from its parent's pages)."""
        for _ in range(16):
            if pid in self.bases:
                return self.bases[pid]
            pid = self.parents.get(pid, 0)
        return 0

    def _sample(self) -> bool:
        """One sample of every process; False once the watch is over (a process killed at the
        limit, or the watched process gone)."""
        for pid in self._pids():
            try:
                st = _status(pid)
                now = st["VmRSS"]  # a zombie has none: gone
            except (OSError, KeyError):
                if self.session is None:
                    return False
                continue
            self.parents.setdefault(pid, st.get("PPid", 0))
            if pid in self._hwm or pid not in self.bases:  # its peak counts since the start (or its own start)
                now = max(now, st.get("VmHWM", 0))
            self.peaks[pid] = max(self.peaks.get(pid, 0), now)
            grown = self.peaks[pid] - self._base_of(pid)
            self.growth = max(self.growth, grown)
            if self.limit is not None and grown > self.limit:
                self.over, self.over_base = self.peaks[pid], self._base_of(pid)
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                return False
        return True

    def _run(self) -> None:
        while self._sample() and not self._stop.wait(self.period_s):
            pass

    def stop(self) -> None:
        """End the watch and take a last sample (of whatever still runs); again, nothing."""
        if self._stop.is_set() or self._thread.ident is None:
            self._stop.set()
            return
        self._stop.set()
        self._thread.join()
        if not self.over:
            self._sample()

    def __enter__(self) -> RssWatch:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def check(self, during: str = "") -> None:
        """Fail the test if a process was killed at the limit, saying how far it grew."""
        if self.over:
            import pytest

            assert self.limit is not None
            pytest.fail(f"{self.what}'s resident size grew from {self.over_base / MB:.0f} MB to "
                        f"{self.over / MB:.0f} MB{' ' + during if during else ''} "
                        f"(killed at +{self.limit / MB:.0f} MB)")
