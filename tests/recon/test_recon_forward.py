"""The exact planar forward model: layer, analytic balls, grid vs points (its adjoint:
test_recon_operator.py)."""
from __future__ import annotations

import numpy as np

from fpscan.physics import Ball, ball_alines, ball_p0
from fpscan.physics.forward import forward_grid, forward_points
from fpscan.service.recon import reconstruct_grid

C, DT = 1500.0, 20e-9
DZ = C * DT
rng = np.random.default_rng(7)


def test_uniform_layer_gives_half_the_profile():
    z = np.arange(64) * DZ
    f = np.exp(-(((z - 20 * DZ) / (3 * DZ)) ** 2))
    p0 = np.repeat(f[:, None], 16, axis=1)
    g = forward_grid(p0, DZ, DZ, DT, 40, C, eps=1e-10, periodic=True)  # an infinite layer
    np.testing.assert_allclose(g, 0.5 * np.repeat(f[:40, None], 16, axis=1), atol=1e-8)


def test_forward_then_reconstruct_recovers_a_layer_exactly():
    z = np.arange(96) * DZ
    f = np.exp(-(((z - 30 * DZ) / (4 * DZ)) ** 2))
    p0 = np.broadcast_to(f[:, None, None], (96, 6, 8)).copy()
    g = forward_grid(p0, 2 * DZ, DZ, DT, 96, C, eps=1e-12, periodic=True)
    back = reconstruct_grid(g, 2 * DZ, DT, C, eps=1e-12, dz=DZ).p0  # p0's rows (the pitch is 2 DZ)
    assert np.abs(back - p0).max() <= 1e-8


def test_forward_points_matches_forward_grid_on_the_grid():
    p0 = rng.standard_normal((20, 6, 7))
    dx = 50e-6
    g = forward_grid(p0, dx, DZ, DT, 30, C, eps=1e-9)
    x = (np.arange(7) - 3) * dx
    y = (np.arange(6) - 2.5) * dx
    pos = np.array([[x[1], y[4]], [x[5], y[0]], [x[3], y[3]]])
    a = forward_points(p0, dx, DZ, pos, DT, 30, C, eps=1e-9)
    ref = np.stack([g[:, 4, 1], g[:, 0, 5], g[:, 3, 3]])
    np.testing.assert_allclose(a, ref, atol=1e-7 * np.abs(ref).max())
    # 2-D
    p2 = rng.standard_normal((20, 9))
    g2 = forward_grid(p2, dx, DZ, DT, 25, C, eps=1e-9)
    a2 = forward_points(p2, dx, DZ, ((np.arange(9) - 4) * dx)[[2, 7], None], DT, 25, C, eps=1e-9)
    np.testing.assert_allclose(a2, g2[:, [2, 7]].T, atol=1e-7 * np.abs(g2).max())


def test_forward_model_of_a_ball_follows_the_n_wave():
    dx = DZ
    n = 40
    x = (np.arange(n) - (n - 1) / 2) * dx
    b = Ball(0.0, 0.0, 24 * DZ, 6 * DZ)
    p0 = ball_p0([b], np.arange(48) * DZ, x, x, supersample=4)
    pos = np.array([[0.0, 0.0], [4 * dx, -3 * dx]])
    sim = forward_points(p0, dx, DZ, pos, DT, 50, C)
    exact = ball_alines(pos, [b], DT, 50, C)
    cc = [np.corrcoef(s, e)[0, 1] for s, e in zip(sim, exact)]
    assert min(cc) > 0.97
    assert np.abs(sim - exact).max() < 0.15 * np.abs(exact).max()  # Gibbs of a sharp ball edge
