"""The link-fault counter counts only faults: a fault-free scan reports 0 (a fresh port's
relay start-up and a reply slower than the retry interval are not faults), a scan with N
injected device resets reports N resets. Real simulator on a pty, real scan files."""
from __future__ import annotations

import time

import pytest

from fpscan.driver.faults import FaultSpec
from fpscan.driver.host import Scanner
from fpscan.driver.scanfile import ScanFile
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import BallSource
from tests.driver.driver_helpers import grid_plan, small_phantom

pytestmark = pytest.mark.timeout(120)


def _scan(tmp_path, sim, plan, name: str, **scanner_options):
    with Scanner(sim.path, **scanner_options) as sc:
        sink = ScanFile.create(tmp_path / f"{name}.h5", plan, instrument=sc.identify(), software_version="test")
        with sink:
            return sc.scan(plan, sink)


def test_fault_free_scans_report_no_faults(tmp_path):
    """Three fresh connections (each starts its relay process: the first reply waits for
    it) report no fault. Then a device that answers late, made so by events, not by a
    clock: it holds its replies (``SimulatedScanner.hold``) until the host has resent its
    command twice, then answers every copy; none was lost, so the count stays 0 and each
    repeated reply is a slow reply (a link statistic), as many as the device saw repeated
    commands. A device that computes a whole plan's A-lines at the plan's end (far longer
    than a 0.2 ms retry interval, on an idle machine) keeps that balance however many
    resends the machine's load lets happen: what is true whatever the timing."""
    import threading

    from tests.waits import HANG_S

    plan = grid_plan(12, 10, n_t=128)
    with SimulatedScanner(SimConfig(source=BallSource(small_phantom()), prf=0.0, seed=4)) as sim:
        results = [_scan(tmp_path, sim, plan, f"scan{i}") for i in range(3)]
        before = sim.stats["duplicate_commands"]  # the fresh connections' own, if any
        with Scanner(sim.path, retry=0.001) as sc:
            replies: list[str] = []
            with sim.hold():
                asking = threading.Thread(target=lambda: replies.append(sc.query("*IDN?")), daemon=True)
                asking.start()
                deadline = time.monotonic() + HANG_S  # a hang guard: the wait ends on the event
                while sc.faults["command_retries"] < 2:  # the host has resent the command twice
                    assert time.monotonic() < deadline and asking.is_alive(), (sc.faults, replies)
                    time.sleep(0.001)
            asking.join(HANG_S)
            assert replies and replies[0].startswith("fpscan"), replies
            sink = ScanFile.create(tmp_path / "held.h5", plan, instrument=sc.identify(), software_version="test")
            with sink:
                held = sc.scan(plan, sink)  # its reads take the repeated replies still on their way
        held_duplicates = sim.stats["duplicate_commands"] - before
    slow_plan = grid_plan(64, 64, n_t=256)
    with SimulatedScanner(SimConfig(source=BallSource(small_phantom()), prf=0.0, seed=4, precompute=True)) as sim:
        hasty = _scan(tmp_path, sim, slow_plan, "hasty", retry=0.0002)
        stats = sim.stats
    for res in [*results, held, hasty]:
        assert res.complete and res.points_done == res.n_points
        assert res.faults == {} and res.faults_recovered == 0, res.faults
    # every copy the held device saw again was answered again and counted as a slow reply
    assert held_duplicates >= 2 and held.link.get("slow_replies", 0) == held_duplicates, (held.link, held_duplicates)
    assert hasty.link.get("slow_replies", 0) == stats["duplicate_commands"], (hasty.link, stats)


@pytest.mark.parametrize("n_resets", [1, 3])
def test_injected_resets_are_counted_once_each(tmp_path, n_resets):
    plan = grid_plan(12, 10, n_t=128)
    spec = FaultSpec.parse(",".join(f"reset={k}" for k in (25, 60, 95)[:n_resets]))
    with SimulatedScanner(SimConfig(source=BallSource(small_phantom()), prf=0.0, seed=5, faults=spec)) as sim:
        res = _scan(tmp_path, sim, plan, "resets")
    assert res.complete and res.points_done == 120
    print(res.faults, res.link)
    # each reset is one fault; the reply the rebooting device was slow to give is not
    assert res.faults == {"resets": n_resets} and res.faults_recovered == n_resets, res.faults


@pytest.mark.parametrize("faults", ["", "reset=30,reset=70"])
def test_cli_scan_reports_the_faults_it_met(tmp_path, faults):
    """`fpscan scan` against `fpscan sim` (real processes): "0 link faults recovered" on a
    clean link, "2 link faults recovered" with two device resets injected."""
    import json
    import re
    import subprocess
    import sys

    from fpscan.clients.processes import simulator

    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(grid_plan(12, 10, n_t=128)))
    extra = ["--faults", faults] if faults else []
    with simulator("--prf", "0", "--seed", "6", *extra, log_path=tmp_path / "sim.log", timeout=30) as (dev, _):
        res = subprocess.run([sys.executable, "-m", "fpscan", "scan", "--device", dev, "--plan", str(plan_path),
                              "--out", str(tmp_path / "scan.h5"), "-q"], capture_output=True, text=True, timeout=90)
    assert res.returncode == 0, res.stderr
    found = re.search(r"(\d+) link faults recovered", res.stdout)
    assert found and int(found[1]) == (2 if faults else 0), res.stdout
