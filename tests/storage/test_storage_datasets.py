"""Dataset import (fpscan.service.storage.loader): the real k-Wave files, NumPy arrays, our scan
files and IPASC files, and bad input."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.driver.scanfile import read_scan
from fpscan.service.formats.ipasc import export_scan
from fpscan.service.recon.dataset import GridDataset, PointDataset
from fpscan.service.storage.loader import detect_format, load_dataset
from tests.storage.storage_helpers import build_plan


def test_kwave_reference_files(shared_data):
    d3 = load_dataset(shared_data / "kwave3d_balls_yarn.h5")
    assert isinstance(d3, GridDataset) and d3.kind == "grid"
    assert d3.data.shape == (751, 96, 96) and d3.data.dtype == np.float32
    assert (d3.dx, d3.dy, d3.dt, d3.sound_speed) == (6e-5, 6e-5, 8e-9, 1500.0)
    with h5py.File(shared_data / "kwave3d_balls_yarn.h5", "r") as f:
        np.testing.assert_array_equal(d3.data[100], f["sensor_data/clean"][100])
    x, y = d3.axes()
    assert x[0] == pytest.approx(-47.5 * 6e-5) and y[-1] == pytest.approx(47.5 * 6e-5)
    d2 = load_dataset(shared_data / "kwave2d_points.h5", dt=1e-8)
    assert d2.data.shape == (3519, 1024) and d2.dy is None
    assert (d2.dx, d2.dt, d2.sound_speed) == (5e-5, 1e-8, 1500.0)
    # explicit spacings win over the file's
    d2b = load_dataset(shared_data / "kwave2d_points.h5", "kwave-hdf5", dx=1e-4, sound_speed=1480.0)
    assert (d2b.dx, d2b.sound_speed) == (1e-4, 1480.0)
    p0 = load_dataset(shared_data / "kwave2d_points.h5", key="p0", dt=1e-8)
    assert p0.data.shape == (256, 1024)


def test_kwave_naming_read_alike_by_the_upload_reader_and_the_replay_source(tmp_path):
    """k-Wave names depth x: in a k-Wave-named file our lateral x spacing is dz_m, here
    unlike the depth spacing dx_m. The upload reader and the simulator's replay source
    (fpscan.driver.sources) take the same pitch from it: a plan at that pitch replays, one at
    the depth spacing does not."""
    import dataclasses

    from fpscan.driver.plan_image import DevicePlan
    from fpscan.driver.sources import ReplaySource

    path = tmp_path / "kwave_named.h5"
    data = np.random.default_rng(2).standard_normal((16, 6, 8))
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data/clean", data=data).attrs["kwave_DataOrder"] = "tyz"
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-5, "dy_m": 6e-5, "dz_m": 6e-5, "c_m_per_s": 1500.0})
    ds = load_dataset(path)
    assert (ds.dx, ds.dy) == (6e-5, 6e-5)
    replay = ReplaySource(path)
    plan = DevicePlan(plan_id="p", n_x=8, n_y=6, pitch=6e-5, n_t=16, averages=1, dt=1e-8, prf=0.0,
                      wavelength=7.5e-7, sound_speed=1500.0, indices=np.zeros((1, 2), np.uint16))
    replay.prepare(plan)
    with pytest.raises(ValueError, match="pitch"):
        replay.prepare(dataclasses.replace(plan, pitch=1e-5))


def test_generic_hdf5_and_npy(tmp_path):
    a = np.random.default_rng(1).standard_normal((50, 4, 6))
    h5 = tmp_path / "mine.h5"
    with h5py.File(h5, "w") as f:  # our own naming: dx_m is lateral x, dy_m lateral y
        f["signals"] = a
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4, "dy_m": 2e-4, "c_m_per_s": 1450.0})
    d = load_dataset(h5)
    assert detect_format(h5) == "kwave-hdf5"
    np.testing.assert_array_equal(d.data, a)
    assert (d.dx, d.dy, d.dt, d.sound_speed) == (1e-4, 2e-4, 1e-8, 1450.0)
    npy = tmp_path / "a.npy"
    np.save(npy, a[:, 0, :].astype(np.int16))
    d = load_dataset(npy, dt=2e-8, dx=5e-5)
    assert detect_format(npy) == "npy" and d.data.dtype == np.float32 and d.data.shape == (50, 6)
    assert (d.dt, d.dx, d.dy, d.sound_speed) == (2e-8, 5e-5, None, 1500.0)


def test_scan_and_ipasc_give_the_same_point_data(tmp_path, make_scan):
    plan = build_plan(5, 4, 40)
    done = [0, 3, 4, 8, 9, 10, 15, 19]
    scan = make_scan("scan.h5", plan, done)
    ipasc = export_scan(scan, tmp_path / "scan_ipasc.h5")
    assert detect_format(scan) == "fpscan" and detect_format(ipasc) == "ipasc"
    a, b = load_dataset(scan), load_dataset(ipasc)
    assert isinstance(a, PointDataset) and isinstance(b, PointDataset)
    ref = read_scan(scan)
    np.testing.assert_array_equal(a.alines, ref.pressure[done])
    np.testing.assert_array_equal(a.positions, np.array(plan["points"]["positions"])[done])
    for name in ("alines", "positions", "weights"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.dt, a.sound_speed) == (b.dt, b.sound_speed) == (2e-8, 1490.0)
    for ga, gb in zip(a.grid, b.grid):
        np.testing.assert_array_equal(ga, gb)
    np.testing.assert_allclose(a.grid[0], (np.arange(5) - 2) * 1e-4, atol=1e-18)
    assert load_dataset(scan, sound_speed=1500.0).sound_speed == 1500.0


def test_bad_input(tmp_path, make_scan):
    a = np.zeros((10, 5))
    np.save(tmp_path / "a.npy", a)
    with pytest.raises(ValueError, match="dt"):
        load_dataset(tmp_path / "a.npy", dx=1e-4)
    with pytest.raises(ValueError, match="dx"):
        load_dataset(tmp_path / "a.npy", dt=1e-8, dx=-1.0)
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="pickles"):
        load_dataset(tmp_path / "obj.npy", dt=1e-8, dx=1e-4)
    for arr, what in [(np.zeros(5), "time first"), (np.zeros((1, 5)), "at least 2"),
                      (np.full((4, 4), np.nan), "NaN"), (np.zeros((3, 3), complex), "real")]:
        np.save(tmp_path / "b.npy", arr)
        with pytest.raises(ValueError, match=what):
            load_dataset(tmp_path / "b.npy", dt=1e-8, dx=1e-4)
    with h5py.File(tmp_path / "two.h5", "w") as f:
        f["a"], f["b"] = np.zeros((4, 4)), np.zeros((4, 4))
    with pytest.raises(ValueError, match="give key"):
        load_dataset(tmp_path / "two.h5", dt=1e-8, dx=1e-4)
    with pytest.raises(ValueError, match="no dataset"):
        load_dataset(tmp_path / "two.h5", key="c", dt=1e-8, dx=1e-4)
    with pytest.raises(ValueError, match="dt is neither"):
        load_dataset(tmp_path / "two.h5", key="a", dx=1e-4)
    (tmp_path / "t.txt").write_text("hello")
    with pytest.raises(ValueError, match="neither HDF5"):
        load_dataset(tmp_path / "t.txt")
    with pytest.raises(ValueError, match="format"):
        load_dataset(tmp_path / "a.npy", "csv")
    with pytest.raises(ValueError, match="no completed"):
        load_dataset(make_scan("empty.h5", build_plan(3, 3, 8), []))
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing.h5")
