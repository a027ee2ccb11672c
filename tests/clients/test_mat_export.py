"""The MATLAB/Octave ``.mat`` export (``service/formats/mat.py``): a reconstruction's p0 in
k-Wave's layout, from the library (``fpscan.export_file``), the CLI (``fpscan export --format
mat``) and a real server on loopback (``GET /api/jobs/{id}/export/mat``, ``Client.export``).

Oracles: ``scipy.io.loadmat`` (an independent MAT reader) reads back the result file's
arrays, read with h5py, in k-Wave's order and naming (p0 the same array, ``x`` the depth,
``y``/``z`` the lateral axes); fpscan's own k-Wave MAT-file reader detects the file and
names it an initial pressure; Octave's ``load`` reads its size, where Octave is installed.
"""
from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

from tests.waits import HANG_S

TOKEN = "mat-token"
N_T, N_Y, N_X, DX, DY, DT, C = 40, 6, 8, 1e-4, 2e-4, 4e-8, 1500.0
#: NER's default depth rows (fpscan.service.recon.depth): the pitch DX down to c·t_last = 2.34 mm
N_Z = int(C * (N_T - 1) * DT / DX) + 1

pytestmark = pytest.mark.timeout(300)


def _expect(volume):
    import h5py

    with h5py.File(volume, "r") as f:
        return {k: f[k][()] for k in ("p0", "z", "y", "x") if k in f}, f.attrs["method"]


def _check(mat, volume):
    """The ``.mat`` file holds the result's p0 and axes in k-Wave's naming (module docstring)."""
    import scipy.io

    want, method = _expect(volume)
    got = scipy.io.loadmat(mat)
    np.testing.assert_array_equal(got["p0"], want["p0"].astype(np.float32))
    assert got["p0"].dtype == np.float32
    # k-Wave's x is the depth, y fpscan's y, z fpscan's lateral x; MATLAB columns (N, 1)
    np.testing.assert_array_equal(got["x"], want["z"].reshape(-1, 1))
    assert got["dx"].item() == pytest.approx(want["z"][1] - want["z"][0])
    if "y" in want:
        np.testing.assert_array_equal(got["y"], want["y"].reshape(-1, 1))
        np.testing.assert_array_equal(got["z"], want["x"].reshape(-1, 1))
        assert got["dy"].item() == pytest.approx(DY) and got["dz"].item() == pytest.approx(DX)
    else:
        np.testing.assert_array_equal(got["y"], want["x"].reshape(-1, 1))
        assert got["dy"].item() == pytest.approx(DX) and "z" not in got and "dz" not in got
    assert str(got["method"][0]) == method and str(got["p0_unit"][0]) in ("a.u.", "Pa")
    assert "x = depth" in str(got["axis_order"][0])
    return got


def _volume(tmp_path, shape):
    import fpscan

    data = np.random.default_rng(5).standard_normal(shape).astype(np.float32)
    np.save(tmp_path / "data.npy", data)
    ds = fpscan.GridDataset(data=data, dx=DX, dy=DY if data.ndim == 3 else None, dt=DT, sound_speed=C)
    out = tmp_path / f"local{data.ndim}d"
    fpscan.write_result(out, fpscan.reconstruct(ds, "ner"), input_id="mat")
    return out / "volume.h5"


def test_mat_export_library_cli_and_server(server, tmp_path):
    import httpx

    import fpscan

    volume = _volume(tmp_path, (N_T, N_Y, N_X))
    assert "mat" in fpscan.export_formats()
    got = _check(fpscan.export_file(volume, tmp_path / "lib.mat", "mat"), volume)
    assert got["p0"].shape == (N_Z, N_Y, N_X)  # (Nx, Ny, Nz) = (n_z, n_y, n_x)

    # fpscan's own k-Wave MAT reader: detected, p0 read back as saved, refused as a scan
    from fpscan.service.formats import detect, open_source
    from fpscan.service.formats.kwave_mat import read_variables

    assert detect(tmp_path / "lib.mat") == "kwave-mat"
    with open_source(tmp_path / "lib.mat") as src:
        variables, listed = read_variables(src, {"p0", "dx", "dy", "dz"})
    assert {"p0", "x", "y", "z", "dx", "dy", "dz", "p0_unit", "method"} <= set(listed)
    np.testing.assert_array_equal(variables["p0"], got["p0"])
    with pytest.raises(ValueError, match="initial pressure p0"):
        fpscan.load_dataset(tmp_path / "lib.mat")

    # the CLI
    done = subprocess.run([sys.executable, "-m", "fpscan", "export", str(volume), "--format", "mat",
                           "--out", str(tmp_path / "cli.mat")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    _check(tmp_path / "cli.mat", volume)

    # the server: listed, linked, served at GET /api/jobs/{id}/export/mat; the HTTP client downloads it
    with fpscan.Client(server, token=TOKEN) as api:
        info = {f["name"]: f for f in api.formats()}
        assert info["mat"]["export_from"] == "result" and info["mat"]["suffix"] == ".mat"
        dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX, dy=DY)
        job = api.start_reconstruction(dataset_id=dataset_id, method="ner")
        api.wait(job, timeout=HANG_S)
        api.download_volume(job, tmp_path / "served.h5")
        fetched = api.export(job, "mat", tmp_path / "served.mat")
    _check(fetched, tmp_path / "served.h5")
    r = httpx.get(f"{server}/api/jobs/{job}/export/mat", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/x-matlab-data"), r.text
    (tmp_path / "raw.mat").write_bytes(r.content)
    _check(tmp_path / "raw.mat", tmp_path / "served.h5")


def test_mat_export_2d_layout(tmp_path):
    import fpscan

    volume = _volume(tmp_path, (N_T, N_X))
    got = _check(fpscan.export_file(volume, tmp_path / "p0.mat", "mat"), volume)
    assert got["p0"].shape == (N_Z, N_X)  # k-Wave (Nx, Ny): x the depth, y fpscan's lateral x


def test_mat_export_refuses_beyond_the_mat_v5_limit(tmp_path):
    from fpscan.service.formats.mat import MAX_VARIABLE_BYTES, export_mat

    assert MAX_VARIABLE_BYTES == 2**31
    volume = _volume(tmp_path, (N_T, N_Y, N_X))
    with pytest.raises(ValueError, match=r"MAT v5 file's limit of 1000 bytes.*MAT v7\.3 \(HDF5\)"):
        export_mat(volume, tmp_path / "big.mat", max_variable_bytes=1000)
    assert not (tmp_path / "big.mat").exists() and list(tmp_path.glob("*.tmp")) == []


@pytest.mark.skipif(shutil.which("octave") is None, reason="octave not installed")
def test_octave_loads_the_mat_export(tmp_path):
    import fpscan

    volume = _volume(tmp_path, (N_T, N_Y, N_X))
    fpscan.export_file(volume, tmp_path / "p0.mat", "mat")
    done = subprocess.run(["octave", "--no-gui", "--quiet", "--eval", "load('p0.mat'); disp(size(p0)); disp(size(z))"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [str(N_Z), str(N_Y), str(N_X), str(N_X), "1"], done.stdout
