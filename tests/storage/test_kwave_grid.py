"""k-Wave's lateral grid: where a file gives its sensor coordinates they are the
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

from fpscan.service.formats import export_file
from fpscan.service.pipeline import reconstruct
from fpscan.service.storage.loader import load_dataset
from fpscan.service.storage.results import read_result, write_result


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
    kwave_vec = lambda n, d: (np.arange(n) - n // 2) * d  # kWaveGrid.x_vec
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


def _ome_planes(path) -> list[dict]:
    """The OME ``Plane`` elements of an OME-TIFF, read with tifffile (an independent reader)."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        planes = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]["Plane"]
    return planes if isinstance(planes, list) else [planes]


def test_over_http_an_upload_keeps_its_coordinates_and_the_ome_tiff_its_origin(shared_data, tmp_path):
    """A k-Wave file uploaded over HTTP reconstructs on the file's own ``sensor_*_m`` grid, the
    same as the local load; the job's OME-TIFF export starts at the volume's first coordinates."""
    from fpscan.clients.http import Client
    from tests.service.service_servers import Server

    src = shared_data / "kwave3d_balls_yarn.h5"
    small = tmp_path / "balls.h5"  # the first 256 samples (the brightest ball is 95 deep): a quick job
    with h5py.File(src) as f, h5py.File(small, "w") as g:
        g.attrs.update(dict(f.attrs))
        g.attrs["Nt"] = 256
        for name in ("sensor_y_m", "sensor_z_m", "sensor_yz_index"):
            g[name] = f[name][()]
        clean = g.create_group("sensor_data").create_dataset("clean", data=f["sensor_data/clean"][:256])
        clean.attrs.update(dict(f["sensor_data/clean"].attrs))
        y_file, z_file = f["sensor_y_m"][()], f["sensor_z_m"][()]
    local = reconstruct(load_dataset(small), "ner")
    np.testing.assert_allclose(local.x, z_file, rtol=0, atol=1e-12)
    np.testing.assert_allclose(local.y, y_file, rtol=0, atol=1e-12)
    srv = Server(tmp_path / "data").start()
    try:
        with Client(srv.url, token=srv.token) as api:
            ds_id = api.upload_dataset(small, "kwave-hdf5")
            job = api.start_reconstruction(dataset_id=ds_id, method="ner")
            api.wait(job, timeout=240)
            api.download_volume(job, tmp_path / "http.h5")
            tif = api.export(job, "ome-tiff", tmp_path / "p0.ome.tif")
    finally:
        srv.stop()
    vol = read_result(tmp_path / "http.h5")
    np.testing.assert_allclose(vol.x, local.x, rtol=0, atol=1e-12)  # the file's sensor_z_m
    np.testing.assert_allclose(vol.y, local.y, rtol=0, atol=1e-12)  # the file's sensor_y_m
    np.testing.assert_allclose(vol.z, local.z, rtol=0, atol=1e-12)
    planes = _ome_planes(tif)
    assert len(planes) == vol.p0.shape[0], len(planes)
    assert {p[f"Position{a}Unit"] for p in planes for a in "XYZ"} == {"µm"}
    for k, p in enumerate(planes):
        assert p["TheZ"] == k
        np.testing.assert_allclose([p["PositionX"], p["PositionY"], p["PositionZ"]],
                                   [vol.x[0] * 1e6, vol.y[0] * 1e6, vol.z[k] * 1e6], rtol=0, atol=1e-6)
    np.testing.assert_allclose([planes[0]["PositionX"], planes[0]["PositionY"]],
                               [z_file[0] * 1e6, y_file[0] * 1e6], rtol=0, atol=1e-6)  # µm


def test_a_2d_ome_tiff_starts_at_its_first_lateral_and_depth_coordinates(tmp_path):
    """2-D (depth as the image's Y): one plane at ``x[0]`` and the first depth ``z[0]``."""
    rng = np.random.default_rng(5)
    line = rng.standard_normal((8, 40))  # (sensor, time), k-Wave's own layout
    y_vec = np.arange(8) * 1e-4 + 7e-4
    scipy.io.savemat(tmp_path / "b.mat", {"sensor_data": line, "Nt": 40.0,
                                          "kgrid": {"dt": 1e-8, "dx": 1e-4, "dy": 1e-4, "y_vec": y_vec}})
    rec = reconstruct(load_dataset(tmp_path / "b.mat"), "ner", n_z=8)
    write_result(tmp_path / "r", rec, input_id="line")
    vol = read_result(tmp_path / "r" / "volume.h5")
    (plane,) = _ome_planes(export_file(tmp_path / "r" / "volume.h5", tmp_path / "p0.ome.tif", "ome-tiff"))
    np.testing.assert_allclose([plane["PositionX"], plane["PositionY"]], [y_vec[0] * 1e6, vol.z[0] * 1e6],
                               rtol=0, atol=1e-6)
    assert "PositionZ" not in plane and plane["PositionXUnit"] == plane["PositionYUnit"] == "µm"
