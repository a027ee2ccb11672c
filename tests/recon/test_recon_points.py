"""NEDNER-NUFFT (`reconstruct_points`) against the direct-sum oracle and against the
grid reconstruction on a full lattice."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.service.recon import reconstruct_grid, reconstruct_points, voronoi_weights
from tests.recon import recon_oracle as oracle

C, DT, DX = 1500.0, 25e-9, 60e-6
# every test twice: small transforms in numpy, and everything in scipy.fft + numba (conftest)
pytestmark = pytest.mark.usefixtures("engine")
rng = np.random.default_rng(99)


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def centred(n, d=DX):
    return (np.arange(n) - (n - 1) / 2) * d


@pytest.mark.parametrize("n_x,n_y", [(9, 7), (8, 6), (8, 7), (9, 6)])
def test_nedner_matches_direct_sum_3d(n_x, n_y):
    n_t, n_pts = 24, 30
    x, y = centred(n_x), centred(n_y)
    pos = np.column_stack([rng.uniform(x[0], x[-1], n_pts), rng.uniform(y[0], y[-1], n_pts)])
    h = rng.uniform(0.5, 1.5, n_pts) * DX * DX
    al = rng.standard_normal((n_pts, n_t))
    # each step: the lateral type-1 NUFFT against the direct sum (via the whole pipeline
    # at two tolerances) and the whole pipeline
    ims = [reconstruct_points(al, pos, DT, C, weights=h, grid=(x, y), eps=e, dz=C * DT) for e in (1e-3, 1e-6)]
    K, (n_yp, n_xp) = ims[0].params["depth_rows"], ims[0].params["lateral_transform"]
    kx, kxw = oracle.kgrid(n_xp, DX)
    ky, kyw = oracle.kgrid(n_yp, DX)
    A = oracle.lateral_dft(al, pos, h / DX**2, kx, ky)
    ref = oracle.invert(A, kx, kxw, ky, kyw, DT, C, K, C * DT, 0.0, x, y, n_lat=(n_yp, n_xp), rows=n_t)
    errs = [rel(im.p0, ref) for im in ims]
    assert errs[1] <= 1e-5 and errs[0] > errs[1], errs


def test_nedner_matches_direct_sum_2d():
    n_t, n_x = 40, 16
    x = centred(n_x)
    pos = np.sort(rng.uniform(x[0], x[-1], 11))[:, None]
    h = rng.uniform(0.5, 1.5, 11) * DX
    al = rng.standard_normal((11, n_t))
    im = reconstruct_points(al, pos, DT, C, weights=h, grid=(x,), dz=C * DT)
    n_xp = im.params["lateral_transform"][1]
    kx, kxw = oracle.kgrid(n_xp, DX)
    A = oracle.lateral_dft(al, pos, h / DX, kx)
    ref = oracle.invert(A, kx, kxw, np.zeros(1), np.ones(1), DT, C, im.params["depth_rows"], C * DT, 0.0, x,
                        n_lat=(1, n_xp), rows=n_t)[:, 0, :]
    assert im.p0.shape == (n_t, n_x)
    assert rel(im.p0, ref) <= 1e-5


def test_lateral_step_is_the_type1_sum():
    # a single sensor, a single sample: p0's lateral spectrum is e^{-i k x_m} h/dx
    n_t, n_x = 16, 10
    x = centred(n_x)
    pos = np.array([[x[3] + 0.37 * DX]])
    al = np.zeros((1, n_t))
    al[0, 5] = 1.0
    im = reconstruct_points(al, pos, DT, C, weights=np.array([DX]), grid=(x,), eps=1e-9, dz=C * DT)
    n_xp = im.params["lateral_transform"][1]
    kx, kxw = oracle.kgrid(n_xp, DX)
    A = oracle.lateral_dft(al, pos, np.ones(1), kx)
    ref = oracle.invert(A, kx, kxw, np.zeros(1), np.ones(1), DT, C, im.params["depth_rows"], C * DT, 0.0, x,
                        n_lat=(1, n_xp), rows=n_t)[:, 0, :]
    assert rel(im.p0, ref) <= 1e-7


@pytest.mark.parametrize("shape", [(32, 12), (32, 10, 12), (30, 9, 11)])
def test_full_lattice_reproduces_grid_reconstruction(shape):
    g = rng.standard_normal(shape)
    n_t = shape[0]
    if len(shape) == 2:
        pos = centred(shape[1])[:, None]
        al = g.T
    else:
        X, Y = np.meshgrid(centred(shape[2]), centred(shape[1]))
        pos = np.column_stack([X.ravel(), Y.ravel()])
        al = g.reshape(n_t, -1).T
    a = reconstruct_grid(g, DX, DT, C, dz=C * DT)
    b = reconstruct_points(al, pos, DT, C, dz=C * DT)  # default Voronoi weights and grid
    np.testing.assert_allclose(voronoi_weights(pos), DX ** (pos.shape[1]), rtol=1e-12)
    assert np.abs(b.p0 - a.p0).max() <= 1e-6 * np.abs(a.p0).max()
    np.testing.assert_allclose(b.x, a.x, atol=1e-12 * DX)
    if len(shape) == 3:
        np.testing.assert_allclose(b.y, a.y, atol=1e-12 * DX)


def test_subset_reconstruction_keeps_lattice_coordinates():
    X, Y = np.meshgrid(centred(12), centred(12))
    pos = np.column_stack([X.ravel(), Y.ravel()])[::5]
    im = reconstruct_points(rng.standard_normal((len(pos), 20)), pos, DT, C)
    on_x = np.abs((im.x - centred(12)[0]) / DX - np.round((im.x - centred(12)[0]) / DX))
    assert on_x.max() < 1e-9
    assert im.x[0] == pytest.approx(pos[:, 0].min()) and im.x[-1] == pytest.approx(pos[:, 0].max())


@pytest.mark.parametrize("n_x,n_y", [(9, 7), (8, 6)])
def test_lattice_mask_matches_direct_sum(n_x, n_y):
    """Sensors on grid nodes (a lattice mask) take the zero-filled-FFT path: the same
    discrete sum, checked against the direct evaluation."""
    n_t = 24
    x, y = centred(n_x), centred(n_y)
    k = rng.choice(n_x * n_y, 25, replace=False)
    pos = np.column_stack([x[k % n_x], y[k // n_x]])
    h = rng.uniform(0.5, 1.5, len(k)) * DX * DX
    al = rng.standard_normal((len(k), n_t))
    im = reconstruct_points(al, pos, DT, C, weights=h, grid=(x, y), eps=1e-9, dz=C * DT)
    n_yp, n_xp = im.params["lateral_transform"]
    kx, kxw = oracle.kgrid(n_xp, DX)
    ky, kyw = oracle.kgrid(n_yp, DX)
    A = oracle.lateral_dft(al, pos, h / DX**2, kx, ky)
    ref = oracle.invert(A, kx, kxw, ky, kyw, DT, C, im.params["depth_rows"], C * DT, 0.0, x, y,
                        n_lat=(n_yp, n_xp), rows=n_t)
    assert rel(im.p0, ref) <= 1e-8
