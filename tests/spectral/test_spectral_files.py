"""fpscan.service.spectral: unmix.h5 round trip and the masked sO2 picture."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from fpscan.physics import spectra
from fpscan.service.recon.unmix import unmix
from fpscan.service.spectral import MASK_COLOUR, read_unmix, so2_map, unmix_reconstructions, write_unmix


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
    black = np.round(np.array(MASK_COLOUR[:3]) * 255).astype(int)
    assert black.max() == 0
    assert (np.abs(pix - black).max(axis=1) <= 1).sum() > 1000  # the masked background
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
    # stored as a person reads them: sound_speed, not the code's c
    assert params["sound_speed"] == 1490.0 and params["n_z"] == 10
    assert params["sound_speed_range"] == [1450.0, 1600.0] and "c" not in params and "c_range" not in params
    (tmp_path / "nan").mkdir()
    with pytest.raises(ValueError, match="JSON"):
        write_unmix(tmp_path / "nan", u, z, x, y, extra={"c": float("nan")})
    assert not any((tmp_path / "nan").iterdir())  # nothing left behind


def test_a_failed_unmix_write_leaves_no_temporary_file(tmp_path):
    """unmix.h5 is written as every file the server puts in place (``fpscan.service.disk.file_replaced``):
    a write that fails once its temporary file was made (coordinates that are not numbers)
    removes it (today's main left ``.unmix.h5.tmp-<pid>`` until the next start-up's sweep), and
    an existing unmix.h5 stays as it was."""
    w, _, p0 = _phantom()
    u = unmix(p0, w)
    z, y, x = np.arange(10) * 1e-4, np.arange(12) * 1e-4, np.arange(14) * 1e-4
    write_unmix(tmp_path, u, z, x, y, input_id="first")
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(ValueError, match="could not convert"):
        write_unmix(tmp_path, u, ["not a depth"] * 10, x, y, input_id="second")
    assert sorted(p.name for p in tmp_path.iterdir()) == before == ["so2.png", "unmix.h5"]
    assert read_unmix(tmp_path / "unmix.h5")["input_id"] == "first"


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


def test_so2_picture_masks_the_noisy_background_and_colours_the_vessels():
    """sO2 as colour with THb as brightness: a noisy background (weak THb, random sO2 that
    the old map painted at full saturation) renders black; the vessels render in colour,
    the oxygenated one red, the deoxygenated one blue, in their own quadrants (row 0 at the
    top, as every picture)."""
    from fpscan.service.pictures.render import png_axes, render_so2, so2_rgb

    rng = np.random.default_rng(3)
    n_y, n_x = 40, 50
    so2 = rng.uniform(0, 1, (n_y, n_x))  # noise: any sO2
    thb = rng.uniform(0, 0.05, (n_y, n_x))  # ... at weak THb
    so2[5:12, 30:45], thb[5:12, 30:45] = 0.97, 1.0  # arterial vessel: small y (top), large x (right)
    so2[28:35, 5:20], thb[28:35, 5:20] = 0.05, 0.8  # venous vessel: large y (bottom), small x (left)
    rgb = so2_rgb(so2, thb, threshold=0.1)
    background = np.ones((n_y, n_x), bool)
    background[5:12, 30:45] = background[28:35, 5:20] = False
    assert rgb[background].max() == 0.0  # masked: black, not noise
    art, ven = rgb[5:12, 30:45].reshape(-1, 3), rgb[28:35, 5:20].reshape(-1, 3)
    assert (art[:, 0] > 0.5).all() and (art[:, 0] > 3 * art[:, 2]).all()  # red
    assert (ven[:, 2] > 0.3).all() and (ven[:, 2] > 2 * ven[:, 0]).all()  # blue, dimmer (THb 0.8)
    with pytest.raises(ValueError, match="one shape"):
        so2_rgb(so2, thb[:-1])

    x, y = (np.arange(n_x) - n_x / 2) * 1e-4, (np.arange(n_y) - n_y / 2) * 1e-4
    png = render_so2(so2, thb, x, y, hlabel="x", vlabel="y", title="sO2")
    g = png_axes(png)
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    area = img[int(g["top"]) + 2:int(g["bottom"]) - 2, int(g["left"]) + 2:int(g["right"]) - 2]
    h, w = area.shape[:2]
    red = (area[..., 0] > 150) & (area[..., 2] < 100)
    blue = (area[..., 2] > 80) & (area[..., 0] < 60)
    rows, cols = np.nonzero(red)
    assert red.sum() > 100 and rows.mean() < h / 2 and cols.mean() > w / 2  # top right
    rows, cols = np.nonzero(blue)
    assert blue.sum() > 100 and rows.mean() > h / 2 and cols.mean() < w / 2  # bottom left
    dark = area.max(axis=2) <= 10
    assert dark.mean() > 0.7  # the background: black
