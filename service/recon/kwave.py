"""Drop-in equivalents of k-Wave's `kspaceLineRecon` (2-D) and `kspacePlaneRecon` (3-D).

Transcribed from the algorithm as documented in `shared/reference/KWAVE_RECON_NOTES.md`
(k-Wave commit 0f1a70f, files last updated 8 June 2017): mirror the data in time to
2 N_t - 1 samples, FFT, multiply by sf = c² sqrt((ω/c)² - k_lat²) / (2ω) (c/2 at DC),
zero the evanescent part |ω| < c |k_lat|, interpolate along ω onto ω' = c |k| (k the grid
with the mirrored length in depth), zero out-of-range queries, inverse FFT, keep the
positive-depth half and scale by 4/c; optional positivity. Interpolation as Octave 7.3
does it: '*linear'/'linear', '*nearest'/'nearest' (ties go to the upper node) and
'cubic'/'*cubic' = pchip along ω (Fritsch-Carlson slopes).

Output grid: (N_t, N_y) / (N_t, N_y, N_z), row i at depth i c dt (row 0 = the sensor
plane), columns at the sensor positions.
"""
from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.interpolate

from driver.physics.nufft import group_columns
from service.recon import checks

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


def _interp_columns(P, w, w_new_cols, method):
    """1-D interpolation along axis 0 of P (n_w, n_cols) from the uniform nodes w to a
    query vector per column (w_new_cols, (n_q, n_cols)); queries above max(w) -> 0
    (MATLAB's NaN / Octave's NA, zeroed by k-Wave)."""
    wmax = w[-1]
    if method in ("linear", "nearest"):
        i = np.clip(np.searchsorted(w, w_new_cols, side="right") - 1, 0, len(w) - 2)
        cols = np.arange(P.shape[1])[None, :]
        if method == "linear":
            frac = (w_new_cols - w[i]) / (w[i + 1] - w[i])
            res = P[i, cols] * (1 - frac) + P[i + 1, cols] * frac
        else:
            upper = (w_new_cols - w[i]) >= (w[i + 1] - w_new_cols)  # ties -> upper node
            res = P[np.where(upper, i + 1, i), cols]
        return np.where(w_new_cols > wmax, 0.0, res)
    # pchip (Octave 'cubic'): columns sharing k_lat² share their query vector
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


def _recon(p, dt, c, lateral_d, interp, pos_cond, chunk=4096, progress=None):
    method = _INTERPS.get(interp)
    if method is None:
        raise ValueError(f"Interp must be one of {sorted(_INTERPS)}, got {interp!r}")
    nt = p.shape[0]
    if nt < 2:
        raise ValueError("p needs at least 2 time samples")
    p = np.concatenate([p[::-1], p[1:]], axis=0).astype(np.float64)  # mirror: 2 Nt - 1
    ntm = p.shape[0]
    kx = _kvec(ntm, dt * c)
    klat = [_kvec(n, d) for n, d in zip(p.shape[1:], lateral_d)]
    lat2 = klat[0][:, None] ** 2 + klat[1][None, :] ** 2 if len(klat) == 2 else klat[0] ** 2
    lat2 = np.ravel(lat2)
    w = c * kx
    axes = tuple(range(p.ndim))
    shape = p.shape
    P = scipy.fft.fftshift(scipy.fft.fftn(scipy.fft.ifftshift(p, axes=axes), axes=axes, workers=-1), axes=axes)
    del p
    P = P.reshape(ntm, -1)
    if progress is not None:
        progress(0.25)
    wc = w[:, None]
    # column chunks bound the memory of the per-column grids (w, k_lat) -> sf, w_new
    for a in range(0, P.shape[1], chunk):
        l2 = lat2[None, a : a + chunk]
        with np.errstate(divide="ignore", invalid="ignore"):
            arg = (wc / c) ** 2 - l2
            sf = np.where(arg >= 0, c**2 * np.sqrt(np.maximum(arg, 0)) / (2 * wc), 0.0)
        sf[(wc == 0) & (l2 == 0)] = c / 2
        block = sf * P[:, a : a + chunk]
        block[np.abs(wc) < c * np.sqrt(l2)] = 0
        block[~np.isfinite(block)] = 0
        w_new = c * np.sqrt((0 + (kx**2)[:, None]) + l2)
        P[:, a : a + chunk] = _interp_columns(block, w, w_new, method)
        if progress is not None:
            progress(0.25 + 0.6 * min(a + chunk, P.shape[1]) / P.shape[1])
    P = P.reshape(shape)
    out = np.real(scipy.fft.fftshift(scipy.fft.ifftn(scipy.fft.ifftshift(P, axes=axes), axes=axes, workers=-1), axes=axes))
    out = out[(ntm + 1) // 2 - 1 :]
    out = 2 * 2 * out / c
    if pos_cond:
        out[out < 0] = 0
    if progress is not None:
        progress(1.0)
    return out


def kspace_line_recon(p, dy, dt, c, data_order="ty", interp="*nearest", pos_cond=False,
                      progress=None) -> np.ndarray:
    """2-D planar reconstruction exactly as k-Wave's ``kspaceLineRecon``.

    Parameters
    ----------
    p : (N_t, N_y) data for ``data_order='ty'`` or (N_y, N_t) for ``'yt'``, sample 0 at
        t = 0 (Pa).
    dy : sensor spacing in m.  dt : sample interval in s.  c : sound speed in m/s.
    interp : '*nearest' (k-Wave's default), 'nearest', '*linear', 'linear', 'cubic'
        (Octave: pchip along ω).
    pos_cond : clip negative values to 0 (k-Wave's PosCond).
    progress : optional callable(fraction) called with increasing fractions in (0, 1]
        (after the FFT, per chunk of columns, at the end). Not a k-Wave option.

    Returns
    -------
    (N_t, N_y) float64 p0, row i at depth i c dt (row 0 on the sensor line).

    Raises
    ------
    ValueError for NaN/inf, wrong ndim, non-positive dy/dt/c, unknown data_order/interp.
    """
    p = checks.finite_array("p", p, (2,))
    if data_order not in ("ty", "yt"):
        raise ValueError(f"data_order must be 'ty' or 'yt', got {data_order!r}")
    if data_order == "yt":
        p = p.T
    dy, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy,), interp, pos_cond, progress=progress)


def kspace_plane_recon(p, dy, dz, dt, c, data_order="tyz", interp="*nearest", pos_cond=False,
                       progress=None) -> np.ndarray:
    """3-D planar reconstruction exactly as k-Wave's ``kspacePlaneRecon``.

    Parameters
    ----------
    p : (N_t, N_y, N_z) data for ``data_order='tyz'`` or (N_y, N_z, N_t) for ``'yzt'``.
    dy, dz : sensor spacings in m.  dt, c, interp, pos_cond, progress : as
        `kspace_line_recon`.

    Returns
    -------
    (N_t, N_y, N_z) float64 p0, plane i at depth i c dt.

    Raises
    ------
    ValueError as `kspace_line_recon`.
    """
    p = checks.finite_array("p", p, (3,))
    if data_order not in ("tyz", "yzt"):
        raise ValueError(f"data_order must be 'tyz' or 'yzt', got {data_order!r}")
    if data_order == "yzt":
        p = np.transpose(p, (2, 0, 1))
    dy, dz, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dz", dz), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy, dz), interp, pos_cond, progress=progress)
