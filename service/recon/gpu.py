"""The GPU path of the planar kernels: NER / NEDNER's inversion and the operator pair on CuPy.

The same discretisation as the CPU kernels — the transform lengths, depth rows, temporal grid
and kernel taps are planned by the same functions (`fpscan.service.recon.planar`,
`fpscan.physics.grid_sizes.pad_sizes`, `fpscan.physics.nufft.make_grid`) — with every array
step written on an array namespace ``xp`` (``cupy`` on a GPU; ``numpy`` in the tests, which
compare this path with the CPU kernels on machines without a GPU):

- the lateral FFTs are ``xp.fft`` (cuFFT on a GPU);
- the temporal NUFFT is `fpscan.physics.temporal_xp` (fpscan's own kernel taps, one gather or
  scatter-add per tap; cufinufft's type-2 transforms need one point set per plan, and here
  every |k_lat| group has its own);
- the depth DCT-I is the FFT of the even extension (`fpscan.physics.temporal_xp.dct1`).

NEDNER's lateral type-1 NUFFT from off-lattice sensors stays on the host (finufft,
`fpscan.service.recon.planar._lateral_spectrum`); its spectrum is copied to the GPU. The operator pair
(`fpscan.service.recon.operator.PlanarOperator` with ``device="cuda"``) covers sensors on the image's
lateral grid and sensors on its nodes (a scan plan's lattice), not off-lattice sensors.

The choice of device and its rules: `fpscan.service.recon.device`.
"""
from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from fpscan.physics import nufft
from fpscan.physics import temporal_xp as txp
from fpscan.physics.lateral import pad_spectrum

__all__ = ["clear_cache", "inversion_peak", "operator_peak", "invert", "OperatorPair"]

_TAPS: dict[tuple, txp.Taps] = {}  # the last inversions' taps on the GPU (NER applied again: no set-up)
_CACHE_SIZE = 2


def clear_cache() -> None:
    """Drop the cached taps (their GPU memory is then free for the pool to give back)."""
    _TAPS.clear()


def inversion_peak(n_t: int, n_cols: int, n_work: int, n_out: int, eps: float, rdtype: Any,
                   data_elements: int = 0) -> int:
    """GPU bytes an inversion (`invert`) holds at its peak: the lateral spectrum (n_t n_cols
    complex), the fine temporal grid and its FFT (2 n_cols L), the taps' per-column index
    (int64) and the evaluation's sums, gathers and products (about 6 complex n_cols n_work),
    the DCT-I's even extension and its FFT (4 n_cols n_work), the data (``data_elements``
    reals) and the image (``n_out`` reals); 25 % on top for cuFFT's work areas.

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_cols : int
        Lateral half-spectrum columns, N_y (N_x // 2 + 1).
    n_work : int
        Depth rows of the transform (K).
    n_out : int
        Output voxels.
    eps : float
        NUFFT tolerance (sets the fine grid).
    rdtype : dtype
        float32 or float64.
    data_elements : int
        Input elements held on the GPU (grid data), 0 for a spectrum made on the host.

    Returns
    -------
    int
        Bytes.
    """
    r = np.dtype(rdtype).itemsize
    L = nufft.grid_length(n_t, "nufft", eps)
    cplx = 2 * r * n_cols * (n_t + 2 * L + 10 * n_work) + 8 * n_cols * n_work
    return int(1.25 * (cplx + r * (data_elements + n_out)))


