"""One server per data folder and per job database, a taken port refused in one line
(``fpscan.service.data_lock`` behind ``fpscan serve``). Real processes: a simulator on a pty,
``fpscan serve`` on 127.0.0.1, a second ``fpscan serve`` as a user would start it by mistake."""
from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from fpscan.clients.http import Client
from fpscan.clients.processes import start_service
from tests.clients.clients_servers import QUIET, clean_env, fpscan_sim, free_port, has_command
from tests.waits import HANG_S

TOKEN = "one-server-token"
N, PITCH = 16, 2e-4

pytestmark = pytest.mark.skipif(not (has_command("serve") and has_command("sim")),
                                reason="`fpscan serve`/`fpscan sim` not available")


def _serve(data_dir, port: int, **env: str) -> subprocess.CompletedProcess:
    """``fpscan serve`` in the foreground (it must exit by itself): its exit status and
    output; one that starts serving instead is stopped and fails the test."""
    proc = subprocess.Popen([sys.executable, "-m", "fpscan", "serve", "--host", "127.0.0.1", "--port", str(port),
                             "--data-dir", str(data_dir), "--no-web"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=clean_env(FPSCAN_TOKEN=TOKEN, **QUIET, **env))
    err: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # until it exits, or says it serves
            err.append(line)
            if '"event": "serving"' in line:
                pytest.fail(f"a second server started: {''.join(err)}")
        out = proc.stdout.read() if proc.stdout is not None else ""
        return subprocess.CompletedProcess(proc.args, proc.wait(timeout=HANG_S), out, "".join(err))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=HANG_S)


def _scanning(api: Client) -> str:
    """Start a scan of N x N points at 40 Hz on the device ``sim`` (256 points: over six seconds,
    time for a second server's refusal) and return its job id once it has measured a point."""
    plan = api.create_plan({"lattice": {"n_x": N, "n_y": N, "pitch": PITCH},
                            "points": [[i, j] for j in range(N) for i in range(N)],
                            "acquisition": {"n_t": 128, "dt": 2e-8, "prf": 40}})
    job = api.start_scan(plan.id, "sim")
    for event, body, _ in api.events(job):  # until the scan has measured a point
        if event == "progress" and (body.get("points_done") or 0) > 0:
            break
    return job


def _one_line(res: subprocess.CompletedProcess) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1 and not res.stdout.strip(), (res.returncode, res.stderr)
    return lines[0]


def test_a_second_server_on_a_live_folder_is_refused_and_the_lock_dies_with_its_holder(tmp_path):
    """A second server on the folder of a server that is scanning exits at once with one line
    naming the holder's PID and touches nothing: the scan stays ``running`` (no "server
    restarted" recovery event) and ends with every point. After a SIGKILL of the first
    server the folder is free again for a new one."""
    data = tmp_path / "data"
    with fpscan_sim("--source", "balls") as (device, _sim):
        first = start_service(data, token=TOKEN, devices={"sim": device}, web=False, env=QUIET,
                              log_path=tmp_path / "first.log")
        try:
            with Client(first.url, token=TOKEN) as api:
                job = _scanning(api)
                line = _one_line(_serve(data, free_port()))
                assert f"pid {first.pid}" in line and "in use by another fpscan server" in line, line
                assert api.get_job(job).state == "running"
                done = api.wait(job, timeout=HANG_S)
                assert done.state == "succeeded"
                events = list(api.events(job))  # the whole record, until the stream closes
                assert not any("server restarted" in str(body) for _, body, _ in events), events
                from fpscan.driver.scanfile import read_scan

                scan = read_scan(api.download_scan(job, tmp_path / "scan.h5"))
                assert scan.completed.all() and len(scan.completed) == N * N
        finally:
            first.kill()  # SIGKILL: no shutdown, no unlock
        second = start_service(data, token=TOKEN, web=False, env=QUIET, log_path=tmp_path / "second.log")
        try:
            assert (data / "fpscan.lock").read_text().strip() == str(second.pid)
        finally:
            second.stop()


def test_a_second_server_on_the_job_database_of_a_live_one_is_refused(tmp_path):
    """Two data folders, one job database (``FPSCAN_DB_PATH``): the second server exits at
    once with one line naming the first's PID and the lock beside the database, and touches
    nothing (the first's scan stays ``running`` and ends with every point, with no "server
    restarted" event). After a SIGKILL of the first, a server on that database starts."""
    db = tmp_path / "shared" / "jobs.sqlite"
    with fpscan_sim("--source", "balls") as (device, _sim):
        first = start_service(tmp_path / "first", token=TOKEN, devices={"sim": device}, web=False,
                              env={**QUIET, "FPSCAN_DB_PATH": str(db)}, log_path=tmp_path / "first.log")
        try:
            with Client(first.url, token=TOKEN) as api:
                job = _scanning(api)
                line = _one_line(_serve(tmp_path / "second", free_port(), FPSCAN_DB_PATH=str(db)))
                assert f"pid {first.pid}" in line and f"{db}.lock" in line and "job database" in line, line
                assert api.get_job(job).state == "running"
                assert api.wait(job, timeout=HANG_S).state == "succeeded"
                events = list(api.events(job))
                assert not any("server restarted" in str(body) for _, body, _ in events), events
        finally:
            first.kill()  # SIGKILL: no shutdown, no unlock
        again = start_service(tmp_path / "second", token=TOKEN, web=False, env={**QUIET, "FPSCAN_DB_PATH": str(db)},
                              log_path=tmp_path / "again.log")
        try:
            assert (tmp_path / "shared" / "jobs.sqlite.lock").read_text().strip() == str(again.pid)
        finally:
            again.stop()


def test_a_port_in_use_is_one_line_before_the_data_folder_is_touched(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        line = _one_line(_serve(tmp_path / "data", port))
    assert f"port {port} is in use" in line, line
    assert not (tmp_path / "data").exists()
