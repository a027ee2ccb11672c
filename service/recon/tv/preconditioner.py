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

from fpscan.physics import array_kernels, fft_engine, workspace
from fpscan.physics.fast_lengths import fast_real_shape

__all__ = ["NerWeight", "ner_weight", "apply_weight", "apply_weight_on"]


class NerWeight(NamedTuple):
    """NER's k-space weight P = k_z / |k| (`ner_weight`), kept as its axes, not as an image.

    Attributes
    ----------
    kz : ndarray
        ``(N_z,)`` depth wavenumbers, rad/m, float64 (shifted by half a bin: > 0).
    lat2 : ndarray
        |k_lat|² ``(N_y, N_x)`` (2-D: ``(1, N_x)``), rad²/m², float64.
    shape : tuple of int
        The padded grid ``(N_z, N_x)`` / ``(N_z, N_y, N_x)``.

    Examples
    --------
    >>> from fpscan.service.recon.tv.preconditioner import ner_weight
    >>> P = ner_weight((4, 6), dx=1e-4, dz=1e-4)
    >>> P.shape, P.kz.shape, P.lat2.shape
    ((4, 6), (4,), (1, 6))
    """

    kz: np.ndarray
    lat2: np.ndarray
    shape: tuple[int, ...]


def ner_weight(shape: Sequence[int], dx: float, dz: float) -> NerWeight:
    """NER's k-space weight k_z / |k| on the orthonormal DCT-II grid of the image zero-padded to
    fast lengths: the inverse of AᵀA's symbol |k| / k_z for a full planar aperture (paper eq. (1);
    Arridge et al., PMB 61 (2016) 8908, the preconditioner).

    Fast lengths: `fpscan.physics.fast_lengths.fast_real_shape` (on axes of 226 = 2·113 the DCT-II
    and its inverse took 2.08 s at 1024 × 226², against 0.57 s at 1024 × 240², float32); mirror
    boundaries at the padded grid's ends; k_i = π j / (N_i d_i), depth shifted by half a bin so
    that the weight is > 0 everywhere; values in (0, 1].

    Parameters
    ----------
    shape : tuple of int
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``.
    dx, dz : float
        Lateral and depth spacing, m.

    Returns
    -------
    NerWeight
        The weight's axes on the padded grid ``fast_real_shape(shape)`` (same axis order): P is
        computed voxel by voxel where it is applied (`apply_weight`), so that it costs no image of
        memory; a symmetric positive definite map of the image (the zero padding is an isometry
        and its adjoint the crop).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.preconditioner import ner_weight
    >>> P = ner_weight((4, 6), dx=1e-4, dz=1e-4)
    >>> bool(np.all(P.kz > 0)), float(P.lat2[0, 0])  # k_z > 0: P positive definite
    (True, 0.0)
    >>> ner_weight((4, 113), 1e-4, 1e-4).shape  # 113 is prime: padded to a fast length
    (4, 120)
    """
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
    """P x: the multiplier ``P`` on the orthonormal DCT-II of ``x`` zero-padded to ``P.shape``
    (all axes), cropped back, in a compiled kernel (no image of its own); the padded image in a
    work array (`fpscan.physics.workspace`), the padding and the crop on every core.

    Parameters
    ----------
    P : NerWeight
        `ner_weight` of x's shape.
    x : ndarray
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or float64; overwritten where
        the grid is padded. A GPU run's (CuPy) takes `apply_weight_on` (a new array there).

    Returns
    -------
    ndarray
        P x, x's shape and dtype (``x`` itself where padded, or a C-contiguous copy of a ``x``
        that is not; the transform runs in place when no axis is padded).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.preconditioner import apply_weight, ner_weight
    >>> P = ner_weight((4, 6), dx=1e-4, dz=1e-4)
    >>> x = np.random.default_rng(0).standard_normal((4, 6))
    >>> y = apply_weight(P, x.copy())
    >>> y.shape, bool(np.linalg.norm(y) < np.linalg.norm(x))  # a weight in (0, 1]
    ((4, 6), True)
    >>> bool(np.vdot(x, y) > 0)  # positive definite
    True
    """
    if not isinstance(x, np.ndarray):
        from fpscan.service.recon.tv.kernels import array_module

        return apply_weight_on(array_module(x), P, x)
    padded = tuple(P.shape) != tuple(x.shape)
    volume = (P.shape[0], P.lat2.shape[0], P.shape[-1])  # the kernels' 3-D views (2-D: one y row)
    if padded:  # zero-padded into a work array (`fpscan.physics.workspace`), on every core
        x = np.ascontiguousarray(x)
        c = workspace.take(volume, x.dtype)
        array_kernels.pad_volume(x.reshape(x.shape[0], -1, x.shape[-1]), c)
        c = c.reshape(P.shape)
    else:
        c = x
    c = scipy.fft.dctn(c, type=2, norm="ortho", workers=fft_engine.workers(), overwrite_x=True)
    c = np.ascontiguousarray(c)  # (the kernel writes through a 3-D view of it)
    _weight_kernel(c.reshape(volume), P.kz, P.lat2)
    c = scipy.fft.idctn(c, type=2, norm="ortho", workers=fft_engine.workers(), overwrite_x=True)
    if not padded:
        return c
    array_kernels.crop_rows(c.reshape(volume), x.reshape(x.shape[0], -1, x.shape[-1]), 0, 0)
    return x


def apply_weight_on(xp: ModuleType, P: NerWeight, x: Any) -> Any:
    """`apply_weight` on the array module ``xp`` (a GPU run's arrays; the tests run it on NumPy).

    NER's k-space weight k_z / |k| on the orthonormal DCT-II of ``x`` zero-padded to
    ``P.shape``, cropped back, as array expressions.

    Parameters
    ----------
    xp : module
        ``cupy`` (its ``cupyx.scipy.fft``) or ``numpy`` (``scipy.fft``).
    P : NerWeight
        The weight's axes (``kz``, ``lat2``, ``shape``).
    x : array
        ``(n_z, n_x)`` or ``(n_z, n_y, n_x)``; not modified.

    Returns
    -------
    array
        A new array of x's shape and dtype.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.preconditioner import apply_weight, apply_weight_on, ner_weight
    >>> P = ner_weight((4, 6), dx=1e-4, dz=1e-4)
    >>> x = np.random.default_rng(0).standard_normal((4, 6))
    >>> bool(np.allclose(apply_weight_on(np, P, x), apply_weight(P, x.copy())))
    True
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
