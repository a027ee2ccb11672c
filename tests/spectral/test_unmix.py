"""Spectral unmixing (fpscan.service.recon.unmix): the closed-form NNLS against scipy's, and
sO2 of simulated structures recovered through forward model -> reconstruction -> unmixing."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from fpscan.physics import Ball, ball_alines, spectra
from fpscan.service.recon import reconstruct_grid
from fpscan.service.recon.unmix import endmember_matrix, nnls2, unmix


@pytest.mark.parametrize("wavelengths", [[750e-9, 850e-9], [700e-9, 760e-9, 800e-9, 900e-9], [532e-9, 560e-9]])
def test_nnls2_equals_scipy_nnls(wavelengths):
    rng = np.random.default_rng(len(wavelengths))
    A = endmember_matrix(wavelengths)
    # a mix of interior solutions, boundary cases and all-negative data
    Y = np.concatenate([rng.standard_normal((len(wavelengths), 600)) * 100,
                        A @ rng.uniform(0, 1, (2, 200)), -np.abs(rng.standard_normal((len(wavelengths), 50)))],
                       axis=1)
    X = nnls2(A, Y, chunk=97)
    ref = np.array([nnls(A, Y[:, j])[0] for j in range(Y.shape[1])]).T
    assert np.all(X >= 0)
    np.testing.assert_allclose(X, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


def test_exact_mixtures_and_fluence():
    w = [700e-9, 750e-9, 850e-9]
    so2 = np.array([0.0, 0.3, 0.6, 0.95, 1.0])
    thb = np.array([1.0, 2.0, 2.3, 0.5, 3.0])  # mol/m³
    mua = spectra.absorption(w, so2, thb)  # (3, 5) m^-1
    phi = np.array([2.0, 1.5, 0.7])[:, None]  # J/m², differs per wavelength
    p0 = 0.2 * phi * mua  # Gruneisen 0.2
    r = unmix(p0, w, fluence=phi[:, 0], gruneisen=0.2, threshold=0.0)
    np.testing.assert_allclose(r.thb, thb, rtol=1e-5)
    np.testing.assert_allclose(r.so2, so2, atol=1e-6)
    # without the fluence the colouring biases sO2: the documented assumption matters
    biased = unmix(p0, w, threshold=0.0)
    assert np.max(np.abs(biased.so2 - so2)) > 0.05


def test_single_wavelength_and_bad_input():
    with pytest.raises(ValueError, match="at least two wavelengths.*has 1 \\(750 nm\\)"):
        unmix(np.ones((1, 4, 4)), [750e-9])
    with pytest.raises(ValueError, match="distinct"):
        unmix(np.ones((2, 4, 4)), [750e-9, 750e-9])
    with pytest.raises(ValueError, match="250-1000 nm"):
        unmix(np.ones((2, 4, 4)), [750e-9, 1064e-9])
    with pytest.raises(ValueError, match="n_wavelengths=2"):
        unmix(np.ones((3, 4, 4)), [750e-9, 850e-9])
    with pytest.raises(ValueError, match="NaN"):
        unmix(np.full((2, 4, 4), np.nan), [750e-9, 850e-9])
    with pytest.raises(ValueError, match="fluence"):
        unmix(np.ones((2, 4, 4)), [750e-9, 850e-9], fluence=[1.0, -1.0])
    with pytest.raises(ValueError, match="threshold"):
        unmix(np.ones((2, 4, 4)), [750e-9, 850e-9], threshold=1.5)


def test_so2_of_simulated_balls_through_reconstruction():
    """Two balls of known sO2 (0.6, 0.95), same THb and fluence, imaged at 750 and 850 nm:
    exact ball A-lines at each wavelength -> NER reconstruction -> unmixing; sO2 in each
    ball's interior within 0.05 of the truth, and the empty background masked."""
    n, dx, dt, n_t, c = 40, 80e-6, 20e-9, 200, 1500.0
    x = (np.arange(n) - (n - 1) / 2) * dx
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    w = [750e-9, 850e-9]
    truth = [(Ball(-0.6e-3, 0.0, 1.5e-3, 250e-6), 0.6), (Ball(0.7e-3, 0.2e-3, 1.9e-3, 250e-6), 0.95)]
    mua = [spectra.absorption(w, so2, spectra.BLOOD_THB) for _, so2 in truth]  # (2,) each, m^-1
    volumes = []
    for k in range(len(w)):
        balls = [Ball(b.x, b.y, b.z, b.radius, amplitude=float(m[k])) for (b, _), m in zip(truth, mua, strict=True)]
        data = ball_alines(pos, balls, dt, n_t, c).T.reshape(n_t, n, n)
        img = reconstruct_grid(data, dx, dt, c)
        volumes.append(img.p0)
    r = unmix(np.stack(volumes), w)
    Z, Y, X = np.meshgrid(img.z, img.y, img.x, indexing="ij")
    for b, so2 in truth:
        inner = (X - b.x) ** 2 + (Y - b.y) ** 2 + (Z - b.z) ** 2 <= (0.5 * b.radius) ** 2
        assert inner.sum() >= 5
        assert r.mask[inner].all()
        assert abs(float(np.median(r.so2[inner])) - so2) < 0.05
        assert np.max(np.abs(r.so2[inner] - so2)) < 0.05
    far = np.ones_like(r.mask)
    for b, _ in truth:
        far &= (X - b.x) ** 2 + (Y - b.y) ** 2 + (Z - b.z) ** 2 > (3 * b.radius) ** 2
    assert r.mask[far].mean() < 0.05
    assert np.isnan(r.so2[~r.mask]).all()
