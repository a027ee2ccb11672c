"""NER-NUFFT and the FFT + interpolation modes against the direct-sum oracle of the
paper's eq. (1) (tests/recon/recon_oracle.py), step by step and end to end."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics import nufft
from fpscan.service.recon import reconstruct_grid
from tests.recon import recon_oracle as oracle

C, DT, DX = 1500.0, 25e-9, 60e-6
# every test twice: small transforms in numpy, and everything in scipy.fft + numba (conftest)
pytestmark = pytest.mark.usefixtures("engine")
rng = np.random.default_rng(1234)


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def centred(n, d=DX):
    return (np.arange(n) - (n - 1) / 2) * d


def oracle_grid(g, dz=None, n_z=None, t0=0.0, rows=None, lateral=None):
    """Direct-sum reconstruction of grid data g (n_t, n_x) or (n_t, n_y, n_x) with a depth
    transform of ``rows`` rows (the implementation's ``params["depth_rows"]``), cropped to
    n_z (default n_t), on a lateral period of ``lateral`` = (n_y', n_x') samples (the
    implementation's ``params["lateral_transform"]``: zero data beyond the aperture)."""
    n_t = g.shape[0]
    vol = g if g.ndim == 3 else g[:, None, :]
    n_y, n_x = vol.shape[1:]
    n_yp, n_xp = lateral or (n_y, n_x)
    x, y = centred(n_x), centred(n_y)
    X, Y = np.meshgrid(x, y)
    pos = np.column_stack([X.ravel(), Y.ravel()])
    kx, kxw = oracle.kgrid(n_xp, DX)
    ky, kyw = oracle.kgrid(n_yp, DX)
    A = oracle.lateral_dft(vol.reshape(n_t, -1).T, pos, np.ones(len(pos)), kx, ky)
    out = oracle.invert(A, kx, kxw, ky, kyw, DT, C, rows or n_z or n_t, dz or C * DT, t0, x, y, n_lat=(n_yp, n_xp),
                        rows=n_z or n_t)
    return out if g.ndim == 3 else out[:, 0, :]


def test_temporal_step_matches_direct_cosine_sums():
    n_t, n_cols = 50, 7
    a = rng.standard_normal((n_cols, n_t)) + 1j * rng.standard_normal((n_cols, n_t))
    klat2 = rng.uniform(0, (np.pi / DX) ** 2, n_cols)
    kz = np.linspace(0, np.pi / (C * DT), 40)
    t0 = 2e-8
    t = t0 + DT * np.arange(n_t)
    omega = C * np.sqrt(klat2[:, None] + kz[None, :] ** 2)
    direct = np.einsum("czn,cn->cz", 2 * np.cos(omega[..., None] * t), a)
    errs = []
    for eps in (1e-3, 1e-6, 1e-10):
        grid = nufft.make_grid(n_t, "nufft", eps)
        U = nufft.to_fine_grid(a.T, grid, t0_is_zero=False)
        E = nufft.evaluate(U, grid, klat2, kz, np.ones(len(kz)), C, DT, t0, inversion=False)
        errs.append(rel(E, direct))
    assert errs[1] <= 1e-5
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] <= 1e-8


def test_temporal_step_in_single_precision_matches_direct_cosine_sums(engine):
    """complex64 coefficients stay complex64 through the fine grid and the interpolation
    (whose tap sums run in float32 in the compiled kernel): at a NUFFT tolerance of 1e-9 the
    result is within float32 rounding (measured 1.2e-7 compiled, 5e-8 in numpy) of the
    float64 direct sums, where complex128 is within the tolerance."""
    n_t, n_cols = 64, 9
    a = (rng.standard_normal((n_cols, n_t)) + 1j * rng.standard_normal((n_cols, n_t))).astype(np.complex64)
    klat2 = rng.uniform(0, (np.pi / DX) ** 2, n_cols)
    kz = np.linspace(0, np.pi / (C * DT), 48)
    t0 = 2e-8
    t = t0 + DT * np.arange(n_t)
    omega = C * np.sqrt(klat2[:, None] + kz[None, :] ** 2)
    direct = np.einsum("czn,cn->cz", 2 * np.cos(omega[..., None] * t), a.astype(np.complex128))
    grid = nufft.make_grid(n_t, "nufft", 1e-9)
    E = {}
    for dtype in (np.complex64, np.complex128):
        U = nufft.to_fine_grid(a.T.astype(dtype), grid, t0_is_zero=False)
        assert U.dtype == dtype
        E[dtype] = nufft.evaluate(U, grid, klat2, kz, np.ones(len(kz)), C, DT, t0, inversion=False)
    assert E[np.complex64].dtype == np.complex64
    assert rel(E[np.complex128], direct) <= 1e-8
    assert rel(E[np.complex64], direct) <= 5e-7


@pytest.mark.parametrize("shape", [(40, 12), (24, 6, 8), (21, 5, 7)])
def test_ner_matches_direct_sum(shape):
    g = rng.standard_normal(shape)
    ims = [reconstruct_grid(g, DX, DT, C, eps=eps, dz=C * DT) for eps in (1e-3, 1e-6, 1e-9)]
    ref = oracle_grid(g, rows=ims[0].params["depth_rows"], lateral=ims[0].params["lateral_transform"])
    errs = [rel(im.p0, ref) for im in ims]
    assert errs[1] <= 1e-5, errs
    assert errs[0] > errs[1] > errs[2], errs


def test_ner_depth_grid_and_time_offset_match_direct_sum():
    g = rng.standard_normal((24, 6, 8))
    im = reconstruct_grid(g, DX, DT, C, dz=20e-6, n_z=30, t0=3e-8)
    # the working depth grid reaches c t_last = 45.4 dz: K >= 47 depths (49: 2 (K - 1) = 96
    # is a fast FFT length), cropped to 30
    assert im.params["depth_rows"] == 49
    ref = oracle_grid(g, dz=20e-6, n_z=30, t0=3e-8, rows=49, lateral=im.params["lateral_transform"])
    assert rel(im.p0, ref) <= 1e-5
    assert im.p0.shape == (30, 6, 8)
    np.testing.assert_allclose(im.z, 20e-6 * np.arange(30))
    np.testing.assert_allclose(im.x, centred(8))
    np.testing.assert_allclose(im.y, centred(6))


def test_shallow_image_is_the_top_of_the_full_depth_image():
    # asking for fewer depths must not fold deeper signals back into the image
    g = rng.standard_normal((48, 6, 8))
    full = reconstruct_grid(g, DX, DT, C, dz=C * DT).p0
    top = reconstruct_grid(g, DX, DT, C, n_z=12, dz=C * DT).p0
    np.testing.assert_allclose(top, full[:12], atol=1e-12 * np.abs(full).max())


def test_float32_is_close_to_float64():
    g = rng.standard_normal((32, 8, 10))
    a = reconstruct_grid(g, DX, DT, C, dz=C * DT).p0
    b = reconstruct_grid(g, DX, DT, C, dtype=np.float32, dz=C * DT).p0
    assert b.dtype == np.float32
    assert rel(b, a) <= 1e-4


@pytest.mark.parametrize("method", ["linear", "nearest", "cubic"])
def test_interpolation_modes_approximate_the_same_formula(method):
    # a smooth (band-limited) signal: interpolation in ω is then a fair approximation
    t = np.arange(128) * DT
    pulse = np.exp(-(((t - 60 * DT) / (6 * DT)) ** 2))
    g = pulse[:, None] * np.hanning(16)[None, :]
    ref = reconstruct_grid(g, DX, DT, C, eps=1e-12, dz=C * DT).p0
    approx = reconstruct_grid(g, DX, DT, C, method=method, dz=C * DT).p0
    assert rel(approx, ref) < 0.3


def test_uniform_layer_comes_back_exactly():
    # g = ½ p0(c t) for a laterally uniform layer (1-D d'Alembert), any aperture
    n_t, n_x = 200, 8
    z = np.arange(n_t) * C * DT
    f = np.exp(-(((z - 80 * C * DT) / (6 * C * DT)) ** 2))
    for shape in ((n_t, n_x), (n_t, 4, n_x)):
        g = 0.5 * np.broadcast_to(f.reshape((n_t,) + (1,) * (len(shape) - 1)), shape)
        p0 = reconstruct_grid(np.ascontiguousarray(g), DX, DT, C, eps=1e-12, dz=C * DT).p0
        err = np.abs(p0 - f.reshape((n_t,) + (1,) * (len(shape) - 1))).max() / f.max()
        assert err <= 1e-8, err


def test_upsampling_interpolates_the_same_image():
    g = rng.standard_normal((32, 6, 8))
    base = reconstruct_grid(g, DX, DT, C, dz=C * DT)
    up = reconstruct_grid(g, DX, DT, C, upsample=2, dz=C * DT)
    assert up.p0.shape == (32, 12, 16)
    np.testing.assert_allclose(up.x[::2], base.x)
    np.testing.assert_allclose(up.y[::2], base.y)
    np.testing.assert_allclose(up.p0[:, ::2, ::2], base.p0, atol=1e-9 * np.abs(base.p0).max())


@pytest.mark.parametrize("method", ["ner", "linear"])
def test_upsampling_a_plane_of_one_row_keeps_one_y(method):
    g = rng.standard_normal((32, 1, 8))
    base = reconstruct_grid(g, DX, DT, C, dz=C * DT, method=method)
    up = reconstruct_grid(g, DX, DT, C, upsample=2, dz=C * DT, method=method)
    assert up.p0.shape == (32, 1, 16) and up.y.shape == (1,), (up.p0.shape, up.y)
    np.testing.assert_allclose(up.y, base.y)
    np.testing.assert_allclose(up.p0[:, :, ::2], base.p0, atol=1e-9 * np.abs(base.p0).max())


def test_positivity_clips_negative_values():
    g = rng.standard_normal((32, 10))
    a = reconstruct_grid(g, DX, DT, C, dz=C * DT).p0
    b = reconstruct_grid(g, DX, DT, C, positivity=True, dz=C * DT).p0
    np.testing.assert_allclose(b, np.maximum(a, 0))
