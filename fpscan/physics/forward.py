"""The exact planar forward model: p0 on a regular grid -> pressure on the plane z = 0.

p solves p_tt = c^2 Δp with p(., 0) = p0, p_t(., 0) = 0 in a homogeneous medium
(the paper §2, there with c = 1). The grid function p0 (rows z_j = j dz, j = 0..n_z-1,
row 0 on the sensor plane; lateral coordinates centred, x_i = (i - (n_x - 1)/2) dx) is
taken as its band-limited (trigonometric) interpolant: a sum of plane waves
exp(i k_lat·x) cos(k_z z) on the DFT lateral wavenumbers and the DCT-I depth wavenumbers
k_z,l = π l / ((n_z - 1) dz). Each mode evolves exactly as cos(c |k| t), so with
F = DFT_x DCT-I_z(p0) dz the data of the half-space source (the physical source in z >= 0,
no mirror image) is

    g(k_lat, t) = (Δk_z / 4π) Σ_l τ_l F(k_lat, k_z,l) 2 cos(c |k| t),   τ_0 = τ_last = 1/2,

evaluated at the sample times by a type-1 NUFFT in time (`fpscan.physics.nufft`) and
transformed back laterally (inverse FFT on the sensor grid, or a type-2 NUFFT at
arbitrary sensor positions with finufft). It is the adjoint of the NER reconstruction's
discrete operator with the inversion weight replaced by the quadrature weight above
(tested by a dot test).

The trigonometric representation is periodic laterally and in depth. ``periodic=False``
(the default) zero-pads p0 so that no periodic image can reach any sensor within the
recorded time window: the result is then the free-space data of the band-limited p0.
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt
import scipy.fft

from fpscan.constants import C_DEFAULT
from fpscan.physics import fft_engine, nufft
from fpscan.physics.axes import centred_index
from fpscan.physics.grid_sizes import pad_sizes
from fpscan.physics.lateral import irfft_lateral
from fpscan.physics.nufft_plans import lateral_plan

__all__ = ["forward_grid", "forward_points"]


def _check_common(p0: npt.ArrayLike, dx: float, dz: float, dt: float, n_t: int, c: float, t0: float,
                  eps: float) -> np.ndarray:
    p0 = np.asarray(p0)
    if p0.ndim not in (2, 3):
        raise ValueError(f"p0 must be (n_z, n_x) or (n_z, n_y, n_x), got shape {p0.shape}")
    if p0.shape[0] < 2:
        raise ValueError("p0 needs at least 2 depth rows")
    if not np.all(np.isfinite(p0)):
        raise ValueError("p0 contains NaN or inf")
    for name, v in (("dx", dx), ("dz", dz), ("dt", dt), ("c", c)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v}")
    if int(n_t) != n_t or n_t < 1:
        raise ValueError(f"n_t must be an integer >= 1, got {n_t}")
    if not np.isfinite(t0) or t0 < 0:
        raise ValueError(f"t0 must be finite and >= 0 s, got {t0}")
    nufft.kernel_params(eps)  # validates eps
    return p0.astype(np.float64, copy=False)


def _kspace_data(p0: np.ndarray, dx: float, dz: float, dt: float, n_t: int, c: float, t0: float, eps: float,
                 full: bool) -> np.ndarray:
    """p0 (n_z, n_y, n_x) -> (n_t, n_y, n_x or n_x//2+1) lateral spectrum of the data."""
    n_z, n_y, n_x = p0.shape
    if full:
        F = scipy.fft.fft2(p0, axes=(1, 2), workers=fft_engine.workers())
        kx = 2 * np.pi * scipy.fft.fftfreq(n_x, dx)
    else:
        F = scipy.fft.rfft2(p0, axes=(1, 2), workers=fft_engine.workers())
        kx = 2 * np.pi * scipy.fft.rfftfreq(n_x, dx)
    ky = 2 * np.pi * scipy.fft.fftfreq(n_y, dx)
    n_cols = F.shape[1] * F.shape[2]
    # DCT-I in depth: F_l = dz * DCT-I(p0)_l
    B = scipy.fft.dct(F.reshape(n_z, n_cols).T, type=1, axis=-1, workers=fft_engine.workers()) * dz
    dk = np.pi / ((n_z - 1) * dz)
    kz = dk * np.arange(n_z)
    tau = np.ones(n_z)
    tau[0] = tau[-1] = 0.5
    qw = dk * tau / (4 * np.pi)
    klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
    grid = nufft.make_grid(n_t, "nufft", eps)
    R = nufft.spread(B, grid, klat2, kz, qw, c, dt, t0)
    del B
    G = nufft.from_fine_grid(R, grid, t0_is_zero=False)  # (n_cols, n_t)
    return G.T.reshape(n_t, F.shape[1], F.shape[2])


def _as3d(p0: np.ndarray) -> tuple[np.ndarray, bool]:
    return (p0[:, None, :], True) if p0.ndim == 2 else (p0, False)


def forward_grid(
    p0: np.ndarray,
    dx: float,
    dz: float,
    dt: float,
    n_t: int,
    c: float = C_DEFAULT,
    *,
    t0: float = 0.0,
    eps: float = 1e-6,
    periodic: bool = False,
) -> np.ndarray:
    """Data on the sensor grid (the lateral grid of p0) from p0, exactly.

    Parameters
    ----------
    p0 : (n_z, n_x) or (n_z, n_y, n_x) initial pressure in Pa; row 0 at the sensor plane.
    dx : lateral spacing in m (x and y). dz : depth spacing in m.
    dt : sample interval in s. n_t : number of samples. c : sound speed in m/s.
    t0 : time of sample 0 in s (>= 0). eps : NUFFT tolerance in [1e-14, 1e-1].
    periodic : keep the lateral/depth periodicity of the grid (no zero padding).

    Returns
    -------
    (n_t, n_x) or (n_t, n_y, n_x) float64 pressure in Pa at t_n = t0 + n dt.

    Raises
    ------
    ValueError for NaN/inf, wrong shapes, non-positive spacings, bad eps.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §2 (the planar forward problem).

    Examples
    --------
    A point of p0 0.8 mm deep below the grid's centre column (dt = dx/c: one sample per
    pixel of travel) reaches that column after 8 samples.

    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> p0 = np.zeros((16, 32))  # (n_z, n_x), Pa
    >>> p0[8, 16] = 1.0
    >>> data = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)
    >>> data.shape, int(data[:, 16].argmax())  # (n_t, n_x)
    ((40, 32), 8)
    """
    p0 = _check_common(p0, dx, dz, dt, n_t, c, t0, eps)
    vol, is2d = _as3d(p0)
    if not periodic:
        nz2, ny2, nx2 = pad_sizes(vol.shape, dx, dz, dt, n_t, c, t0)
        vol = _embed(vol, (nz2, ny2, nx2))
    G = _kspace_data(vol, dx, dz, dt, int(n_t), c, t0, eps, full=False)
    data = irfft_lateral(G, vol.shape[1:])
    if not periodic:
        data = _crop_lateral(data, p0.shape[-1], 1 if is2d else p0.shape[1])
    return data[:, 0, :] if is2d else data


def _embed(vol: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    nz, ny, nx = vol.shape
    out = np.zeros(shape)
    oy, ox = (shape[1] - ny) // 2, (shape[2] - nx) // 2
    out[:nz, oy : oy + ny, ox : ox + nx] = vol
    return out


def _crop_lateral(data: np.ndarray, n_x: int, n_y: int) -> np.ndarray:
    oy, ox = (data.shape[1] - n_y) // 2, (data.shape[2] - n_x) // 2
    return data[:, oy : oy + n_y, ox : ox + n_x]


def forward_points(
    p0: np.ndarray,
    dx: float,
    dz: float,
    positions: np.ndarray,
    dt: float,
    n_t: int,
    c: float = C_DEFAULT,
    *,
    t0: float = 0.0,
    eps: float = 1e-6,
    periodic: bool = False,
) -> np.ndarray:
    """A-lines at arbitrary sensor positions on the plane z = 0 from p0, exactly.

    Parameters
    ----------
    p0 : (n_z, n_x) or (n_z, n_y, n_x) initial pressure in Pa (lateral grid centred on
        the optical axis, x_i = (i - (n_x - 1)/2) dx).
    positions : (n_points, 1) x in m for 2-D p0, (n_points, 2) (x, y) in m for 3-D.
    Other parameters as `forward_grid`.

    Returns
    -------
    (n_points, n_t) float64 pressure in Pa.

    Raises
    ------
    ValueError for bad p0/spacings/eps (as `forward_grid`), positions of the wrong shape
    or non-finite.

    Examples
    --------
    At a grid position the A-line is :func:`forward_grid`'s column (x = 0.05 mm is column
    16 of 32 at 0.1 mm).

    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid, forward_points
    >>> p0 = np.zeros((16, 32))
    >>> p0[8, 16] = 1.0
    >>> kw = dict(dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)
    >>> alines = forward_points(p0, positions=np.array([[5e-5]]), **kw)  # (n_points, n_t)
    >>> alines.shape, bool(np.allclose(alines[0], forward_grid(p0, **kw)[:, 16], atol=1e-5))
    ((1, 40), True)
    """
    p0 = _check_common(p0, dx, dz, dt, n_t, c, t0, eps)
    pos = np.asarray(positions, dtype=np.float64)
    want = 1 if p0.ndim == 2 else 2
    if pos.ndim != 2 or pos.shape[1] != want or len(pos) == 0:
        raise ValueError(f"positions must have shape (n_points, {want}) for {p0.ndim}-D p0, got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise ValueError("positions must be finite")
    vol, is2d = _as3d(p0)
    if not periodic:
        # sensors beyond the grid's extent widen the padding (same padding as
        # forward_grid for sensors within it, so both see the same band-limited p0)
        half = 0.5 * (max(vol.shape[1], vol.shape[2]) - 1) * dx
        extra = 2.0 * max(0.0, float(np.max(np.abs(pos))) - half)
        nz2, ny2, nx2 = pad_sizes(vol.shape, dx, dz, dt, n_t, c, t0, extra_lateral=extra)
        vol = _embed(vol, (nz2, ny2, nx2))
    n_z, n_y, n_x = vol.shape
    G = _kspace_data(vol, dx, dz, dt, int(n_t), c, t0, eps, full=True)  # (n_t, n_y, n_x)
    # grid index of a coordinate: i = x/dx + (n-1)/2; mode k_j = 2π j/(n dx) (FFT order)
    tx = 2 * np.pi * centred_index(pos[:, 0], n_x, dx) / n_x
    tol = max(eps, 1e-14)
    # planned once per mask and size (nufft_plans): repeated forward models only execute
    if is2d:
        plan = lateral_plan(2, (tx,), (n_x,), int(n_t), eps=tol, isign=1, dtype=np.complex128)
        vals = plan.execute(np.ascontiguousarray(G[:, 0, :]))
        scale = n_x
    else:
        ty = 2 * np.pi * centred_index(pos[:, 1], n_y, dx) / n_y
        plan = lateral_plan(2, (ty, tx), (n_y, n_x), int(n_t), eps=tol, isign=1, dtype=np.complex128)
        vals = plan.execute(np.ascontiguousarray(G))
        scale = n_x * n_y
    return np.ascontiguousarray((vals.real / scale).T)
