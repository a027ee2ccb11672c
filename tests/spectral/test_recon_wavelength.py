"""Plain per-wavelength reconstruction of a multi-wavelength scan: a
two-wavelength scan file reconstructed at each wavelength (library, ``fpscan recon
--wavelength K|all``, HTTP ``wavelength``) gives the volume that NEDNER
(``fpscan.service.recon.reconstruct_points``) makes of that wavelength's own A-lines, read
straight from the file with ``fpscan.driver.scanfile.read_scan``; the wavelength is recorded in
nm; a bad choice is a ValueError / exit status / 422 naming it."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from fpscan.clients.cli import main as fpscan_main
from fpscan.driver.scanfile import read_scan
from fpscan.physics.axes import centred_axis
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon import reconstruct_points
from fpscan.service.storage.loader import load_dataset, load_wavelengths
from tests.spectral.test_unmix_scan import PITCH, N, _scan

WAVELENGTHS = [750e-9, 850e-9]


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    path = tmp_path_factory.mktemp("wl") / "scan.h5"
    _scan(path, WAVELENGTHS)
    return path


def _direct(path, k: int) -> np.ndarray:
    """NEDNER of wavelength k's A-lines, straight from the scan file (the oracle)."""
    s = read_scan(path)
    done = s.completed_all[k]
    grid = (centred_axis(N, PITCH), centred_axis(N, PITCH))
    return reconstruct_points(s.pressure_all[k][done], s.positions[done], s.dt, s.sound_speed,
                              weights=s.weights[done], grid=grid, dtype=np.float64).p0


def _volume(path) -> tuple[np.ndarray, dict]:
    with h5py.File(path, "r") as f:
        return f["p0"][()], json.loads(f.attrs["params"])


def _close(a, b):
    np.testing.assert_allclose(a, b, atol=1e-9 * np.abs(b).max())


def test_library_each_wavelength_and_bad_choices(scan, tmp_path):
    direct = [_direct(scan, k) for k in (0, 1)]
    assert np.abs(direct[0] - direct[1]).max() > 0.05 * np.abs(direct[0]).max()  # the wavelengths differ
    for k in (0, 1):
        rec = reconstruct(load_dataset(scan, wavelength=k), "nedner", dtype="float64")
        _close(rec.p0, direct[k])
        assert rec.params["wavelength_index"] == k and rec.params["wavelength_nm"] == pytest.approx(
            WAVELENGTHS[k] * 1e9)
    every = load_wavelengths(scan, wavelength="all")
    assert [d.meta["wavelength_index"] for d in every] == [0, 1]
    default = reconstruct(load_dataset(scan), "nedner", dtype="float64")  # the documented default: the first
    assert default.params["wavelength_index"] == 0 and default.params["wavelength_nm"] == pytest.approx(750)
    with pytest.raises(ValueError, match=r"wavelength index 2 is out of range: the scan has 2 wavelengths "
                                         r"\(750 nm, 850 nm\)"):
        load_dataset(scan, wavelength=2)
    with pytest.raises(ValueError, match="wavelength must be an index >= 0"):
        load_wavelengths(scan, wavelength=-1)
    np.save(tmp_path / "a.npy", np.zeros((16, 4)))
    with pytest.raises(ValueError, match="a npy file holds one wavelength's data"):
        load_dataset(tmp_path / "a.npy", dt=2e-8, dx=1e-4, wavelength=1)


