"""service.spectral: unmix.h5 round trip and the masked sO2 picture."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from driver.physics import spectra
from service.recon.unmix import unmix
from service.spectral import MASK_COLOUR, read_unmix, so2_map, unmix_reconstructions, write_unmix


def _phantom():
    w = [750e-9, 850e-9]
    so2 = np.zeros((10, 12, 14))
    so2[3:6, 2:6, 2:6] = 0.6
    so2[3:6, 7:11, 8:12] = 0.95
    thb = np.where(so2 > 0, 2.0, 0.0)
    return w, so2, spectra.absorption(w, so2, thb)


def test_unmix_file_round_trip_and_picture(tmp_path):
    w, so2, p0 = _phantom()
    u = unmix(p0, w)
    z, y, x = np.arange(10) * 1e-4, np.arange(12) * 1e-4, np.arange(14) * 1e-4
    summary = write_unmix(tmp_path, u, z, x, y, input_id="dataset:abc")
    r = read_unmix(tmp_path / "unmix.h5")
    np.testing.assert_array_equal(r["mask"], so2 > 0)
    np.testing.assert_allclose(r["so2"][so2 > 0], so2[so2 > 0], atol=1e-6)
    assert np.isnan(r["so2"][so2 == 0]).all()
    assert r["input_id"] == "dataset:abc" and r["wavelengths_m"].tolist() == w
    assert summary["masked_fraction"] == pytest.approx(1 - (so2 > 0).mean())
    m = so2_map(u)
    assert m.shape == (12, 14) and m[3, 3] == pytest.approx(0.6) and m[8, 9] == pytest.approx(0.95)
    assert np.isnan(m[0, 0])
    png = Image.open(io.BytesIO((tmp_path / "so2.png").read_bytes())).convert("RGB")
    pix = np.asarray(png).reshape(-1, 3).astype(int)
    grey = np.round(np.array(MASK_COLOUR[:3]) * 255).astype(int)
    assert (np.abs(pix - grey).max(axis=1) <= 1).sum() > 1000  # the masked background
    assert ((pix[:, 0] > 150) & (pix[:, 2] < 80)).sum() > 500  # sO2 0.95: red
    # the colour bar: the map's low end (sO2 0, dark blue) that no voxel has, in a strip at the right
    img = np.asarray(png).astype(int)
    blue = (img[..., 2] > 120) & (img[..., 0] < 80)
    assert blue.sum() > 200 and np.nonzero(blue)[1].min() > 0.75 * img.shape[1]


def test_unmix_parameters_are_the_result_files_canonical_json(tmp_path):
    """unmix.h5's parameters are written as reconstruction results write theirs: numpy
    values (as a job's options carry them) become JSON, NaN is refused with a ValueError."""
    w, _, p0 = _phantom()
    u = unmix(p0, w)
    z, y, x = np.arange(10) * 1e-4, np.arange(12) * 1e-4, np.arange(14) * 1e-4
    write_unmix(tmp_path, u, z, x, y, extra={"c": np.float64(1490.0), "n_z": np.int64(10),
                                             "c_range": np.array([1450.0, 1600.0])})
    params = read_unmix(tmp_path / "unmix.h5")["params"]
    assert params["c"] == 1490.0 and params["n_z"] == 10 and params["c_range"] == [1450.0, 1600.0]
    (tmp_path / "nan").mkdir()
    with pytest.raises(ValueError, match="JSON"):
        write_unmix(tmp_path / "nan", u, z, x, y, extra={"c": float("nan")})
    assert not any((tmp_path / "nan").iterdir())  # nothing left behind


def test_unmix_reconstructions_checks():
    class R:
        def __init__(self, p0, z):
            self.p0, self.z, self.x, self.y = p0, z, np.arange(p0.shape[-1]), np.arange(p0.shape[1])

    a = R(np.ones((4, 3, 3)), np.arange(4))
    with pytest.raises(ValueError, match="at least two wavelengths.*has 1"):
        unmix_reconstructions([a], [750e-9])
    with pytest.raises(ValueError, match="2 volumes for 3"):
        unmix_reconstructions([a, a], [750e-9, 800e-9, 850e-9])
    with pytest.raises(ValueError, match="one grid"):
        unmix_reconstructions([a, R(np.ones((4, 3, 3)), np.arange(4) * 2.0)], [750e-9, 850e-9])
