"""The grid the model-based method works on: the record's extent and the data's band above their
noise floor, the operator's time sampling and tv's default image depth grid (issue 47, item 1).

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
- **the record's extent** (`data_extent`): the record is cut after the last sample that shows
  signal — an echo above σ √(2 ln (100 N)) at any sensor (the universal threshold of
  Donoho & Johnstone for 100 N samples), or energy summed over the A-lines from that sample
  on above the noise's by 5 of its standard deviations — and a margin of 2 % of the
  record; ``whole_record`` keeps it all. The model stays exact (the operator simply has
  fewer samples), and a source at depth z is heard only at t >= z / c, so the image's
  default depth ends where the kept record does. What the cut drops is noise and one piece
  of information: the far sensors' silence about shallow voxels they would hear late.
  Measured on the paper's scan at half size (113², 512 samples, 30 dB; the same λ), after
  150 iterations the cut record's image and the whole record's have the same CC with the
  true balls (0.9845 both); at the stopping rule's earlier stop they differ by where the
  rule stops (docs/performance.md). It shortens the operator's record, its depth and its
  lateral padding (which grows with c t_last, `service.recon.operator`): the paper's scan
  (three balls 2.9-4.3 mm deep, heard by the farthest sensors until sample 755 of 1024)
  keeps 776 samples, and a pair works on 801 × 384² points instead of 1025 × 450²: tv took
  425 s instead of 934 s there. An image depth the caller gives is always reached: the cut
  never falls before its last row's sample;
- **the operator's sampling**: M samples on the kept record's interval,
  `driver.physics.resample.resampled_length` (its kept band reaches f_c), the data low-passed
  and resampled to them exactly (`driver.physics.resample.resample`), the operator
  band-limited to f_c in k-space (`service.recon.operator.PlanarOperator` ``band``);
- **the image's depth grid**: dz = c dt' and n_z = M when the caller sets neither, as every
  planar method's default dz = c dt and n_z = n_t (the depth Nyquist wavenumber then equals
  the band's); a dz or n_z the caller gives is kept, and the other then follows that rule at
  the record's own sampling (dz = c dt, n_z = n_t), so that a caller who fixes one of them
  gets the grid it had before.

Data whose band reaches the record's Nyquist frequency and whose signal lasts to the record's
end keep today's grid exactly (no cut, no resampling, no band limit). Pure numpy (scipy's DCT
is imported on first use; no numba), so that a server can size a tv job from it: `tv_grid`
without data gives the grid of a whole, full-band record, the largest tv may choose; given
the `RecordFacts` a server stores with a dataset when it imports it (`record_facts`: σ, the
samples up to the last echo, their band), the grid tv will choose for those data.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from driver.constants import C_DEFAULT
from driver.physics.resample import resampled_length

__all__ = ["TvGrid", "RecordFacts", "noise_sigma", "data_band", "data_extent", "record_facts", "tv_grid"]


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
    g = np.moveaxis(np.asarray(data), time_axis, 0)
    half = g.shape[0] // 2
    if half < 1 or g.size == 0:
        return 0.0
    g = g.reshape(g.shape[0], -1)  # (n_t, A-lines): a view for A-lines (n, n_t) and for time-first grid data
    d = np.empty((half, g.shape[1]))  # |g_{2n+1} - g_{2n}| / √2, in float64 and in blocks: no float64 copy of the data
    step = max(1, 2**19 // g.shape[1])
    for a in range(0, half, step):
        b = min(half, a + step)
        block = np.asarray(g[2 * a : 2 * b], dtype=np.float64)
        np.abs(np.subtract(block[1::2], block[0::2], out=d[a:b]), out=d[a:b])
        np.divide(d[a:b], math.sqrt(2.0), out=d[a:b])
    return float(np.median(d) / 0.6745)


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
    record_n_t : int
        Samples of the record kept, from its first (`data_extent`); the record's own n_t when
        nothing is cut. The operator's ``n_t`` samples span the kept record's interval.
    extent_reason : str
        What set the kept record: ``"data"`` (the data hold no more signal than noise after
        it), ``"image"`` (the depth the caller gave reaches further), ``"record"`` (nothing
        cut: the signal lasts to the record's end, or the data were not looked at).

    Examples
    --------
    >>> from service.recon.tv_grid import tv_grid
    >>> grid = tv_grid(1024, 8e-9, 1500.0, bandwidth=20e6)  # (n_t, dt, c): a 20 MHz sensor
    >>> grid.n_t, grid.resampled, grid.reason, grid.record_n_t, grid.extent_reason
    (330, True, 'declared', 1024, 'record')
    """

    n_t: int
    dt: float
    band: float | None
    dz: float
    n_z: int
    reason: str
    record_n_t: int
    extent_reason: str

    @property
    def resampled(self) -> bool:
        """Whether the operator works at fewer samples than the kept record has (a band limit)."""
        return self.band is not None

    @property
    def cut(self) -> bool:
        """Whether the record's end is dropped (``record_n_t`` below the record's samples)."""
        return self.extent_reason != "record"


