"""Multi-wavelength acquisition end to end: host driver ↔ simulated FP scanner on a real
pty with a spectral (HbO2/Hb) phantom, real scan files, ground truth from the simulator's
record and from the published extinction table; SIGKILL of the scanning process and
resume; bad wavelength lists."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from fpscan.driver.faults import FaultSpec
from fpscan.driver.host import Scanner
from fpscan.driver.plan import aline_order, check_plan, load_plan, plan_id_of
from fpscan.driver.plan_image import plan_image
from fpscan.driver.scanfile import FORMAT_1, ScanFile, read_scan
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import BallSource
from fpscan.physics import ball_alines
from fpscan.physics.spectra import absorption
from tests.driver.driver_helpers import grid_plan, read_record, small_phantom
from tests.waits import HANG_S

pytestmark = pytest.mark.timeout(120)
WAVELENGTHS = [7.6e-7, 8.5e-7]  # either side of the HbO2/Hb isosbestic point (~800 nm)
SO2 = [0.6, 0.95, 0.8]  # one per ball of small_phantom()


def spectral_plan(n_x, n_y, *, n_t=128, order=None, prf=0.0, wavelengths=WAVELENGTHS):
    plan = grid_plan(n_x, n_y, n_t=n_t, prf=prf)
    plan["acquisition"]["wavelengths"] = list(wavelengths)
    if order is not None:
        plan["acquisition"]["wavelength_order"] = order
    plan["id"] = plan_id_of(plan)
    return plan


def spectral_sim(tmp_path, **kw) -> SimulatedScanner:
    kw.setdefault("prf", 0.0)
    return SimulatedScanner(SimConfig(source=BallSource(small_phantom(), so2=SO2),
                                      record=tmp_path / "truth.h5", **kw))


def assert_every_aline_matches_record(scan_path, record_path, plan):
    scan = read_scan(scan_path)
    samples, scale, dc, sent = read_record(record_path, plan["id"])
    n = len(plan["points"]["indices"])
    assert scan.alines_all.shape == (2, n, plan["acquisition"]["n_t"])
    assert scan.completed_all.all() and sent.all()
    assert np.array_equal(scan.alines_all, samples)  # bit-identical, both wavelengths
    assert np.array_equal(scan.meta_all["scale"], scale)
    assert np.array_equal(scan.meta_all["wavelength_index"], [[0] * n, [1] * n])
    assert np.array_equal(scan.meta_all["excitation_wavelength_m"],
                          np.repeat(np.array(WAVELENGTHS)[:, None], n, axis=1))
    return scan


def expected_pressure(plan, w):
    """Independent oracle: each ball's exact wave with p0 = Γ Φ μa(λ_w) (μa from the
    published molar extinction of HbO2 and Hb at the ball's sO2, whole-blood THb)."""
    a = plan["acquisition"]
    pos = np.asarray(plan["points"]["positions"], dtype=np.float64)
    mu_a = absorption(WAVELENGTHS[w], np.array(SO2), 150 / 64500 * 1e3)[0]
    out = np.zeros((len(pos), a["n_t"]))
    for ball, mu in zip(small_phantom(), mu_a):
        b = type(ball)(ball.x, ball.y, ball.z, ball.radius, 0.2 * 100.0 * mu)
        out += ball_alines(pos, [b], a["dt"], a["n_t"], 1500.0)
    return out


