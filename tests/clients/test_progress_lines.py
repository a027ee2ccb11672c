"""Progress a person reads without a terminal: `fpscan recon` writes a line per report (period
0) with stage, % and ETA, in order; the lines repeat every period between reports; a client
that joins a running job reports its stages in the order the job made them (no stale later
stage first). Oracles: the command's own stderr through a pipe, a real ``fpscan serve``."""
from __future__ import annotations

import io
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from tests.clients.clients_servers import clean_env
from tests.waits import HANG_S

TOKEN = "progress-test-token"
LINE = re.compile(r"^recon tv: (?P<stage>[a-z][a-z ]*(?: \d+/\d+)?)  (?P<pct>\d+)%(?P<rest>.*)$")


def test_recon_progress_lines_off_a_terminal(tmp_path):
    """A small tv job with stderr piped (not a terminal) and FPSCAN_PROGRESS_PERIOD=0:
    several lines, stages in order, percentages non-decreasing, the iterations counted
    up, an ETA once the rate is known."""
    rng = np.random.default_rng(0)
    np.save(tmp_path / "in.npy", rng.standard_normal((64, 16)).astype(np.float32))
    res = subprocess.run(
        [sys.executable, "-m", "clients", "recon", str(tmp_path / "in.npy"), "--dt", "20ns", "--dx", "30um",
         "--method", "tv", "--iterations", "8", "--n-z", "16", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=300, env=clean_env(FPSCAN_PROGRESS_PERIOD="0"))
    assert res.returncode == 0, res.stderr
    print(res.stderr)
    lines = [m for m in map(LINE.match, res.stderr.splitlines()) if m]
    assert len(lines) >= 8, res.stderr
    pcts = [int(m["pct"]) for m in lines]
    assert pcts == sorted(pcts) and pcts[0] == 0 and pcts[-1] == 100, pcts
    iterations = [int(m["stage"].split()[1].split("/")[0]) for m in lines if m["stage"].startswith("iteration")]
    assert len(iterations) >= 3 and iterations == sorted(iterations), iterations
    assert any(re.search(r"ETA \d\d:\d\d", m["rest"]) for m in lines), res.stderr
    assert "\x1b[" not in res.stderr  # no terminal control codes in a log


class _Log(io.StringIO):
    """A log stream (not a terminal) that a reader thread may poll."""

    def isatty(self) -> bool:
        return False


def test_progress_lines_repeat_every_period_between_reports():
    """One report, then silence (a long step): the line comes again every period, so a log
    shows the job is alive; the ETA it had counts down, never up."""
    from clients.cli._common import ProgressBar

    log = _Log()
    with ProgressBar("recon tv", stream=log, period=0.05) as bar:
        bar({"stage": "iteration 3/60", "fraction": 0.3, "eta_s": 100.0})
        deadline = time.monotonic() + HANG_S
        while log.getvalue().count("\n") < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 4 and all(line.startswith("recon tv: iteration 3/60  30%") for line in lines), lines
    etas = [int(m[1]) * 60 + int(m[2]) for m in (re.search(r"ETA (\d\d):(\d\d)", line) for line in lines) if m]
    assert len(etas) == len(lines) and etas == sorted(etas, reverse=True), lines


def test_progress_period_from_the_environment(monkeypatch):
    from clients.cli._common import PROGRESS_PERIOD_S, progress_period

    monkeypatch.delenv("FPSCAN_PROGRESS_PERIOD", raising=False)
    assert progress_period() == PROGRESS_PERIOD_S
    monkeypatch.setenv("FPSCAN_PROGRESS_PERIOD", "0.5")
    assert progress_period() == 0.5
    for bad in ("-1", "soon", "nan"):
        monkeypatch.setenv("FPSCAN_PROGRESS_PERIOD", bad)
        with pytest.raises(ValueError, match="FPSCAN_PROGRESS_PERIOD"):
            progress_period()


def test_wait_joining_a_running_job_reports_stages_in_order(server, tmp_path):
    """``Client.wait`` started while a tv job iterates: the first progress it reports is the
    job's first stage, never the current one before the earlier ones (the demo's stale
    ``writing 90%`` before ``starting 0%``); fractions never go back."""
    from clients.http import Client

    rng = np.random.default_rng(1)
    np.save(tmp_path / "in.npy", rng.standard_normal((128, 24)).astype(np.float32))
    with Client(server, token=TOKEN) as api, Client(server, token=TOKEN) as control:
        ds = api.upload_dataset(tmp_path / "in.npy", "npy", dt=20e-9, dx=30e-6)
        # tol 0: no stopping rule, so the job iterates until it is cancelled (with the default rule
        # it may converge, and succeed, before the cancel arrives: CI under load did so once)
        job_id = api.start_reconstruction(dataset_id=ds, method="tv", params={"iterations": 10000, "n_z": 64, "tol": 0})
        deadline = time.monotonic() + HANG_S
        while not str(api.get_job(job_id).progress.stage or "").startswith("iteration"):
            assert time.monotonic() < deadline, api.get_job(job_id)
            time.sleep(0.05)
        seen: list[dict] = []
        cancelled = threading.Event()

        def on_progress(p: dict) -> None:
            seen.append(p)
            if str(p.get("stage", "")).startswith("iteration") and not cancelled.is_set():
                cancelled.set()  # seen iterating: end the job (it would run for minutes)
                control.cancel_job(job_id)

        job = api.wait(job_id, on_progress=on_progress, timeout=120, raise_on_failure=False)
    assert job.state == "cancelled"
    stages = [p.get("stage") for p in seen]
    fractions = [p["fraction"] for p in seen if p.get("fraction") is not None and p.get("stage") != "cancelled"]
    assert stages[0] in ("starting", "loading"), stages
    assert fractions == sorted(fractions), list(zip(stages, fractions))
