"""tv's preconditioner: NER's k-space weight P = k_z / |k|, applied on the image's DCT-II.

For a full planar aperture AᵀA has the symbol |k| / k_z (`fpscan.service.recon.planar`: F = const ·
(k_z/ω) E against the adjoint's E), so P = k_z / |k| inverts it. `ner_weight` keeps P as its
axes on the orthonormal DCT-II grid of the image zero-padded to fast lengths (symmetric and
positive definite), and `apply_weight` applies it voxel by voxel in a numba kernel
(``cache=True``; `fpscan.service.recon.methods.tv`'s ``kernel_modules``): no image of its own.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from types import ModuleType
from typing import Any, NamedTuple

import numba
import numpy as np
import scipy.fft

from fpscan.physics.fast_lengths import fast_real_shape

__all__: list[str] = []


class NerWeight(NamedTuple):
    """NER's k-space weight P = k_z / |k| (`ner_weight`), kept as its axes, not as an image:
    ``kz`` ``(N_z,)`` and ``lat2`` = |k_lat|² ``(N_y, N_x)`` (2-D: ``(1, N_x)``), rad/m and
    rad²/m², float64; ``shape`` the padded grid ``(N_z, N_x)`` / ``(N_z, N_y, N_x)``."""

    kz: np.ndarray
    lat2: np.ndarray
    shape: tuple[int, ...]


def ner_weight(shape: Sequence[int], dx: float, dz: float) -> NerWeight:
    """NER's k-space weight k_z / |k| on the orthonormal DCT-II grid of the image zero-padded
    to fast lengths (`fpscan.physics.fast_lengths.fast_real_shape`: on axes of 226 = 2·113 the
    DCT-II and its inverse took 2.08 s at 1024 × 226², against 0.57 s at 1024 × 240², float32;
    mirror boundaries at the padded grid's ends; k_i = π j / (N_i d_i), depth shifted by
    half a bin so that the weight is > 0 everywhere), in (0, 1]: the inverse of AᵀA's symbol
    |k| / k_z for a full planar aperture.

    Parameters
    ----------
    shape : tuple of int
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``.
    dx, dz : float
        Lateral and depth spacing, m.

    Returns
    -------
    NerWeight
        The weight's axes on the padded grid ``fast_real_shape(shape)`` (same axis order):
        P is computed voxel by voxel where it is applied (`apply_weight`), so that it costs
        no image of memory. `apply_weight` applies it as x -> crop(DCTᵀ P DCT pad(x)), a
        symmetric positive definite map of the image (the zero padding is an isometry and
        its adjoint the crop); on a grid that is already fast it is the image's own DCT-II."""
    grid = fast_real_shape(tuple(int(n) for n in shape))
    ks = [np.pi * np.arange(n) / (n * d) for n, d in zip(grid, (dz,) + (dx,) * (len(grid) - 1))]
    kz = ks[0] + np.pi / (2 * grid[0] * dz)  # half a depth bin: k_z > 0, so P is positive definite
    lat2 = sum(k * k for k in np.meshgrid(*ks[1:], indexing="ij", sparse=True))  # |k_lat|², grid[1:]
    lat2 = np.ascontiguousarray(np.broadcast_to(lat2, grid[1:]), dtype=np.float64).reshape(-1, grid[-1])
    return NerWeight(kz, lat2, grid)


@numba.njit(parallel=True, cache=True, fastmath=True)
def _weight_kernel(c: np.ndarray, kz: np.ndarray, lat2: np.ndarray) -> None:
    """c[i, j, l] *= kz[i] / sqrt(kz[i]² + lat2[j, l]) in place (c: DCT coefficients, 3-D)."""
    for i in numba.prange(c.shape[0]):
        k = kz[i]
        k2 = k * k
        for j in range(c.shape[1]):
            row = c[i, j]
            lat = lat2[j]
            for m in range(c.shape[2]):
                row[m] *= k / math.sqrt(k2 + lat[m])


def apply_weight(P: NerWeight, x: np.ndarray) -> np.ndarray:
    """P x: the multiplier ``P`` (`ner_weight`, on the padded grid ``P.shape``) on the
    orthonormal DCT-II of ``x`` zero-padded to that grid (all axes), cropped back; ``x`` is
    overwritten and returned, in its dtype (the transform runs in place when no axis is
    padded). A GPU run's image (CuPy) takes `apply_weight_on` (a new array there)."""
    if not isinstance(x, np.ndarray):
        from fpscan.service.recon.tv.kernels import array_module

        return apply_weight_on(array_module(x), P, x)
    pad = [(0, N - n) for N, n in zip(P.shape, x.shape)]
    padded = any(after for _, after in pad)
    c = scipy.fft.dctn(np.pad(x, pad) if padded else x, type=2, norm="ortho", workers=-1, overwrite_x=True)
    c = np.ascontiguousarray(c)  # (the kernel writes through a 3-D view of it)
    _weight_kernel(c.reshape(P.shape[0], P.lat2.shape[0], P.shape[-1]), P.kz, P.lat2)
    c = scipy.fft.idctn(c, type=2, norm="ortho", workers=-1, overwrite_x=True)
    if not padded:
        return c
    x[...] = c[tuple(slice(0, n) for n in x.shape)]
    return x


def apply_weight_on(xp: ModuleType, P: NerWeight, x: Any) -> Any:
    """`apply_weight` on ``xp`` (a GPU run's arrays; the tests run it on NumPy): NER's k-space weight k_z / |k|
    on the orthonormal DCT-II of ``x`` zero-padded to ``P.shape``, cropped back (a new array of
    x's dtype; ``x`` is not modified).

    Parameters
    ----------
    xp : module
        ``cupy`` (its ``cupyx.scipy.fft``) or ``numpy`` (``scipy.fft``).
    P : NerWeight
        The weight's axes (``kz``, ``lat2``, ``shape``).
    x : array ``(n_z, n_x)`` or ``(n_z, n_y, n_x)``

    Returns
    -------
    array of x's shape and dtype.
    """
    sfft: Any = scipy.fft
    if xp is not np:
        import cupyx.scipy.fft  # a GPU run's only

        sfft = cupyx.scipy.fft
    pad = [(0, N - n) for N, n in zip(P.shape, x.shape)]
    c = sfft.dctn(xp.pad(x, pad), type=2, norm="ortho")
    kz = xp.asarray(P.kz)[:, None, None]
    weight = kz / xp.sqrt(kz * kz + xp.asarray(P.lat2)[None])
    c = c.reshape(P.shape[0], P.lat2.shape[0], P.shape[-1]) * weight.astype(c.dtype)
    c = sfft.idctn(c.reshape(P.shape), type=2, norm="ortho")
    return xp.ascontiguousarray(c[tuple(slice(0, n) for n in x.shape)].astype(x.dtype, copy=False))
