"""`fpscan sim` and `fpscan scan` as real processes: SIGKILL the host mid-scan, run it
again on the same file, and compare with an uninterrupted scan and the ground truth."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from fpscan.clients.processes import start_simulator
from fpscan.driver.scanfile import read_scan
from tests.driver.driver_helpers import grid_plan, read_record
from tests.waits import HANG_S

pytestmark = pytest.mark.timeout(120)
FPSCAN = [sys.executable, "-m", "fpscan"]


def completed_count(path) -> int:
    try:
        return int(read_scan(path).completed.sum())
    except (OSError, ValueError, KeyError):
        return 0  # not created yet


def scan_cmd(dev, plan_path, out):
    return FPSCAN + ["scan", "--device", dev, "--plan", str(plan_path), "--out", str(out), "-q"]


def test_sigkill_host_mid_scan_then_resume(tmp_path):
    plan = grid_plan(25, 24, n_t=512)  # 600 points at 400 Hz: 1.5 s per full scan
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(plan))
    record = tmp_path / "truth.h5"
    # the simulator started as the demo and the service tests start it (fpscan.clients.processes)
    dev, sim = start_simulator("--prf", "400", "--seed", "5", "--snr", "50", "--record", str(record),
                               log_path=tmp_path / "sim.log", timeout=HANG_S)
    try:
        assert dev.startswith("/dev/"), dev
        killed = tmp_path / "killed.h5"
        host = subprocess.Popen(scan_cmd(dev, plan_path, killed), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + HANG_S
        while completed_count(killed) < 150 and time.monotonic() < deadline:
            time.sleep(0.05)
        host.send_signal(signal.SIGKILL)
        host.wait(timeout=10)
        # its reader process (fpscan.driver.relay) follows it within a moment, freeing the port
        import psutil

        def relays():
            out = []
            for p in psutil.process_iter(["cmdline"]):
                cmd = p.info["cmdline"] or []
                if "fpscan.driver.relay" in cmd and str(host.pid) in cmd:
                    out.append(p)
            return out

        deadline = time.monotonic() + HANG_S
        while relays() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not relays()
        partial = completed_count(killed)
        assert 150 <= partial < 600, partial
        # run it again on the same output: it resumes and completes
        r = subprocess.run(scan_cmd(dev, plan_path, killed), capture_output=True, text=True, check=False,
                           timeout=HANG_S)
        assert r.returncode == 0, r.stderr
        # its rate counts only what this run acquired
        assert f"({partial} from before, resumed); this run {600 - partial} points" in r.stdout, r.stdout
        assert "600/600 points complete" in r.stdout
        # an uninterrupted scan of the same plan
        clean = tmp_path / "clean.h5"
        r = subprocess.run(scan_cmd(dev, plan_path, clean), capture_output=True, text=True, check=False,
                           timeout=HANG_S)
        assert r.returncode == 0, r.stderr
    finally:
        sim.stop(timeout=20)  # SIGTERM, then SIGKILL after 20 s
    assert sim.poll() == 0, (tmp_path / "sim.log").read_text()  # it ended cleanly on SIGTERM
    a, b = read_scan(killed), read_scan(clean)
    assert a.completed.all() and b.completed.all()
    assert np.array_equal(a.alines, b.alines) and np.array_equal(a.scale, b.scale)
    assert np.array_equal(a.meta["point_index"], np.arange(600))
    samples, _, _, sent = read_record(record, plan["id"])
    assert sent.all() and np.array_equal(a.alines_all, samples)
    assert np.abs(a.alines).max() > 10000  # real signals (noise at SNR 50 included)


def test_sim_cli_rejects_bad_options(tmp_path):
    def fpscan(*args):
        return subprocess.run(FPSCAN + list(args), capture_output=True, text=True,
                              timeout=60, check=False)

    r = fpscan("sim", "--source", "replay", str(tmp_path / "missing.h5"))
    assert r.returncode == 2 and "no such file" in r.stderr
    r = fpscan("sim", "--faults", "explode=3")
    assert r.returncode == 2 and "bad fault spec" in r.stderr
    r = fpscan("sim", "--dc-variation", "1.5")
    assert r.returncode == 2 and "dc_variation" in r.stderr
    r = fpscan("scan", "--device", str(tmp_path / "nope"), "--plan", str(tmp_path / "p.json"),
               "--out", str(tmp_path / "o.h5"))
    assert r.returncode == 1 and "error" in r.stderr


def test_ctrl_c_leaves_the_device_idle(tmp_path):
    """Ctrl-C (SIGINT to the host's process group) mid-scan: exit 130, the resume command
    named, the device idle before the plan's end. The test acts on the host's own progress
    lines (a line per report: ``FPSCAN_PROGRESS_PERIOD=0``), not on a poll of the file."""
    import re
    import threading

    from fpscan.driver.host import Scanner

    plan = grid_plan(30, 30, n_t=128)  # 900 points at 50 Hz: 18 s if never stopped
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(plan))
    dev, sim = start_simulator("--prf", "50", log_path=tmp_path / "sim.log", timeout=HANG_S)
    try:
        out = tmp_path / "scan.h5"
        cmd = [a for a in scan_cmd(dev, plan_path, out) if a != "-q"]
        # SIGINT as a terminal leaves it: a parallel test worker (pytest-xdist) ignores it,
        # and an ignored signal is inherited across exec
        host = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, env={**os.environ, "FPSCAN_PROGRESS_PERIOD": "0"},
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        lines: list[str] = []
        thirty = threading.Event()

        def read_stderr() -> None:
            for line in host.stderr:
                lines.append(line)
                m = re.search(r"(\d+)/900 points", line)
                if m and int(m.group(1)) >= 30:
                    thirty.set()

        reader = threading.Thread(target=read_stderr, daemon=True)
        reader.start()
        assert thirty.wait(HANG_S), "".join(lines)
        os.killpg(host.pid, signal.SIGINT)  # as a terminal's Ctrl-C: host and its relay
        host.wait(timeout=HANG_S)
        reader.join(HANG_S)
        err = "".join(lines)
        assert host.returncode == 130, err
        # it says how to resume: the same command again
        assert "to resume, run the same command again" in err and f"--out {out}" in err, err
        with Scanner(dev) as sc:
            st = sc.status()
        assert st.state == "IDLE" and st.next_index < 900
        assert 30 <= completed_count(out) < 900
    finally:
        sim.stop(timeout=20)
