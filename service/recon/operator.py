"""The planar photoacoustic operator pair: p0 on a grid -> sensor data, and its adjoint.

`PlanarOperator` wraps the exact planar forward model of `driver.physics.forward`
(DESIGN §3) as a linear operator A with its true adjoint Aᴴ (= Aᵀ, everything is real),
for 2-D (line sensor, p0 of shape (n_z, n_x)) and 3-D (plane sensor, (n_z, n_y, n_x)),
with the sensors either on the image's lateral grid or at arbitrary lateral positions.
It is a `pylops.LinearOperator` (``dims`` = `ishape`, ``dimsd`` = `oshape`), so every
pylops/pyproximal solver runs on it; `forward` / `adjoint` take and return arrays of the
natural shapes.

The discrete sums (periodic case; the non-periodic default first zero-pads p0 to the
shape (N_z, N_y, N_x) that `forward_grid` / `forward_points` use, so that no periodic
image reaches a sensor within the record, and crops/embeds accordingly). With
F(k_lat, k_z,l) = dz Σ_x e^{-i k_lat·x} DCT-I_z(p0)_l on the DFT lateral wavenumbers and
k_z,l = l Δk, Δk = π / ((N_z - 1) dz), τ_0 = τ_last = ½, τ_l = 1 otherwise::

    G(k_lat, t_n) = (Δk / 4π) Σ_l τ_l F(k_lat, k_z,l) 2 cos(c |k| t_n),   t_n = t0 + n dt
    forward (grid):   g(x, t_n)   = IDFT_lat G(·, t_n)(x)
    forward (points): g_m(t_n)    = Re Σ_k G(k, t_n) e^{i k·x_m} / (N_x N_y)

(the temporal sum is a type-1 NUFFT in time, the point evaluation a type-2 NUFFT with
finufft; both to the tolerance ``eps``). The adjoint applies the transposed steps in
reverse: lateral DFT of the data (grid) or a type-1 NUFFT from the sensor positions
Σ_m g_m e^{-i k·x_m} symmetrised to a Hermitian spectrum (points); the temporal type-2
NUFFT Σ_n a_n 2 cos(c |k| t_n) times dz Δk / 4π; the DCT-I in depth with both end rows
halved; the inverse lateral DFT; crop to the image. ⟨A x, y⟩ = ⟨x, Aᴴ y⟩ holds to the
NUFFT tolerance (dot test ~1e-12 at eps = 1e-12).

The adjoint is not the inverse: the inverse is the NER/NEDNER reconstruction
(`reconstruct_grid` / `reconstruct_points`), which weights k-space by k_z/ω instead.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pylops
import scipy.fft

from driver.physics import nufft
from driver.physics.axes import centred_index
from driver.physics.forward import _pad_sizes, forward_grid, forward_points
from driver.physics.nufft_plans import lateral_plan
from service.recon import checks


class PlanarOperator(pylops.LinearOperator):
    """A: p0 (n_z, n_x) / (n_z, n_y, n_x) on a regular grid -> data at the sensors.

    Parameters
    ----------
    shape : image shape (n_z, n_x) (2-D) or (n_z, n_y, n_x) (3-D); row 0 at z = 0,
        lateral coordinates centred on the optical axis, x_i = (i - (n_x - 1)/2) dx.
    dx : lateral pitch in m (x and y). dz : depth spacing in m.
    dt : sample interval in s. n_t : samples per A-line. c : sound speed in m/s.
    positions : None for sensors on the image's lateral grid (data (n_t, n_x) /
        (n_t, n_y, n_x), time first); else (n_points, 1) x or (n_points, 2) (x, y) in m,
        centred coordinates as above (data (n_points, n_t)).
    t0 : time of sample 0 in s (>= 0). eps : NUFFT tolerance in [1e-14, 1e-1].
    periodic : keep the grid's lateral/depth periodicity (no zero padding); the default
        False models free space exactly as `forward_grid` / `forward_points` do.
    dtype : float32 or float64: dtype of the arrays returned (the transforms themselves
        run in float64/complex128).

    Attributes
    ----------
    ishape, oshape : image and data shapes. dtype : as given. padded_shape : the
    working grid (N_z, N_y, N_x) (= the image shape when ``periodic``).

    Raises
    ------
    ValueError naming the problem: bad shape, non-positive dx/dz/dt/c, n_t < 1, t0 < 0,
    eps outside its range, positions of the wrong shape, non-finite or duplicated,
    bad dtype; `forward`/`adjoint` raise it for arrays of the wrong shape or with NaN/inf.
    """

    def __init__(self, shape, dx: float, dz: float, dt: float, n_t: int, c: float = 1500.0, *,
                 positions=None, t0: float = 0.0, eps: float = 1e-6, periodic: bool = False,
                 dtype=np.float64):
        shape = tuple(int(s) for s in shape)
        if len(shape) not in (2, 3) or min(shape) < 1 or shape[0] < 2:
            raise ValueError(f"shape must be (n_z, n_x) or (n_z, n_y, n_x) with n_z >= 2, got {shape}")
        self.dx = checks.positive("dx", dx)
        self.dz = checks.positive("dz", dz)
        self.dt = checks.positive("dt", dt)
        self.c = checks.positive("c", c)
        if int(n_t) != n_t or n_t < 1:
            raise ValueError(f"n_t must be an integer >= 1, got {n_t!r}")
        self.n_t = int(n_t)
        if not np.isfinite(t0) or t0 < 0:
            raise ValueError(f"t0 must be finite and >= 0 s, got {t0!r}")
        self.t0 = float(t0)
        self.eps = checks.check_eps(eps)
        self.periodic = bool(periodic)
        rdtype = checks.check_dtype(dtype)
        self.is2d = len(shape) == 2
        vol = (shape[0], 1, shape[1]) if self.is2d else shape
        if positions is None:
            self.positions = None
            oshape = (self.n_t,) + shape[1:]
            extra = 0.0
        else:
            d = 1 if self.is2d else 2
            pos = checks.finite_array("positions", positions, (1, 2)).astype(np.float64)
            pos = pos[:, None] if pos.ndim == 1 else pos
            if pos.shape[1] != d:
                raise ValueError(f"positions must have shape (n_points, {d}) for a {len(shape)}-D image, got {pos.shape}")
            self.positions = pos
            oshape = (len(pos), self.n_t)
            half = 0.5 * (max(vol[1], vol[2]) - 1) * self.dx
            extra = 2.0 * max(0.0, float(np.max(np.abs(pos))) - half)
        self._vol = vol
        self.padded_shape = vol if self.periodic else _pad_sizes(vol, self.dx, self.dz, self.dt, self.n_t,
                                                                   self.c, self.t0, extra_lateral=extra)
        super().__init__(dtype=rdtype, dims=shape, dimsd=oshape, explicit=False, name="PlanarOperator")

    # -- shapes ------------------------------------------------------------------
    @property
    def ishape(self) -> tuple[int, ...]:
        """Image shape (n_z, n_x) or (n_z, n_y, n_x)."""
        return tuple(self.dims)

    @property
    def oshape(self) -> tuple[int, ...]:
        """Data shape: (n_t, n_x) / (n_t, n_y, n_x) on the grid, (n_points, n_t) at points."""
        return tuple(self.dimsd)

    def transform_lengths(self) -> dict[str, tuple[int, ...]]:
        """The FFT lengths `forward` and `adjoint` run on the working grid `padded_shape`
        (N_z, N_y, N_x): "lateral" ((N_x,) or (N_y, N_x)), "depth" (2 (N_z - 1),) of the
        DCT-I, "temporal" (L,) of the temporal NUFFT's oversampled grid. Without
        ``periodic`` they are fast lengths (`driver.physics.fast_lengths`); a periodic
        operator keeps the image's own grid."""
        n_z2, n_y2, n_x2 = self.padded_shape
        lat = (n_x2,) if self.is2d else (n_y2, n_x2)
        return {"lateral": lat, "depth": (2 * (n_z2 - 1),),
                "temporal": (nufft.grid_length(self.n_t, "nufft", self.eps),)}

    def _check(self, name: str, a, shape) -> np.ndarray:
        arr = checks.finite_array(name, a, (len(shape),))
        if arr.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
        return arr

    # -- the pair ------------------------------------------------------------------
    def forward(self, p0) -> np.ndarray:
        """A p0: the data (`oshape`) of p0 (`ishape`), Pa -> Pa; equals `forward_grid` /
        `forward_points` with the same parameters."""
        p0 = self._check("p0", p0, self.ishape)
        kw: dict[str, Any] = dict(t0=self.t0, eps=self.eps, periodic=self.periodic)
        if self.positions is None:
            g = forward_grid(p0, self.dx, self.dz, self.dt, self.n_t, self.c, **kw)
        else:
            g = forward_points(p0, self.dx, self.dz, self.positions, self.dt, self.n_t, self.c, **kw)
        return g.astype(self.dtype, copy=False)

    def adjoint(self, data) -> np.ndarray:
        """Aᴴ data: the true adjoint of `forward` (not its inverse), `oshape` -> `ishape`."""
        data = self._check("data", data, self.oshape).astype(np.float64, copy=False)
        n_z2, n_y2, n_x2 = self.padded_shape
        n_z, n_y, n_x = self._vol
        oy, ox = (n_y2 - n_y) // 2, (n_x2 - n_x) // 2
        if self.positions is None:
            vol = np.zeros((self.n_t, n_y2, n_x2))
            vol[:, oy : oy + n_y, ox : ox + n_x] = data.reshape(self.n_t, n_y, n_x)
            A = scipy.fft.rfft2(vol, axes=(1, 2), workers=-1)
            del vol
        else:
            A = self._spectrum_at_points(data, n_y2, n_x2)
        p = self._adjoint_core(A, n_z2, n_y2, n_x2)[:n_z, oy : oy + n_y, ox : ox + n_x]
        p = p[:, 0, :] if self.is2d else p
        return np.ascontiguousarray(p, dtype=self.dtype)

    def _spectrum_at_points(self, data: np.ndarray, n_y: int, n_x: int) -> np.ndarray:
        """Adjoint of the type-2 point evaluation: Hermitian part of the type-1 NUFFT
        Σ_m g_m(t) e^{-i k·x_m}, as an rfft2-shaped half spectrum (n_t, n_y, n_x//2+1)."""
        pos = self.positions
        assert pos is not None  # point data only
        strengths = np.ascontiguousarray(data.T).astype(np.complex128)  # (n_t, n_points)
        tx = 2 * np.pi * centred_index(pos[:, 0], n_x, self.dx) / n_x
        # planned once per mask (driver.physics.nufft_plans): every iteration only executes
        eps = max(self.eps, 1e-14)
        if self.is2d:
            plan = lateral_plan(1, (tx,), (n_x,), self.n_t, eps=eps, isign=-1, dtype=np.complex128)
            Y = plan.execute(strengths)[:, None, :]
        else:
            ty = 2 * np.pi * centred_index(pos[:, 1], n_y, self.dx) / n_y
            plan = lateral_plan(1, (ty, tx), (n_y, n_x), self.n_t, eps=eps, isign=-1, dtype=np.complex128)
            Y = plan.execute(strengths)
        del strengths
        # Re(·) in the forward -> Hermitian part here: ½ (Y(k) + conj Y(-k)), FFT index order
        iy = (-np.arange(n_y)) % n_y
        ix = (-np.arange(n_x // 2 + 1)) % n_x
        return 0.5 * (Y[:, :, : n_x // 2 + 1] + np.conj(Y[:, iy][:, :, ix]))

    def _adjoint_core(self, A: np.ndarray, n_z: int, n_y: int, n_x: int) -> np.ndarray:
        """Transpose of the periodic forward model on the working grid: half lateral
        spectrum of the data (n_t, n_y, n_x//2+1) -> image (n_z, n_y, n_x)."""
        n_xr = n_x // 2 + 1
        kx = 2 * np.pi * scipy.fft.rfftfreq(n_x, self.dx)
        ky = 2 * np.pi * scipy.fft.fftfreq(n_y, self.dx)
        klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
        dk = np.pi / ((n_z - 1) * self.dz)
        kz = dk * np.arange(n_z)
        qw = np.full(n_z, self.dz * dk / (4 * np.pi))
        grid = nufft.make_grid(self.n_t, "nufft", self.eps)
        U = nufft.to_fine_grid(A.reshape(self.n_t, n_y * n_xr), grid, t0_is_zero=False)
        del A
        F = nufft.evaluate(U, grid, klat2, kz, qw, self.c, self.dt, self.t0, inversion=False, n_chunks=1)
        del U
        re = F.view(np.float64).reshape(F.shape[0], n_z, 2)  # DCT-I of real and imaginary parts
        F = scipy.fft.dct(re, type=1, axis=1, overwrite_x=True, workers=-1).reshape(F.shape[0], 2 * n_z)
        F = F.view(np.complex128)
        K: np.ndarray = np.empty((n_z, n_y * n_xr), dtype=np.complex128)
        nufft.transpose(F, K)
        del F
        K = K.reshape(n_z, n_y, n_xr)
        K[[0, -1]] *= 0.5  # DCT-Iᵀ = diag(τ) DCT-I diag(1/τ), τ = ½ at both ends
        return scipy.fft.irfft2(K, s=(n_y, n_x), axes=(1, 2), workers=-1, overwrite_x=True)

    # -- pylops ------------------------------------------------------------------
    def _matvec(self, x):
        return self.forward(np.asarray(x).reshape(self.ishape)).ravel()

    def _rmatvec(self, y):
        return self.adjoint(np.asarray(y).reshape(self.oshape)).ravel()