class RecordFacts(NamedTuple):
    """What a record holds above its noise (`record_facts`): the facts `tv_grid` reads off the
    data, kept where the data are not at hand — a server stores them with a dataset when it
    imports it (``service.storage.datasets.import_dataset``), so that its admission sizes a tv
    job on the grid tv will choose (``service.recon.methods.tv``).

    Attributes
    ----------
    n_t : int
        Samples per A-line of the record.
    signal_n_t : int or None
        Samples kept after the cut past the last echo (`data_extent`, margin included); None:
        the signal lasts to the record's end (or no sample shows signal: noise alone).
    band : float or None
        The band above the noise floor of those samples (`data_band`), Hz, as `tv_grid` keeps
        it; None: their own sampling is the coarsest that keeps it (up to Nyquist).
    sigma : float
        The noise's standard deviation per sample (`noise_sigma`), in the data's unit.

    Examples
    --------
    >>> from service.recon.tv_grid import RecordFacts
    >>> RecordFacts.from_dict(RecordFacts(1024, 776, None, 0.01).as_dict())
    RecordFacts(n_t=1024, signal_n_t=776, band=None, sigma=0.01)
    """

    n_t: int
    signal_n_t: int | None
    band: float | None
    sigma: float

    def as_dict(self) -> dict:
        """The facts as a JSON-ready dict (the dataset record's ``record_facts``)."""
        return dict(self._asdict())

    @classmethod
    def from_dict(cls, d: dict) -> RecordFacts:
        """The facts from :meth:`as_dict`'s dict.

        Raises
        ------
        ValueError
            A field missing or out of range (n_t < 2, a kept length outside [1, n_t), a
            non-positive band, a negative σ).
        """
        try:
            n_t, kept, band, sigma = int(d["n_t"]), d["signal_n_t"], d["band"], float(d["sigma"])
            kept = None if kept is None else int(kept)
            band = None if band is None else float(band)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"record facts need n_t, signal_n_t, band and sigma, got {d!r}") from None
        if n_t < 2 or (kept is not None and not 1 <= kept < n_t) or (band is not None and not (
                math.isfinite(band) and band > 0)) or not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"record facts out of range: {d!r}")
        return cls(n_t, kept, band, sigma)


