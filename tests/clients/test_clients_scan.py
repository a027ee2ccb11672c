"""A real scan through a real server and simulator, then the CLI on its results:
`jobs wait`, `export` (local and from the server), `recon` (local and on the server),
and the failure path of a job (a scanner whose port does not exist)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from fpscan.clients.http import Client, JobFailed
from tests.clients.clients_servers import clean_env, fpscan_server, fpscan_sim, has_command
from tests.waits import HANG_S

TOKEN = "scan-test-token"
N, PITCH = 16, 4e-4

pytestmark = [pytest.mark.skipif(not (has_command("serve") and has_command("sim")),
                                 reason="`fpscan serve`/`fpscan sim` not available yet"),
              pytest.mark.long(90)]


def fpscan(*args, timeout=HANG_S):
    return subprocess.run([sys.executable, "-m", "fpscan", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=clean_env(FPSCAN_TOKEN=TOKEN))


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    """(server url, scan job id, downloaded scan file) of a full 16x16 lattice scan."""
    tmp = tmp_path_factory.mktemp("scan")
    data = tmp / "data"
    data.mkdir()
    with fpscan_sim("--source", "balls", "--prf", "0") as (device, _sim):
        devices = {"sim": device, "ghost": str(tmp / "no-such-tty")}
        with fpscan_server(data, token=TOKEN, devices=devices) as (url, _srv):
            with Client(url, token=TOKEN) as api:
                plan = api.create_plan({"lattice": {"n_x": N, "n_y": N, "pitch": PITCH},
                                        "points": [[i, j] for j in range(N) for i in range(N)],
                                        "acquisition": {"n_t": 384, "dt": 2e-8, "prf": 0}})
                job_id = api.start_scan(plan.id, "sim")
                seen = []
                job = api.wait(job_id, on_progress=seen.append, timeout=HANG_S)
                assert job.state == "succeeded"
                assert any(p.get("points_total") == N * N for p in seen)
                scan = api.download_scan(job_id, tmp / "scan.h5")
                yield {"url": url, "job": job_id, "scan": scan, "tmp": tmp, "api": api, "plan": plan}


def test_jobs_wait_on_finished_scan(scanned):
    res = fpscan("jobs", "wait", scanned["job"], "--server", scanned["url"], "--quiet")
    assert res.returncode == 0, res.stderr
    assert "succeeded" in res.stdout


def test_scan_file_holds_every_point(scanned):
    from fpscan.driver.scanfile import read_scan

    scan = read_scan(scanned["scan"])
    assert scan.completed.all() and len(scan.completed) == N * N


def test_export_local_equals_server(scanned):
    import h5py

    tmp = scanned["tmp"]
    local = fpscan("export", scanned["scan"], "--out", tmp / "local_ipasc.h5")
    assert local.returncode == 0, local.stderr
    remote = fpscan("export", "--server", scanned["url"], "--job", scanned["job"], "--out", tmp / "remote_ipasc.h5")
    assert remote.returncode == 0, remote.stderr
    with h5py.File(tmp / "local_ipasc.h5", "r") as a, h5py.File(tmp / "remote_ipasc.h5", "r") as b:
        da, db = a["binary_time_series_data"][...], b["binary_time_series_data"][...]
        assert da.shape[0] == N * N
        np.testing.assert_array_equal(da, db)


def test_recon_of_scan_local_equals_server(scanned):
    import h5py

    tmp = scanned["tmp"]
    opts = ["--method", "nedner", "--dtype", "float32", "--n-z", "128", "--quiet"]
    local = fpscan("recon", scanned["scan"], *opts, "--out", tmp / "r_local")
    assert local.returncode == 0, local.stderr
    remote = fpscan("recon", "--server", scanned["url"], "--scan-job", scanned["job"], *opts, "--out", tmp / "r_remote")
    assert remote.returncode == 0, remote.stderr
    with h5py.File(tmp / "r_local" / "volume.h5", "r") as a, h5py.File(tmp / "r_remote" / "volume.h5", "r") as b:
        pa, pb = a["p0"][...], b["p0"][...]
    assert pa.shape == (128, N, N)
    np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-4 * np.abs(pa).max())


def test_plan_and_scan_with_server_options(scanned):
    """`fpscan plan --out` then `fpscan scan --server --plan FILE`: the server stores the
    file under its own id and scans it as a job; `fpscan plan --server` creates a plan there."""
    from fpscan.driver.scanfile import read_scan

    tmp, url = scanned["tmp"], scanned["url"]
    local = fpscan("plan", "equispaced", "--interval", "3", "--n-x", N, "--pitch", PITCH, "--n-t", 128,
                   "--dt", 2e-8, "--prf", 0, "--out", tmp / "sub.json")
    assert local.returncode == 0, local.stderr
    doc = json.loads((tmp / "sub.json").read_text())
    res = fpscan("scan", "--server", url, "--scanner", "sim", "--plan", tmp / "sub.json",
                 "--out", tmp / "sub_scan.h5", "--quiet")
    assert res.returncode == 0, res.stderr
    n = len(doc["points"]["indices"])
    assert f"{n}/{n} points" in res.stdout
    scan = read_scan(tmp / "sub_scan.h5")
    assert scan.plan["id"] == doc["id"] and scan.completed.all() and len(scan.completed) == n
    remote = fpscan("plan", "equispaced", "--interval", "3", "--n-x", N, "--pitch", PITCH, "--n-t", 128,
                    "--dt", 2e-8, "--prf", 0, "--server", url, "--out", tmp / "sub_remote.json")
    assert remote.returncode == 0, remote.stderr
    assert json.loads((tmp / "sub_remote.json").read_text()) == doc  # same builder, same id


def test_scan_on_a_missing_port_fails_with_reason(scanned):
    api = scanned["api"]
    job_id = api.start_scan(scanned["plan"].id, "ghost")
    with pytest.raises(JobFailed) as err:
        api.wait(job_id, timeout=HANG_S)
    job = err.value.job
    assert job.state == "failed" and job.error
    assert job.error in str(err.value)
    res = fpscan("jobs", "wait", job_id, "--server", scanned["url"], "--quiet")
    assert res.returncode == 1
    assert len(res.stderr.strip().splitlines()) == 1 and "failed" in res.stderr


def _poll(fn, until, timeout=HANG_S, interval=0.05):
    import time

    deadline = time.monotonic() + timeout
    while True:
        value = fn()
        if until(value):
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not reached within {timeout} s: last {value!r}")
        time.sleep(interval)


@pytest.fixture(scope="module")
def slow_scanner(tmp_path_factory):
    """A server with a simulator firing at 50 Hz (256 points take 5.1 s: time to act mid-scan)."""
    tmp = tmp_path_factory.mktemp("slow")
    data = tmp / "data"
    data.mkdir()
    with fpscan_sim("--source", "balls", "--prf", "50") as (device, _sim):
        with fpscan_server(data, token=TOKEN, devices={"slow": device}) as (url, _srv):
            with Client(url, token=TOKEN) as api:
                plan = api.create_plan({"lattice": {"n_x": N, "n_y": N, "pitch": PITCH},
                                        "points": [[i, j] for j in range(N) for i in range(N)],
                                        "acquisition": {"n_t": 256, "dt": 2e-8, "prf": 50}})
                yield api, plan, tmp


def test_pause_resume_and_live_preview(slow_scanner):
    from PIL import Image

    from fpscan.driver.scanfile import read_scan

    api, plan, tmp = slow_scanner
    job_id = api.start_scan(plan.id, "slow")
    _poll(lambda: api.get_job(job_id), lambda j: (j.progress.points_done or 0) >= 20)
    paused = api.pause_scan(job_id)
    assert paused.id == job_id
    job = _poll(lambda: api.get_job(job_id), lambda j: j.state == "paused")
    assert job.progress.points_done < N * N
    api.resume_scan(job_id)
    job = api.wait(job_id, timeout=HANG_S)
    assert job.state == "succeeded"
    scan = read_scan(api.download_scan(job_id, tmp / "paused.h5"))
    assert scan.completed.all() and len(scan.completed) == N * N
    info = api.scan_preview(job_id)
    if info.version > 0:  # a preview was rendered while the scan ran
        assert 0 < info.points_used <= N * N
        with Image.open(api.download_scan_preview(job_id, "xy", tmp / "live_xy.png")) as im:
            assert im.format == "PNG"


def test_abort_ends_cancelled(slow_scanner):
    from fpscan.clients.http import JobCancelled

    api, plan, _tmp = slow_scanner
    job_id = api.start_scan(plan.id, "slow")
    _poll(lambda: api.get_job(job_id), lambda j: (j.progress.points_done or 0) >= 10)
    api.abort_scan(job_id)
    with pytest.raises(JobCancelled) as err:
        api.wait(job_id, timeout=HANG_S)
    assert err.value.job.state == "cancelled"
    assert err.value.job.progress.points_done < N * N


def test_progress_bar_on_a_terminal(slow_scanner):
    """`fpscan jobs wait` on a real terminal (a pty) while a 50 Hz scan runs draws the rich
    progress bar with the points done, A-lines/s and the ETA, and ends at all points."""
    import os
    import pty
    import select
    import time

    api, plan, _tmp = slow_scanner
    job_id = api.start_scan(plan.id, "slow")
    master, slave = pty.openpty()
    env = clean_env(FPSCAN_TOKEN=TOKEN, COLUMNS="160", TERM="xterm")
    proc = subprocess.Popen([sys.executable, "-m", "fpscan", "jobs", "wait", job_id,
                             "--server", api.base_url], stdin=slave, stdout=slave, stderr=slave, env=env)
    os.close(slave)
    out = b""
    deadline = time.monotonic() + HANG_S
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not chunk:
                    break
                out += chunk
            elif proc.poll() is not None:
                break
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        os.close(master)
    text = out.decode(errors="replace")
    assert f"{N * N}/{N * N} points" in text
    assert "A-lines/s" in text and "ETA" in text
    assert "succeeded" in text


def test_server_dying_mid_wait_raises_server_unavailable(tmp_path):
    """SIGKILL the server while the client waits on a running scan: wait() ends with
    ServerUnavailable (no hang), and the job survives in the SQLite file for the next
    server (which reports it as paused, resumable). The command line against the dead server
    says what survives and the commands that reattach; `fpscan jobs resume` then `jobs wait`
    finish the scan on the next server."""
    import os
    import signal
    import threading

    from fpscan.clients.http import ServerUnavailable

    data = tmp_path / "data"
    data.mkdir()
    with fpscan_sim("--source", "balls", "--prf", "100") as (device, _sim):
        with fpscan_server(data, token=TOKEN, devices={"slow": device}) as (url, srv):
            with Client(url, token=TOKEN) as api:
                plan = api.create_plan({"lattice": {"n_x": N, "n_y": N, "pitch": PITCH},
                                        "points": [[i, j] for j in range(N) for i in range(N)],
                                        "acquisition": {"n_t": 128, "dt": 2e-8, "prf": 100}})
                job_id = api.start_scan(plan.id, "slow")
                outcome = {}

                def waiter():
                    try:
                        outcome["job"] = api.wait(job_id, timeout=HANG_S)
                    except Exception as exc:  # the outcome is the test
                        outcome["error"] = exc

                t = threading.Thread(target=waiter)
                t.start()
                _poll(lambda: api.get_job(job_id), lambda j: (j.progress.points_done or 0) >= 5)
                os.killpg(srv.pid, signal.SIGKILL)
                t.join(timeout=HANG_S)
                assert not t.is_alive()
                assert isinstance(outcome.get("error"), ServerUnavailable), outcome
        # the command line against the server that is gone: what survives and how to reattach
        gone = fpscan("jobs", "wait", job_id, "--server", url)
        assert gone.returncode == 1 and "Traceback" not in gone.stderr, gone.stderr
        assert f"Job {job_id} is kept in the server's job store" in gone.stderr, gone.stderr
        assert f"fpscan jobs wait {job_id} --server {url}" in gone.stderr, gone.stderr
        assert f"fpscan jobs resume {job_id} --server {url}" in gone.stderr, gone.stderr
        with fpscan_server(data, token=TOKEN, devices={"slow": device}) as (url, _srv):
            with Client(url, token=TOKEN) as api:
                job = api.get_job(job_id)
                assert job.state == "paused"
            resumed = fpscan("jobs", "resume", job_id[:12], "--server", url)
            assert resumed.returncode == 0, resumed.stderr
            assert f"{job_id}: " in resumed.stdout and f"fpscan jobs wait {job_id[:12]}" in resumed.stdout
            waited = fpscan("jobs", "wait", job_id, "--server", url, "--quiet")
            assert waited.returncode == 0 and f"{job_id}: succeeded" in waited.stdout, waited.stderr


def test_cli_cancel_of_a_running_scan(slow_scanner):
    api, plan, _tmp = slow_scanner
    job_id = api.start_scan(plan.id, "slow")
    _poll(lambda: api.get_job(job_id), lambda j: (j.progress.points_done or 0) >= 5)
    res = fpscan("jobs", "cancel", job_id, "--server", api.base_url)
    assert res.returncode == 0, res.stderr
    job = api.wait(job_id, timeout=HANG_S, raise_on_failure=False)
    assert job.state == "cancelled"
    assert job.progress.points_done < N * N
    res = fpscan("jobs", "list", "--state", "cancelled", "--server", api.base_url)
    assert res.returncode == 0 and job_id[:12] in res.stdout  # the list shows short ids (a unique prefix)


def test_scan_server_preview_wavelength(scanned):
    """`fpscan scan --server --preview-wavelength M` on a two-wavelength plan: the job's
    live preview shows that wavelength (index 1 of the plan's); a wavelength the plan
    lacks, and the flag on a local scan, are refused with the reason."""
    tmp, url, api = scanned["tmp"], scanned["url"], scanned["api"]
    made = fpscan("plan", "equispaced", "--interval", "4", "--n-x", N, "--pitch", PITCH, "--n-t", 96,
                  "--dt", 2e-8, "--prf", 0, "--wavelength", 7.6e-7, "--wavelength", 8.5e-7,
                  "--out", tmp / "two.json")
    assert made.returncode == 0, made.stderr
    wrong = fpscan("scan", "--server", url, "--scanner", "sim", "--plan", tmp / "two.json",
                   "--preview-wavelength", 9e-7, "--quiet")
    assert wrong.returncode == 2 and "not one of the plan's wavelengths (7.6e-07, 8.5e-07 m)" in wrong.stderr
    local = fpscan("scan", "--device", tmp / "no-such-tty", "--plan", tmp / "two.json", "--out", tmp / "x.h5",
                   "--preview-wavelength", 8.5e-7)
    assert local.returncode == 2 and "--preview-wavelength is for a scan on a server" in local.stderr
    res = fpscan("scan", "--server", url, "--scanner", "sim", "--plan", tmp / "two.json",
                 "--preview-wavelength", 8.5e-7, "--quiet")
    assert res.returncode == 0, res.stderr
    job_id = res.stdout.split("scan job ", 1)[1].split()[0]
    assert api.get_job(job_id).params["preview_wavelength"] == 1
    assert api.scan_preview(job_id).wavelength_index == 1