def test_cli_wavelength_one_and_all(scan, tmp_path, capsys):
    direct = [_direct(scan, k) for k in (0, 1)]
    out = tmp_path / "one"
    assert fpscan_main(["recon", str(scan), "--method", "nedner", "--dtype", "float64", "--wavelength", "1",
                        "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    p0, params = _volume(out / "volume.h5")
    _close(p0, direct[1])
    assert params["wavelength_index"] == 1 and params["wavelength_nm"] == pytest.approx(850)
    out = tmp_path / "all"
    assert fpscan_main(["recon", str(scan), "--method", "nedner", "--dtype", "float64", "--wavelength", "all",
                        "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    for k in (0, 1):
        p0, params = _volume(out / f"wavelength_{k}" / "volume.h5")
        _close(p0, direct[k])
        assert params["wavelength_nm"] == pytest.approx(WAVELENGTHS[k] * 1e9)
    _close(_volume(out / "volume.h5")[0], direct[0])
    capsys.readouterr()
    # no choice on a two-wavelength scan: the first, said on stderr and recorded
    assert fpscan_main(["recon", str(scan), "--method", "nedner", "--out", str(tmp_path / "d")]) == 0
    err = capsys.readouterr().err
    assert "has 2 wavelengths (750 nm, 850 nm): reconstructing the first (index 0)" in err
    assert _volume(tmp_path / "d" / "volume.h5")[1]["wavelength_index"] == 0
    assert fpscan_main(["recon", str(scan), "--wavelength", "5", "--out", str(tmp_path / "bad"), "-q"]) == 2
    assert "wavelength index 5 is out of range" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        fpscan_main(["recon", str(scan), "--wavelength", "blue"])
    assert exc.value.code == 2 and "--wavelength: must be an index >= 0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.mark.timeout(180)
def test_http_wavelength_one_all_and_bad(tmp_path, capsys):
    """A two-wavelength scan job (real uvicorn, pty simulator); reconstructions at
    wavelength 1 and 'all' (the latter by ``fpscan recon --server --scan-job --wavelength
    all``) equal NEDNER of the downloaded file's own A-lines; bad choices are 422s."""
    from fpscan.driver.simulator import SimulatedScanner
    from fpscan.driver.sources import BallSource
    from fpscan.physics import Ball
    from tests.service.service_servers import TOKEN, Server, has_recon, wait_job

    if not has_recon():
        pytest.skip("the reconstruction stack is not installed")
    balls = [Ball(2e-4, -1e-4, 0.6e-3, 1.5e-4, 1.0), Ball(-2e-4, 2e-4, 0.9e-3, 1.5e-4, 1.0)]
    sim = SimulatedScanner(source=BallSource(balls, so2=[0.3, 1.0]), prf=0.0, seed=2).start()
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}).start()
    try:
        with srv.client() as c:
            r = c.post("/api/plans", json={
                "lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4}, "points": [[i, j] for j in range(8) for i in range(8)],
                "acquisition": {"n_t": 80, "dt": 2e-8, "prf": 0.0, "wavelengths": [760e-9, 850e-9]}})
            assert r.status_code == 201, r.text
            r = c.post("/api/scans", json={"plan_id": r.json()["id"], "scanner_id": "sim"})
            scan_id = r.json()["id"]
            assert wait_job(c, scan_id)["state"] == "succeeded"
            path = tmp_path / "scan.h5"
            path.write_bytes(c.get(f"/api/scans/{scan_id}/file").content)
            body = {"scan_job_id": scan_id, "method": "nedner", "params": {"dtype": "float64"}}
            for bad, reason in ((2, "wavelength index 2 is out of range: scan job"), ("red", "wavelength")):
                r = c.post("/api/reconstructions", json={**body, "wavelength": bad})
                assert r.status_code == 422 and reason in r.text, r.text
            r = c.post("/api/reconstructions", json={**body, "wavelength": 0, "unmix": {}})
            assert r.status_code == 422 and "unmix reconstructs every wavelength" in r.text
            r = c.post("/api/reconstructions", json={**body, "wavelength": 1})
            one = wait_job(c, r.json()["id"])
            assert one["state"] == "succeeded", one
            (tmp_path / "one.h5").write_bytes(c.get(f"/api/reconstructions/{one['id']}/volume.h5").content)
            assert c.get(f"/api/reconstructions/{one['id']}/volume.h5?wavelength=0").status_code == 404
            with open(path, "rb") as fh:  # an uploaded scan file stores the wavelength asked for
                r = c.post("/api/datasets", data={"format": "fpscan", "wavelength": "2"},
                           files={"file": ("scan.h5", fh)})
            assert r.status_code == 422 and "wavelength index 2 is out of range" in r.text, r.text
        out = tmp_path / "all"
        assert fpscan_main(["recon", "--server", srv.url, "--token", TOKEN, "--scan-job", scan_id,
                            "--method", "nedner", "--dtype", "float64", "--wavelength", "all", "--out", str(out),
                            "-q"]) == 0, capsys.readouterr().err
        up = tmp_path / "uploaded"
        assert fpscan_main(["recon", str(path), "--server", srv.url, "--token", TOKEN, "--method", "nedner",
                            "--dtype", "float64", "--wavelength", "1", "--out", str(up), "-q"]) == 0, \
            capsys.readouterr().err
    finally:
        srv.stop()
        sim.stop()
    s = read_scan(path)
    assert s.completed_all.all()
    grid = (centred_axis(8, 1e-4), centred_axis(8, 1e-4))
    direct = [reconstruct_points(s.pressure_all[k], s.positions, s.dt, s.sound_speed, weights=s.weights,
                                 grid=grid, dtype=np.float64).p0 for k in (0, 1)]
    for one in (tmp_path / "one.h5", up / "volume.h5"):  # the scan job's wavelength 1, and the upload's
        p0, params = _volume(one)
        _close(p0, direct[1])
        assert params["wavelength_index"] == 1 and params["wavelength_nm"] == pytest.approx(850)
    for k in (0, 1):
        p0, params = _volume(out / f"wavelength_{k}" / "volume.h5")
        _close(p0, direct[k])
        assert params["wavelength_nm"] == pytest.approx([760, 850][k])
