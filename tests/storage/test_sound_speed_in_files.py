"""Every file fpscan writes names the speed of sound as a person reads it (``sound_speed``,
``sound_speed_range``, ``sound_speed_values``: fpscan.service.names), and every reader still
loads a file an older fpscan wrote with the older name (``c``; the scan file's
``sound_speed_m_per_s``) to the same numbers. Real files: written by the code under test,
and the older ones made with h5py directly, attribute by attribute, as that fpscan did."""
from __future__ import annotations

import json
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from fpscan.driver.scanfile import read_scan
from fpscan.service.formats.dataset import DATASET_FORMAT
from fpscan.service.formats.dataset import write as write_dataset
from fpscan.service.formats.result import RESULT_FORMAT, read_result, write_reconstruction
from fpscan.service.formats.unmix import UNMIX_FORMAT
from fpscan.service.recon.dataset import GridDataset, PointDataset
from fpscan.service.recon.unmix import unmix
from fpscan.service.spectral import read_unmix, write_unmix
from fpscan.service.storage.loader import load_dataset
from tests.json_keys import all_keys
from tests.storage.storage_helpers import build_plan

OLD = ("c", "c_range", "c_values", "sound_speed_m_per_s")


def _grid() -> GridDataset:
    data = np.random.default_rng(1).standard_normal((40, 5, 6)).astype(np.float32)
    return GridDataset(data=data, dx=1e-4, dy=2e-4, dt=2e-8, sound_speed=1487.5, t0=1e-7, source="npy")


def test_dataset_file_says_sound_speed_and_reads_an_older_c(tmp_path):
    ds = _grid()
    write_dataset(tmp_path / "new.h5", ds)
    with h5py.File(tmp_path / "new.h5", "r") as f:
        assert f.attrs["sound_speed"] == 1487.5 and not set(OLD) & set(f.attrs), dict(f.attrs)
    new = load_dataset(tmp_path / "new.h5", "dataset")
    # as fpscan-dataset/1 was written before: the speed of sound under "c"
    with h5py.File(tmp_path / "old.h5", "w") as f:
        f.create_dataset("data", data=ds.data)
        f.attrs.update({"format": DATASET_FORMAT, "layout": "grid", "dt": 2e-8, "c": 1487.5, "t0": 1e-7,
                        "source": "npy", "p0_unit": "a.u.", "dx": 1e-4, "dy": 2e-4})
    old = load_dataset(tmp_path / "old.h5")  # detected, then loaded
    for d in (new, old):
        assert isinstance(d, GridDataset) and d.sound_speed == 1487.5 and d.dt == 2e-8 and d.t0 == 1e-7
        assert (d.dx, d.dy) == (1e-4, 2e-4) and d.data.dtype == np.float32
        np.testing.assert_array_equal(d.data, ds.data)
    # a point dataset the same way (the other layout)
    pts = PointDataset(alines=ds.data.reshape(40, -1).T[:7].copy(), positions=np.arange(14.0).reshape(7, 2) * 1e-4,
                       weights=None, dt=2e-8, sound_speed=1533.0, grid=(np.arange(6) * 1e-4, np.arange(5) * 2e-4))
    write_dataset(tmp_path / "points.h5", pts)
    with h5py.File(tmp_path / "points.h5", "r+") as f:
        assert f.attrs["sound_speed"] == 1533.0 and "c" not in f.attrs
        f.attrs["c"] = f.attrs["sound_speed"]  # make it an older fpscan's file
        del f.attrs["sound_speed"]
    assert load_dataset(tmp_path / "points.h5", "dataset").sound_speed == 1533.0


def _rec(params: dict) -> SimpleNamespace:
    p0 = np.random.default_rng(2).random((8, 4, 5)).astype(np.float32)
    return SimpleNamespace(p0=p0, z=np.arange(8) * 3e-5, y=np.arange(4) * 1e-4, x=np.arange(5) * 1e-4,
                           params=params, p0_unit="a.u.")


