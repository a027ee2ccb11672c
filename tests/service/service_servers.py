"""Helpers for the service tests: a real ``fpscan serve`` (uvicorn) on 127.0.0.1 in a
subprocess with its own data folder and SQLite file; every wait has a timeout and every
process is cleaned up."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

REPO = Path(__file__).resolve().parents[2]
TOKEN = "test-token-123"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """One ``fpscan serve`` subprocess. ``env`` adds ``FPSCAN_*`` settings."""

    def __init__(self, data_dir: Path, *, token: str | None = TOKEN, devices: dict | None = None,
                 env: dict | None = None):
        self.data_dir = Path(data_dir)
        self.token = token
        self.devices = devices or {}
        self.extra_env = env or {}
        self.proc: subprocess.Popen | None = None
        self.port = 0
        self.log = self.data_dir.parent / f"{self.data_dir.name}-server.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def headers(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def client(self, timeout: float = 30.0) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers=self.headers(), timeout=timeout)

    def start(self, timeout: float = 60.0) -> Server:
        self.port = free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}
        env.update({"FPSCAN_DATA_DIR": str(self.data_dir), "FPSCAN_DEVICES": json.dumps(self.devices),
                    "FPSCAN_HEARTBEAT_S": "0.5", "FPSCAN_PREVIEW_INTERVAL_S": "1.0",
                    "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"})
        if self.token:
            env["FPSCAN_TOKEN"] = self.token
        env.update(self.extra_env)
        logf = open(self.log, "ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "clients", "serve", "--host", "127.0.0.1",
                                      "--port", str(self.port), "--no-web"],
                                     cwd=REPO, env=env, stdout=logf, stderr=subprocess.STDOUT)
        logf.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited {self.proc.returncode}:\n{self.log.read_text()[-3000:]}")
            try:
                if httpx.get(self.url + "/api/health", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"server did not start in {timeout} s:\n{self.log.read_text()[-3000:]}")

    def workers(self) -> list:
        """The server's child processes (executor and preview workers), as psutil objects."""
        import psutil

        try:
            return psutil.Process(self.proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def kill(self) -> None:
        """SIGKILL the server (a crash)."""
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)


def wait_job(client: httpx.Client, job_id: str, states=("succeeded", "failed", "cancelled"),
             timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/api/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} not in {states} after {timeout} s: {job}")


def has_recon() -> bool:
    try:
        from service.recon import reconstruct_grid, reconstruct_points  # noqa: F401
    except ImportError:
        return False
    return True


needs_recon = pytest.mark.skipif(not has_recon(), reason="service.recon not available")




def wait_gone(procs, timeout: float = 15.0) -> list:
    """Wait until the psutil processes ``procs`` have exited; returns those still alive."""
    import psutil

    _, alive = psutil.wait_procs(procs, timeout=timeout)
    return alive