def operator_peak(op: Any) -> int:
    """GPU bytes the operator pair on ``op``'s working grid holds at its peak: its taps
    (both directions), the k-space of the image and of the data, the fine temporal grid, the
    depth step's DCT-I and the scatter-add's real view; 25 % on top.

    Parameters
    ----------
    op : fpscan.service.recon.operator.PlanarOperator

    Returns
    -------
    int
        Bytes.
    """
    n_z2, n_y2, n_x2 = op.padded_shape
    r = np.dtype(op.dtype).itemsize
    cols = n_y2 * (n_x2 // 2 + 1)
    L = nufft.grid_length(op.n_t, "nufft", op.eps)
    taps = 2 * (8 * cols * n_z2 + 2 * r * cols * n_z2)
    work = 2 * r * cols * (max(op.n_t, n_z2) + 2 * L + 8 * n_z2) + 8 * cols * n_z2
    vol = r * (int(np.prod(op.ishape)) + int(np.prod(op.oshape)))
    return int(1.25 * (taps + work + 2 * vol))


def _cached_taps(key: tuple, make: Any) -> txp.Taps:
    """The taps of ``key`` from the cache, made by ``make()`` on a miss."""
    tp = _TAPS.get(key)
    if tp is None:
        tp = make()
        if len(_TAPS) >= _CACHE_SIZE:
            _TAPS.pop(next(iter(_TAPS)))
        _TAPS[key] = tp
    return tp


def invert(xp: ModuleType, A: Any, n_x: int, dx: float, dy: float, dt: float, c: float, n_work: int,
           dz: float, t0: float, eps: float, rdtype: Any, upsample: int, keep: tuple[int, int, int]) -> Any:
    """`fpscan.service.recon.planar._invert` (method ``ner``) on ``xp``: the lateral half spectrum ``A``
    ``(n_t, n_y, n_x // 2 + 1)`` complex -> p0 ``keep`` = (rows, y, x) of ``(n_work, n_y u,
    n_x u)``, in ``rdtype``.

    The temporal NUFFT evaluated at ω = c |k| with the inversion's weight (the paper, eq. (1)), the
    DCT-I in depth, the (upsampled) inverse lateral FFT, cropped.

    Parameters
    ----------
    xp : module
        ``cupy`` (or ``numpy``).
    A : array ``(n_t, n_y, n_x // 2 + 1)`` complex
        The lateral spectrum (``n_x`` the transform's length along x).
    n_x : int
    dx, dy, dt, c, dz, t0 : float
        Pitches (m), sample interval (s), sound speed (m/s), depth step (m), time of sample 0 (s).
    n_work : int
        Depth rows of the transform (K).
    eps : float
        NUFFT tolerance.
    rdtype : dtype
        float32 or float64.
    upsample : int
    keep : tuple of int
        The leading (rows, y, x) kept.

    Returns
    -------
    array ``keep`` of ``rdtype``.
    """
    n_t, n_y, n_xr = A.shape
    rdtype = np.dtype(rdtype)
    ctype = np.result_type(rdtype, np.complex64)
    grid = nufft.make_grid(n_t, "nufft", eps)

    def make() -> txp.Taps:
        kx = 2 * np.pi * np.fft.rfftfreq(n_x, dx)
        ky = 2 * np.pi * np.fft.fftfreq(n_y, dy)
        klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
        dk = np.pi / ((n_work - 1) * dz)
        kz = dk * np.arange(n_work)
        qw = np.full(n_work, c * c * dt * dk / np.pi)
        return txp.taps(xp, grid, klat2, kz, qw, c, dt, t0, True, rdtype)

    tp = _cached_taps((xp.__name__, "invert", n_t, n_y, n_x, dx, dy, dt, c, n_work, dz, t0, eps, rdtype.name),
                      make)
    U = txp.to_fine_grid(xp, A.reshape(n_t, n_y * n_xr).T.astype(ctype, copy=False), grid, t0 == 0)
    F = txp.evaluate(xp, U, tp)  # (n_cols, n_work)
    del U
    F = txp.dct1(xp, F, axis=1)
    K = xp.ascontiguousarray(F[:, : keep[0]].T).reshape(keep[0], n_y, n_xr)
    del F
    ups_y = n_y > 1
    if upsample > 1:
        K = pad_spectrum(K, n_y, n_x, upsample, ups_y, xp=xp)
    shape = ((n_y * upsample) if ups_y else n_y, n_x * upsample)
    p0 = xp.fft.irfft2(K, s=shape, axes=(1, 2))[:, : keep[1], : keep[2]]
    if upsample > 1:
        p0 = p0 * upsample ** (2 if ups_y else 1)
    return xp.ascontiguousarray(p0.astype(rdtype, copy=False))


class OperatorPair:
    """The planar operator pair of a `fpscan.service.recon.operator.PlanarOperator` on ``xp``: its
    working grid, band and sensors, its forward and adjoint, with the taps made once.

    Parameters
    ----------
    op : fpscan.service.recon.operator.PlanarOperator
        Planned (its ``_setup`` ran); sensors on its grid or on nodes of it.
    xp : module
        ``cupy`` (or ``numpy``).

    Raises
    ------
    ValueError
        Sensors off the working grid's nodes (the lateral NUFFT pair runs on the CPU only).
    """

    def __init__(self, op: Any, xp: ModuleType) -> None:
        if op.positions is not None and op._nodes is None:
            raise ValueError("the GPU operator needs the sensors on nodes of the image's lateral grid "
                             "(a scan plan's lattice); these are off it")
        self.op, self.xp = op, xp
        rd = np.dtype(op.dtype)
        kept = np.setdiff1d(np.arange(len(op._klat2)), op._skipped)
        self.kept = xp.asarray(kept)
        self.n_cols = len(op._klat2)
        klat2 = op._klat2[kept]
        n_z2 = op.padded_shape[0]
        self.cut = None
        if op.band is not None:  # the band's k-space ball: rows at and past `rows` are zero
            kc2 = (2 * np.pi * op.band / op.c) ** 2
            dk = op._kz[1] - op._kz[0]
            rows = np.minimum(np.floor(np.sqrt(np.maximum(kc2 - klat2, 0.0)) / dk).astype(np.int64) + 1, n_z2)
            if np.any(rows < n_z2):
                self.cut = xp.asarray(np.arange(n_z2)[None, :] >= rows[:, None])
        args = (op._grid, klat2, op._kz)
        self.taps_forward = txp.taps(xp, *args, op._qw_forward, op.c, op.dt, op.t0, False, rd)
        self.taps_adjoint = txp.taps(xp, *args, op._qw_adjoint, op.c, op.dt, op.t0, False, rd)
        if op._nodes is not None:
            rows_, row_of, cols = op._nodes
            self.nodes = (xp.asarray(rows_), xp.asarray(row_of), xp.asarray(cols))

    # lateral steps ----------------------------------------------------------------
    def _spectrum(self, vol: Any) -> Any:
        """(m, n_y, n_x) real -> (m, N_y, N_x//2+1): the half spectrum of its centred
        embedding in the working grid (`PlanarOperator._lateral_spectrum`)."""
        xp, op = self.xp, self.op
        _, n_y2, n_x2 = op.padded_shape
        _, n_y, n_x = op._vol
        oy, ox = op._off
        m = vol.shape[0]
        pad = xp.zeros((m, n_y, n_x2), dtype=vol.dtype)
        pad[:, :, ox : ox + n_x] = vol
        S = xp.zeros((m, n_y2, n_x2 // 2 + 1), dtype=np.result_type(vol.dtype, np.complex64))
        S[:, oy : oy + n_y] = xp.fft.rfft(pad, axis=2)
        return xp.fft.fft(S, axis=1) if n_y2 > 1 else S

    def _inverse(self, S: Any) -> Any:
        """(m, N_y, N_x//2+1) -> the image's (m, n_y, n_x) window of its inverse lateral DFT
        (`PlanarOperator._lateral_inverse`)."""
        xp, op = self.xp, self.op
        _, n_y2, n_x2 = op.padded_shape
        _, n_y, n_x = op._vol
        oy, ox = op._off
        if n_y2 > 1:
            S = xp.fft.ifft(S, axis=1)[:, oy : oy + n_y]
        return xp.fft.irfft(S, n=n_x2, axis=2)[:, :, ox : ox + n_x]

    # the pair ----------------------------------------------------------------------
    def forward(self, p0: Any) -> Any:
        """A p0 on ``xp``: ``p0`` of the operator's ``ishape`` -> data of its ``oshape``."""
        xp, op = self.xp, self.op
        n_z2, n_y2, n_x2 = op.padded_shape
        n_z = op._vol[0]
        rd = np.dtype(op.dtype)
        Y = self._spectrum(xp.asarray(p0, dtype=rd).reshape(op._vol)).reshape(n_z, -1)
        B = xp.zeros((len(self.kept), n_z2), dtype=Y.dtype)
        B[:, :n_z] = Y[:, self.kept].T
        del Y
        B = txp.dct1(xp, B, axis=1)
        if self.cut is not None:
            B[self.cut] = 0
        op._tick()
        G = txp.from_fine_grid(xp, txp.spread(xp, B, self.taps_forward), op._grid, False)  # (kept, n_t)
        del B
        T = xp.zeros((op.n_t, self.n_cols), dtype=G.dtype)
        T[:, self.kept] = G.T
        del G
        T = T.reshape(op.n_t, n_y2, n_x2 // 2 + 1)
        op._tick()
        if op.positions is None:
            g = self._inverse(T)
            return xp.ascontiguousarray((g[:, 0, :] if op.is2d else g).astype(rd, copy=False))
        rows, row_of, cols = self.nodes
        if n_y2 > 1:
            T = xp.take(xp.fft.ifft(T, axis=1), rows, axis=1)
        g = xp.fft.irfft(T, n=n_x2, axis=2)  # (n_t, len(rows), N_x)
        return xp.ascontiguousarray(g[:, row_of, cols].T.astype(rd, copy=False))

    def adjoint(self, data: Any) -> Any:
        """Aᵀ data on ``xp``: data of the operator's ``oshape`` -> an image of its ``ishape``."""
        xp, op = self.xp, self.op
        n_z2, n_y2, n_x2 = op.padded_shape
        n_z, n_y, n_x = op._vol
        rd = np.dtype(op.dtype)
        data = xp.asarray(data, dtype=rd)
        if op.positions is None:
            S = self._spectrum(data.reshape(op.n_t, n_y, n_x))
        else:
            rows, row_of, cols = self.nodes
            placed = xp.zeros((op.n_t, len(rows), n_x2), dtype=rd)
            placed[:, row_of, cols] = data.T
            S = xp.zeros((op.n_t, n_y2, n_x2 // 2 + 1), dtype=np.result_type(rd, np.complex64))
            S[:, rows] = xp.fft.rfft(placed, axis=2)
            del placed
            if n_y2 > 1:
                S = xp.fft.fft(S, axis=1)
        A = S.reshape(op.n_t, -1)[:, self.kept].T
        del S
        F = txp.evaluate(xp, txp.to_fine_grid(xp, A, op._grid, False), self.taps_adjoint)  # (kept, N_z)
        del A
        if self.cut is not None:
            F[self.cut] = 0
        F = txp.dct1(xp, F, axis=1)
        op._tick()
        K = xp.zeros((n_z, self.n_cols), dtype=F.dtype)
        K[:, self.kept] = F[:, :n_z].T
        del F
        K[0] *= 0.5  # DCT-Iᵀ = diag(τ) DCT-I diag(1/τ), τ = ½ at both ends
        if n_z == n_z2:
            K[-1] *= 0.5
        p = self._inverse(K.reshape(n_z, n_y2, n_x2 // 2 + 1))
        p = p[:, 0, :] if op.is2d else p
        return xp.ascontiguousarray(p.astype(rd, copy=False))
