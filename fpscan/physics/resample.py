"""Band-limited resampling of time series: the cosine series of a record, cut at a frequency
and sampled again on the same interval.

A record of N samples g_n = g(t0 + n dt), n = 0..N-1, is the cosine series (the DCT-I: the
record extended evenly about its first and its last sample, so that the extension has no
jump at either end; at t0 = 0 it is also the physical even extension of planar PAT data,
as in `fpscan.physics.nufft`)::

    g(t) = (1 / (2 (N - 1))) [ y_0 + 2 Σ_{k=1}^{N-2} y_k cos(π k τ) + y_{N-1} cos(π (N - 1) τ) ],
    τ = (t - t0) / T,  T = (N - 1) dt,  y = DCT-I(g)

whose term k has the frequency k / (2 T). `resample` keeps the terms k <= K - 2 (all below
the new Nyquist frequency) and evaluates the series at M = K samples on the same interval,
dt' = T / (M - 1): a DCT-I of length M. It is exact for a series that has no term k >= M - 1
(the samples of such a series at dt' are its values), and otherwise it is that series' ideal
low-pass: the terms it drops are the band above (M - 2) / (2 T). `resample_adjoint` is its
transpose (a DCT-I of length M, the coefficients zero-padded, a DCT-I of length N), so that
a linear model evaluated at the new rate and this low-pass can be used as one operator
(`fpscan.service.recon.tv`).

White noise of variance σ² per sample keeps its variance per sample at the new rate times
(M - 1) / (N - 1) (the share of the band kept): its density per hertz is unchanged.
"""
from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from fpscan.physics import fft_engine

__all__ = ["resample", "resample_adjoint", "resampled_length"]


