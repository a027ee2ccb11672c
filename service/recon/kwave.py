"""Drop-in equivalents of k-Wave's `kspaceLineRecon` (2-D) and `kspacePlaneRecon` (3-D).

Transcribed from the algorithm as documented in `shared/reference/KWAVE_RECON_NOTES.md`
(k-Wave commit 0f1a70f, files last updated 8 June 2017): mirror the data in time to
2 N_t - 1 samples, FFT, multiply by sf = c² sqrt((ω/c)² - k_lat²) / (2ω) (c/2 at DC),
zero the evanescent part |ω| < c |k_lat|, interpolate along ω onto ω' = c |k| (k the grid
with the mirrored length in depth), zero out-of-range queries, inverse FFT, keep the
positive-depth half and scale by 4/c; optional positivity. Interpolation as Octave 7.3
does it: ``'*linear'``/``'linear'``, ``'*nearest'``/``'nearest'`` (ties go to the upper node) and
``'cubic'``/``'*cubic'`` = pchip along ω (Fritsch-Carlson slopes).

Output grid: (N_t, N_y) / (N_t, N_y, N_z), row i at depth i c dt (row 0 = the sensor
plane), columns at the sensor positions.

The numbers are k-Wave's, computed on the symmetries k-Wave leaves unused (real data:
lateral rfft; the mirrored series is even: one half of the ω and k_z axes, each column's
mapping in one compiled loop), which makes it a few times faster and its peak memory a
few times the input instead of ~15 times. The data stay time first, as the lateral FFT
leaves them (no transpose). The transforms run in `fpscan.service.recon.kwave_dft`, the DFT
engine of these modes: the time and depth transforms of the even series as real matrix
products (BLAS beats the FFT at k-Wave's odd lengths) or by the prime-factor algorithm, else
FFTs (`kwave_dft.even_transforms`); the lateral real DFT as a matrix product at lengths
with a large prime factor (`kwave_dft.product_length`: 226 = 2·113, the paper's scan), an
FFT otherwise. This module is k-Wave's algorithm: the grids, the scaling and the k-space
mapping (`_map_columns`, compiled; pchip in `_cubic_block`).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
import numpy.typing as npt
import scipy.fft

from fpscan.physics.nufft import group_columns
from fpscan.service.progress import Fraction, rising, span
from fpscan.service.recon import checks
from fpscan.service.recon.kwave_dft import even_transforms, lateral_forward, lateral_inverse

__all__ = ["transform_lengths", "kspace_line_recon", "kspace_plane_recon"]

_INTERPS = {"linear": "linear", "*linear": "linear", "nearest": "nearest", "*nearest": "nearest",
            "cubic": "cubic", "*cubic": "cubic"}


def _kvec(n: int, d: float) -> np.ndarray:
    """kWaveGrid.makeDim: (2 pi / d) * n with the middle element forced to 0."""
    if n % 2 == 0:
        v = np.arange(-n // 2, n // 2) / n
    else:
        v = np.arange(-(n - 1) // 2, (n - 1) // 2 + 1) / n
    v[n // 2] = 0.0
    return (2 * np.pi / d) * v


def _pchip_columns(P: np.ndarray, w: np.ndarray, w_new_cols: np.ndarray) -> np.ndarray:
    """Piecewise-cubic Hermite (pchip, Octave's 'cubic') interpolation along axis 0 of P
    (n_w, n_cols) from the uniform nodes w to a query vector per column (w_new_cols,
    (n_q, n_cols)); queries above max(w) -> 0 (MATLAB's NaN / Octave's NA, zeroed by
    k-Wave). Columns sharing k_lat² share their query vector and are interpolated together.
    (Nearest and linear run in the compiled `_map_columns`.) scipy.interpolate is imported
    here, by the one mode that uses it: its import (~0.2 s) is most of the k-Wave modes' own."""
    import scipy.interpolate

    wmax = w[-1]
    out = np.zeros((w_new_cols.shape[0], P.shape[1]), dtype=np.complex128)
    gvals, gptr, order = group_columns(w_new_cols[0, :])
    for g in range(len(gvals)):
        cols = order[gptr[g] : gptr[g + 1]]
        q = w_new_cols[:, cols[0]]
        vals = P[:, cols]
        re = scipy.interpolate.PchipInterpolator(w, vals.real, axis=0, extrapolate=False)(q)
        im = scipy.interpolate.PchipInterpolator(w, vals.imag, axis=0, extrapolate=False)(q)
        res = np.where((q > wmax)[:, None], 0.0, re + 1j * im)
        out[:, cols] = np.nan_to_num(res)
    return out



_BLOCK = 8  # columns the mapping takes at a time (8 complex128: two cache lines of a row)


@numba.njit(parallel=True, cache=True)
def _map_columns(P: np.ndarray, lat2: np.ndarray, w: np.ndarray, kz: np.ndarray, c: float, nearest: bool,
                 out: np.ndarray) -> None:
    """k-Wave's k-space mapping for the ω >= 0 half, one lateral column per column of P
    (n_w, n_cols), time first (compiled, in place of numpy fancy indexing): out[l, j] =
    interp_ω(sf · P[:, j]) evaluated at ω' = c sqrt(kz_l² + lat2_j).

    sf = c² sqrt((ω/c)² - k_lat²) / (2ω) (c/2 at ω = k_lat = 0), zero where |ω| < c|k_lat|;
    linear interpolation or the nearest node (ties to the upper node) on the uniform nodes
    w, located as searchsorted(w, ω', side='right') - 1 clipped to [0, n_w - 2] (k-Wave's
    interp1 on the same nodes); queries above w[-1] give 0."""
    n_w, n_cols = P.shape
    n_q = kz.shape[0]
    wmax = w[n_w - 1]
    dw = w[1] - w[0]
    n_blocks = (n_cols + _BLOCK - 1) // _BLOCK
    for b in numba.prange(n_blocks):  # a block of adjacent columns: whole cache lines a row
        j0 = b * _BLOCK
        nb = min(_BLOCK, n_cols - j0)
        blk = np.empty((n_w, _BLOCK), dtype=P.dtype)
        for jj in range(nb):
            l2 = lat2[j0 + jj]
            kl = c * math.sqrt(l2)
            for i in range(n_w):
                wi = w[i]
                if wi == 0.0 and l2 == 0.0:
                    sf = c / 2.0
                elif abs(wi) < kl:
                    sf = 0.0
                else:
                    arg = (wi / c) ** 2 - l2
                    sf = c * c * math.sqrt(arg) / (2.0 * wi) if arg >= 0.0 and wi != 0.0 else 0.0
                blk[i, jj] = sf * P[i, j0 + jj]
        for q in range(n_q):
            for jj in range(nb):
                l2 = lat2[j0 + jj]
                wq = c * math.sqrt(kz[q] * kz[q] + l2)
                if wq > wmax:
                    out[q, j0 + jj] = 0.0
                    continue
                i = min(int(wq / dw), n_w - 2)
                while i > 0 and w[i] > wq:
                    i -= 1
                while i < n_w - 2 and w[i + 1] <= wq:
                    i += 1
                if nearest:
                    out[q, j0 + jj] = blk[i + 1, jj] if (wq - w[i]) >= (w[i + 1] - wq) else blk[i, jj]
                else:
                    frac = (wq - w[i]) / (w[i + 1] - w[i])
                    out[q, j0 + jj] = blk[i, jj] * (1.0 - frac) + blk[i + 1, jj] * frac


_CUBIC_BYTES = 2 << 20  # one of `_cubic_block`'s arrays of a chunk of columns (memory.KWAVE_STEP_BYTES)


def _cubic_block(P_half: np.ndarray, w_full: np.ndarray, lat2: np.ndarray, phase: np.ndarray, kx: np.ndarray,
                 c: float) -> np.ndarray:
    """The pchip (Octave 'cubic') mapping of a chunk of columns (rows of ``P_half``, (cols, N)
    -> (cols, N)) on the full mirrored ω grid (pchip slopes at ω = 0 see the negative
    side), as k-Wave evaluates it.

    pchip acts on the real and imaginary parts separately, so it does not commute with a
    complex phase: the columns carry the phase ``phase`` that k-Wave's lateral
    ``ifftshift`` gives them (1 or -1 for even sizes) while being interpolated."""
    n = P_half.shape[1]
    P = np.concatenate([P_half[:, :0:-1], P_half], axis=1).T * phase[None, :]  # even in ω
    wc = w_full[:, None]
    l2 = lat2[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        arg = (wc / c) ** 2 - l2
        sf = np.where(arg >= 0, c**2 * np.sqrt(np.maximum(arg, 0)) / (2 * wc), 0.0)
    sf[(wc == 0) & (l2 == 0)] = c / 2
    block = sf * P
    block[np.abs(wc) < c * np.sqrt(l2)] = 0
    block[~np.isfinite(block)] = 0
    w_new = c * np.sqrt((kx[n - 1 :] ** 2)[:, None] + l2)
    return (_pchip_columns(block, w_full, w_new) * np.conj(phase)[None, :]).T


def transform_lengths(data_shape: Sequence[int]) -> dict[str, tuple[int, ...]]:
    """The DFT lengths `kspace_line_recon` / `kspace_plane_recon` run for data of a given shape.

    These are k-Wave's grids, not rounded to fast lengths: the mirrored length fixes the ω
    and k_z nodes k-Wave interpolates between, and the unpadded lateral grid its lateral
    periodicity, so any other length changes the numbers beyond rounding. An exact DFT of
    these lengths through fast ones (Bluestein's chirp-z: two FFTs at a fast length
    >= 3 N_t - 2) would cost about what pocketfft's own handling costs: 0.75x, 1.06x, 1.08x
    of it at N_t = 256, 1024, 3519 (per-point FFT timings). Up to
    `fpscan.service.recon.kwave_dft.MATRIX_MAX_N` samples the temporal and depth DFTs run as
    matrix products instead (faster than any FFT of these lengths there), above it by the
    prime-factor algorithm where 2 N_t - 1 has a coprime split (`kwave_dft.PFA_MAX_SUM`),
    and the lateral real DFT as a product at lengths `kwave_dft.product_length` names; the
    lengths stay the same.

    Parameters
    ----------
    data_shape : tuple of int
        ``(N_t, N_y)`` or ``(N_t, N_y, N_z)``, time first.

    Returns
    -------
    dict of str to tuple of int
        ``"lateral"`` the data's own lateral shape, ``"temporal"`` and ``"depth"``
        ``(2 N_t - 1,)``, the mirrored series.

    Raises
    ------
    ValueError
        A shape that is not 2-D or 3-D with N_t >= 2.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspaceLineRecon.m`` / ``kspacePlaneRecon.m`` (``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> from fpscan.service.recon.kwave import transform_lengths
    >>> transform_lengths((40, 32))
    {'lateral': (32,), 'temporal': (79,), 'depth': (79,)}
    >>> transform_lengths((40,))
    Traceback (most recent call last):
    ...
    ValueError: data_shape must be (N_t, N_y) or (N_t, N_y, N_z) with N_t >= 2, got (40,)
    """
    shape = tuple(int(n) for n in data_shape)
    if len(shape) not in (2, 3) or shape[0] < 2 or min(shape) < 1:
        raise ValueError(f"data_shape must be (N_t, N_y) or (N_t, N_y, N_z) with N_t >= 2, got {data_shape!r}")
    ntm = 2 * shape[0] - 1
    return {"lateral": shape[1:], "temporal": (ntm,), "depth": (ntm,)}



def _recon(p: np.ndarray, dt: float, c: float, lateral_d: tuple[float, ...], interp: str, pos_cond: bool,
           dtype: npt.DTypeLike = np.float64, progress: Fraction | None = None) -> np.ndarray:
    """k-Wave's algorithm (module doc) on the symmetries it leaves unused: the data are
    real (lateral rfft) and the mirrored series even (one half of the ω and k_z axes), so
    the transforms run on about a quarter of the mirrored volume and the peak memory stays
    a few times the input. Same numbers as k-Wave to rounding."""
    method = _INTERPS.get(interp)
    if method is None:
        raise ValueError(f"Interp must be one of {sorted(_INTERPS)}, got {interp!r}")
    rdtype = checks.check_dtype(dtype)
    nt = p.shape[0]
    if nt < 2:
        raise ValueError("p needs at least 2 time samples")
    ntm = transform_lengths(p.shape)["temporal"][0]
    kx = _kvec(ntm, dt * c)
    w_full = c * kx
    w = w_full[nt - 1 :]  # ω >= 0 nodes
    lat_shape = p.shape[1:]
    lat_axes = tuple(range(1, p.ndim))
    # lateral wavenumbers in rfft order (k-Wave's shifted grid holds the same set)
    kl = [2 * np.pi * scipy.fft.fftfreq(n, d) for n, d in zip(lat_shape[:-1], lateral_d[:-1])]
    kl.append(2 * np.pi * scipy.fft.rfftfreq(lat_shape[-1], lateral_d[-1]))
    lat2 = kl[0][:, None] ** 2 + kl[1][None, :] ** 2 if len(kl) == 2 else kl[0] ** 2
    lat2 = np.ascontiguousarray(np.ravel(lat2), dtype=np.float64)
    if method == "cubic":  # phase of k-Wave's lateral ifftshift: fft(roll(x, -s))_k = e^{2πiks/n} X_k
        ph = [np.exp(2j * np.pi * np.arange(n) * (n // 2) / n) for n in lat_shape[:-1]]
        ph.append(np.exp(2j * np.pi * np.arange(lat_shape[-1] // 2 + 1) * (lat_shape[-1] // 2) / lat_shape[-1]))
        phase = np.ravel(ph[0][:, None] * ph[1][None, :] if len(ph) == 2 else ph[0])
    A = lateral_forward(np.asarray(p, dtype=rdtype), lat_axes)
    spec_shape = A.shape
    n_cols = int(np.prod(spec_shape[1:]))
    a = A.reshape(nt, n_cols)  # time first: lateral column j is a[:, j]
    kernel = rising(progress)  # strictly increasing fractions, each step through its span
    if kernel is not None:
        kernel(0.15)
    kz = np.ascontiguousarray(kx[nt - 1 :], dtype=np.float64)

    # k-Wave's k-space mapping of columns c0:c1 (P: their ω >= 0 half)
    def mapping(P: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        if method != "cubic":
            _map_columns(P, lat2[c0:c1], w, kz, float(c), method == "nearest", out)
            return
        # pchip's buffers, about ten arrays of (2 N - 1) x step in complex128: `_CUBIC_BYTES` each
        step = max(16, min(-(-n_cols // 32), _CUBIC_BYTES // (ntm * 16)))
        for s0 in range(c0, c1, step):
            s1 = min(s0 + step, c1)
            out[:, s0 - c0 : s1 - c0] = _cubic_block(P[:, s0 - c0 : s1 - c0].T.astype(np.complex128), w_full,
                                                     lat2[s0:s1], phase[s0:s1], kx, c).T

    scale = (4.0 / c) / ntm  # the depth transform's 1 / M and the image's 4 / c, in its matrix or pass
    even_transforms(a, mapping, scale, rdtype, span(kernel, 0.15, 0.85))  # in place: A holds the image's k-space
    del a
    res = lateral_inverse(A, lat_shape, lat_axes)
    del A
    if pos_cond:
        np.maximum(res, 0, out=res)
    if kernel is not None:
        kernel(1.0)
    return res.astype(rdtype, copy=False)


def kspace_line_recon(p: npt.ArrayLike, dy: float, dt: float, c: float, data_order: str = "ty",
                      interp: str = "*nearest", pos_cond: bool = False, progress: Fraction | None = None,
                      dtype: npt.DTypeLike = np.float64) -> np.ndarray:
    """2-D planar reconstruction exactly as k-Wave's ``kspaceLineRecon``.

    Parameters
    ----------
    p : ndarray, shape ``(N_t, N_y)`` for ``data_order='ty'`` or ``(N_y, N_t)`` for ``'yt'``
        Pressure, Pa; sample 0 at t = 0.
    dy : float
        Sensor spacing, m.
    dt : float
        Sample interval, s.
    c : float
        Sound speed, m/s.
    data_order : {"ty", "yt"}, optional
        Axis order of ``p``.
    interp : str, optional
        ``'*nearest'`` (k-Wave's default), ``'nearest'``, ``'*linear'``, ``'linear'``, ``'cubic'`` (Octave: pchip
        along ω).
    pos_cond : bool, optional
        Clip negative values to 0 (k-Wave's PosCond).
    progress : callable, optional
        ``progress(fraction)`` called with increasing fractions in (0, 1] (after the FFT, per
        chunk of columns, at the end). Not a k-Wave option.
    dtype : float64 or float32, optional
        float64 (k-Wave's precision) or float32 (working precision and output; half the
        memory, relative error ~1e-6). Not a k-Wave option.

    Returns
    -------
    ndarray, shape ``(N_t, N_y)``
        p0 of ``dtype``, row i at depth i c dt (row 0 on the sensor line).

    Raises
    ------
    ValueError
        NaN/inf, wrong ndim, non-positive dy/dt/c, unknown data_order/interp.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspaceLineRecon.m`` (k-Wave commit 0f1a70f, ``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.kwave import kspace_line_recon
    >>> p0 = np.zeros((16, 32))  # a point source at depth row 8, pitch 0.1 mm
    >>> p0[8, 16] = 1.0
    >>> data = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)  # (N_t, N_y)
    >>> img = kspace_line_recon(data, 1e-4, 1e-4 / 1500, 1500.0)  # rows c dt = 0.1 mm apart
    >>> img.shape, img.dtype, np.unravel_index(img.argmax(), img.shape)
    ((40, 32), dtype('float64'), (np.int64(8), np.int64(16)))
    """
    p = checks.finite_array("p", p, (2,))
    if data_order not in ("ty", "yt"):
        raise ValueError(f"data_order must be 'ty' or 'yt', got {data_order!r}")
    if data_order == "yt":
        p = p.T
    dy, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy,), interp, pos_cond, dtype=dtype, progress=progress)


def kspace_plane_recon(p: npt.ArrayLike, dy: float, dz: float, dt: float, c: float, data_order: str = "tyz",
                       interp: str = "*nearest", pos_cond: bool = False, progress: Fraction | None = None,
                       dtype: npt.DTypeLike = np.float64) -> np.ndarray:
    """3-D planar reconstruction exactly as k-Wave's ``kspacePlaneRecon``.

    Parameters
    ----------
    p : ndarray, shape ``(N_t, N_y, N_z)`` for ``data_order='tyz'`` or ``(N_y, N_z, N_t)`` for ``'yzt'``
        Pressure, Pa; sample 0 at t = 0. (k-Wave's y and z are the two lateral axes.)
    dy, dz : float
        Sensor spacings along the two lateral axes, m.
    dt, c, interp, pos_cond, progress, dtype
        As `kspace_line_recon` (dt in s, c in m/s).
    data_order : {"tyz", "yzt"}, optional
        Axis order of ``p``.

    Returns
    -------
    ndarray, shape ``(N_t, N_y, N_z)``
        p0 of ``dtype``, plane i at depth i c dt.

    Raises
    ------
    ValueError
        As `kspace_line_recon`.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspacePlaneRecon.m`` (k-Wave commit 0f1a70f, ``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.kwave import kspace_plane_recon
    >>> p0 = np.zeros((8, 8, 8))  # (n_z, n_y, n_x), a point source in the middle
    >>> p0[4, 4, 4] = 1.0
    >>> data = forward_grid(p0, 1e-4, 1e-4, 1e-4 / 1500, 24, 1500.0)  # (N_t, N_y, N_z)
    >>> img = kspace_plane_recon(data, 1e-4, 1e-4, 1e-4 / 1500, 1500.0)
    >>> img.shape, np.unravel_index(img.argmax(), img.shape)
    ((24, 8, 8), (np.int64(4), np.int64(4), np.int64(4)))
    """
    p = checks.finite_array("p", p, (3,))
    if data_order not in ("tyz", "yzt"):
        raise ValueError(f"data_order must be 'tyz' or 'yzt', got {data_order!r}")
    if data_order == "yzt":
        p = np.transpose(p, (2, 0, 1))
    dy, dz, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dz", dz), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy, dz), interp, pos_cond, dtype=dtype, progress=progress)
