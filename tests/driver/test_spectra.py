"""fpscan.physics.spectra: Prahl's haemoglobin table, interpolation, μa, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fpscan.physics import spectra


def test_table_rows_as_published():
    wl, eps = spectra.extinction_table()
    assert wl.shape == (376,) and eps.shape == (376, 2)
    assert wl[0] == pytest.approx(250e-9) and wl[-1] == pytest.approx(1000e-9)
    assert np.allclose(np.diff(wl), 2e-9)
    # rows of omlc.org/spectra/hemoglobin/summary.html, cm^-1/M -> m^2/mol (x 0.1)
    published = {750: (518.0, 1405.24), 800: (816.0, 761.72), 850: (1058.0, 691.32),
                 532: (43876.0, 40584.0), 1000: (1024.0, 206.784)}
    for nm, (ox, de) in published.items():
        e = spectra.molar_extinction(nm * 1e-9)
        assert e.shape == (1, 2)
        assert e[0] == pytest.approx([ox * 0.1, de * 0.1], rel=1e-12)
    with pytest.raises(ValueError):
        wl[0] = 1.0  # read-only


def test_interpolation_is_linear_between_rows():
    e = spectra.molar_extinction([751e-9, 757e-9])
    # 750: (518, 1405.24), 752: (533.2, 1515.32); 756: (562, 1560.48), 758: (574, 1560.48)
    assert e[0] == pytest.approx([0.1 * (518 + 533.2) / 2, 0.1 * (1405.24 + 1515.32) / 2])
    assert e[1] == pytest.approx([0.1 * (562 + 574) / 2, 0.1 * 1560.48])


def test_absorption_of_whole_blood():
    # Prahl's recipe: mu_a = 2.303 e [cm^-1/M] x[g/L] / 64500 -> 150 g/L at 800 nm (isosbestic-ish)
    so2, thb = 0.7, spectra.BLOOD_THB
    mu = spectra.absorption([800e-9, 750e-9], so2, thb)
    ref = [math.log(10) * 150 / 64500 * (so2 * ox + (1 - so2) * de) * 100  # cm^-1 -> m^-1
           for ox, de in ((816.0, 761.72), (518.0, 1405.24))]
    assert mu.shape == (2,)
    assert mu == pytest.approx(ref, rel=1e-12)
    # arrays broadcast: (n_wavelengths, *S)
    m = spectra.absorption([750e-9, 850e-9], np.array([[0.0], [1.0]]), np.ones(3))
    assert m.shape == (2, 2, 3)
    assert m[0, 0, 0] == pytest.approx(math.log(10) * 140.524)
    assert m[1, 1, 2] == pytest.approx(math.log(10) * 105.8)


@pytest.mark.parametrize("bad, match", [
    ([], "at least one"),
    (np.array([249e-9]), "250-1000 nm"),
    ([1001e-9], "250-1000 nm"),
    (750.0, "250-1000 nm"),
    ([float("nan")], "finite"),
    (["red"], "numbers"),
    ("750e-9", "numbers"),
])
def test_bad_wavelengths(bad, match):
    with pytest.raises(ValueError, match=match):
        spectra.molar_extinction(bad)
    with pytest.raises(ValueError, match=match):
        spectra.absorption(bad, 0.5, 1.0)


def test_outside_table_but_valid_excitation():
    from fpscan.driver.plan import check_wavelengths
    assert check_wavelengths([1064e-9]) == [1064e-9]  # a plan may ask for it ...
    with pytest.raises(ValueError, match="250-1000 nm"):
        spectra.molar_extinction([750e-9, 1064e-9])


@pytest.mark.parametrize("so2, thb", [(1.2, 1.0), (-0.1, 1.0), (0.5, -1.0), (float("inf"), 1.0)])
def test_bad_absorption_args(so2, thb):
    with pytest.raises(ValueError):
        spectra.absorption(750e-9, so2, thb)