def test_two_wavelengths_with_link_faults_every_aline_once(tmp_path):
    plan = spectral_plan(12, 10)  # 120 points × 2 wavelengths, per point (the default)
    n = 120
    faults = FaultSpec.parse("corrupt=1e-4,drop=1e-4,stall=70:1.0,reset=150")
    appended = []

    class CountingFile(ScanFile):
        def append(self, k, samples, meta):
            ok = super().append(k, samples, meta)
            appended.append((meta["wavelength_index"], k, ok))
            return ok

    with spectral_sim(tmp_path, faults=faults, seed=4) as sim:
        with Scanner(sim.path, response_timeout=10) as sc:
            sink = CountingFile.create(tmp_path / "scan.h5", plan, instrument=sc.identify(),
                                       software_version="test")
            with sink:
                res = sc.scan(plan, sink)
        stats = dict(sim.stats)
    print("host faults:", res.faults, res.link, "device:", stats)
    assert res.complete and res.points_done == n and res.alines_done == res.n_alines == 2 * n
    assert stats["resets"] == 1 and res.faults["resets"] == 1 and res.faults["bad_frames"] > 0
    # every (wavelength, point) appended exactly once, none refused as a duplicate
    assert sorted((w, k) for w, k, _ in appended) == [(w, k) for w in (0, 1) for k in range(n)]
    assert all(ok for _, _, ok in appended)
    scan = assert_every_aline_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)
    # the physics: each wavelength's A-lines are the phantom at that wavelength's absorption
    for w in (0, 1):
        want = expected_pressure(plan, w)
        quantum = scan.meta_all["scale"][w][:, None] / scan.meta_all["dc_level"][w][:, None]
        assert np.all(np.abs(scan.pressure_all[w] - want) <= 0.5 * quantum * (1 + 1e-9))
    # sO2 0.6 and 0.95 balls really differ in spectrum: the wavelength ratio is not one number
    assert not np.allclose(expected_pressure(plan, 1).max(1), expected_pressure(plan, 0).max(1))


@pytest.mark.parametrize("order", ["per_point", "per_pass"])
def test_acquisition_order_follows_the_plan(tmp_path, order):
    plan = spectral_plan(6, 5, n_t=64, order=order, prf=2000.0)  # 30 points × 2
    with spectral_sim(tmp_path, prf=2000.0) as sim, Scanner(sim.path) as sc:
        with ScanFile.create(tmp_path / "scan.h5", plan, instrument={},
                             software_version="t") as sf:
            assert sc.scan(plan, sf).complete
    scan = assert_every_aline_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)
    # one run, one boot: the device's pulse counter orders the A-lines as fired
    pulses = scan.meta_all["pulse_number"]
    k, w = aline_order(30, 2, order)
    assert np.array_equal(pulses[w, k], np.sort(pulses.ravel()))
    assert len(np.unique(pulses)) == 60


def test_sigkill_two_wavelength_scan_then_resume(tmp_path):
    plan = spectral_plan(16, 15, n_t=256, order="per_pass", prf=400.0)  # 480 A-lines, 1.2 s
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(plan))
    out = tmp_path / "scan.h5"

    def done() -> int:
        try:
            return int(read_scan(out).completed_all.sum())
        except (OSError, ValueError, KeyError):
            return 0

    with spectral_sim(tmp_path, prf=400.0, seed=2, snr=50.0) as sim:
        cmd = [sys.executable, "-m", "fpscan", "scan", "--device", sim.path, "--plan",
               str(plan_path), "--out", str(out), "-q"]
        host = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + HANG_S
        while done() < 300 and time.monotonic() < deadline:  # into the second pass
            time.sleep(0.05)
        host.send_signal(signal.SIGKILL)
        host.wait(timeout=10)
        partial = read_scan(out)
        assert 300 <= partial.completed_all.sum() < 480
        assert partial.completed_all[0].all()  # per pass: wavelength 0 finished first
        # a new process resumes on the same file (retrying while the old relay lets go)
        for _ in range(20):
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG_S)
            if r.returncode == 0 or "lock" not in r.stderr:
                break
            time.sleep(0.2)
        assert r.returncode == 0, r.stderr
    with h5py.File(out, "r") as f:  # closed cleanly by the second run
        assert f.attrs["format"] == "fpscan-scan/2"
    assert_every_aline_matches_record(out, tmp_path / "truth.h5", plan)


