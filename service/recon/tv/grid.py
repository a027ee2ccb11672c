"""The grid the model-based method works on: the operator's band and time sampling, the image's
depth grid and the record kept for it (docs/tv-measurements.md, "Grid").

The planar model maps each k-space component of p0 to one temporal frequency, f = c |k| / 2π
(the paper, eq. (1)), so a band f_c of the data is a ball |k| <= 2π f_c / c of the image's k-space. tv
(`fpscan.service.recon.tv`) adds hundreds of sensors' views coherently, so what its image can use is
set by the scan's geometry, not by what one A-line shows above its noise:

- **the band f_c**: c / (2 pitch), the band the lateral sampling resolves (its lateral Nyquist
  wavenumber π / pitch), so that the default grid is isotropic (dz = the pitch); a sensor
  bandwidth the scan declares (``bandwidth``) replaces it, lower or higher; at or above the
  record's Nyquist frequency there is no band. Anchors: k-Wave's own grid limit c / (2 dx) (its
  simulations carry nothing above it) and the paper's resolution argument (the pitch sets the
  lateral band). The band depends on the pitch alone, so the cut record and the whole record,
  and data at any noise level, get the same band. Until 2026-11-26 the band was read off the
  data per A-line (Wiener's cut of each sensor's spectrum against its noise): one A-line's SNR
  is far below the coherent image's, and on k-Wave's vessel tree at 4 % of the points and 20 dB
  below the peak that cut fell to 0.79 MHz (6 operator samples) and tv's CC with p0 to 0.36,
  where the whole band gives 0.95 (docs/results.md, "tv's quality gate"). tv does not go above
  the pitch's band by itself: the coherent image's evidence (the full-band NEDNER image's depth
  spectrum against the noise image's, ``benchmarks/bench_tv_band_evidence.py``) ends below it on
  k-Wave's data and on noisy scans, but reaches the record's Nyquist frequency on the paper's
  exact A-lines at 30 dB below their RMS, where a 25 MHz band buys CC 0.982 against 0.978 for 2.4
  times the time (220 against 90 NERs); a scan whose sensor band is known declares it;
- **the image's depth grid**: dz = c / (2 f_c) (c dt without a band), down to the depth c t_e of
  the record's last echo above the noise (`data_extent`: the last sample where any A-line, or
  the energy of all of them from there on, beats the noise; a margin of 2 % of the record) —
  a source deeper than that would be heard later; ``whole_record`` images the whole record's
  depth. A dz or n_z the caller gives is kept, and the other follows this default (every
  method's rule, `fpscan.service.recon.depth`: the spacing the image's lattice resolves, as
  deep as the record reaches; tv's depth is its signal's end);
- **the record kept**: every sample on which the model of that image draws — until the
  farthest sensor hears the image's last row, sqrt(z_last² + ρ²) / c with ρ the largest lateral
  distance between a sensor and a column of the image (``reach``), and the margin (for the
  band-limited operator's spread and the voxels' size). After it the model predicts silence
  at every sensor in 3-D (Huygens' principle), so the samples there are the noise's alone and
  dropping them changes nothing the image can use; a line's record is kept whole, since a 2-D
  wave rings on after its front (a tail ∝ 1/t²). The cut shortens the operator's record and its
  lateral padding (which grows with c t_last, `fpscan.service.recon.operator`); on the paper's scan
  (ρ up to 16 mm) nothing is cut;
- **the operator's sampling**: M samples on the kept record's interval,
  `fpscan.physics.resample.resampled_length` (its kept band reaches f_c), the data low-passed
  and resampled to them exactly (`fpscan.physics.resample.resample`), the operator
  band-limited to f_c in k-space (`fpscan.service.recon.operator.PlanarOperator` ``band``).

Pure numpy (no numba), so that a server can size a tv job from it: `tv_grid` without data
gives the grid of the whole record; given the `RecordFacts` a server stores with a dataset when
it imports it (`record_facts`: σ and the samples up to the last echo), the grid tv will choose
for those data.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from fpscan.constants import C_DEFAULT
from fpscan.physics.resample import resampled_length
from fpscan.service.recon.depth import depth_grid

__all__ = ["TvGrid", "RecordFacts", "noise_sigma", "data_extent", "record_facts", "tv_grid"]


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
    >>> from fpscan.service.recon.tv.grid import noise_sigma
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
        What set the band: ``"lateral"`` (what the lateral pitch resolves, c / (2 pitch)),
        ``"declared"`` (the caller's sensor bandwidth), ``"nyquist"`` (the record's own
        sampling is the coarsest that keeps the band, or no pitch was given).
    record_n_t : int
        Samples of the record kept, from its first; the record's own n_t when nothing is cut.
        The operator's ``n_t`` samples span the kept record's interval.
    extent_reason : str
        What set the kept record: ``"image"`` (the farthest sensor has heard the image's last
        row: the model predicts silence after it), ``"record"`` (nothing cut).

    Examples
    --------
    >>> from fpscan.service.recon.tv.grid import tv_grid
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
    imports it (``fpscan.service.storage.loader.import_dataset``), so that its admission sizes a tv
    job on the grid tv will choose (``fpscan.service.recon.methods.tv``).

    Attributes
    ----------
    n_t : int
        Samples per A-line of the record.
    signal_n_t : int or None
        Samples up to the last echo (`data_extent`, margin included): they set tv's default
        image depth; None: the signal lasts to the record's end (or no sample shows signal:
        noise alone).
    sigma : float
        The noise's standard deviation per sample (`noise_sigma`), in the data's unit.

    Examples
    --------
    >>> from fpscan.service.recon.tv.grid import RecordFacts
    >>> RecordFacts.from_dict(RecordFacts(1024, 776, 0.01).as_dict())
    RecordFacts(n_t=1024, signal_n_t=776, sigma=0.01)
    """

    n_t: int
    signal_n_t: int | None
    sigma: float

    def as_dict(self) -> dict:
        """The facts as a JSON-ready dict (the dataset record's ``record_facts``)."""
        return dict(self._asdict())

    @classmethod
    def from_dict(cls, d: dict) -> RecordFacts:
        """The facts from :meth:`as_dict`'s dict (other keys, such as the ``band`` that records
        stored before 2026-11-26 carry, are ignored).

        Raises
        ------
        ValueError
            A field missing or out of range (n_t < 2, a kept length outside [1, n_t), a
            negative σ).
        """
        try:
            n_t, kept, sigma = int(d["n_t"]), d["signal_n_t"], float(d["sigma"])
            kept = None if kept is None else int(kept)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"record facts need n_t, signal_n_t and sigma, got {d!r}") from None
        if n_t < 2 or (kept is not None and not 1 <= kept < n_t) or not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"record facts out of range: {d!r}")
        return cls(n_t, kept, sigma)