def record_facts(data: npt.ArrayLike, dt: float, time_axis: int) -> RecordFacts:
    """The facts `tv_grid` reads off a record, without the caller's options: its noise σ
    (`noise_sigma`, of every k-th A-line when the record holds more than 2 × 4 million
    samples), and the cut after its last echo (`data_extent`) and the band of the samples kept
    above the noise floor (`data_band`) of `tv_grid`'s default grid, all in blocks (a server
    computes them at import, beside the data). `tv_grid` given these ``facts`` instead
    of the data picks the grid it picks from the data, except where a depth the caller gives
    keeps more of the record than the signal does: there the band is the one of the signal's
    samples, at least as wide as that of the longer, noisier record (an estimate that errs
    towards the larger grid).

    Parameters
    ----------
    data : array_like
        Samples, any shape, time along ``time_axis`` (A-lines ``(n, n_t)`` with 1; grid data
        ``(n_t, ...)`` with 0).
    dt : float
        Sample interval, s.
    time_axis : int
        The time axis.

    Returns
    -------
    RecordFacts

    Raises
    ------
    ValueError
        dt not finite and > 0; fewer than 2 samples along ``time_axis``.

    Examples
    --------
    Pulses that end by sample 300 of 1000 on 64 A-lines of white noise:

    >>> import numpy as np
    >>> from service.recon.tv_grid import record_facts, tv_grid
    >>> t = np.arange(1000)
    >>> data = np.where((t > 200) & (t < 300), 1.0, 0.0) + 0.01 * np.random.default_rng(0).standard_normal((64, 1000))
    >>> facts = record_facts(data, 1e-8, time_axis=1)
    >>> facts.signal_n_t
    320
    >>> tv_grid(1000, 1e-8, 1500.0, facts=facts) == tv_grid(1000, 1e-8, 1500.0, data=data, time_axis=1)
    True
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be finite and > 0, got {dt!r}")
    a = np.asarray(data)
    n_t = int(a.shape[time_axis])
    if n_t < 2:
        raise ValueError(f"a record needs at least 2 samples, got {n_t}")
    lines = np.moveaxis(a, time_axis, 0).reshape(n_t, -1)  # (n_t, A-lines): a view for A-lines and grid data
    # σ from at most `_FACTS_SIGMA_SAMPLES` differences (every k-th A-line): noise_sigma holds its
    # differences in float64, which for the largest uploads would not fit beside the data
    stride = max(1, math.ceil(lines.shape[1] * (n_t // 2) / _FACTS_SIGMA_SAMPLES))
    sigma = noise_sigma(lines[:, ::stride], 0)
    chosen = tv_grid(n_t, dt, data=a, time_axis=time_axis, sigma=sigma)  # the default grid: its cut and band
    return RecordFacts(n_t, chosen.record_n_t if chosen.cut else None, chosen.band, sigma)


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


def data_extent(data: npt.ArrayLike, time_axis: int, sigma: float) -> int | None:
    """Samples of the record that hold signal above its noise (module doc): the last sample
    that shows signal by either of two tests, and a margin after it.

    - an echo at one sensor: any A-line's |g| above σ √(2 ln (100 N)), N the data's
      samples (Donoho & Johnstone's universal threshold σ √(2 ln N) for 100 times the
      samples: the largest of N samples of white noise passes it with a probability of
      about 2 / (100 √(2π) t) ≈ 0.15 % at t ≈ 5.5 σ, where at σ √(2 ln N) it is 10-20 %),
      so a strong echo that only a few far sensors hear is kept however small its share of
      the whole record's energy;
    - signal spread over many samples, each below that threshold: the data's energy from the
      sample on, summed over the A-lines, above the noise's by more than `_EXTENT_Z` = 5
      standard deviations of the noise's energy there (m samples of white noise: mean m σ²,
      standard deviation σ² √(2 m)) — a test of the tail, as `data_band`'s, but against the
      noise's spread rather than twice its mean, because a weak echo in time is short beside
      the long noise after it (a 2-D source's 1/√t tail, a few far sensors' last echoes);

    then `_EXTENT_MARGIN` of the record more (at least `_EXTENT_MARGIN_MIN` samples), for the
    fall of the last echo from the threshold to the noise (a Gaussian pulse of width s and
    height 100 σ takes 0.6 s to fall from 5 σ to σ). A test that finds signal by chance keeps
    more, never less.

    Parameters
    ----------
    data : array_like
        Samples, any shape, time along ``time_axis`` (A-lines ``(n, n_t)`` with 1; grid data
        ``(n_t, ...)`` with 0).
    time_axis : int
        The time axis.
    sigma : float
        The noise's standard deviation per sample, in the data's unit (`noise_sigma`).

    Returns
    -------
    int or None
        K < n_t: the samples 0..K - 1 are kept, the rest hold no more than noise; None when
        the signal (with the margin) lasts to the record's end, when no sample shows signal
        (noise alone), or without a noise estimate (σ <= 0).

    References
    ----------
    .. [1] D. L. Donoho, I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage",
       Biometrika 81 (1994) 425 (the universal threshold).

    Examples
    --------
    Pulses that end by sample 300 of 1000, on 64 A-lines of white noise (the margin: 20
    samples):

    >>> import numpy as np
    >>> from service.recon.tv_grid import data_extent
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(1000)
    >>> g = np.where((t > 200) & (t < 300), 1.0, 0.0) + 0.01 * rng.standard_normal((64, 1000))
    >>> data_extent(g, 1, sigma=0.01)
    320
    >>> data_extent(rng.standard_normal((64, 1000)), 1, sigma=1.0) is None  # noise alone
    True
    """
    g = np.moveaxis(np.asarray(data), time_axis, 0)
    n = g.shape[0]
    if n < 3 or not sigma > 0 or g.size == 0:
        return None
    g = g.reshape(n, -1)  # (n_t, A-lines): a view for A-lines (n, n_t) and for time-first grid data
    lines = g.shape[1]
    sigma = float(sigma)
    threshold = sigma * math.sqrt(2.0 * math.log(100.0 * g.size))
    energy, loudest = np.empty(n), np.empty(n)
    step = max(1, 2**20 // lines)
    for a in range(0, n, step):  # per sample: Σ over the A-lines of its square, and its largest |g|
        block = np.asarray(g[a : a + step], dtype=np.float64)
        energy[a : a + step] = np.einsum("ij,ij->i", block, block)
        loudest[a : a + step] = np.abs(block).max(axis=1)
    tail = np.cumsum(energy[::-1])[::-1]  # tail[k] = Σ_{j >= k} energy[j]
    count = lines * np.arange(n, 0, -1, dtype=np.float64)  # samples from k on
    noise_tail = sigma**2 * count  # their energy's mean under white noise
    heard = np.flatnonzero((loudest > threshold) | (tail - noise_tail > _EXTENT_Z * sigma**2 * np.sqrt(2.0 * count)))
    if heard.size == 0:  # noise alone
        return None
    kept = int(heard[-1]) + 1 + max(_EXTENT_MARGIN_MIN, math.ceil(_EXTENT_MARGIN * n))
    return kept if kept < n else None


#: `data_extent`'s test of the tail: its energy above the noise's mean by this many standard deviations
_EXTENT_Z = 5.0
#: the margin `data_extent` keeps after the last sample with signal: a share of the record, and
#: at least so many samples
_EXTENT_MARGIN = 0.02
_EXTENT_MARGIN_MIN = 4


def tv_grid(n_t: int, dt: float, c: float = C_DEFAULT, *, data: npt.ArrayLike | None = None, time_axis: int = 0,
            sigma: float | None = None, bandwidth: float | None = None, dz: float | None = None,
            n_z: int | None = None, t0: float = 0.0, whole_record: bool = False,
            facts: RecordFacts | None = None) -> TvGrid:
    """The grid tv works on (module doc): the record's kept extent, the operator's samples and
    band, and the image's depth grid.

    Parameters
    ----------
    n_t : int
        Samples per A-line of the record (>= 2).
    dt : float
        Its sample interval, s.
    c : float, optional
        Sound speed, m/s.
    data : array_like, optional
        The record, time along ``time_axis``: its extent (`data_extent`) and its band above
        the noise floor (`data_band`, of the kept record) set the grid. None (and no
        ``bandwidth``): the whole record at full band, today's grid dz = c dt.
    time_axis : int, optional
        The time axis of ``data`` (0 for grid data ``(n_t, ...)``, 1 for A-lines ``(n, n_t)``).
    sigma : float, optional
        The data's noise σ per sample (default `service.recon.tv.noise_sigma` of ``data``).
    bandwidth : float, optional
        A sensor bandwidth the caller declares, Hz: the band instead of the data's estimate.
    dz, n_z : optional
        The image's depth spacing (m) and samples, kept as given; with neither given c dt' and
        M, with one given the other c dt or n_t (the record's own rule). The kept record
        always reaches the depth of the image's last row.
    t0 : float, optional
        Time of sample 0, s (where the image's last row is heard).
    whole_record : bool, optional
        Keep the whole record (no cut after the last echo, `data_extent`): the samples after
        it are noise, but they also say that the far sensors hear nothing of the image's
        shallow voxels (module doc).
    facts : RecordFacts, optional
        Without ``data``: what the record was found to hold (`record_facts`), read instead of
        the data (a server sizing a job from a stored dataset's record).

    Returns
    -------
    TvGrid

    Raises
    ------
    ValueError
        n_t < 2, non-positive dt, c or bandwidth; ``facts`` of another record length.

    Examples
    --------
    >>> from service.recon.tv_grid import tv_grid
    >>> g = tv_grid(1024, 8e-9, 1500.0)  # nothing known of the data: the full band
    >>> g.n_t, g.band, round(g.dz * 1e6, 3), g.n_z, g.reason
    (1024, None, 12.0, 1024, 'nyquist')
    >>> g = tv_grid(1024, 8e-9, 1500.0, bandwidth=20e6)  # a 20 MHz sensor
    >>> g.n_t, g.band, round(g.dz * 1e6, 2), g.n_z, g.reason
    (330, 20000000.0, 37.31, 330, 'declared')

    A record whose signal ends at sample 600 of 1024 (64 A-lines): the rest is cut, and the
    default image ends where the kept record does:

    >>> import numpy as np
    >>> t = np.arange(1024)
    >>> data = np.where((t > 500) & (t < 600), 1.0, 0.0) + 0.01 * np.random.default_rng(0).standard_normal((64, 1024))
    >>> g = tv_grid(1024, 8e-9, 1500.0, data=data, time_axis=1, sigma=0.01)
    >>> g.record_n_t, g.extent_reason, g.n_z == g.n_t  # 600 and the margin, 2 % of the record
    (621, 'data', True)
    >>> tv_grid(1024, 8e-9, 1500.0, data=data, time_axis=1, sigma=0.01, n_z=900).record_n_t  # a deeper image: reached
    900
    """
    if int(n_t) != n_t or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    for name, v in (("dt", dt), ("c", c)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    n_t = int(n_t)
    if bandwidth is not None and not (np.isfinite(bandwidth) and bandwidth > 0):
        raise ValueError(f"bandwidth must be finite and > 0 Hz, got {bandwidth!r}")
    if data is not None and sigma is None:
        sigma = noise_sigma(data, time_axis)
    if data is None and facts is not None:
        if facts.n_t != n_t:
            raise ValueError(f"the record facts are of a record of {facts.n_t} samples, not {n_t}")
        extent = facts.signal_n_t
    else:
        extent = None if data is None or sigma is None or whole_record else data_extent(data, time_axis, float(sigma))
    kept, extent_reason = (n_t, "record") if whole_record else _kept_record(n_t, dt, c, extent, dz, n_z, t0)
    band, reason = None, "nyquist"
    if bandwidth is not None:
        band, reason = float(bandwidth), "declared"
    elif data is not None:
        assert sigma is not None  # set above
        head = np.asarray(data)[(slice(None),) * time_axis + (slice(0, kept),)]  # the kept record: a view
        band = data_band(head, dt, time_axis, float(sigma))
        reason = "nyquist" if band is None else "data"
    elif facts is not None:  # the band of the signal's samples: at least that of a longer record (`record_facts`)
        band = facts.band
        reason = "nyquist" if band is None else "data"
    m = kept if band is None else resampled_length(kept, dt, band)
    if m >= kept:  # the record's own rate is the coarsest that keeps the band
        band, m, reason = None, kept, "nyquist"
    dt_m = dt if m == kept else (kept - 1) * dt / (m - 1)
    if dz is None and n_z is None:  # the image's depth grid follows the operator's sampling
        dz_out, n_z_out = c * dt_m, m
    else:  # a caller who sets either keeps today's rule for the other (dz = c dt, n_z = n_t)
        dz_out = c * dt if dz is None else float(dz)
        n_z_out = n_t if n_z is None else int(n_z)
    if not math.isfinite(dz_out) or dz_out <= 0:
        raise ValueError(f"dz must be finite and > 0 m, got {dz!r}")
    return TvGrid(m, dt_m, band, dz_out, n_z_out, reason, kept, extent_reason)


#: the fewest samples a cut record keeps
_MIN_KEPT = 8
#: `record_facts` reads σ from at most this many sample differences (a few MB; the median of
#: 4 million white-noise differences is within 0.1 % of σ)
_FACTS_SIGMA_SAMPLES = 1 << 22


def _kept_record(n_t: int, dt: float, c: float, extent: int | None, dz: float | None, n_z: int | None,
                 t0: float) -> tuple[int, str]:
    """(samples kept, why) for `tv_grid`: the data's extent (`data_extent`; None: the whole
    record), but never before the sample that hears the last row of an image depth the caller
    gives."""
    kept = n_t if extent is None else max(extent, min(n_t, _MIN_KEPT))
    if kept >= n_t:  # the signal lasts to the end (or the record is shorter than the fewest kept)
        return n_t, "record"
    if dz is None and n_z is None:
        return kept, "data"
    last_row = ((n_t if n_z is None else int(n_z)) - 1) * (c * dt if dz is None else float(dz))
    reach = (last_row / c - float(t0)) / dt  # the sample that hears it (NaN or inf: a dz tv_grid refuses)
    if not reach < n_t - 1:
        return n_t, "record"
    if reach >= kept - 1:
        return int(math.ceil(reach)) + 1, "image"
    return kept, "data"
