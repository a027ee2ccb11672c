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
