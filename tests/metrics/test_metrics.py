"""fpscan.service.metrics against analytic cases and direct computations."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fpscan.service.metrics import (
    bounding_box,
    cc_vs_diameter,
    cc_vs_pixels,
    correlation_coefficient,
    disc_mask,
    edge_spread,
    fit_edge_spread,
    fit_lorentz,
    lorentz,
    mip,
    mips,
    roi_mask,
    sharpness_vs_diameter,
    side_lobe_level,
    tenenbaum_sharpness,
)

RNG = np.random.default_rng(7)


# ---------------------------------------------------------------- resolution fits
@pytest.mark.parametrize("w", [23e-6, 62e-6])
def test_lorentz_fwhm_recovered_to_1_percent(w):
    dz = 12e-6
    z = np.arange(40) * dz
    z0 = 17.3 * dz
    profile = lorentz(z, 3.0, z0, w)
    fit = fit_lorentz(z, profile)
    assert fit.fwhm == pytest.approx(w, rel=0.01)
    assert fit.center == pytest.approx(z0, abs=0.01 * dz)
    # the paper fits 8 samples around the maximum
    fit8 = fit_lorentz(z, profile, window=8)
    assert fit8.fwhm == pytest.approx(w, rel=0.01)


def test_lorentz_fit_with_baseline_and_noise():
    z = np.linspace(-1e-4, 1e-4, 81)
    w = 30e-6
    clean = lorentz(z, 1e-5, 5e-6, w, baseline=0.2)
    noisy = clean + 1e-3 * clean.max() * RNG.standard_normal(z.size)
    fit = fit_lorentz(z, noisy, baseline=True)
    assert fit.fwhm == pytest.approx(w, rel=0.01)
    assert fit.baseline == pytest.approx(0.2, abs=0.01 * clean.max())


def test_lorentz_half_maximum_is_at_half_width():
    # independent check of the model itself: value at z0 ± w/2 is half the peak
    w, z0 = 5.0, 1.0
    peak = lorentz(np.array([z0]), 2.0, z0, w)[0]
    assert peak == pytest.approx(2 * 2.0 / (np.pi * w))
    assert lorentz(np.array([z0 + w / 2, z0 - w / 2]), 2.0, z0, w) == pytest.approx([peak / 2, peak / 2])


@pytest.mark.parametrize("a0", [1.5, -0.7])
def test_arctan_edge_width_recovered_to_1_percent(a0):
    dx = 60e-6
    x = (np.arange(48) - 23.6) * dx
    w = 41e-6
    profile = edge_spread(x, 0.1, a0, 0.4 * dx, w)
    fit = fit_edge_spread(x, profile)
    assert fit.fwhm == pytest.approx(w, rel=0.01)
    assert fit.edge == pytest.approx(0.4 * dx, abs=0.01 * dx)
    assert fit.step == pytest.approx(a0, rel=0.01)


def test_edge_fit_window_on_wide_edge():
    x = np.linspace(-1.0, 1.0, 201)
    profile = edge_spread(x, -2.0, 4.0, 0.1, 0.15)
    assert fit_edge_spread(x, profile, window=60).fwhm == pytest.approx(0.15, rel=0.01)


def test_undersampled_peak_and_edge_are_rejected():
    # a Gaussian of FWHM 1.5 samples, centred between samples: least squares would
    # collapse the Lorentz width to zero (a pure 1/z² tail) — it must say so instead
    z = np.arange(60.0)
    peak = np.exp(-0.5 * ((z - 30.37) / (1.5 / 2.3548)) ** 2)
    with pytest.raises(ValueError, match="under-sampled"):
        fit_lorentz(z, peak, window=8)
    step = (z > 30.5).astype(float)
    with pytest.raises(ValueError, match="under-sampled"):
        fit_edge_spread(z, step)
    # two samples per FWHM is measurable
    wide = np.exp(-0.5 * ((z - 30.37) / (2.5 / 2.3548)) ** 2)
    assert 1.0 < fit_lorentz(z, wide, window=8).fwhm < 2.5


def test_side_lobe_level_of_sinc():
    # first side lobe of sinc: |sinc| max beyond the first zero = 0.2172336
    x = np.linspace(-6, 6, 12001)
    assert side_lobe_level(np.sinc(x)) == pytest.approx(0.2172336, rel=1e-4)
    # a Gaussian has no side lobe
    assert side_lobe_level(np.exp(-x**2)) == 0.0


def test_fit_errors():
    z = np.arange(10.0)
    with pytest.raises(ValueError, match="same length"):
        fit_lorentz(z, np.ones(9))
    with pytest.raises(ValueError, match="positive peak"):
        fit_lorentz(z, -np.ones(10))
    with pytest.raises(ValueError, match="NaN"):
        fit_lorentz(z, np.full(10, np.nan))
    with pytest.raises(ValueError, match="increasing"):
        fit_edge_spread(z[::-1], z)
    with pytest.raises(ValueError, match="no edge"):
        fit_edge_spread(z, np.ones(10))
    with pytest.raises(ValueError, match="at least"):
        fit_lorentz(z[:3], np.ones(3))


# ---------------------------------------------------------------- correlation
def test_cc_of_affine_copy_is_one():
    img = RNG.standard_normal((40, 50))
    assert correlation_coefficient(3.7 * img - 12.0, img) == pytest.approx(1.0, abs=1e-12)
    assert correlation_coefficient(-0.5 * img + 1.0, img) == pytest.approx(-1.0, abs=1e-12)
    # invariant to tiny and huge scales
    assert correlation_coefficient(1e-30 * img, 1e30 * img) == pytest.approx(1.0, abs=1e-12)


def test_cc_matches_numpy_corrcoef_in_region():
    a = RNG.standard_normal((30, 30))
    b = a + RNG.standard_normal((30, 30))
    mask = disc_mask((np.arange(30.0), np.arange(30.0)), 20.0)
    expected = np.corrcoef(a[mask], b[mask])[0, 1]
    assert correlation_coefficient(a, b, mask) == pytest.approx(expected, rel=1e-12)


def test_cc_errors():
    a = np.ones((4, 4))
    with pytest.raises(ValueError, match="constant"):
        correlation_coefficient(a, RNG.standard_normal((4, 4)))
    with pytest.raises(ValueError, match="shape"):
        correlation_coefficient(a, np.ones((4, 5)))
    with pytest.raises(ValueError, match="pixel"):
        correlation_coefficient(a, a, np.eye(4, dtype=bool) & False)


# ---------------------------------------------------------------- ROI
def test_disc_and_roi_mask():
    x = (np.arange(101) - 50) * 0.1  # -5..5
    mask = disc_mask((x, x), 6.0)
    # pixel count of a disc of radius 30 px: Gauss circle problem, close to pi r^2
    assert abs(mask.sum() - np.pi * 30**2) < 2 * np.pi * 30
    assert mask[50, 50] and mask[50, 80] and not mask[50, 81] and not mask[0, 0]
    ref = np.zeros((101, 101))
    ref[50, 50] = 1.0
    ref[50, 60] = 0.05
    ref[50, 61] = 0.03
    ref[10, 10] = 1.0  # outside the disc
    roi = roi_mask(ref, axes=(x, x), diameter=6.0, threshold=0.04)
    assert sorted(zip(*np.nonzero(roi))) == [(50, 50), (50, 60)]
    assert bounding_box(roi) == (slice(50, 51), slice(50, 61))
    off = disc_mask((x, x), 1.0, center=(2.0, -3.0))
    iy, ix = np.nonzero(off)
    assert np.allclose([x[iy].mean(), x[ix].mean()], [2.0, -3.0])
    with pytest.raises(ValueError, match="threshold"):
        roi_mask(ref, threshold=1.5)
    with pytest.raises(ValueError, match="diameter"):
        disc_mask((x, x), -1.0)
    with pytest.raises(ValueError, match="empty"):
        bounding_box(np.zeros((3, 3), bool))


# ---------------------------------------------------------------- sharpness
def _tenenbaum_direct(u):
    """Direct 3x3 Sobel sums with mirrored borders (numpy 'symmetric' = scipy 'reflect')."""
    g = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], float)
    p = np.pad(u, 1, mode="symmetric")
    n0, n1 = u.shape
    total = 0.0
    for i in range(n0):
        for j in range(n1):
            win = p[i:i + 3, j:j + 3]
            total += np.sum(g * win) ** 2 + np.sum(g.T * win) ** 2
    return total / u.size


def test_tenenbaum_constant_is_zero():
    assert tenenbaum_sharpness(np.full((17, 23), 4.2)) == 0.0


def test_tenenbaum_matches_direct_sum_and_ramp():
    u = RNG.standard_normal((12, 9))
    assert tenenbaum_sharpness(u) == pytest.approx(_tenenbaum_direct(u), rel=1e-12)
    # interior of a ramp a*j: Sobel along columns = 8a, along rows = 0
    ramp = np.tile(0.5 * np.arange(20.0), (20, 1))
    mask = np.zeros_like(ramp, bool)
    mask[5:15, 5:15] = True
    crop = ramp[5:15, 5:15]
    assert tenenbaum_sharpness(ramp, mask) == pytest.approx(_tenenbaum_direct(crop), rel=1e-12)
    assert tenenbaum_sharpness(ramp[:, 1:-1]) > 0
    g = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], float)
    assert np.sum(g * ramp[3:6, 3:6]) == pytest.approx(8 * 0.5)


def test_tenenbaum_errors():
    with pytest.raises(ValueError, match="2-D"):
        tenenbaum_sharpness(np.ones(5))
    with pytest.raises(ValueError, match="NaN"):
        tenenbaum_sharpness(np.full((3, 3), np.nan))


# ---------------------------------------------------------------- MIPs
def test_mips_of_known_volume():
    n_z, n_y, n_x = 5, 6, 7
    vol = np.zeros((n_z, n_y, n_x))
    vol[2, 3, 4] = 9.0
    vol[4, 0, 0] = -11.0
    xy, xz, yz = mips(vol).values()
    exp_xy = np.zeros((n_y, n_x)); exp_xy[3, 4] = 9.0
    exp_xz = np.zeros((n_z, n_x)); exp_xz[2, 4] = 9.0
    exp_yz = np.zeros((n_z, n_y)); exp_yz[2, 3] = 9.0
    assert np.array_equal(xy, exp_xy) and np.array_equal(xz, exp_xz) and np.array_equal(yz, exp_yz)
    exp_abs = exp_xy.copy(); exp_abs[0, 0] = 11.0
    assert np.array_equal(mip(vol, "xy", absolute=True), exp_abs)
    # a separable volume: MIP = outer product of maxima
    a, b, c = RNG.random(n_z), RNG.random(n_y), RNG.random(n_x)
    sep = a[:, None, None] * b[None, :, None] * c[None, None, :]
    assert np.allclose(mip(sep, "xz"), b.max() * np.outer(a, c))
    with pytest.raises(ValueError, match="plane"):
        mip(vol, "zz")
    with pytest.raises(ValueError, match="volume"):
        mip(np.ones((3, 3)))


# ---------------------------------------------------------------- curves
def test_cc_vs_pixels_adds_brightest_reference_pixels_first():
    ref = RNG.random((20, 20))
    img = ref + 0.3 * RNG.standard_normal((20, 20))
    region = disc_mask((np.arange(20.0), np.arange(20.0)), 14.0)
    counts = [2, 10, 50, int(region.sum())]
    got = cc_vs_pixels(img, ref, counts, region=region)
    for n, cc in zip(counts, got):
        thr = np.sort(ref[region])[::-1][n - 1]
        sel = region & (ref >= thr)
        assert sel.sum() == n
        assert cc == pytest.approx(np.corrcoef(img[sel], ref[sel])[0, 1], rel=1e-12)
    with pytest.raises(ValueError, match="pixel counts"):
        cc_vs_pixels(img, ref, [1], region=region)


def test_cc_and_sharpness_vs_diameter():
    x = np.arange(41.0) - 20
    yy, xx = np.meshgrid(x, x, indexing="ij")
    ref = np.exp(-(xx**2 + yy**2) / 100.0)
    img = 2 * ref + 1
    cc = cc_vs_diameter(img, ref, [0.5, 5.0, 20.0], axes=(x, x), threshold=0.04)
    assert np.isnan(cc[0])  # a single pixel: undefined
    assert cc[1:] == pytest.approx([1.0, 1.0])
    sh = sharpness_vs_diameter(img, ref, [5.0, 20.0], axes=(x, x), threshold=0.04)
    m = roi_mask(ref, axes=(x, x), diameter=20.0, threshold=0.04)
    assert sh[1] == pytest.approx(tenenbaum_sharpness(img[bounding_box(m)]))


# ---------------------------------------------------------------- properties
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), a=st.floats(1e-3, 1e3), b=st.floats(-1e3, 1e3))
def test_cc_affine_invariance_and_tenenbaum_scaling(seed, a, b):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((9, 11))
    v = u + 0.5 * rng.standard_normal((9, 11))
    mask = rng.random((9, 11)) < 0.7
    mask[0, 0] = mask[1, 1] = True
    assert correlation_coefficient(a * v + b, u, mask) == pytest.approx(correlation_coefficient(v, u, mask), abs=1e-9)
    # Sobel is linear and kills constants: F(a U + b) = a² F(U)
    assert tenenbaum_sharpness(a * u + b) == pytest.approx(a * a * tenenbaum_sharpness(u), rel=1e-6)