def resampled_length(n_t: int, dt: float, band: float) -> int:
    """The fewest samples M on the same interval whose kept band (`resample`) reaches ``band``.

    Parameters
    ----------
    n_t : int
        Samples of the record (>= 2).
    dt : float
        Its sample interval, s.
    band : float
        The highest frequency to keep, Hz (> 0).

    Returns
    -------
    int
        M = ceil(2 band T) + 2 with T = (n_t - 1) dt, at most ``n_t`` (the record's own rate
        already keeps everything below its Nyquist frequency).

    Raises
    ------
    ValueError
        n_t < 2, or dt or band not finite and > 0.

    Examples
    --------
    >>> from fpscan.physics.resample import resampled_length
    >>> resampled_length(1024, 8e-9, 20e6)  # 8 ns -> about 24 ns: keeps up to 20 MHz
    330
    >>> resampled_length(1024, 8e-9, 1e9)  # above Nyquist: the record as it is
    1024
    """
    if int(n_t) != n_t or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    for name, v in (("dt", dt), ("band", band)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    span = (int(n_t) - 1) * float(dt)
    need = 2.0 * float(band) * span
    if need >= n_t:
        return int(n_t)
    return min(int(n_t), int(math.ceil(need * (1 - 1e-12))) + 2)


def _check(x: npt.ArrayLike, axis: int, n_out: int, n_in: int | None) -> tuple[np.ndarray, int]:
    x = np.asarray(x)
    if x.dtype.kind not in "fiu":
        raise ValueError(f"resampling needs real samples, got dtype {x.dtype}")
    axis = axis % x.ndim
    n = x.shape[axis]
    if n_in is not None and n != n_in:
        raise ValueError(f"expected {n_in} samples along axis {axis}, got {n}")
    if int(n_out) != n_out or n_out < 2:
        raise ValueError(f"the new length must be an integer >= 2, got {n_out!r}")
    return x, axis


def resample(x: npt.ArrayLike, n_out: int, axis: int = -1) -> np.ndarray:
    """The record's cosine series cut below the new Nyquist frequency and sampled at ``n_out``
    points on the same interval [t0, t_last] (module doc).

    Parameters
    ----------
    x : array_like
        Real samples, n >= 2 of them along ``axis`` (e.g. A-lines ``(n_points, n_t)``,
        ``axis=1``; grid data ``(n_t, n_y, n_x)``, ``axis=0``).
    n_out : int
        M >= 2 samples; the new interval is (n - 1) dt / (M - 1). M >= n keeps every term
        (an interpolation of the same series).
    axis : int, optional
        The time axis (default the last).

    Returns
    -------
    ndarray
        ``x``'s shape with M along ``axis``; float32 for float32 input, else float64.

    Raises
    ------
    ValueError
        Non-real input, fewer than 2 samples, or M < 2.

    Examples
    --------
    A cosine of 3 periods over the record, at 41 samples and at 13: the same curve.

    >>> import numpy as np
    >>> from fpscan.physics.resample import resample
    >>> t = np.linspace(0.0, 1.0, 41)
    >>> y = resample(np.cos(2 * np.pi * 3 * t), 13)
    >>> bool(np.allclose(y, np.cos(2 * np.pi * 3 * np.linspace(0.0, 1.0, 13))))
    True
    """
    import scipy.fft

    x, axis = _check(x, axis, n_out, None)
    n = x.shape[axis]
    if n < 2:
        raise ValueError(f"resampling needs at least 2 samples along axis {axis}, got {n}")
    dtype = np.float32 if x.dtype == np.float32 else np.float64
    y = scipy.fft.dct(np.asarray(x, dtype=dtype), type=1, axis=axis, workers=fft_engine.workers())
    keep = min(int(n_out) - 1, n)  # terms k <= M - 2 (and k < n)
    shape = list(x.shape)
    shape[axis] = int(n_out)
    z = np.zeros(shape, dtype=dtype)
    idx = [slice(None)] * x.ndim
    idx[axis] = slice(0, keep)
    z[tuple(idx)] = y[tuple(idx)]
    out = scipy.fft.dct(z, type=1, axis=axis, overwrite_x=True, workers=fft_engine.workers())
    out *= 1.0 / (2 * (n - 1))
    return out


def resample_adjoint(x: npt.ArrayLike, n_in: int, axis: int = -1) -> np.ndarray:
    """The transpose of `resample` to ``n_in`` samples: ⟨resample(u), v⟩ = ⟨u,
    resample_adjoint(v)⟩ for every u of ``n_in`` samples.

    Parameters
    ----------
    x : array_like
        Real samples at the new rate, M >= 2 along ``axis``.
    n_in : int
        The record's own length n >= 2.
    axis : int, optional
        The time axis.

    Returns
    -------
    ndarray
        ``x``'s shape with ``n_in`` along ``axis``.

    Raises
    ------
    ValueError
        As `resample`.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.resample import resample, resample_adjoint
    >>> rng = np.random.default_rng(0)
    >>> u, v = rng.standard_normal(50), rng.standard_normal(17)
    >>> bool(np.isclose(np.dot(resample(u, 17), v), np.dot(u, resample_adjoint(v, 50))))
    True
    """
    import scipy.fft

    x, axis = _check(x, axis, n_in, None)
    m = x.shape[axis]
    if m < 2:
        raise ValueError(f"resampling needs at least 2 samples along axis {axis}, got {m}")
    n = int(n_in)
    dtype = np.float32 if x.dtype == np.float32 else np.float64
    # resample = (1 / (2 (n - 1))) D_M Z D_n, D the (unnormalised) DCT-I and Z the cut: its
    # transpose is (1 / (2 (n - 1))) D_nᵀ Zᵀ D_Mᵀ, with D_mᵀ = W D_m W⁻¹, W = diag(½, 1, ..., 1, ½)
    w = _end_weights(m, axis, x.ndim, dtype)
    y = scipy.fft.dct(np.asarray(x, dtype=dtype) / w, type=1, axis=axis, workers=fft_engine.workers()) * w
    keep = min(m - 1, n)
    shape = list(x.shape)
    shape[axis] = n
    z: np.ndarray = np.zeros(shape, dtype=dtype)
    idx = [slice(None)] * x.ndim
    idx[axis] = slice(0, keep)
    wn = _end_weights(n, axis, x.ndim, dtype)
    z[tuple(idx)] = y[tuple(idx)]
    z = z / wn
    out = scipy.fft.dct(z, type=1, axis=axis, overwrite_x=True, workers=fft_engine.workers()) * wn
    out *= 1.0 / (2 * (n - 1))
    return out


def _end_weights(n: int, axis: int, ndim: int, dtype: npt.DTypeLike) -> np.ndarray:
    """diag(½, 1, ..., 1, ½) of length n, shaped to broadcast along ``axis``."""
    w = np.ones(n, dtype=dtype)
    w[[0, -1]] = 0.5
    shape = [1] * ndim
    shape[axis] = n
    return w.reshape(shape)
