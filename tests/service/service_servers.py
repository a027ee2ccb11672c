"""Helpers for the service tests: a real ``fpscan serve`` (uvicorn) on 127.0.0.1 in a
subprocess with its own data folder and SQLite file; every wait has a timeout and every
process is cleaned up."""
from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest

from fpscan.clients.processes import Service, start_service
from tests.clients.clients_servers import QUIET
from tests.waits import HANG_S

REPO = Path(__file__).resolve().parents[2]
TOKEN = "test-token-123"


class Server:
    """One ``fpscan serve`` subprocess (``fpscan.clients.processes.start_service``) with fast
    heartbeats and previews. ``env`` adds ``FPSCAN_*`` settings."""

    def __init__(self, data_dir: Path, *, token: str | None = TOKEN, devices: dict | None = None,
                 env: dict | None = None):
        self.data_dir = Path(data_dir)
        self.token = token
        self.devices = devices or {}
        self.extra_env = env or {}
        self.service: Service | None = None
        self.log = self.data_dir.parent / f"{self.data_dir.name}-server.log"

    @property
    def proc(self):
        return None if self.service is None else self.service.proc

    @property
    def port(self) -> int:
        return 0 if self.service is None else self.service.port

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def headers(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def client(self, timeout: float = 30.0) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers=self.headers(), timeout=timeout)

    def start(self, timeout: float = HANG_S) -> Server:
        # no warm-up (QUIET); test_worker_priority turns it on
        env = {"FPSCAN_HEARTBEAT_S": "0.5", "FPSCAN_PREVIEW_INTERVAL_S": "1.0", "OMP_NUM_THREADS": "1", **QUIET}
        env.update(self.extra_env)
        self.service = start_service(self.data_dir, token=self.token, devices=self.devices, env=env,
                                     log_path=self.log, web=False, timeout=timeout)
        return self

    def workers(self) -> list:
        """The server's child processes (executor and preview workers), as psutil objects."""
        import psutil

        try:
            return psutil.Process(self.service.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def kill(self) -> None:
        """SIGKILL the server alone (a crash)."""
        if self.service is not None:
            self.service.kill()

    def stop(self) -> None:
        if self.service is not None:
            self.service.stop()


def wait_job(client: httpx.Client, job_id: str, states=("succeeded", "failed", "cancelled"),
             timeout: float = HANG_S) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/api/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} not in {states} after {timeout} s: {job}")


def has_recon() -> bool:
    try:
        from fpscan.service.recon import reconstruct_grid, reconstruct_points  # noqa: F401
    except ImportError:
        return False
    return True


needs_recon = pytest.mark.skipif(not has_recon(), reason="fpscan.service.recon not available")




def wait_gone(procs, timeout: float = HANG_S) -> list:
    """Wait until the psutil processes ``procs`` have exited; returns those still alive."""
    import psutil

    _, alive = psutil.wait_procs(procs, timeout=timeout)
    return alive


def session_processes(sid: int) -> list:
    """The processes of session ``sid`` (psutil objects): a server started by
    ``start_service`` leads its own session, and every process it starts stays in it, also
    once the server is gone and they are the init process's children."""
    import os

    import psutil

    out = []
    for p in psutil.process_iter():
        try:
            if os.getsid(p.pid) == sid:
                out.append(p)
        except (ProcessLookupError, PermissionError):
            pass
    return out


class PeakRss:
    """The largest resident-set growth of a server's processes while the block runs
    (``with PeakRss(server_pid) as peak: ...; peak.growth``): every process of its session,
    sampled every few ms by a thread, by its peak resident set (``VmHWM`` of
    ``/proc/PID/status``: a peak between two samples is not missed while the process lives);
    a process that was there before counts from its resident set then (its peak reset,
    ``/proc/PID/clear_refs``), one started meanwhile (an import child, forked from the fork
    server) from its parent's. ``growth`` (bytes) and ``peaks`` (pid -> bytes) after the block."""

    def __init__(self, sid: int, period_s: float = 0.003):
        self.sid, self.period_s = sid, period_s
        self.base: dict[int, int] = {}
        self.parent: dict[int, int] = {}
        self.peaks: dict[int, int] = {}
        self.growth = 0

    @staticmethod
    def _status(pid: int) -> dict[str, int]:
        out = {}
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(("VmRSS:", "VmHWM:", "PPid:")):
                    key, value = line.split(":", 1)
                    out[key] = int(value.split()[0]) * (1024 if key != "PPid" else 1)
        return out

    def _sample(self) -> None:
        for p in session_processes(self.sid):
            try:
                st = self._status(p.pid)
            except OSError:
                continue
            self.parent.setdefault(p.pid, st.get("PPid", 0))
            self.peaks[p.pid] = max(self.peaks.get(p.pid, 0), st.get("VmHWM", 0), st.get("VmRSS", 0))

    def __enter__(self) -> PeakRss:
        import threading

        for p in session_processes(self.sid):
            try:
                with open(f"/proc/{p.pid}/clear_refs", "w") as fh:
                    fh.write("5")  # reset the peak resident set to the current one
            except OSError:
                pass
            try:
                self.base[p.pid] = self._status(p.pid)["VmRSS"]
            except (OSError, KeyError):
                pass
        self._stop = threading.Event()

        def run() -> None:
            while not self._stop.is_set():
                self._sample()
                self._stop.wait(self.period_s)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()
        grown = [peak - self.base.get(pid, self.base.get(self.parent.get(pid, 0), 0))
                 for pid, peak in self.peaks.items()]
        self.growth = max([0, *grown])
