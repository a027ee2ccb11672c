"""`fpscan unmix` (local) and the unmixing / autofocus job over HTTP (real uvicorn):
two per-wavelength .npy files of two balls of known sO2 (0.6 and 0.95, same THb and
fluence, exact ball A-lines) → reconstruct every wavelength → NNLS unmixing; the sO2 in
each ball's interior is read back from unmix.h5 and compared with the truth."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from fpscan.clients.cli import main as fpscan_main
from fpscan.physics import Ball, ball_alines, spectra
from fpscan.service.spectral import read_unmix
from tests.service.service_servers import Server, needs_recon, wait_job

N, DX, DT, NT, C = 40, 80e-6, 20e-9, 200, 1500.0
W = [750e-9, 850e-9]
TRUTH = [(Ball(-0.6e-3, 0.0, 1.5e-3, 250e-6), 0.6), (Ball(0.7e-3, 0.2e-3, 1.9e-3, 250e-6), 0.95)]


@pytest.fixture(scope="module")
def npy_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("unmix")
    x = (np.arange(N) - (N - 1) / 2) * DX
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    paths = []
    for k, w in enumerate(W):
        balls = [Ball(b.x, b.y, b.z, b.radius, float(spectra.absorption(w, s, spectra.BLOOD_THB)[0]))
                 for b, s in TRUTH]
        data = ball_alines(pos, balls, DT, NT, C).T.reshape(NT, N, N).astype(np.float32)
        p = folder / f"w{k}.npy"
        np.save(p, data)
        paths.append(p)
    return paths


def _check_so2(u):
    # THb and the mask are in the output: THb = HbO2 + Hb, mask = THb >= 0.1 x its maximum
    np.testing.assert_allclose(u["thb"], u["hbo2"] + u["hb"], rtol=1e-6, atol=1e-6 * u["thb"].max())
    assert u["thb"].max() > 0 and np.array_equal(u["mask"], (u["thb"] >= 0.1 * u["thb"].max()) & (u["thb"] > 0))
    Z, Y, X = np.meshgrid(u["z"], u["y"], u["x"], indexing="ij")
    for b, so2 in TRUTH:
        inner = (X - b.x) ** 2 + (Y - b.y) ** 2 + (Z - b.z) ** 2 <= (0.5 * b.radius) ** 2
        assert inner.sum() >= 5 and u["mask"][inner].all()
        assert np.max(np.abs(u["so2"][inner] - so2)) < 0.05, (so2, np.nanmedian(u["so2"][inner]))


def test_cli_unmix_two_files(npy_files, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["unmix", *map(str, npy_files), "--wavelengths", *map(str, W), "--dt", str(DT), "--dx", str(DX),
            "--method", "ner", "--out", str(out), "-q"]
    assert fpscan_main(argv) == 0
    assert "unmix.h5" in capsys.readouterr().out
    u = read_unmix(out / "unmix.h5")
    _check_so2(u)
    assert u["wavelengths_m"].tolist() == W
    assert (out / "wavelength_0" / "volume.h5").is_file() and (out / "wavelength_1" / "volume.h5").is_file()
    assert Image.open(out / "so2.png").size[0] > 100
    # one wavelength: a clear error, nothing reconstructed
    rc = fpscan_main(["unmix", str(npy_files[0]), "--wavelengths", "7.5e-07", "--dt", str(DT), "--dx", str(DX),
                      "--out", str(tmp_path / "one"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "at least two wavelengths" in err and "has 1 (750 nm)" in err
    assert not (tmp_path / "one").exists()
    rc = fpscan_main(["unmix", *map(str, npy_files), "--dt", str(DT), "--dx", str(DX), "-q"])
    assert rc == 2 and "--wavelengths" in capsys.readouterr().err


@pytest.mark.slow
@needs_recon
def test_http_unmix_and_autofocus(npy_files, tmp_path):
    from fpscan.clients.http import Client

    srv = Server(tmp_path / "data").start()
    try:
        with Client(srv.url, token=srv.token, timeout=60) as api:
            ids = [api.upload_dataset(p, "npy", dt=DT, dx=DX) for p in npy_files]
            job_id = api.start_unmix(dataset_ids=ids, wavelengths=W, method="ner", threshold=0.1)
            job = wait_job(srv.client(), job_id)
            assert job["state"] == "succeeded", job
            api.download_unmix(job_id, tmp_path / "unmix.h5")
            api.download_so2(job_id, tmp_path / "so2.png")
            _check_so2(read_unmix(tmp_path / "unmix.h5"))
            png = Image.open(io.BytesIO((tmp_path / "so2.png").read_bytes()))
            assert png.format == "PNG"
            # `fpscan unmix --server` runs the same job there and downloads the same files; the
            # local run of the same command gives the same unmixing
            common = [*map(str, npy_files), "--wavelengths", *map(str, W), "--dt", str(DT), "--dx", str(DX),
                      "--method", "ner", "-q"]
            assert fpscan_main(["unmix", *common, "--server", srv.url, "--token", srv.token,
                                "--out", str(tmp_path / "remote")]) == 0
            assert fpscan_main(["unmix", *common, "--out", str(tmp_path / "local")]) == 0
            remote, local = read_unmix(tmp_path / "remote" / "unmix.h5"), read_unmix(tmp_path / "local" / "unmix.h5")
            _check_so2(remote)
            np.testing.assert_array_equal(remote["mask"], local["mask"])
            np.testing.assert_allclose(remote["so2"], local["so2"], atol=1e-4)
            assert Image.open(tmp_path / "remote" / "so2.png").format == "PNG"
            with srv.client() as http:
                r = http.post("/api/reconstructions", json={"dataset_ids": ids[:1], "wavelengths": W[:1],
                                                            "method": "ner", "unmix": {}})
                assert r.status_code == 422 and "at least two wavelengths" in r.text
                r = http.post("/api/reconstructions", json={"dataset_id": ids[0], "method": "ner",
                                                            "params": {"c": "fast"}})
                assert r.status_code == 422
            # autofocus through the API: the search is recorded with the result
            af_id = api.start_reconstruction(dataset_id=ids[0], method="ner",
                                             params={"c": "auto", "c_range": [1470, 1530]})
            job = wait_job(srv.client(), af_id)
            assert job["state"] == "succeeded", job
            result = job.get("result") or job["params"]["result"]
            af = result["autofocus"]
            # plumbing only (accuracy: tests/spectral/test_autofocus.py): these two big balls on a
            # 40 x 40 aperture focus within 1 %
            assert abs(af["sound_speed"] - C) / C < 0.01 and af["sound_speed_range"] == [1470, 1530]
            assert len(af["sound_speed_values"]) == len(af["sharpness"]) == af["evaluations"] >= 7
            assert result["sound_speed"] == af["sound_speed"]
            with srv.client() as http:
                r = http.get(f"/api/reconstructions/{af_id}/so2.png")
                assert r.status_code == 404 and "not unmixed" in r.text
    finally:
        srv.stop()
