"""Sound-speed autofocus (fpscan.service.autofocus): simulated data at c = 1480 m/s and the
k-Wave 3-D reference data (c = 1500 m/s) searched from the default interval."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.constants import C_AUTOFOCUS_RANGE
from fpscan.physics import Ball, ball_alines
from fpscan.service import autofocus as af
from fpscan.service.recon import reconstruct_grid
from fpscan.service.recon.dataset import GridDataset


def _recon(ds, sound_speed, dtype="float32", **opts):
    return reconstruct_grid(ds.data, ds.dx, ds.dt, sound_speed, dy=ds.dy, t0=ds.t0, dtype=np.dtype(dtype), **opts)


def _unimodal_around(result, tol):
    cs, s = np.array(result.sound_speed_values), np.array(result.sharpness)
    left, right = s[cs < result.sound_speed - tol], s[cs > result.sound_speed + tol]
    return bool(np.all(np.diff(left) > 0) and np.all(np.diff(right) < 0))


def test_autofocus_simulated_balls_1480():
    n, dx, dt, n_t, c_true = 48, 80e-6, 16e-9, 256, 1480.0
    x = (np.arange(n) - (n - 1) / 2) * dx
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    balls = [Ball(0.0, 0.0, 1.6e-3, 150e-6), Ball(0.7e-3, -0.5e-3, 2.4e-3, 200e-6, 0.7),
             Ball(-0.8e-3, 0.6e-3, 2.0e-3, 120e-6)]
    data = ball_alines(pos, balls, dt, n_t, c_true).T.reshape(n_t, n, n)
    data += 0.01 * np.abs(data).max() * np.random.default_rng(0).standard_normal(data.shape)
    ds = GridDataset(data, dx, dt, 1500.0, dy=dx)
    r = af.autofocus(ds, _recon)
    assert abs(r.sound_speed - c_true) / c_true < 0.003, r.as_params()
    assert r.sound_speed_range == C_AUTOFOCUS_RANGE and not r.at_edge
    assert r.evaluations == len(r.sound_speed_values) == len(r.sharpness)
    assert _unimodal_around(r, 5.0), r.as_params()


def test_autofocus_kwave_3d(shared_data):
    with h5py.File(shared_data / "kwave3d_balls_yarn.h5", "r") as f:
        data = f["sensor_data/clean"][...]
        dx, dt, c_ref = float(f.attrs["dy_m"]), float(f.attrs["dt_s"]), float(f.attrs["c_m_per_s"])
    ds = GridDataset(data, dx, dt, 1540.0, dy=dx)  # the dataset's own c is not used
    r = af.autofocus(ds, _recon)
    assert abs(r.sound_speed - c_ref) / c_ref < 0.005, r.as_params()
    assert _unimodal_around(r, 5.0), r.as_params()


def test_focus_function_and_bad_input():
    img = np.zeros((8, 16, 16))
    assert af.focus_sharpness(img) == 0.0
    img[4, 8, 8] = 1.0
    blurred = np.zeros_like(img)
    blurred[4, 6:11, 6:11] = 0.2
    assert af.focus_sharpness(img) > af.focus_sharpness(blurred)
    assert af.focus_sharpness(5 * img) == pytest.approx(af.focus_sharpness(img))  # scale-free
    with pytest.raises(ValueError, match="shape"):
        af.focus_sharpness(np.zeros(5))
    with pytest.raises(ValueError):
        af.focus_sharpness(np.full((4, 4), np.nan))
    for bad in [(1600, 1450), (1450,), ("a", "b"), (0, 1500), (1450, float("inf")), None]:
        with pytest.raises(ValueError, match="sound_speed_range"):
            af.check_sound_speed_range(bad)
    ds = GridDataset(np.zeros((64, 4, 4)), 1e-4, 1e-8, 1500.0, dy=1e-4)
    with pytest.raises(ValueError, match="decimation"):
        af.autofocus(ds, _recon, decimation=9)
    with pytest.raises(ValueError, match="n_coarse"):
        af.search(lambda c: 0.0, n_coarse=2)


def test_search_finds_maximum_of_known_curve():
    calls = []

    def f(c):
        calls.append(c)
        return -abs(c - 1523.4) ** 1.5

    c, curve, at_edge = af.search(f, (1450, 1600), xtol=0.5)
    assert abs(c - 1523.4) < 0.5 and not at_edge
    assert len(curve) == len(set(calls)) < 25
    c, _, at_edge = af.search(lambda c: -c, (1450, 1600))
    assert at_edge and c < 1455
