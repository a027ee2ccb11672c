"""Real fpscan processes for the client/CLI tests: the service (``fpscan serve`` on
127.0.0.1, its own SQLite file) and the simulated scanner (``fpscan sim`` on a pty).
Every wait has a timeout; every process is stopped (its whole session) on exit."""
from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def has_command(name: str) -> bool:
    from clients.cli import _subcommand_modules

    return any(m.COMMAND == name for m in _subcommand_modules())


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=15)
        except (subprocess.TimeoutExpired, ProcessLookupError):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=15)


def clean_env(**extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}
    env.update(extra)
    return env


@contextlib.contextmanager
def fpscan_server(data_dir: Path, *, token: str | None = None, devices: dict | None = None,
                  timeout: float = 60.0):
    """Yield ``(url, proc)`` of a running ``fpscan serve``."""
    port = free_port()
    env = clean_env(FPSCAN_DATA_DIR=str(data_dir))
    if token:
        env["FPSCAN_TOKEN"] = token
    if devices:
        env["FPSCAN_DEVICES"] = json.dumps(devices)
    log = open(data_dir.parent / f"server-{port}.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "clients", "serve", "--host", "127.0.0.1",
                             "--port", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                if httpx.get(url + "/api/health", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"fpscan serve did not start (exit {proc.poll()}): "
                                   + Path(log.name).read_text()[-2000:])
            time.sleep(0.2)
        yield url, proc
    finally:
        _stop(proc)
        log.close()


@contextlib.contextmanager
def fpscan_sim(*args: str, timeout: float = 60.0):
    """Yield ``(device_path, proc)`` of a running ``fpscan sim`` (its first stdout line)."""
    proc = subprocess.Popen([sys.executable, "-m", "clients", "sim", *args], env=clean_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + timeout
        buf = b""
        while b"\n" not in buf:
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError(f"fpscan sim printed no device path (exit {proc.poll()})")
            ready, _, _ = select.select([proc.stdout], [], [], 0.2)
            if ready:
                buf += os.read(proc.stdout.fileno(), 4096)
        import threading

        # keep reading stdout so that the simulator never blocks on a full pipe
        threading.Thread(target=lambda: [None for _ in iter(lambda: proc.stdout.read(4096), b"")],
                         daemon=True).start()
        yield buf.split(b"\n", 1)[0].decode().strip(), proc
    finally:
        _stop(proc)
        proc.stdout.close()
