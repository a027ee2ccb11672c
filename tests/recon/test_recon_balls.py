"""Analytic balls: exact N-shaped waves (averaged over each sample interval) on a
planar sensor grid, reconstructed with NER and with linear interpolation."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics import Ball, ball_alines, ball_p0
from fpscan.service.recon import reconstruct_grid
from tests.recon import recon_oracle as oracle

C, DT, DX = 1500.0, 20e-9, 100e-6
N_T, N_LAT = 128, 24
DZ = C * DT


@pytest.fixture(scope="module")
def setup():
    x = (np.arange(N_LAT) - (N_LAT - 1) / 2) * DX
    X, Y = np.meshgrid(x, x)
    pos = np.column_stack([X.ravel(), Y.ravel()])
    balls = [Ball(0.0, 0.0, 40 * DZ, 3 * DZ), Ball(3 * DX, -2 * DX, 70 * DZ, 3 * DZ), Ball(-2 * DX, 3 * DX, 100 * DZ, 3 * DZ)]
    al = ball_alines(pos, balls, DT, N_T, C)
    data = al.T.reshape(N_T, N_LAT, N_LAT)
    kx, kxw = oracle.kgrid(N_LAT, DX)
    A = oracle.lateral_dft(al, pos, np.ones(len(pos)), kx, kx)
    rows = reconstruct_grid(data[:, :2, :2], DX, DT, C, dz=DZ).params["depth_rows"]  # K depends on n_t, dt, c, dz only
    exact = oracle.invert(A, kx, kxw, kx, kxw, DT, C, rows, DZ, 0.0, x, x, n_lat=(N_LAT, N_LAT), rows=N_T)
    z = np.arange(N_T) * DZ
    analytic = ball_p0(balls, z, x, x, supersample=3)
    region = np.zeros(exact.shape, bool)
    Z, YY, XX = np.meshgrid(z, x, x, indexing="ij")
    for b in balls:
        region |= (Z - b.z) ** 2 + (YY - b.y) ** 2 + (XX - b.x) ** 2 <= (2.5 * b.radius) ** 2
    return dict(x=x, z=z, balls=balls, data=data, exact=exact, analytic=analytic, region=region)


def rel(a, b, m):
    return float(np.linalg.norm((a - b)[m]) / np.linalg.norm(b[m]))


def test_ball_centres_within_one_voxel_and_amplitude_falls_with_depth(setup):
    im = reconstruct_grid(setup["data"], DX, DT, C, dz=DZ)
    peaks = []
    for b in setup["balls"]:
        iz = int(round(b.z / DZ))
        iy, ix = (int(round(v / DX + (N_LAT - 1) / 2)) for v in (b.y, b.x))
        win = im.p0[iz - 6 : iz + 7, max(iy - 3, 0) : iy + 4, max(ix - 3, 0) : ix + 4]
        k = np.unravel_index(np.argmax(win), win.shape)
        fz = im.z[iz - 6 + k[0]]
        fy = im.y[max(iy - 3, 0) + k[1]]
        fx = im.x[max(ix - 3, 0) + k[2]]
        assert abs(fz - b.z) <= DZ * (1 + 1e-9) and abs(fy - b.y) <= DX * (1 + 1e-9) and abs(fx - b.x) <= DX * (1 + 1e-9)
        peaks.append(win.max())
    # limited view: the aperture subtends a smaller solid angle for deeper balls
    assert peaks[0] > peaks[1] > peaks[2] > 0
    assert peaks[0] < 1.0  # a finite aperture never restores the full amplitude


def test_ner_is_the_exact_discrete_result_and_linear_is_not(setup):
    ner = reconstruct_grid(setup["data"], DX, DT, C, dz=DZ).p0  # the oracle's rows, c·dt (the pitch is 100 µm)
    lin = reconstruct_grid(setup["data"], DX, DT, C, method="linear", dz=DZ).p0
    m = setup["region"]
    e_ner = rel(ner, setup["exact"], m)
    e_lin = rel(lin, setup["exact"], m)
    assert e_ner <= 1e-5
    assert e_ner * 100 <= e_lin
    # and closer to the analytic image
    assert rel(ner, setup["analytic"], m) < rel(lin, setup["analytic"], m)
