"""The grid the model-based method works on: the data's band above their noise floor, the
operator's time sampling and tv's default image depth grid (issue 47, item 1).

The planar model maps each k-space component of p0 to one temporal frequency, f = c |k| / 2π
(DESIGN §3.1), so a band of the data is a ball |k| <= 2π f_c / c of the image's k-space. tv
(`service.recon.tv`) therefore works at the band the data carry above their noise floor, not
at the sampling the scanner happened to use:

- **the band f_c** (`data_band`): the data's cosine-series coefficients (the DCT-I of each
  A-line, the basis `driver.physics.resample` cuts in) against the noise's: white noise of
  σ per sample gives each coefficient the mean square 2 (n - 2) σ² (the two end ones
  (4 n - 6) σ²; σ from `noise_sigma`). f_c is the lowest frequency above which the data's
  energy is at most twice the noise's, i.e. above which the data hold no more signal than
  noise — Wiener's cut, the low-pass that minimises the expected squared error of the
  filtered data keeps exactly the frequencies where the signal's power exceeds the
  noise's; summed over the band above (not bin by bin) so that no smoothing window is
  needed. Scanned from the top, the first band that fails ends the scan, so a chance
  excess of noise near Nyquist errs towards keeping more. A sensor bandwidth the caller
  declares (``bandwidth``) replaces the estimate. This is the data's floor, not what tv can
  make of them: tv adds the sensors' views coherently and TV knows the image is sparse, so it
  draws on a band below the noise as well (k-Wave's balls-and-yarn data, 11 % of the points,
  30 dB: the cut falls at 7.5 MHz, tv's CC 0.977 against 0.980 at the full 62.5 MHz and at
  12.5 MHz, k-Wave's own grid limit; the same comparison between the data's NEDNER image and
  that of the noise alone, in k-space shells, cut at 8.4 MHz — no Wiener-type cut reaches
  12.5 MHz there, docs/performance.md);
- **the operator's sampling**: M samples on the record's own interval,
  `driver.physics.resample.resampled_length` (its kept band reaches f_c), the data low-passed
  and resampled to them exactly (`driver.physics.resample.resample`), the operator
  band-limited to f_c in k-space (`service.recon.operator.PlanarOperator` ``band``);
- **the image's depth grid**: dz = c dt' and n_z = M when the caller sets neither, as every
  planar method's default dz = c dt and n_z = n_t (the depth Nyquist wavenumber then equals
  the band's); a dz or n_z the caller gives is kept, and the other then follows that rule at
  the record's own sampling (dz = c dt, n_z = n_t), so that a caller who fixes one of them
  gets the grid it had before.

Data whose band reaches the record's Nyquist frequency keep today's grid exactly (no
resampling, no band limit). Pure numpy (scipy's DCT is imported on first use; no numba), so
that a server can size a tv job from it (`tv_grid` without data gives the grid of a
full-band record: the largest tv may choose).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from driver.constants import C_DEFAULT
from driver.physics.resample import resampled_length

__all__ = ["TvGrid", "noise_sigma", "data_band", "tv_grid"]


def noise_sigma(data: npt.ArrayLike, time_axis: int) -> float:
    """Noise standard deviation of ``data`` (Pa), from the median absolute deviation of
    the finest Haar wavelet coefficients along ``time_axis`` (Donoho & Johnstone 1994):
    σ = median |g_{2n+1} − g_{2n}| / (√2 · 0.6745).

    Robust to a sparse signal: steps and edges change few of the pairwise differences.

    Parameters
    ----------
    data : array_like
        Samples in any unit (Pa, or the instrument's), any shape; e.g. A-lines ``(n, n_t)``
        (``time_axis=1``) or grid data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` (``time_axis=0``).
    time_axis : int
        The axis along which the samples follow in time.

    Returns
    -------
    float
        σ̂ in the data's unit; 0.0 when there are fewer than 2 samples along ``time_axis``.

    References
    ----------
    .. [1] D. L. Donoho, I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage",
       Biometrika 81 (1994) 425.

    Examples
    --------
    Seeded white noise of σ = 0.01 Pa on 8 A-lines of 512 samples, with and without a step:

    >>> import numpy as np
    >>> from service.recon.tv_grid import noise_sigma
    >>> noise = np.random.default_rng(0).normal(0.0, 0.01, (8, 512))  # (n, n_t)
    >>> round(noise_sigma(noise, time_axis=1), 4), round(noise_sigma(noise.T, time_axis=0), 4)
    (0.0101, 0.0101)
    >>> step = np.where(np.arange(512) >= 100, 1.0, 0.0)  # a 1 Pa edge barely moves it
    >>> round(noise_sigma(noise + step, time_axis=1), 4)
    0.0101
    >>> noise_sigma(np.ones((3, 1)), time_axis=1)  # one sample: no estimate
    0.0
    """
    g = np.moveaxis(np.asarray(data, dtype=np.float64), time_axis, -1)
    n = g.shape[-1] // 2 * 2
    if n < 2:
        return 0.0
    d = (g[..., 1:n:2] - g[..., 0:n:2]) / math.sqrt(2.0)
    return float(np.median(np.abs(d)) / 0.6745)


class TvGrid(NamedTuple):
    """tv's working grid (`tv_grid`).

    Attributes
    ----------
    n_t : int
        Samples per A-line the operator works on (M; the record's own n_t at full band).
    dt : float
        Their interval, s (the record's own dt at full band).
    band : float or None
        The operator's band limit f_c, Hz; None: the record's Nyquist frequency (no limit).
    dz : float
        Depth spacing of the image, m.
    n_z : int
        Depth samples of the image.
    reason : str
        What set the band: ``"data"`` (the data's band above their noise floor),
        ``"declared"`` (the caller's sensor bandwidth), ``"nyquist"`` (the data are full band,
        or were not looked at).

    Examples
    --------
    >>> from service.recon.tv_grid import tv_grid
    >>> grid = tv_grid(1024, 8e-9, 1500.0, bandwidth=20e6)  # (n_t, dt, c): a 20 MHz sensor
    >>> grid.n_t, grid.resampled, grid.reason
    (330, True, 'declared')
    """

    n_t: int
    dt: float
    band: float | None
    dz: float
    n_z: int
    reason: str

    @property
    def resampled(self) -> bool:
        """Whether the operator works at fewer samples than the record has."""
        return self.band is not None


def data_band(data: npt.ArrayLike, dt: float, time_axis: int, sigma: float) -> float | None:
    """The data's band above their noise floor, Hz (module doc): the lowest frequency above
    which the data's energy is at most twice the noise's.

    Parameters
    ----------
    data : array_like
        Samples, any shape, time along ``time_axis`` (A-lines ``(n, n_t)`` with 1; grid data
        ``(n_t, ...)`` with 0).
    dt : float
        Sample interval, s.
    time_axis : int
        The time axis.
    sigma : float
        The noise's standard deviation per sample, in the data's unit
        (`service.recon.tv.noise_sigma`).

    Returns
    -------
    float or None
        f_c = (K - 1) / (2 (n_t - 1) dt) for the first K coefficients kept, Hz; None when the
        whole band up to Nyquist holds signal, when no band holds more signal than noise (noise
        alone: nothing to read a band from), or without a noise estimate (σ <= 0).

    Raises
    ------
    ValueError
        dt not finite and > 0.

    Examples
    --------
    Two cosines of 2 and 5 MHz in white noise, 512 samples at 10 ns (Nyquist 50 MHz):

    >>> import numpy as np
    >>> from service.recon.tv_grid import data_band
    >>> t = np.arange(512) * 1e-8
    >>> rng = np.random.default_rng(0)
    >>> g = np.cos(2e6 * 2 * np.pi * t) + np.cos(5e6 * 2 * np.pi * t) + 0.01 * rng.standard_normal((16, 512))
    >>> f = data_band(g, 1e-8, 1, sigma=0.01)
    >>> bool(5e6 <= f < 6e6)
    True
    >>> data_band(rng.standard_normal((16, 512)), 1e-8, 1, sigma=1.0) is None  # noise alone
    True
    """
    import scipy.fft

    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be finite and > 0, got {dt!r}")
    g = np.moveaxis(np.asarray(data), time_axis, -1)
    n = g.shape[-1]
    if n < 3 or not sigma > 0:
        return None
    g = g.reshape(-1, n)
    power = np.zeros(n)
    for a in range(0, len(g), 256):  # the coefficients' mean square over the A-lines, in blocks
        y = scipy.fft.dct(np.asarray(g[a : a + 256], dtype=np.float64), type=1, axis=1, workers=-1)
        power += np.einsum("ij,ij->j", y, y)
    power /= len(g)
    # each coefficient's mean square under white noise of σ: σ² Σ_j D_kj² (D the DCT-I), i.e.
    # 2 (n - 2) σ² inside and (4 n - 6) σ² at k = 0 and k = n - 1
    noise = np.full(n, 2.0 * (n - 2))
    noise[[0, -1]] = 4.0 * n - 6.0
    noise *= float(sigma) ** 2
    tail = np.cumsum(power[::-1])[::-1]  # tail[k] = Σ_{j >= k} power[j]
    noise_tail = np.cumsum(noise[::-1])[::-1]
    signal_free = tail <= 2.0 * noise_tail  # the band from k up holds no more signal than noise
    if signal_free[0] or not signal_free[-1]:  # no signal above the noise anywhere, or up to Nyquist
        return None
    # scanned from the top: the first k (going down) whose band holds signal ends the band
    k_keep = int(np.flatnonzero(~signal_free)[-1]) + 1  # the terms 0..k_keep - 1 are kept
    if k_keep >= n - 1:
        return None
    return max(k_keep - 1, 1) / (2.0 * (n - 1) * float(dt))


def tv_grid(n_t: int, dt: float, c: float = C_DEFAULT, *, data: npt.ArrayLike | None = None, time_axis: int = 0,
            sigma: float | None = None, bandwidth: float | None = None, dz: float | None = None,
            n_z: int | None = None) -> TvGrid:
    """The grid tv works on (module doc): the operator's samples and band, and the image's
    depth grid.

    Parameters
    ----------
    n_t : int
        Samples per A-line of the record (>= 2).
    dt : float
        Its sample interval, s.
    c : float, optional
        Sound speed, m/s.
    data : array_like, optional
        The record, time along ``time_axis``: its band above the noise floor sets the grid
        (`data_band`). None (and no ``bandwidth``): the full band, today's grid dz = c dt.
    time_axis : int, optional
        The time axis of ``data`` (0 for grid data ``(n_t, ...)``, 1 for A-lines ``(n, n_t)``).
    sigma : float, optional
        The data's noise σ per sample (default `service.recon.tv.noise_sigma` of ``data``).
    bandwidth : float, optional
        A sensor bandwidth the caller declares, Hz: the band instead of the data's estimate.
    dz, n_z : optional
        The image's depth spacing (m) and samples, kept as given; with neither given c dt' and
        M, with one given the other c dt or n_t (the record's own rule).

    Returns
    -------
    TvGrid

    Raises
    ------
    ValueError
        n_t < 2, non-positive dt, c or bandwidth.

    Examples
    --------
    >>> from service.recon.tv_grid import tv_grid
    >>> g = tv_grid(1024, 8e-9, 1500.0)  # nothing known of the data: the full band
    >>> g.n_t, g.band, round(g.dz * 1e6, 3), g.n_z, g.reason
    (1024, None, 12.0, 1024, 'nyquist')
    >>> g = tv_grid(1024, 8e-9, 1500.0, bandwidth=20e6)  # a 20 MHz sensor
    >>> g.n_t, g.band, round(g.dz * 1e6, 2), g.n_z, g.reason
    (330, 20000000.0, 37.31, 330, 'declared')
    """
    if int(n_t) != n_t or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    for name, v in (("dt", dt), ("c", c)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    n_t = int(n_t)
    band, reason = None, "nyquist"
    if bandwidth is not None:
        if not (np.isfinite(bandwidth) and bandwidth > 0):
            raise ValueError(f"bandwidth must be finite and > 0 Hz, got {bandwidth!r}")
        band, reason = float(bandwidth), "declared"
    elif data is not None:
        if sigma is None:
            sigma = noise_sigma(data, time_axis)
        band = data_band(data, dt, time_axis, float(sigma))
        reason = "nyquist" if band is None else "data"
    m = n_t if band is None else resampled_length(n_t, dt, band)
    if m >= n_t:  # the record's own rate is the coarsest that keeps the band
        band, m, reason = None, n_t, "nyquist"
    dt_m = dt if m == n_t else (n_t - 1) * dt / (m - 1)
    if dz is None and n_z is None:  # the image's depth grid follows the operator's sampling
        dz_out, n_z_out = c * dt_m, m
    else:  # a caller who sets either keeps today's rule for the other (dz = c dt, n_z = n_t)
        dz_out = c * dt if dz is None else float(dz)
        n_z_out = n_t if n_z is None else int(n_z)
    if not math.isfinite(dz_out) or dz_out <= 0:
        raise ValueError(f"dz must be finite and > 0 m, got {dz!r}")
    return TvGrid(m, dt_m, band, dz_out, n_z_out, reason)
