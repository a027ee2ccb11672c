"""Start and stop fpscan's own processes: the service (``fpscan serve``, uvicorn on
127.0.0.1) and the simulated scanner (``fpscan sim`` on a pseudo-terminal).

The one place that does it, for ``fpscan demo``, the tests and the benchmarks. Every
child runs in its own session with its output in a log file; every wait has a timeout
(``RuntimeError`` with the log's tail when it runs out); :meth:`Process.stop` ends the
child with SIGTERM and then removes whatever is left of its session with SIGKILL.
Needs only the standard library and httpx (the client's dependencies).
"""
from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import httpx

__all__ = ["Process", "Service", "clean_env", "fpscan_argv", "free_port", "service", "simulator",
           "start_service", "start_simulator"]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (another program may still take it).

    Returns
    -------
    int
        The port number.
    """
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fpscan_argv(*args: str) -> list[str]:
    """The command line of ``fpscan ARGS...`` with this interpreter.

    Parameters
    ----------
    *args : str
        The arguments after ``fpscan``.

    Returns
    -------
    list of str
        ``[sys.executable, "-m", "fpscan", *args]``.
    """
    return [sys.executable, "-m", "fpscan", *args]


def clean_env(**extra: str) -> dict[str, str]:
    """The environment of the current process without any ``FPSCAN_*`` setting, plus ``extra``.

    Parameters
    ----------
    **extra : str
        Variables to add (or override).

    Returns
    -------
    dict[str, str]
        A new environment mapping.
    """
    env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}
    env.update(extra)
    return env


class Process:
    """A child process in its own session, its stdout/stderr appended to ``log_path``.

    With ``stdout_pipe`` its stdout is a pipe for :meth:`first_line` (then copied on to
    the log so that the child never blocks on a full pipe).

    Parameters
    ----------
    argv : list of str
        The command line.
    log_path : str or os.PathLike
        The log file (appended to; its folder is created).
    env : Mapping[str, str], optional
        The child's environment (None: this process's).
    stdout_pipe : bool, optional
        Make stdout a pipe for :meth:`first_line` (default False: stdout goes to the log).
    cwd : str or os.PathLike, optional
        The child's working directory (None: this process's).

    Attributes
    ----------
    argv : list of str
        As given.
    log_path : Path
        As given.
    proc : subprocess.Popen
        The child.
    pid : int
        Its process id.
    """

    def __init__(self, argv: list[str], *, log_path: str | os.PathLike, env: Mapping[str, str] | None = None,
                 stdout_pipe: bool = False, cwd: str | os.PathLike | None = None):
        self.argv = list(argv)
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log: IO[bytes] = open(self.log_path, "ab")  # closed in stop()
        self.proc = subprocess.Popen(
            argv, env=None if env is None else dict(env), cwd=cwd, stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE if stdout_pipe else self._log, stderr=self._log,
            start_new_session=True,
        )

    @property
    def pid(self) -> int:
        return self.proc.pid

    def poll(self) -> int | None:
        """The exit status, or None while it runs."""
        return self.proc.poll()

    def log_tail(self, n: int = 3000) -> str:
        """The last ``n`` characters of the log."""
        self._log.flush()
        try:
            return self.log_path.read_text(errors="replace")[-n:]
        except OSError:
            return ""

    def first_line(self, timeout: float) -> str:
        """The first line the child prints on stdout (the device path for ``fpscan sim``)."""
        if self.proc.stdout is None:
            raise RuntimeError("first_line() needs stdout_pipe=True")
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        buf = b""
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], 0.2)
            if ready:
                chunk = os.read(fd, 4096)
                if not chunk:
                    break
                buf += chunk
                if b"\n" in buf:
                    line = buf.split(b"\n", 1)[0]
                    self._log.write(buf)
                    self._drain()
                    return line.decode().strip()
            elif self.proc.poll() is not None:
                break
        name = " ".join(map(str, self.argv[2:4]))
        try:  # its output ended: it is exiting (a refused option), and says why on stderr
            status = self.proc.wait(timeout=max(0.0, deadline - time.monotonic()))  # within the caller's bound
        except subprocess.TimeoutExpired:
            status = None
        if status is not None:
            raise RuntimeError(f"{name} exited (status {status}) before its first line:\n{self.log_tail()}")
        raise RuntimeError(f"{name} printed no first line within {timeout:.0f} s:\n{self.log_tail()}")

    def _drain(self) -> None:
        stdout = self.proc.stdout
        assert stdout is not None

        def pump() -> None:
            try:
                for chunk in iter(lambda: os.read(stdout.fileno(), 65536), b""):
                    self._log.write(chunk)
            except (OSError, ValueError):
                pass

        threading.Thread(target=pump, daemon=True).start()

    def kill(self) -> None:
        """SIGKILL the child alone (a crash: its own children are left as they are)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=15)

    def stop(self, timeout: float = 15.0) -> None:
        """SIGTERM the child and wait up to ``timeout`` s, then SIGKILL what is left of its
        session (the child, and any worker it started)."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                pass
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=timeout)
        if self.proc.stdout is not None:
            with contextlib.suppress(OSError):
                self.proc.stdout.close()
        self._log.close()


class Service(Process):
    """A running ``fpscan serve`` on 127.0.0.1 (see :func:`start_service`).

    Parameters
    ----------
    argv : list of str
        The command line.
    port : int
        The port it listens on.
    token : str or None
        Its bearer token (None: no token).
    data_dir : Path
        Its data folder.
    **kw : Any
        Passed to :class:`Process` (``log_path``, ``env``, ...).

    Attributes
    ----------
    port : int
        As given.
    token : str or None
        As given.
    data_dir : Path
        As given.
    url : str
        ``http://127.0.0.1:<port>``.
    """

    def __init__(self, argv: list[str], *, port: int, token: str | None, data_dir: Path, **kw: Any):
        super().__init__(argv, **kw)
        self.port, self.token, self.data_dir = port, token, data_dir

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def headers(self) -> dict[str, str]:
        """The bearer-token header (empty without a token)."""
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def wait_healthy(self, timeout: float) -> dict:
        """Wait until ``GET /api/health`` answers 200; returns its body."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                r = httpx.get(self.url + "/api/health", headers=self.headers(), timeout=2)
                if r.status_code == 200:
                    return r.json()
            except httpx.HTTPError:
                pass
            if self.proc.poll() is not None:
                raise RuntimeError(f"fpscan serve exited {self.proc.returncode}:\n{self.log_tail()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"fpscan serve did not answer within {timeout:.0f} s:\n{self.log_tail()}")
            time.sleep(0.2)


def start_service(data_dir: str | os.PathLike, *, token: str | None = None, devices: Mapping[str, str] | None = None,
                  env: Mapping[str, str] | None = None, log_path: str | os.PathLike | None = None,
                  web: bool = True, timeout: float = 90.0, attempts: int = 3) -> Service:
    """Start ``fpscan serve`` on a free port of 127.0.0.1 and wait until it is healthy.

    ``data_dir``: its ``FPSCAN_DATA_DIR``; ``token``: ``FPSCAN_TOKEN`` (None: a server
    without a token, ``FPSCAN_NO_TOKEN``, loopback only); ``devices``:
    ``FPSCAN_DEVICES`` (scanner id -> device path); ``env``: further ``FPSCAN_*``
    settings (the caller's own ``FPSCAN_*`` variables are not passed on); ``web``: serve
    the web page. A port taken by another program in between is retried ``attempts``
    times. Raises ``RuntimeError`` (with the log's tail) when it does not start.

    Parameters
    ----------
    data_dir : str or os.PathLike
        The service's data folder (``FPSCAN_DATA_DIR``).
    token : str, optional
        ``FPSCAN_TOKEN`` (None: no token, ``FPSCAN_NO_TOKEN=true``). ``fpscan serve`` refuses a
        token of under 128 bits of estimated entropy unless ``env`` allows it
        (``FPSCAN_ALLOW_WEAK_TOKEN``).
    devices : Mapping[str, str], optional
        ``FPSCAN_DEVICES``: scanner id -> device path.
    env : Mapping[str, str], optional
        Further environment variables (``FPSCAN_*`` settings).
    log_path : str or os.PathLike, optional
        The log file (default ``<data_dir>-server.log`` beside the data folder).
    web : bool, optional
        Serve the web page (default True).
    timeout : float, optional
        Seconds to wait for ``GET /api/health`` to answer 200 (default 90).
    attempts : int, optional
        Tries with a fresh port when the server exits before it is healthy (default 3).

    Returns
    -------
    Service
        The healthy service; the caller stops it (:meth:`Process.stop`).

    Raises
    ------
    RuntimeError
        It exited on every attempt or did not answer within ``timeout`` (the log's tail in
        the message).
    """
    data_dir = Path(data_dir)
    log = Path(log_path) if log_path is not None else data_dir.parent / f"{data_dir.name}-server.log"
    full_env = clean_env(FPSCAN_DATA_DIR=str(data_dir), PYTHONUNBUFFERED="1")
    if token:
        full_env["FPSCAN_TOKEN"] = token
    else:
        full_env["FPSCAN_NO_TOKEN"] = "true"
    if devices is not None:
        full_env["FPSCAN_DEVICES"] = json.dumps(dict(devices))
    full_env.update(env or {})
    for attempt in range(max(1, attempts)):
        port = free_port()
        argv = fpscan_argv("serve", "--host", "127.0.0.1", "--port", str(port), *(() if web else ("--no-web",)))
        srv = Service(argv, port=port, token=token, data_dir=data_dir, log_path=log, env=full_env)
        try:
            srv.wait_healthy(timeout)
            return srv
        except RuntimeError:
            alive = srv.poll() is None
            srv.stop()
            if alive or attempt == attempts - 1:  # silent for `timeout` s, or out of tries
                raise
    raise AssertionError("unreachable")


def start_simulator(*args: str, log_path: str | os.PathLike, timeout: float = 60.0) -> tuple[str, Process]:
    """Start ``fpscan sim ARGS...`` on a pseudo-terminal; returns ``(device path, process)``.

    Parameters
    ----------
    *args : str
        ``fpscan sim``'s arguments.
    log_path : str or os.PathLike
        The log file.
    timeout : float, optional
        Seconds to wait for the device path, its first line (default 60).

    Returns
    -------
    tuple of (str, Process)
        The device path (``/dev/pts/N``) and the process; the caller stops it.

    Raises
    ------
    RuntimeError
        No (or an empty) first line within ``timeout``; the process is stopped.
    """
    proc = Process(fpscan_argv("sim", *args), log_path=log_path, env=clean_env(), stdout_pipe=True)
    try:
        device = proc.first_line(timeout)
        if not device:
            raise RuntimeError("fpscan sim printed an empty device path")
    except BaseException:
        proc.stop()
        raise
    return device, proc


@contextlib.contextmanager
def service(data_dir: str | os.PathLike, **kw: Any) -> Iterator[Service]:
    """:func:`start_service` as a context manager that stops it on exit.

    Parameters
    ----------
    data_dir : str or os.PathLike
        The service's data folder.
    **kw : Any
        :func:`start_service`'s options.

    Returns
    -------
    context manager of Service
        Entered, the healthy service.
    """
    srv = start_service(data_dir, **kw)
    try:
        yield srv
    finally:
        srv.stop()


@contextlib.contextmanager
def simulator(*args: str, log_path: str | os.PathLike, timeout: float = 60.0) -> Iterator[tuple[str, Process]]:
    """:func:`start_simulator` as a context manager that stops it on exit.

    Parameters
    ----------
    *args, log_path, timeout
        As :func:`start_simulator`.

    Returns
    -------
    context manager of tuple of (str, Process)
        Entered, the device path and the process.
    """
    device, proc = start_simulator(*args, log_path=log_path, timeout=timeout)
    try:
        yield device, proc
    finally:
        proc.stop()