def test_result_volume_says_sound_speed_and_reads_an_older_c(tmp_path):
    autofocus = {"c": 1490.0, "c_range": [1450.0, 1600.0], "c_values": [1450.0, 1490.0, 1600.0],
                 "sharpness": [0.1, 0.9, 0.2]}
    params = {"method": "ner", "c": 1490.0, "dz": 3e-5, "autofocus": autofocus}
    rec = _rec(params)
    write_reconstruction(tmp_path / "new.h5", rec, input_id="d1")
    assert rec.params == params  # the in-memory parameters keep the code's names
    with h5py.File(tmp_path / "new.h5", "r") as f:
        stored = json.loads(f.attrs["params"])
        group = {k: json.loads(v) for k, v in f["params"].attrs.items()}
    assert stored["sound_speed"] == 1490.0 and stored["autofocus"]["sound_speed_range"] == [1450.0, 1600.0]
    assert stored["autofocus"]["sound_speed_values"] == [1450.0, 1490.0, 1600.0]
    assert group["sound_speed"] == 1490.0 and group["autofocus"] == stored["autofocus"]
    assert not set(OLD) & (all_keys(stored) | set(group)), stored
    new = read_result(tmp_path / "new.h5")
    # a result file as an older fpscan wrote it: the same attributes with c, c_range, c_values
    with h5py.File(tmp_path / "old.h5", "w") as f:
        f.create_dataset("p0", data=rec.p0)
        for name in ("z", "y", "x"):
            f.create_dataset(name, data=getattr(rec, name))
        f.attrs.update({"format": RESULT_FORMAT, "method": "ner", "params": json.dumps(params), "input_id": "d1",
                        "software_version": "0.1", "created_utc": "2026-01-01T00:00:00+00:00"})
    old = read_result(tmp_path / "old.h5")
    assert new.params == old.params == {"method": "ner", "sound_speed": 1490.0, "dz": 3e-5,
                                        "autofocus": {"sound_speed": 1490.0, "sound_speed_range": [1450.0, 1600.0],
                                                      "sound_speed_values": [1450.0, 1490.0, 1600.0],
                                                      "sharpness": [0.1, 0.9, 0.2]}}
    for r in (new, old):
        np.testing.assert_array_equal(r.p0, rec.p0)
        np.testing.assert_array_equal(r.z, rec.z)


def test_unmix_file_says_sound_speed_and_reads_an_older_c(tmp_path):
    w = np.array([7.6e-7, 8.5e-7])
    p0 = np.random.default_rng(3).random((2, 6, 3, 4)) + 0.5
    u = unmix(p0, w)
    z, y, x = np.arange(6) * 1e-4, np.arange(3) * 1e-4, np.arange(4) * 1e-4
    write_unmix(tmp_path, u, z, x, y, input_id="d1",
                extra={"method": "ner", "c": 1490.0, "autofocus": {"c": 1490.0, "c_range": [1450.0, 1600.0]}})
    with h5py.File(tmp_path / "unmix.h5", "r") as f:
        stored = json.loads(f.attrs["params"])
    assert stored["sound_speed"] == 1490.0 and stored["autofocus"]["sound_speed_range"] == [1450.0, 1600.0]
    assert not set(OLD) & all_keys(stored), stored
    new = read_unmix(tmp_path / "unmix.h5")
    # an unmix.h5 an older fpscan wrote: its parameters with c and c_range
    older = {**{k: v for k, v in stored.items() if k not in ("sound_speed", "autofocus")}, "c": 1490.0,
             "autofocus": {"c": 1490.0, "c_range": [1450.0, 1600.0]}}
    (tmp_path / "old").mkdir()
    with h5py.File(tmp_path / "old" / "unmix.h5", "w") as f:
        f.attrs.update({"format": UNMIX_FORMAT, "params": json.dumps(older), "input_id": "d1"})
        for name in ("hbo2", "hb", "thb", "so2"):
            f.create_dataset(name, data=getattr(u, name))
        f.create_dataset("mask", data=u.mask.astype(np.uint8))
        for name, v in (("z", z), ("x", x), ("y", y), ("wavelengths_m", u.wavelengths)):
            f.create_dataset(name, data=v)
    old = read_unmix(tmp_path / "old" / "unmix.h5")
    assert old["params"] == new["params"] and new["params"]["sound_speed"] == 1490.0
    for name in ("so2", "thb", "mask"):
        np.testing.assert_array_equal(old[name], new[name])


@pytest.mark.parametrize("older", [False, True])
def test_scan_file_says_sound_speed_and_reads_the_older_name(tmp_path, make_scan, older):
    plan = build_plan(n_x=4, n_y=3, n_t=32)  # acquisition.sound_speed 1490 m/s
    path = make_scan("scan.h5", plan)
    with h5py.File(path, "r+") as f:
        assert f.attrs["sound_speed"] == 1490.0 and "sound_speed_m_per_s" not in f.attrs, dict(f.attrs)
        if older:  # as an older fpscan wrote the scan file
            f.attrs["sound_speed_m_per_s"] = f.attrs["sound_speed"]
            del f.attrs["sound_speed"]
    assert read_scan(path).sound_speed == 1490.0
    assert load_dataset(path).sound_speed == 1490.0  # the scan file as reconstruction input
