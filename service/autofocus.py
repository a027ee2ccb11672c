"""Sound-speed autofocus: the c that maximises the Tenenbaum sharpness of the image.

A wrong speed of sound defocuses a planar reconstruction: every point source turns into
an arc. fpscan picks c within a search interval (default ``fpscan.constants.C_AUTOFOCUS_RANGE``, 1450-1600 m/s)
as the maximiser of a focus function, as the paper (Appendix "Quality measures") uses
the Tenenbaum sharpness to judge images:

- **Focus function** (:func:`focus_sharpness`): the Tenenbaum sharpness
  (:func:`fpscan.service.metrics.sharpness.tenenbaum_sharpness`, Sobel gradient energy) of the
  maximum-intensity projection of p0 along depth (the xy-MIP of a volume; of a 2-D
  image, its lateral profile), divided by the projection's mean square. Projecting
  along depth leaves out the depth axis, whose scale itself changes with c (z = c·t:
  a lower c compresses every structure in depth and would look "sharper"); dividing by
  the energy makes it independent of the image's scale.
- **Speed**: the search runs on a copy of the data decimated in time by q (an
  anti-aliased polyphase resampler, ``scipy.signal.resample_poly``, which keeps sample
  times exact), with q chosen from the data's spectrum (:func:`choose_decimation`: the
  band holding 90 % of the signal power above the noise floor stays below 0.8 of
  the new Nyquist frequency; q ≤ 8), reconstructed in float32 on one fixed depth grid
  for every c. Lateral sampling is never decimated (it moves the focus).
- **Search**: ``n_coarse`` speeds evenly over the interval, then a bounded Brent search
  (``scipy.optimize.minimize_scalar(method="bounded")``) between the neighbours of the
  best one, to ``xtol`` m/s. Every evaluation is kept as the sharpness curve.

The chosen c, the curve, the decimation and the time go into the result's ``params``
(``params["autofocus"]``, :meth:`Autofocus.as_params`).
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fpscan.constants import C_AUTOFOCUS_RANGE
from fpscan.service.progress import Fraction, Progress, span
from fpscan.service.recon.checks import check_sound_speed_range

__all__ = [
    "MAX_DECIMATION", "Autofocus", "check_sound_speed_range", "focus_sharpness", "choose_decimation", "search",
    "autofocus", "focus_then_reconstruct",
]

MAX_DECIMATION = 8


@dataclass
class Autofocus:
    """Outcome of an autofocus search (:func:`autofocus`).

    Attributes
    ----------
    sound_speed : float
        The chosen speed of sound, m/s.
    sound_speed_values : list of float
        Every evaluated c in ascending order, m/s (the sharpness curve's abscissae).
    sharpness : list of float
        The focus value (:func:`focus_sharpness`, dimensionless) at each of ``sound_speed_values``.
    sound_speed_range : tuple of float
        The search interval ``(c_min, c_max)``, m/s.
    decimation : int
        The time decimation factor q the search ran with.
    evaluations : int
        Reconstructions run.
    time_s : float
        Wall time of the search, s.
    at_edge : bool
        True when the maximum lies at an end of the interval (widen it); default False.
    extra : dict
        Further entries for :meth:`as_params` (:func:`autofocus` puts the search's depth
        grid there: ``dz`` in m and ``n_z``); default empty.
    """

    sound_speed: float
    sound_speed_values: list[float]
    sharpness: list[float]
    sound_speed_range: tuple[float, float]
    decimation: int
    evaluations: int
    time_s: float
    at_edge: bool = False
    extra: dict = field(default_factory=dict)

    def as_params(self) -> dict:
        """JSON-serialisable summary for a result's ``params["autofocus"]``."""
        return {"sound_speed": self.sound_speed, "sound_speed_range": list(self.sound_speed_range), "sound_speed_values": self.sound_speed_values,
                "sharpness": self.sharpness, "decimation": self.decimation,
                "evaluations": self.evaluations, "time_s": self.time_s, "at_edge": self.at_edge,
                "focus_function": "Tenenbaum sharpness of the depth MIP / its mean square", **self.extra}


def focus_sharpness(p0: np.ndarray) -> float:
    """Focus value of an image: Tenenbaum sharpness of its depth MIP / the MIP's mean square.

    Parameters
    ----------
    p0 : numpy.ndarray
        The image, ``(n_z, n_y, n_x)`` or ``(n_z, n_x)`` (depth first).

    Returns
    -------
    float
        The focus value, ≥ 0 and dimensionless (0 for an all-zero image).

    Raises
    ------
    ValueError
        Another shape (or an empty array); NaN or inf in ``p0``.
    """
    from fpscan.service.metrics.projections import mip
    from fpscan.service.metrics.sharpness import tenenbaum_sharpness

    p = np.asarray(p0)
    if p.ndim not in (2, 3) or p.size == 0:
        raise ValueError(f"p0 must be (n_z, n_y, n_x) or (n_z, n_x), got shape {p.shape}")
    # the depth MIP: xy of the volume; of a 2-D image (n_z, n_x), its one row (1, n_x)
    try:
        projection = np.asarray(mip(p if p.ndim == 3 else p[:, None, :], "xy"), dtype=np.float64)
    except ValueError:  # the shape is checked above: NaN
        raise ValueError("p0 contains NaN or inf") from None
    energy = float(np.mean(projection * projection))
    if not math.isfinite(energy):
        raise ValueError("p0 contains NaN or inf")
    return tenenbaum_sharpness(projection) / energy if energy > 0 else 0.0


def choose_decimation(alines: np.ndarray, *, max_q: int = MAX_DECIMATION) -> int:
    """Time decimation factor q (1..max_q) that keeps the signal band of ``alines``
    below 0.8 of the decimated Nyquist frequency.

    The band edge is the frequency below which 90 % of the signal power lies: the mean
    power spectrum over (up to 512) A-lines less its noise floor (the median power of the
    upper half of the spectrum). Keeps ≥ 32 samples.

    Parameters
    ----------
    alines : numpy.ndarray
        The signals, ``(n_t, ...)`` (time first; e.g. ``(n_t, n_y, n_x)`` or ``(n_t, n)``).
    max_q : int, optional
        The largest factor; default :data:`MAX_DECIMATION` (8).

    Returns
    -------
    int
        q; 1 when the spectrum is too short (fewer than 4 bins) or holds no signal above
        its noise floor.
    """
    a = np.asarray(alines)
    n_t = a.shape[0]
    flat = a.reshape(n_t, -1)
    step = max(1, flat.shape[1] // 512)
    power = np.mean(np.abs(np.fft.rfft(np.asarray(flat[:, ::step], dtype=np.float64), axis=0)) ** 2, axis=1)
    if power.size < 4 or not np.any(power > 0):
        return 1
    floor = float(np.median(power[power.size // 2:]))
    signal = np.maximum(power - floor, 0.0)
    total = float(signal.sum())
    if total <= 0:
        return 1
    k = int(np.searchsorted(np.cumsum(signal), 0.9 * total))
    edge = (k + 1) / power.size  # fraction of the Nyquist frequency
    q = int(max(1, min(max_q, math.floor(0.8 / edge), n_t // 32)))
    return q


def search(sharpness_at: Callable[[float], float], sound_speed_range: tuple[float, float] = C_AUTOFOCUS_RANGE, *,
           n_coarse: int = 7, xtol: float = 2.0) -> tuple[float, dict[float, float], bool]:
    """Maximise ``sharpness_at(c)`` over ``sound_speed_range`` (m/s): ``n_coarse`` even samples,
    then a bounded Brent search (scipy) between the best sample's neighbours to ``xtol``.

    Parameters
    ----------
    sharpness_at : callable
        ``sharpness_at(c) -> float``: the focus value at speed ``c`` (m/s); called once per c.
    sound_speed_range : tuple of float, optional
        ``(c_min, c_max)`` in m/s (:func:`check_sound_speed_range`); default
        ``fpscan.constants.C_AUTOFOCUS_RANGE``.
    n_coarse : int, optional
        Evenly spaced speeds sampled first, ends included; at least 3; default 7.
    xtol : float, optional
        The Brent search's tolerance, m/s; default 2.

    Returns
    -------
    c_best : float
        The speed with the highest value seen (Brent's answer or a better sample), m/s.
    curve : dict of float to float
        Every evaluated speed (m/s) and its value.
    at_edge : bool
        True when the best coarse sample is an end of the interval and ``c_best`` lies
        within ``2 * xtol`` of an end (widen the interval).

    Raises
    ------
    ValueError
        A bad ``sound_speed_range`` (:func:`check_sound_speed_range`); ``n_coarse`` < 3; ``xtol`` not a finite
        number > 0.
    """
    from scipy.optimize import minimize_scalar

    lo, hi = check_sound_speed_range(sound_speed_range)
    if n_coarse < 3:
        raise ValueError(f"n_coarse must be >= 3, got {n_coarse}")
    if not (math.isfinite(xtol) and xtol > 0):
        raise ValueError(f"xtol must be > 0 m/s, got {xtol}")
    curve: dict[float, float] = {}

    def f(c: float) -> float:
        c = float(c)
        if c not in curve:
            curve[c] = float(sharpness_at(c))
        return curve[c]

    grid = np.linspace(lo, hi, n_coarse)
    values = [f(c) for c in grid]
    k = int(np.argmax(values))
    a, b = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, n_coarse - 1)])
    res = minimize_scalar(lambda c: -f(c), bounds=(a, b), method="bounded", options={"xatol": xtol})
    best = max(curve, key=lambda c: curve[c])  # Brent's answer, or a better sample seen on the way
    c_best = float(res.x) if curve.get(float(res.x), -np.inf) >= curve[best] else best
    at_edge = k in (0, n_coarse - 1) and min(abs(c_best - lo), abs(c_best - hi)) <= 2 * xtol
    return c_best, curve, at_edge


def _decimated(dataset: Any, q: int) -> Any:
    """A copy of a grid/point dataset decimated in time by q (sample times kept)."""
    from scipy.signal import resample_poly

    if q == 1:
        return dataset
    if getattr(dataset, "kind", None) == "grid":
        data = resample_poly(np.asarray(dataset.data, dtype=np.float32), 1, q, axis=0).astype(np.float32)
        return dataclasses.replace(dataset, data=data, dt=dataset.dt * q)
    alines = resample_poly(np.asarray(dataset.alines, dtype=np.float32), 1, q, axis=1).astype(np.float32)
    return dataclasses.replace(dataset, alines=alines, dt=dataset.dt * q)


def _time_first(dataset: Any) -> np.ndarray:
    if getattr(dataset, "kind", None) == "grid":
        return np.asarray(dataset.data)
    return np.asarray(dataset.alines).T


def autofocus(dataset: Any, reconstruct: Callable[..., Any], *, sound_speed_range: Any = C_AUTOFOCUS_RANGE,
              n_coarse: int = 7, xtol: float = 2.0, decimation: int | None = None,
              options: dict | None = None, progress: Fraction | None = None) -> Autofocus:
    """Find the speed of sound (m/s) that focuses ``dataset`` best (module docstring).

    Every c is reconstructed on one depth grid: ``dz = c_min·dt·q/2`` (twice as fine as the
    decimated samples at c_min), ``n_z`` rows as deep as c_max reaches.

    Parameters
    ----------
    dataset : GridDataset or PointDataset
        A grid or point dataset (:mod:`fpscan.service.storage.loader`: ``data`` ``(n_t, ...)``
        / ``alines`` ``(n, n_t)``, ``dt`` s, ``t0`` s).
    reconstruct : callable
        ``reconstruct(dataset, sound_speed=..., dz=..., n_z=..., dtype="float32", **options)`` → an
        object with ``p0`` (the pipeline's dispatch bound to a method, its ``should_stop``
        included: a cancelled reconstruction ends the search).
    sound_speed_range : tuple of float, optional
        ``(c_min, c_max)`` in m/s; default ``fpscan.constants.C_AUTOFOCUS_RANGE``.
    n_coarse : int, optional
        See :func:`search`; default 7.
    xtol : float, optional
        See :func:`search`, m/s; default 2.
    decimation : int, optional
        Time decimation factor q (1..8); None (default): :func:`choose_decimation`.
    options : dict, optional
        Further reconstruction options (e.g. ``eps``, ``upsample``); ``dz``, ``n_z`` and
        ``dtype`` are the search's own.
    progress : callable, optional
        ``progress(fraction)`` after each evaluation (the fraction of ``n_coarse + 8``,
        at most 1).

    Returns
    -------
    Autofocus
        The chosen c, the sharpness curve, q, the evaluations and the time; ``extra``
        holds the search's ``dz`` (m) and ``n_z``.

    Raises
    ------
    ValueError
        A bad interval (:func:`check_sound_speed_range`), decimation, ``n_coarse`` or ``xtol``
        (:func:`search`); an image with NaN or inf (:func:`focus_sharpness`); what
        ``reconstruct`` raises for the dataset.
    """
    lo, hi = check_sound_speed_range(sound_speed_range)
    t_start = time.perf_counter()
    if decimation is None:
        q = choose_decimation(_time_first(dataset))
    else:
        q = int(decimation)
        if not 1 <= q <= MAX_DECIMATION:
            raise ValueError(f"decimation must be an integer in 1..{MAX_DECIMATION}, got {decimation!r}")
    dec = _decimated(dataset, q)
    n_t = _time_first(dataset).shape[0]
    # one depth grid for every c, twice as fine as the decimated samples at c_min (a finer
    # grid makes the depth MIP less sensitive to where a structure falls between rows),
    # as deep as c_max reaches
    dz = lo * dataset.dt * q / 2.0
    n_z = max(2, int(math.ceil(hi * (dataset.t0 + n_t * dataset.dt) / dz)))
    opts = dict(options or {})
    opts.update(dz=dz, n_z=n_z, dtype="float32")
    expected = n_coarse + 8
    done = [0]

    def sharpness_at(c: float) -> float:
        value = focus_sharpness(reconstruct(dec, sound_speed=c, **opts).p0)
        done[0] += 1
        if progress is not None:
            progress(min(1.0, done[0] / expected))
        return value

    c_best, curve, at_edge = search(sharpness_at, (lo, hi), n_coarse=n_coarse, xtol=xtol)
    cs = sorted(curve)
    return Autofocus(sound_speed=c_best, sound_speed_values=cs, sharpness=[curve[c] for c in cs], sound_speed_range=(lo, hi),
                     decimation=q, evaluations=len(curve), time_s=time.perf_counter() - t_start,
                     at_edge=at_edge, extra={"dz": dz, "n_z": n_z})


def focus_then_reconstruct(dataset: Any, method: str, reconstruct: Callable[..., Any], options: Any, *,
                           progress: Progress | None = None,
                           should_stop: Callable[[], bool] | None = None) -> Any:
    """``sound_speed="auto"`` for the dispatch: :func:`autofocus`, then one reconstruction of the
    full data at the chosen speed.

    The search reconstructs with ``method`` (a direct method of the dispatch; an iterative
    one, ``Method.iterative`` of ``fpscan.service.recon.methods``, searches with the input's default
    direct method instead, ``fpscan.service.recon.methods.default_for``), lateral upsampling 1,
    float32. Progress: the search reports stage ``"autofocus"`` over [0, 0.5], the final
    reconstruction the rest.

    Parameters
    ----------
    dataset : GridDataset or PointDataset
        The input, as for :func:`autofocus`.
    method : str
        The reconstruction method's name.
    reconstruct : callable
        The dispatch (``fpscan.service.pipeline.reconstruct``):
        ``reconstruct(dataset, method, options, progress=..., should_stop=...)``.
    options : fpscan.service.recon.methods.MethodOptions
        The method's validated options, ``sound_speed="auto"``; its ``sound_speed_range`` (m/s;
        None: ``fpscan.constants.C_AUTOFOCUS_RANGE``) is the search interval. The search passes on
        those its own method takes but the depth grid, precision and upsampling (``dz``, ``n_z``,
        ``dtype``, ``upsample``); the final reconstruction takes them all, at the chosen speed.
    progress : Progress, optional
        Receives the stages and fractions above.
    should_stop : callable, optional
        ``should_stop() -> bool``, passed to every reconstruction (a cancelled job ends the
        search).

    Returns
    -------
    object
        The final reconstruction (what ``reconstruct`` returns); its ``params["sound_speed"]`` is
        the chosen speed (m/s) and ``params["autofocus"]`` the search (:meth:`Autofocus.as_params`,
        with ``search_method``).

    Raises
    ------
    ValueError
        A bad ``sound_speed_range``; what the dispatch raises.
    """
    rng = check_sound_speed_range(C_AUTOFOCUS_RANGE if options.sound_speed_range is None
                                  else options.sound_speed_range)
    from fpscan.service.recon.methods import METHODS, default_for

    search_method = method
    if METHODS[method].iterative:
        search_method = default_for("grid" if getattr(dataset, "kind", None) == "grid" else "points")
    takes = set(METHODS[search_method].options)
    # the search method's own options only (an iterative method's lam, max_iter... are not the search's);
    # the speeds tried lie within the interval, checked above
    skip = {"dz", "n_z", "dtype", "upsample", "sound_speed", "sound_speed_range", "force"}
    search_opts = {k: v for k, v in options.model_dump(exclude_defaults=True).items() if k in takes and k not in skip}

    def at(ds: Any, **o: Any) -> Any:
        return reconstruct(ds, search_method, {**search_opts, **o, "force": True}, should_stop=should_stop)

    found = autofocus(dataset, at, sound_speed_range=rng, progress=span(progress, 0.0, 0.5, "autofocus"))
    final = options.model_copy(update={"sound_speed": found.sound_speed, "sound_speed_range": None, "force": True})
    rec = reconstruct(dataset, method, final, progress=span(progress, 0.5, 1.0), should_stop=should_stop)
    rec.params["sound_speed"] = found.sound_speed
    rec.params["autofocus"] = {**found.as_params(), "search_method": search_method}
    return rec