def record_facts(data: npt.ArrayLike, dt: float, time_axis: int) -> RecordFacts:
    """The facts `tv_grid` reads off a record: its noise σ (`noise_sigma`, of every k-th A-line
    when the record holds more than 2 × 4 million samples) and the samples up to its last echo
    (`data_extent`), in blocks (a server computes them at import, beside the data). `tv_grid`
    given these ``facts`` instead of the data picks the grid it picks from the data.

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
    >>> from fpscan.service.recon.tv.grid import record_facts, tv_grid
    >>> t = np.arange(1000)
    >>> data = np.where((t > 200) & (t < 300), 1.0, 0.0) + 0.01 * np.random.default_rng(0).standard_normal((64, 1000))
    >>> facts = record_facts(data, 1e-8, time_axis=1)
    >>> facts.signal_n_t
    320
    >>> kw = dict(pitch=60e-6, reach=3e-3)
    >>> tv_grid(1000, 1e-8, 1500.0, facts=facts, **kw) == tv_grid(1000, 1e-8, 1500.0, data=data, time_axis=1, **kw)
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
    end = data_extent(a, time_axis, sigma)
    return RecordFacts(n_t, None if end is None else int(end), sigma)


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
      standard deviation σ² √(2 m)) — a test of the tail, against the
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
    >>> from fpscan.service.recon.tv.grid import data_extent
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
            facts: RecordFacts | None = None, pitch: float | None = None, reach: float | None = None) -> TvGrid:
    """The grid tv works on (module doc): the operator's band and samples, the image's depth
    grid and the record kept for it.

    Parameters
    ----------
    n_t : int
        Samples per A-line of the record (>= 2).
    dt : float
        Its sample interval, s.
    c : float, optional
        Sound speed, m/s.
    data : array_like, optional
        The record, time along ``time_axis``: the end of its signal (`data_extent`) sets the
        default image depth. None (and no ``facts``): the whole record's depth.
    time_axis : int, optional
        The time axis of ``data`` (0 for grid data ``(n_t, ...)``, 1 for A-lines ``(n, n_t)``).
    sigma : float, optional
        The data's noise σ per sample (default `noise_sigma` of ``data``).
    bandwidth : float, optional
        A sensor bandwidth the caller declares, Hz: the band, whatever the lateral pitch.
    dz, n_z : optional
        The image's depth spacing (m) and rows, kept as given; the one not given follows the
        default: the band's c / (2 f_c) (c dt at full band), down to the signal's end
        (`fpscan.service.recon.depth.depth_grid`, every method's rule, with tv's band and depth).
    t0 : float, optional
        Time of sample 0, s.
    whole_record : bool, optional
        Keep the whole record, and with the default depth image all of it (the signal's end not
        read).
    facts : RecordFacts, optional
        Without ``data``: what the record was found to hold (`record_facts`), read instead of
        the data (a server sizing a job from a stored dataset's record).
    pitch : float, optional
        The image's lateral pitch, m: without a declared ``bandwidth`` the band is c / (2 pitch),
        what the lateral sampling resolves (an isotropic grid). None: the record's Nyquist.
    reach : float, optional
        The largest lateral distance between a sensor and a column of the image, m: the record
        is kept until the farthest sensor has heard the image's last row (`_kept_record`).
        None: the whole record is kept.

    Returns
    -------
    TvGrid

    Raises
    ------
    ValueError
        n_t < 2, non-positive dt, c, bandwidth or pitch, a negative reach; ``facts`` of another
        record length; ``dz`` or ``n_z`` out of range (``fpscan.service.recon.checks.OptionError``).

    Examples
    --------
    >>> from fpscan.service.recon.tv.grid import tv_grid
    >>> g = tv_grid(1024, 8e-9, 1500.0)  # nothing known of the sensors: the full band
    >>> g.n_t, g.band, round(g.dz * 1e6, 3), g.n_z, g.reason
    (1024, None, 12.0, 1024, 'nyquist')
    >>> g = tv_grid(1024, 8e-9, 1500.0, pitch=60e-6)  # a 60 µm lattice: 12.5 MHz, dz = 60 µm
    >>> g.n_t, g.band, round(g.dz * 1e6, 2), g.n_z, g.reason
    (207, 12500000.0, 60.0, 205, 'lateral')
    >>> g = tv_grid(1024, 8e-9, 1500.0, bandwidth=20e6, pitch=60e-6)  # a 20 MHz sensor declared
    >>> g.n_t, g.band, round(g.dz * 1e6, 2), g.n_z, g.reason
    (330, 20000000.0, 37.5, 328, 'declared')

    A record whose signal ends at sample 600 of 1024 (64 A-lines): the default image ends there,
    and the record is kept until a sensor 3 mm to the side hears its last row:

    >>> import numpy as np
    >>> t = np.arange(1024)
    >>> data = np.where((t > 500) & (t < 600), 1.0, 0.0) + 0.01 * np.random.default_rng(0).standard_normal((64, 1024))
    >>> g = tv_grid(1024, 8e-9, 1500.0, data=data, time_axis=1, sigma=0.01, pitch=60e-6, reach=3e-3)
    >>> round((g.n_z - 1) * g.dz * 1e3, 2), g.record_n_t, g.extent_reason  # 620 samples: 7.4 mm deep
    (7.44, 698, 'image')
    >>> tv_grid(1024, 8e-9, 1500.0, data=data, time_axis=1, sigma=0.01, pitch=60e-6).record_n_t  # no reach: all
    1024
    """
    if int(n_t) != n_t or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    for name, v in (("dt", dt), ("c", c)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    n_t = int(n_t)
    if bandwidth is not None and not (np.isfinite(bandwidth) and bandwidth > 0):
        raise ValueError(f"bandwidth must be finite and > 0 Hz, got {bandwidth!r}")
    if pitch is not None and not (np.isfinite(pitch) and pitch > 0):
        raise ValueError(f"pitch must be finite and > 0 m, got {pitch!r}")
    if reach is not None and not (np.isfinite(reach) and reach >= 0):
        raise ValueError(f"reach must be finite and >= 0 m, got {reach!r}")
    if data is None and facts is not None and facts.n_t != n_t:
        raise ValueError(f"the record facts are of a record of {facts.n_t} samples, not {n_t}")
    # the band: a declared sensor band, else what the lateral pitch resolves (module doc)
    band, reason = None, "nyquist"
    if bandwidth is not None:
        band, reason = float(bandwidth), "declared"
    elif pitch is not None:
        band, reason = float(c) / (2.0 * float(pitch)), "lateral"
    if band is not None and band >= 0.5 / dt * (1 - 1e-9):  # at or above the record's Nyquist frequency
        band, reason = None, "nyquist"
    # the image's depth grid, every method's rule (`fpscan.service.recon.depth.depth_grid`): dz and n_z as
    # given, else the spacing the band resolves, c / (2 f_c) (the pitch itself at the lateral band, c dt at
    # full band), and the rows down to the depth the signal's end reaches (heard straight above it)
    spacing = float(c) / (2.0 * band) if band is not None else None
    end = n_t if whole_record or n_z is not None else _signal_end(n_t, data, time_axis, sigma, facts)
    dz_out, n_z_out = depth_grid(end, dt, float(c), spacing, dz=dz, n_z=n_z, t0=float(t0))
    if whole_record or reach is None:
        kept, extent_reason = n_t, "record"
    else:
        kept, extent_reason = _kept_record(n_t, dt, float(c), (n_z_out - 1) * dz_out + dz_out, float(reach)
                                           + (pitch or 0.0), float(t0))
    m = kept if band is None else resampled_length(kept, dt, band)
    if m >= kept:  # the record's own rate is the coarsest that keeps the band
        band, m, reason = None, kept, "nyquist"
    dt_m = dt if m == kept else (kept - 1) * dt / (m - 1)
    return TvGrid(m, dt_m, band, dz_out, n_z_out, reason, kept, extent_reason)


def _signal_end(n_t: int, data: npt.ArrayLike | None, time_axis: int, sigma: float | None,
                facts: RecordFacts | None) -> int:
    """Samples up to the record's last echo above its noise (`data_extent`, or the stored
    ``facts``): the whole record when nothing is known or the signal lasts to its end."""
    if data is not None:
        if sigma is None:
            sigma = noise_sigma(data, time_axis)
        extent = data_extent(data, time_axis, float(sigma))
    else:
        extent = None if facts is None else facts.signal_n_t
    return n_t if extent is None else min(n_t, max(int(extent), _MIN_KEPT))


#: the fewest samples a cut record keeps
_MIN_KEPT = 8
#: `record_facts` reads σ from at most this many sample differences (a few MB; the median of
#: 4 million white-noise differences is within 0.1 % of σ)
_FACTS_SIGMA_SAMPLES = 1 << 22


def _kept_record(n_t: int, dt: float, c: float, depth: float, reach: float, t0: float) -> tuple[int, str]:
    """(samples kept, why) for `tv_grid`: every sample on which the model of the image draws —
    until the farthest sensor (``reach`` to the side, m) hears a source ``depth`` deep (m),
    sqrt(depth² + reach²) / c, and the margin (`_EXTENT_MARGIN`: the band-limited operator's
    spread and the voxels' own size); after it the model predicts silence at every sensor, so
    the samples there are the noise's alone and dropping them loses nothing."""
    last = (math.hypot(depth, reach) / c - t0) / dt  # the sample that hears the farthest voxel
    margin = max(_EXTENT_MARGIN_MIN, math.ceil(_EXTENT_MARGIN * n_t))
    if not last + margin < n_t - 1:
        return n_t, "record"
    return max(_MIN_KEPT, int(math.ceil(last)) + 1 + margin), "image"
