"""k-Wave's kspaceLineRecon / kspacePlaneRecon transcribed literally (test oracle).

Step by step as `shared/reference/KWAVE_RECON_NOTES.md` describes them: mirror to
2 N_t - 1 samples, complex fftn with (i)fftshift, sf, evanescent zeroing, interpolation
along ω on the full mirrored grid (column by column, numpy), ifftn, keep the positive
depths, 4/c. No use of the symmetries, so it is an independent check of
`fpscan.service.recon.kwave` at sizes (odd lateral sizes, 3-D) the stored k-Wave data lack."""
from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.interpolate

from fpscan.physics.nufft import group_columns


def kvec(n: int, d: float) -> np.ndarray:
    """kWaveGrid.makeDim: (2 pi / d) * n with the middle element forced to 0."""
    if n % 2 == 0:
        v = np.arange(-n // 2, n // 2) / n
    else:
        v = np.arange(-(n - 1) // 2, (n - 1) // 2 + 1) / n
    v[n // 2] = 0.0
    return (2 * np.pi / d) * v


_INTERPS = {"linear": "linear", "*linear": "linear", "nearest": "nearest", "*nearest": "nearest",
            "cubic": "cubic", "*cubic": "cubic"}


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


def recon(p, dt, c, lateral_d, interp, pos_cond=False, chunk=4096):
    method = _INTERPS.get(interp)
    if method is None:
        raise ValueError(f"Interp must be one of {sorted(_INTERPS)}, got {interp!r}")
    nt = p.shape[0]
    if nt < 2:
        raise ValueError("p needs at least 2 time samples")
    p = np.concatenate([p[::-1], p[1:]], axis=0).astype(np.float64)  # mirror: 2 Nt - 1
    ntm = p.shape[0]
    kx = kvec(ntm, dt * c)
    klat = [kvec(n, d) for n, d in zip(p.shape[1:], lateral_d)]
    lat2 = klat[0][:, None] ** 2 + klat[1][None, :] ** 2 if len(klat) == 2 else klat[0] ** 2
    lat2 = np.ravel(lat2)
    w = c * kx
    axes = tuple(range(p.ndim))
    shape = p.shape
    P = scipy.fft.fftshift(scipy.fft.fftn(scipy.fft.ifftshift(p, axes=axes), axes=axes, workers=-1), axes=axes)
    del p
    P = P.reshape(ntm, -1)
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
    P = P.reshape(shape)
    out = np.real(scipy.fft.fftshift(scipy.fft.ifftn(scipy.fft.ifftshift(P, axes=axes), axes=axes, workers=-1), axes=axes))
    out = out[(ntm + 1) // 2 - 1 :]
    out = 2 * 2 * out / c
    if pos_cond:
        out[out < 0] = 0
    return out
