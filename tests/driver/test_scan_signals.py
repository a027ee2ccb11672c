"""`fpscan scan` stopped by SIGINT, SIGTERM or SIGKILL at random moments of a real simulated
scan: after SIGINT/SIGTERM the file is closed (a plain ``h5py.File(path, "r")`` opens it) and
holds the points the message counts; after SIGKILL, ``fpscan repair`` (or the resume) leaves
such a file, with the A-lines the killed writer had marked complete."""
from __future__ import annotations

import contextlib
import json
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time

import h5py
import numpy as np
import pytest

from fpscan.clients.processes import start_simulator
from fpscan.driver.scanfile import completed_count
from tests.driver.driver_helpers import grid_plan
from tests.waits import HANG_S

# mostly real time: the simulator's PRF and each host's start-up
pytestmark = [pytest.mark.timeout(300), pytest.mark.waits]
FPSCAN = [sys.executable, "-m", "fpscan"]
N = 300  # points of the plan: 0.3 s at 1 kHz
TRIALS = 24  # 8 of each signal


def plain_count(path) -> int:
    """Points complete, read by a plain (not SWMR) HDF5 reader: it opens only a closed file."""
    with h5py.File(path, "r") as f:
        return int(np.asarray(f["completed"][()], dtype=bool).all(axis=0).sum())


def start_scan(dev, plan_path, out, target):
    """``fpscan scan`` with a progress line per report (every 0.25 s); the returned event is
    set once a line says ``target`` points are done (or the scan is over)."""
    host = subprocess.Popen(FPSCAN + ["scan", "--device", dev, "--plan", str(plan_path), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "FPSCAN_PROGRESS_PERIOD": "0"},
                            # as a terminal leaves SIGINT (a test worker may ignore it)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines: list[str] = []
    reached = threading.Event()

    def read_stderr() -> None:
        for line in host.stderr:
            lines.append(line)
            m = re.search(rf"(\d+)/{N} points", line)
            if m and int(m.group(1)) >= target:
                reached.set()
        reached.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    return host, lines, reached, reader


def test_signals_at_random_moments_leave_files_every_reader_opens(tmp_path):
    plan = grid_plan(20, 15, n_t=64)
    assert len(plan["points"]["indices"]) == N
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(plan))
    rng = random.Random(20261128)
    sigs = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL] * (TRIALS // 3)
    rng.shuffle(sigs)
    seen: list[tuple[str, int, int]] = []
    dev, sim = start_simulator("--prf", "1000", log_path=tmp_path / "sim.log", timeout=HANG_S)
    try:
        for trial, sig in enumerate(sigs):
            out = tmp_path / f"scan{trial}.h5"
            # the moment: a random time after the host's first progress line (it may be
            # connecting, creating the file, scanning, or done); any count is right
            host, lines, reached, reader = start_scan(dev, plan_path, out, 0)
            assert reached.wait(HANG_S), "".join(lines)
            time.sleep(rng.uniform(0.0, 0.4))
            with contextlib.suppress(ProcessLookupError):  # it may have ended already
                if sig == signal.SIGTERM and trial % 2:
                    host.send_signal(sig)  # `kill PID`
                else:
                    os.killpg(host.pid, sig)  # Ctrl-C, or a service manager's stop of the group
            host.wait(timeout=HANG_S)
            reader.join(HANG_S)
            err = "".join(lines)
            if f"done  100%  {N}/{N} points" in err and host.returncode in (0, -sig, 128 + sig):
                # the signal came after the scan ended (its file closed, complete): the
                # process exits as the signal's default action or the summary says
                said = N
                assert plain_count(out) == N
            elif sig == signal.SIGKILL:
                assert host.returncode == -signal.SIGKILL
                if not out.exists():  # killed before the file was in place
                    seen.append((sig.name, -1, 0))
                    continue
                killed = completed_count(out)  # as an SWMR reader: the file is left open
                r = subprocess.run(FPSCAN + ["repair", str(out)], capture_output=True, text=True,
                                   timeout=HANG_S, check=False)
                assert r.returncode == 0, r.stderr
                m = re.search(rf"(\d+)/{N} points complete", r.stdout)
                assert m, r.stdout
                said = int(m.group(1))
                assert said == killed == plain_count(out), (r.stdout, killed)
            else:
                assert host.returncode == 128 + sig, err
                m = re.search(rf"interrupted(?: \(SIGTERM\))?: (\d+)(?:/{N})? points are in", err)
                assert m, err
                assert "to resume, run the same command again" in err, err
                said = int(m.group(1))
                assert plain_count(out) == said if out.exists() else said == 0, err
            assert not out.with_name(out.name + ".lock").exists()
            seen.append((sig.name, host.returncode, said))
        # a killed scan's file also resumes to the end, and then every reader opens it
        out = tmp_path / "resumed.h5"
        host, lines, reached, reader = start_scan(dev, plan_path, out, 0)  # "running": the file is in place
        assert reached.wait(HANG_S), "".join(lines)
        os.killpg(host.pid, signal.SIGKILL)
        host.wait(timeout=HANG_S)
        reader.join(HANG_S)
        r = subprocess.run(FPSCAN + ["scan", "--device", dev, "--plan", str(plan_path), "--out", str(out), "-q"],
                           capture_output=True, text=True, timeout=HANG_S, check=False)
        assert r.returncode == 0, r.stderr
        assert plain_count(out) == N
    finally:
        sim.stop(timeout=20)
    assert len(seen) == TRIALS, seen
    # the moments spread over the scan: some signals stopped it part-way
    assert any(0 < n < N for _, _, n in seen), seen
