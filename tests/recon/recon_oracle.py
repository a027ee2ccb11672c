"""Direct-sum evaluation of the discrete inversion formula (the paper's eq. (1), discretised
by sums as in its Section 2 and written out by the functions below): the independent
reference for the NUFFT-based reconstructions (O(N²) matrix sums, small sizes only).

Lateral wavenumbers are the symmetric set k_j = 2π j/(n d), j = -n/2..n/2 (n even: both
ends with weight 1/2, the band-limited split of the Nyquist pair), so the formula is
defined the same way for sensors on and off the grid."""
from __future__ import annotations

import numpy as np


def kgrid(n: int, d: float):
    """(k (m,), weights (m,)) for a lateral axis of n samples at spacing d."""
    if n == 1:
        return np.zeros(1), np.ones(1)
    j = np.arange(-(n // 2), n // 2 + 1)
    w = np.ones(len(j))
    if n % 2 == 0:
        w[[0, -1]] = 0.5
    else:
        j = np.arange(-(n // 2), n // 2 + 1)
    return 2 * np.pi * j / (n * d), w


def lateral_dft(g, positions, h_over_cell, kx, ky=None):
    """A(k, n) = Σ_m h_m/ΔA g_m(t_n) e^{-i k·x_m}; g (n_points, n_t) -> (n_t, n_ky, n_kx)."""
    ky = np.zeros(1) if ky is None else ky
    x = positions[:, 0]
    y = positions[:, 1] if positions.shape[1] > 1 else np.zeros(len(x))
    phase = np.exp(-1j * (ky[:, None, None] * y[None, None, :] + kx[None, :, None] * x[None, None, :]))
    return np.einsum("yxm,mn->nyx", phase, g * h_over_cell[:, None])


def even_transform(A, omega, dt, t0):
    """E(k, ω) = Σ_n A(k, n) 2 cos(ω t_n), t = 0 counted once. A (n_t, ky, kx); omega (ky, kx, n_z)."""
    n_t = A.shape[0]
    t = t0 + dt * np.arange(n_t)
    w = 2 * np.cos(omega[..., None] * t)  # (ky, kx, n_z, n_t)
    if t0 == 0:
        w[..., 0] *= 0.5
    return np.einsum("yxzn,nyx->yxz", w, A)


def invert(A, kx, kxw, ky, kyw, dt, c, n_z, dz, t0, x_out, y_out=None, n_lat=None, rows=None):
    """The discrete formula from the lateral spectrum A (n_t, n_ky, n_kx) to p0
    (rows, n_y, n_x) at the output coordinates, with n_z = K depth-transform rows (the
    implementation records its K as ``params["depth_rows"]``) and the first ``rows``
    (default all K) returned; n_lat = (n_y, n_x) grid sizes."""
    dk = np.pi / ((n_z - 1) * dz)
    kz = dk * np.arange(n_z)
    omega = c * np.sqrt(ky[:, None, None] ** 2 + kx[None, :, None] ** 2 + kz[None, None, :] ** 2)
    E = even_transform(A, omega, dt, t0)  # (n_ky, n_kx, n_z)
    with np.errstate(divide="ignore", invalid="ignore"):
        wgt = np.where(omega > 0, kz / omega, 1.0 / c)
    F = (c * c * dt * dk / np.pi) * wgt * E * (omega * dt <= np.pi * (1 + 1e-12))
    F = F * (kyw[:, None, None] * kxw[None, :, None])
    z = np.arange(n_z)
    tau = np.ones(n_z)
    tau[[0, -1]] = 0.5
    C = 2 * tau[None, :] * np.cos(np.pi * np.outer(z, z) / (n_z - 1))  # DCT-I (j, l)
    Fz = np.einsum("jl,yxl->jyx", C, F)
    yv = np.zeros(1) if y_out is None else y_out
    ph = np.exp(1j * (ky[None, :, None, None] * yv[:, None, None, None] + kx[None, None, :, None] * x_out[None, None, None, :]))
    out = np.einsum("jyx,Yyxi->jYi", Fz, ph) / np.prod(n_lat)
    return out.real[:rows]
