"""A toy export format, added as one file (``service/formats/npz.py``) and
this test: with no other edit it is offered by the library (``fpscan.export_file``), the CLI
(``fpscan export --format npz``, locally and from a server's job, and in its help), the HTTP
API (``GET /api/formats``, the job's ``export_npz`` link, ``GET /api/jobs/{id}/export/npz``)
and the HTTP client (``Client.export``); the web page's downloads list every format of
``GET /api/formats`` (tests/web/test_web_page.py checks that list against the page).

Oracle: the arrays ``np.load`` reads back equal the result file's, read with h5py.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tests.waits import HANG_S

TOKEN = "npz-token"
N, DX, DT, N_T, C = 8, 1e-4, 4e-8, 48, 1500.0

pytestmark = pytest.mark.timeout(300)


def _expect(volume):
    import h5py

    with h5py.File(volume, "r") as f:
        return {k: f[k][()] for k in ("p0", "z", "y", "x")}


def _check(npz, want):
    with np.load(npz) as got:
        assert got["p0"].dtype == np.float32
        for k, v in want.items():
            np.testing.assert_array_equal(got[k], v.astype(got[k].dtype), err_msg=k)
        assert str(got["method"]) == "ner" and str(got["p0_unit"]) in ("a.u.", "Pa")


def test_npz_export_everywhere_from_one_file(server, tmp_path):
    import fpscan
    from fpscan.clients.http import field_of

    rng = np.random.default_rng(3)
    data = rng.standard_normal((N_T, N, N)).astype(np.float32)
    np.save(tmp_path / "data.npy", data)
    rec = fpscan.reconstruct(fpscan.GridDataset(data=data, dx=DX, dy=DX, dt=DT, sound_speed=C), "ner")
    fpscan.write_result(tmp_path / "local", rec, input_id="npz")
    volume = tmp_path / "local" / "volume.h5"
    want = _expect(volume)

    # the library
    assert "npz" in fpscan.export_formats()
    _check(fpscan.export_file(volume, tmp_path / "lib.npz", "npz"), want)
    # the CLI: its help names the format, a local export writes it
    helped = subprocess.run([sys.executable, "-m", "fpscan", "export", "--help"], capture_output=True, text=True,
                            timeout=120)
    assert helped.returncode == 0 and "npz" in helped.stdout, helped.stdout
    done = subprocess.run([sys.executable, "-m", "fpscan", "export", str(volume), "--format", "npz",
                           "-o", str(tmp_path / "cli.npz")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    _check(tmp_path / "cli.npz", want)

    # the server: listed, linked, served; the HTTP client downloads it
    with fpscan.Client(server, token=TOKEN) as api:
        info = {f["name"]: f for f in api.formats()}
        assert info["npz"]["export_from"] == "result" and info["npz"]["suffix"] == ".npz"
        dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX, dy=DX)
        job = api.start_reconstruction(dataset_id=dataset_id, method="ner")
        api.wait(job, timeout=HANG_S)
        links = field_of(api.get_job(job), "links")
        assert field_of(links, "export_npz") == f"/api/jobs/{job}/export/npz"
        api.download_volume(job, tmp_path / "served.h5")
        got = api.export(job, "npz", tmp_path / "served.npz")
    assert got == tmp_path / "served.npz"
    _check(got, _expect(tmp_path / "served.h5"))
    # fpscan export from the server's job
    done = subprocess.run([sys.executable, "-m", "fpscan", "export", "--server", server, "--token", TOKEN,
                           "--job", job, "--format", "npz", "-o", str(tmp_path / "remote.npz")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    _check(tmp_path / "remote.npz", _expect(tmp_path / "served.h5"))
