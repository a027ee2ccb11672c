"""k-Wave's lateral grid (issue 61.4): where a file gives its sensor coordinates they are the
image's grid; a k-Wave file without them follows ``kWaveGrid``'s ``(i - floor(N/2))·dx``; the
result file and the exports carry the same coordinates.

Oracles: the reference file's own ``sensor_y_m``/``sensor_z_m`` and its true p0 (real k-Wave
output, ``shared/data``), and ``kWaveGrid``'s formula written out here."""
from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import scipy.io

from service.formats import export_file
from service.pipeline import reconstruct
from service.storage.datasets import load_dataset
from service.storage.results import read_result, write_result


def test_brightest_voxel_sits_at_the_files_sensor_coordinates(shared_data, tmp_path):
    path = shared_data / "kwave3d_balls_yarn.h5"
    with h5py.File(path) as f:
        y_file, z_file, p0 = f["sensor_y_m"][()], f["sensor_z_m"][()], f["p0"][()]
    ds = load_dataset(path)
    ds = dataclasses.replace(ds, data=ds.data[:256])  # the brightest ball is 1.1 mm deep: 95 samples
    rec = reconstruct(ds, "ner")
    # our x is k-Wave's z, our y k-Wave's y: the image's grid is the file's
    np.testing.assert_allclose(rec.x, z_file, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec.y, y_file, rtol=0, atol=1e-12)
    _, iy, ix = np.unravel_index(np.argmax(rec.p0), rec.p0.shape)
    _, jy, jz = np.unravel_index(np.argmax(p0), p0.shape)  # (depth, y, z)
    assert abs(rec.y[iy] - y_file[jy]) < 1e-9 and abs(rec.x[ix] - z_file[jz]) < 1e-9, \
        (rec.y[iy], y_file[jy], rec.x[ix], z_file[jz])
    # the result file and the exports carry the same coordinates
    write_result(tmp_path / "r", rec, input_id="balls")
    vol = read_result(tmp_path / "r" / "volume.h5")
    np.testing.assert_allclose(vol.x, z_file, atol=1e-12)
    np.testing.assert_allclose(vol.y, y_file, atol=1e-12)
    zarr = export_file(tmp_path / "r" / "volume.h5", tmp_path / "p0.ome.zarr", "ome-zarr")
    attrs = json.loads((zarr / "zarr.json").read_text())["attributes"]["ome"]["multiscales"][0]
    trans = [t for t in attrs["datasets"][0]["coordinateTransformations"] if t["type"] == "translation"][0]
    np.testing.assert_allclose(trans["translation"][1:], [y_file[0] * 1e6, z_file[0] * 1e6], atol=1e-6)  # µm


def test_kwave_files_without_coordinates_follow_kwavegrid(tmp_path):
    """An even lateral size: kWaveGrid's x_vec = (i - N/2)·dx, half a pitch off the centred
    (i - (N - 1)/2)·dx; an odd one: both agree. A file in our own naming stays centred."""
    rng = np.random.default_rng(3)
    data = rng.standard_normal((32, 6, 5)).astype(np.float32)  # (t, y, x): N_y = 6 even, N_x = 5 odd
    kw = tmp_path / "kwave.h5"
    with h5py.File(kw, "w") as f:
        f.create_dataset("sensor_data", data=data).attrs["kwave_DataOrder"] = "tyz"
        f.attrs.update({"dt_s": 1e-8, "dy_m": 1e-4, "dz_m": 1e-4})
    ours = tmp_path / "ours.h5"
    with h5py.File(ours, "w") as f:
        f["sensor_data"] = data
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4, "dy_m": 1e-4})
    kwave_vec = lambda n, d: (np.arange(n) - n // 2) * d  # noqa: E731  (kWaveGrid.x_vec)
    rec = reconstruct(load_dataset(kw), "ner", n_z=8)
    np.testing.assert_allclose(rec.x, kwave_vec(5, 1e-4), atol=1e-15)
    np.testing.assert_allclose(rec.y, kwave_vec(6, 1e-4), atol=1e-15)
    np.testing.assert_allclose(rec.params["lateral_shift_m"], [0.0, -5e-5], atol=1e-18)
    rec = reconstruct(load_dataset(ours), "ner", n_z=8)
    np.testing.assert_allclose(rec.y, (np.arange(6) - 2.5) * 1e-4, atol=1e-15)
    assert "lateral_shift_m" not in rec.params
    # a MAT-file (k-Wave's output) likewise, and its kgrid.y_vec where it saved one
    line = rng.standard_normal((8, 40))  # (sensor, time), k-Wave's own layout
    scipy.io.savemat(tmp_path / "a.mat", {"sensor_data": line, "dt": 1e-8, "dx": 1e-4, "Nt": 40.0})
    rec = reconstruct(load_dataset(tmp_path / "a.mat"), "ner", n_z=8)
    np.testing.assert_allclose(rec.x, kwave_vec(8, 1e-4), atol=1e-15)
    y_vec = np.arange(8) * 1e-4 + 7e-4
    scipy.io.savemat(tmp_path / "b.mat", {"sensor_data": line, "Nt": 40.0,
                                          "kgrid": {"dt": 1e-8, "dx": 1e-4, "dy": 1e-4, "y_vec": y_vec}})
    rec = reconstruct(load_dataset(tmp_path / "b.mat"), "ner", n_z=8)
    np.testing.assert_allclose(rec.x, y_vec, atol=1e-15)


def test_coordinates_that_are_not_the_grid_are_refused(tmp_path):
    path = tmp_path / "bad.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data", data=np.zeros((16, 4, 4), np.float32)).attrs["kwave_DataOrder"] = "tyz"
        f.attrs.update({"dt_s": 1e-8, "dy_m": 1e-4, "dz_m": 1e-4})
        f["sensor_z_m"] = np.arange(4) * 2e-4  # twice the pitch
    try:
        load_dataset(path)
    except ValueError as exc:
        assert "sensor x coordinates are not a regular grid" in str(exc)
    else:
        raise AssertionError("coordinates off the grid were accepted")
