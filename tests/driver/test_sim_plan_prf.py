"""``fpscan sim`` without ``--prf`` fires at the PRF each plan asks for (its acquisition.prf;
50 Hz for a plan that asks for none), so a scan takes what the plan's estimate says; an
explicit ``--prf`` is the laser's for every plan. Real simulator processes on a pty, real
scans; the A-lines' device timestamps (the simulated laser's pulse clock) are the oracle."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.clients.processes import simulator
from fpscan.driver.acquire import acquire
from fpscan.driver.scanfile import read_scan
from tests.driver.driver_helpers import grid_plan
from tests.waits import HANG_S

pytestmark = pytest.mark.timeout(120)


def _spacing(device: str, plan: dict, out) -> np.ndarray:
    assert acquire(device, plan, out).complete
    return np.diff(read_scan(out).meta["timestamp_s"])


def test_the_plan_rate_paces_a_simulator_started_without_prf(tmp_path):
    with simulator("--seed", "2", log_path=tmp_path / "sim.log", timeout=HANG_S) as (device, _proc):
        assert np.allclose(_spacing(device, grid_plan(4, 3, n_t=64, prf=400.0), tmp_path / "a.h5"), 1 / 400, atol=1e-9)
        # a plan that asks for no rate (0: the device's own): the simulator's 50 Hz
        assert np.allclose(_spacing(device, grid_plan(3, 2, n_t=64, prf=0.0), tmp_path / "b.h5"), 1 / 50, atol=1e-9)
    log = (tmp_path / "sim.log").read_text()
    assert "the plan's PRF" in log, log


def test_an_explicit_prf_wins_over_the_plan(tmp_path):
    with simulator("--prf", "1000", log_path=tmp_path / "sim.log", timeout=HANG_S) as (device, _proc):
        assert np.allclose(_spacing(device, grid_plan(4, 3, n_t=64, prf=40.0), tmp_path / "a.h5"), 1 / 1000, atol=1e-9)