def test_single_wavelength_users_read_what_they_had(tmp_path):
    """An fpscan-scan/1 file (written here with h5py in that layout) reads as one
    wavelength; a version-2 file of one wavelength gives the same views."""
    plan = grid_plan(4, 3, n_t=32)
    n, n_t = 12, 32
    rng = np.random.default_rng(1)
    alines = rng.integers(-2000, 2000, (n, n_t)).astype(np.int16)
    v1_meta = np.dtype([(k, "<u8" if k in ("run_id", "boot_id", "pulse_number") else
                         "<i8" if k == "point_index" else "<f8")
                        for k in ("run_id", "boot_id", "point_index", "pulse_number",
                                  "timestamp_s", "bias_wavelength_m", "dc_level",
                                  "pulse_energy_j", "dt_s", "scale", "offset")])
    meta = np.zeros(n, v1_meta)
    meta["point_index"] = np.arange(n)
    meta["dc_level"], meta["scale"], meta["offset"] = 0.5, 1e-3, 2e-4
    done = np.ones(n, np.uint8)
    done[5] = 0
    path = tmp_path / "v1.h5"
    with h5py.File(path, "w", libver="latest") as f:
        f["alines"], f["aline_meta"], f["completed"] = alines, meta, done
        f["positions"] = np.asarray(plan["points"]["positions"])
        f["indices"] = np.asarray(plan["points"]["indices"], dtype=np.int32)
        f["weights"] = np.asarray(plan["points"]["weights"])
        f.create_dataset("plan_json", data=json.dumps(plan), dtype=h5py.string_dtype())
        f.attrs.update(format=FORMAT_1, plan_id=plan["id"], n_points=n, n_t=n_t, dt_s=8e-9,
                       sound_speed_m_per_s=1500.0, wavelengths_m=[7.5e-7],
                       acquisition_json=json.dumps(plan["acquisition"]), instrument_json="{}",
                       software_version="0.1", created_utc="2026-01-01T00:00:00+00:00")
    s = read_scan(path)
    assert s.n_wavelengths == 1 and s.alines.shape == (n, n_t) and s.pressure.shape == (n, n_t)
    want = (alines.astype(np.float64) * 1e-3 + 2e-4) / 0.5
    np.testing.assert_array_equal(s.pressure[done == 1], want[done == 1])
    assert np.isnan(s.pressure[5]).all() and s.completed.sum() == 11
    assert s.meta["excitation_wavelength_m"][0] == 7.5e-7 and s.meta["wavelength_index"].max() == 0
    assert s.completed_only().n_points == 11
    with pytest.raises(ValueError, match="resumed"):
        ScanFile.open_append(path)


@pytest.mark.parametrize("wavelengths, match", [
    ([], "at least one"), ([3.5e-7], "400 nm"), ([7.5e-7, 2.1e-6], "2000 nm"),
    ([7.5e-7, 8e-7, 7.5e-7], "repeat"), ("7.5e-7", "list"),
])
def test_bad_wavelength_lists_are_refused(tmp_path, wavelengths, match):
    plan = grid_plan(3, 3)
    plan["acquisition"]["wavelengths"] = wavelengths
    plan["id"] = plan_id_of(plan)
    for check in (check_plan, plan_image,
                  lambda p: ScanFile.create(tmp_path / "x.h5", p, instrument={},
                                            software_version="t")):
        with pytest.raises(ValueError, match=match):
            check(plan)
    assert not (tmp_path / "x.h5").exists()


def test_bad_wavelength_order_is_refused():
    plan = spectral_plan(3, 3, order="sideways")
    with pytest.raises(ValueError, match="wavelength_order"):
        load_plan(plan)


def test_plan_builder_and_cli_carry_the_wavelength_order(tmp_path):
    from fpscan.service.plans import Lattice, make_plan

    plain = make_plan("full", lattice=Lattice(3, 3, 1e-4), wavelengths=WAVELENGTHS).to_dict()
    assert "wavelength_order" not in plain["acquisition"]  # absent = per point; ids unchanged
    out = tmp_path / "plan.json"
    r = subprocess.run([sys.executable, "-m", "fpscan", "plan", "full", "--n-x", "3",
                        "--pitch", "1e-4", "--wavelength", "7.6e-7", "--wavelength", "8.5e-7",
                        "--wavelength-order", "per_pass", "--out", str(out)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    plan = load_plan(out)
    assert plan["acquisition"]["wavelength_order"] == "per_pass"
    assert plan["acquisition"]["wavelengths"] == WAVELENGTHS
    with pytest.raises(ValueError, match="per_point"):
        make_plan("full", lattice=Lattice(3, 3, 1e-4), wavelengths=WAVELENGTHS,
                  wavelength_order="sideways")
