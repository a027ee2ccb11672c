"""``fpscan recon --server`` against a server that is down: the command ends in one
line that says what survives and how to go on, never a bare "connection refused" or a traceback.

- Before anything was sent (no server at the URL): it asks whether ``fpscan serve`` runs there and
  says that the jobs a server accepted are kept in its job store.
- After its job was accepted (the server killed while the command waits): it names the job, says
  that the job is kept and runs again when the server does, and gives ``fpscan jobs wait ID``;
  the next server on the same data folder runs the job to its end, and that command reattaches.

The job is held in the queue (the one worker busy with an earlier tv job that runs every one of
its iterations, ``--tol 0``), so the server is killed while the command's job is accepted and not
yet done, whatever the machine's speed: the test waits for events (the job in the store), no clock.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from fpscan.clients.http import Client
from tests.clients.clients_servers import clean_env, fpscan_server, has_command
from tests.waits import HANG_S

TOKEN = "down-test-token"

pytestmark = [pytest.mark.timeout(600),
              pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available yet"),
              pytest.mark.long(30)]


def _recon_cmd(path, url, *extra):
    return [sys.executable, "-m", "fpscan", "recon", str(path), "--format", "npy", "--dt", "2e-8",
            "--dx", "1e-4", "--server", url, "--quiet", *extra]


def _env():
    return clean_env(FPSCAN_TOKEN=TOKEN)


def _until(get, ok):
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        value = get()
        if ok(value):
            return value
        time.sleep(0.05)
    raise AssertionError(f"no such state within {HANG_S} s: {value!r}")


def test_recon_against_a_server_that_is_down_says_what_survives_and_how_to_reattach(tmp_path):
    rng = np.random.default_rng(4)
    small = tmp_path / "small.npy"
    np.save(small, rng.standard_normal((64, 12, 12)))
    busy = tmp_path / "busy.npy"
    np.save(busy, rng.standard_normal((256, 40, 40)))
    data = tmp_path / "data"
    data.mkdir()
    with fpscan_server(data, token=TOKEN) as (url, _srv):
        pass  # a server was here: nothing runs at its URL now
    before = subprocess.run(_recon_cmd(small, url), capture_output=True, text=True, timeout=HANG_S, env=_env())
    assert before.returncode != 0 and "Traceback" not in before.stderr, before.stderr
    assert f"Is `fpscan serve` running at {url}?" in before.stderr, before.stderr
    assert "Jobs it accepted before are kept in its job store" in before.stderr, before.stderr
    assert len(before.stderr.strip().splitlines()) == 1, before.stderr

    with fpscan_server(data, token=TOKEN) as (url, srv):
        with Client(url, token=TOKEN) as api:
            ds = api.upload_dataset(busy, "npy", dt=2e-8, dx=1e-4)
            first = api.start_reconstruction(dataset_id=ds, method="tv",
                                             params={"iterations": 100000, "tol": 0})
            _until(lambda: api.get_job(first).state, lambda s: s == "running")
            cmd = subprocess.Popen(_recon_cmd(small, url, "--method", "nedner", "--out", str(tmp_path / "out")),
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
            try:
                mine = _until(lambda: [j for j in api.list_jobs() if j.id != first],
                              lambda jobs: len(jobs) == 1)[0]
                assert api.get_job(mine.id).state == "queued"  # behind the busy worker: not done
                os.killpg(srv.pid, signal.SIGKILL)
                _out, err = cmd.communicate(timeout=HANG_S)
            finally:
                if cmd.poll() is None:
                    cmd.kill()
    assert cmd.returncode != 0 and "Traceback" not in err, err
    assert f"Job {mine.id} is kept in the server's job store" in err, err
    assert "a reconstruction is run again" in err, err
    assert f"fpscan jobs wait {mine.id} --server {url}" in err, err

    with fpscan_server(data, token=TOKEN) as (url2, _srv2):
        with Client(url2, token=TOKEN) as api:
            api.cancel_job(first)  # the busy job again: the command's job is next
        again = subprocess.run([sys.executable, "-m", "fpscan", "jobs", "wait", mine.id, "--server", url2,
                                "--quiet"], capture_output=True, text=True, timeout=HANG_S, env=_env())
    assert again.returncode == 0 and f"{mine.id}: succeeded" in again.stdout, (again.stdout, again.stderr)
