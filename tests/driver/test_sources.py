"""The simulator's sources and signal model, checked through the serial link against the
physics module (fpscan.physics, an independent implementation of the exact forward
models) and against statistics of the injected noise."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.driver.acquire import acquire
from fpscan.driver.scanfile import read_scan
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import BallSource, VolumeSource, default_phantom
from fpscan.physics import ball_alines
from fpscan.physics.forward import forward_points
from tests.driver.driver_helpers import grid_plan, small_phantom

pytestmark = pytest.mark.timeout(120)


def scan_with(tmp_path, plan, **cfg):
    cfg.setdefault("prf", 0.0)
    with SimulatedScanner(SimConfig(**cfg)) as sim:
        res = acquire(sim.path, plan, tmp_path / "scan.h5")
    assert res.complete
    return read_scan(tmp_path / "scan.h5")


def test_balls_with_dc_map_give_exact_n_waves_after_dc_normalisation(tmp_path):
    plan = grid_plan(16, 12, n_t=300)
    scan = scan_with(tmp_path, plan, source=BallSource(small_phantom()), dc_variation=0.4,
                     dc_level=0.8)
    want = ball_alines(np.asarray(plan["points"]["positions"]), small_phantom(), 8e-9, 300)
    half_step = (scan.scale / scan.dc_level)[:, None] * 0.5
    assert np.all(np.abs(scan.pressure - want) <= half_step * (1 + 1e-6))
    dc = scan.dc_level
    assert 0.8 * 0.6 - 1e-6 <= dc.min() < 0.7 and 0.9 < dc.max() <= 0.8 * 1.4 + 1e-6


def test_volume_source_is_the_planar_forward_model(tmp_path):
    p0 = np.zeros((12, 16, 16))
    p0[5:8, 6:9, 7:10] = 1.0
    p0[9:11, 3:5, 10:12] = 0.5
    vol = tmp_path / "p0.h5"
    with h5py.File(vol, "w") as f:
        f["p0"] = p0
        f.attrs["dx_m"] = 6e-5
    plan = grid_plan(8, 6, 6e-5, n_t=128)
    scan = scan_with(tmp_path, plan, source=VolumeSource(vol))
    want = forward_points(p0, 6e-5, 6e-5, np.asarray(plan["points"]["positions"]), 8e-9, 128)
    assert np.abs(want).max() > 0.01
    assert np.all(np.abs(scan.pressure - want) <= scale_half(scan) * (1 + 1e-6) + 1e-12)


def scale_half(scan):
    return (scan.scale / scan.dc_level)[:, None] * 0.5


def test_noise_at_snr_and_bandwidth(tmp_path):
    plan = grid_plan(12, 12, n_t=1024)
    snr = 40.0
    scan = scan_with(tmp_path, plan, source=BallSource(small_phantom()), snr=snr, seed=7,
                     bandwidth=20e6)
    clean = ball_alines(np.asarray(plan["points"]["positions"]), small_phantom(), 8e-9, 1024)
    # the sensor's 2nd-order Butterworth low-pass (scipy), then white noise of std peak/snr
    from scipy.signal import butter, sosfilt

    filtered = sosfilt(butter(2, 20e6, fs=125e6, output="sos"), clean, axis=1)
    assert np.abs(filtered - clean).max() > 0.05  # the bandwidth limit matters here
    sigma = max(b.amplitude for b in small_phantom()) / snr
    resid = scan.pressure - filtered
    assert resid.std() == pytest.approx(sigma, rel=0.03)
    assert abs(resid.mean()) < 0.01 * sigma and np.abs(resid).max() < 6 * sigma
    lag1 = np.mean(resid[:, 1:] * resid[:, :-1]) / resid.var()
    assert abs(lag1) < 0.02  # white
    # reproducible: the same seed gives the same A-lines, another seed does not
    (tmp_path / "b").mkdir()
    again = scan_with(tmp_path / "b", plan, source=BallSource(small_phantom()), snr=snr,
                      seed=7, bandwidth=20e6)
    assert np.array_equal(again.alines, scan.alines)


def test_the_sensor_response_refuses_a_band_or_interval_that_is_not_positive():
    from fpscan.driver.simulator import sensor_response

    for bandwidth, dt in ((0.0, 8e-9), (-1e6, 8e-9), (float("nan"), 8e-9), (20e6, 0.0), (20e6, float("inf"))):
        with pytest.raises(ValueError, match="finite and > 0"):
            sensor_response(np.ones((2, 16)), bandwidth, dt)


def test_default_phantom_has_balls_and_a_curved_tube():
    balls = default_phantom()
    tube = [b for b in balls if b.radius == pytest.approx(0.1e-3)]
    assert len(balls) - len(tube) >= 3 and len(tube) >= 20
    xyz = np.array([[b.x, b.y, b.z] for b in tube])
    steps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    assert steps.max() < 2 * 0.1e-3  # neighbouring tube balls overlap: a continuous tube
    assert np.ptp(xyz[:, 1]) > 0.5e-3 and np.ptp(xyz[:, 2]) > 0.5e-3  # curved, not straight
    half = 226 * 6e-5 / 2
    assert all(abs(b.x) < half and abs(b.y) < half and b.z > b.radius for b in balls)


def test_averaging_pulses_reduces_noise_by_sqrt_n(tmp_path):
    plan = grid_plan(8, 8, n_t=1024, averages=4)
    snr = 20.0
    scan = scan_with(tmp_path, plan, source=BallSource(small_phantom()), snr=snr, seed=3)
    clean = ball_alines(np.asarray(plan["points"]["positions"]), small_phantom(), 8e-9, 1024)
    sigma = max(b.amplitude for b in small_phantom()) / snr / np.sqrt(4)
    assert (scan.pressure - clean).std() == pytest.approx(sigma, rel=0.05)


@pytest.mark.parametrize("source", ["volume", "replay"])
def test_volume_and_replay_files_go_through_the_hdf5_vetting(tmp_path, source):
    # a file that points at another one (an external link), and one whose dataset declares far more
    # than it stores: both refused before anything is read, as every HDF5 input of the service
    from fpscan.driver.sources import ReplaySource

    secret = tmp_path / "secret.h5"
    with h5py.File(secret, "w") as f:
        f["p0"] = np.ones((2, 2, 2))
    linked = tmp_path / "linked.h5"
    with h5py.File(linked, "w") as f:
        f.attrs["dx_m"] = 1e-4
        f.attrs["dt_s"] = 8e-9
        f["p0"] = h5py.ExternalLink(str(secret), "p0")
        f["sensor_data/clean"] = h5py.ExternalLink(str(secret), "p0")
    sparse = tmp_path / "sparse.h5"
    with h5py.File(sparse, "w") as f:
        f.attrs["dx_m"] = 1e-4
        f.attrs["dt_s"] = 8e-9
        for name in ("p0", "sensor_data/clean"):
            f.create_dataset(name, shape=(512, 512, 512), dtype="f8", chunks=(64, 64, 64), compression="gzip")
    make = (lambda p: VolumeSource(p)) if source == "volume" else (lambda p: ReplaySource(p))
    with pytest.raises(ValueError, match="external link"):
        make(linked)
    with pytest.raises(ValueError, match="never written|declare"):
        make(sparse)
