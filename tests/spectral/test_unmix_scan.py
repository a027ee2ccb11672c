"""`fpscan unmix` on a two-wavelength scan file (fpscan.driver.scanfile, n_wavelengths = 2):
every point at 750 and 850 nm, int16 A-lines of two balls of known sO2 (0.6 and 0.95,
exact ball waves, the simulator's HbO2/Hb absorption) → one reconstruction per wavelength
→ NNLS unmixing; sO2 in each ball's interior within 0.05. A single-wavelength scan file
asked to unmix is refused with the reason."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.clients.cli import main as fpscan_main
from fpscan.driver.plan import plan_id_of
from fpscan.driver.scanfile import META_KEYS, ScanFile
from fpscan.physics import Ball, ball_alines, spectra
from fpscan.service.spectral import read_unmix

PITCH, N, NT, DT, C = 80e-6, 40, 200, 20e-9, 1500.0
TRUTH = [(Ball(-0.6e-3, 0.0, 1.5e-3, 250e-6), 0.6), (Ball(0.7e-3, 0.2e-3, 1.9e-3, 250e-6), 0.95)]


def _scan(path, wavelengths) -> None:
    idx = [(i, j) for j in range(N) for i in range(N)]
    pos = [[(i - (N - 1) / 2) * PITCH, (j - (N - 1) / 2) * PITCH] for i, j in idx]
    plan = {"format": "fpscan-plan/1", "lattice": {"n_x": N, "n_y": N, "pitch": PITCH},
            "mask": {"kind": "points", "params": {}},
            "points": {"indices": [list(p) for p in idx], "positions": pos, "weights": [PITCH ** 2] * len(idx)},
            "order": "rows",
            "acquisition": {"n_t": NT, "dt": DT, "averages": 1, "wavelengths": list(wavelengths), "prf": 0.0,
                            "sound_speed": C}}
    plan["id"] = plan_id_of(plan)
    p = np.asarray(pos)
    with ScanFile.create(path, plan, instrument={"idn": "test"}, software_version="test") as sf:
        for w, lam in enumerate(wavelengths):
            balls = [Ball(b.x, b.y, b.z, b.radius, float(spectra.absorption(lam, s, spectra.BLOOD_THB)[0]))
                     for b, s in TRUTH]
            alines = ball_alines(p, balls, DT, NT, C)
            scale = np.abs(alines).max() / 30000
            for k in range(len(p)):
                meta = dict.fromkeys(META_KEYS, 0)
                meta.update(point_index=k, wavelength_index=w, dc_level=1.0, scale=scale, offset=0.0, dt_s=DT)
                sf.append(k, np.round(alines[k] / scale).astype(np.int16), meta)


def test_unmix_two_wavelength_scan_file(tmp_path, capsys):
    scan = tmp_path / "scan.h5"
    _scan(scan, [750e-9, 850e-9])
    out = tmp_path / "out"
    assert fpscan_main(["unmix", str(scan), "--method", "ner", "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    u = read_unmix(out / "unmix.h5")
    assert u["wavelengths_m"].tolist() == [750e-9, 850e-9]
    Z, Y, X = np.meshgrid(u["z"], u["y"], u["x"], indexing="ij")
    for b, so2 in TRUTH:
        inner = (X - b.x) ** 2 + (Y - b.y) ** 2 + (Z - b.z) ** 2 <= (0.5 * b.radius) ** 2
        assert inner.sum() >= 5 and u["mask"][inner].all()
        assert np.max(np.abs(u["so2"][inner] - so2)) < 0.05


def test_single_wavelength_scan_file_is_refused(tmp_path, capsys):
    scan = tmp_path / "one.h5"
    _scan(scan, [750e-9])
    rc = fpscan_main(["unmix", str(scan), "--out", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "needs at least two wavelengths" in err and "has 1 (750 nm)" in err
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="at least two wavelengths"):
        from fpscan.service.spectral import load_wavelength_datasets
        load_wavelength_datasets([scan])
