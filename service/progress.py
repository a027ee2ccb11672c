"""Progress of long work: the one callback shape and the one remap helper.

A :data:`Progress` is ``progress(fraction, stage)``: ``fraction`` in [0, 1], non-decreasing
over one piece of work (a step may repeat its fraction, e.g. so that a cancel raised from the
callback is heard), ``stage`` a short text for a person (``"reconstructing"``,
``"iteration 3/50"``, ``"autofocus"``). Everything that reports progress to the job's
progress file, the SSE events or the CLI's progress bar takes this shape
(:func:`service.pipeline.reconstruct`, :func:`service.spectral.reconstruct_wavelengths`,
:func:`service.autofocus.focus_then_reconstruct`, ``reconstruct_tv``).

A part of a larger piece of work reports through :func:`span`, which maps its own [0, 1]
onto ``[lo, hi]`` of the outer callback. The callable :func:`span` returns also takes the
kernels' one-argument form ``progress(fraction)`` (``service.recon.planar``,
``service.recon.kwave``, ``driver.physics.nufft``, ``service.autofocus.autofocus``), then
reporting the span's ``stage``: it is the one adapter between the kernels and a
:data:`Progress`. Inside a kernel, :func:`rising` turns the kernel's own one-argument
callback into a :data:`Progress` that passes on only rising fractions (the kernels promise
strictly increasing ones), so that the kernel's steps report through :func:`span` too.

Examples
--------
>>> seen = []
>>> outer = span(lambda f, stage: seen.append((round(f, 3), stage)), 0.2, 0.9)
>>> inner = span(outer, 0.0, 0.5, "warm start")  # the first half of the part
>>> inner(0.5)  # the one-argument form of a kernel: the span's stage
>>> inner(2.0, "norm estimate")  # clamped to 1
>>> outer(1.0, "reconstructing")
>>> seen
[(0.375, 'warm start'), (0.55, 'norm estimate'), (0.9, 'reconstructing')]
>>> span(None, 0.0, 0.5) is None  # no callback: nothing to report to
True
>>> fractions = []
>>> kernel = rising(fractions.append)  # a kernel's one-argument callback
>>> span(kernel, 0.1, 0.5)(1.0)  # a step of the kernel over [0.1, 0.5], ended
>>> kernel(0.5)  # no rise: not passed on
>>> span(kernel, 0.5, 1.0)(0.5)
>>> fractions
[0.5, 0.75]
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import overload

__all__ = ["Progress", "Fraction", "Span", "span", "Rising", "rising", "DEFAULT_STAGE"]

#: ``progress(fraction, stage)``: fraction in [0, 1] (non-decreasing), stage text
Progress = Callable[[float, str], None]
#: a kernel's one-argument ``progress(fraction)`` (fraction in [0, 1]); a :class:`Span` is one
Fraction = Callable[[float], None]

#: the stage a :class:`Span` reports for a one-argument call when it was given none
DEFAULT_STAGE = "reconstructing"


def _clamp(fraction: float) -> float:
    f = float(fraction)
    if math.isnan(f):
        raise ValueError("a progress fraction must be a number in [0, 1], got nan")
    return 0.0 if f < 0.0 else 1.0 if f > 1.0 else f


class Span:
    """A :data:`Progress` over ``[lo, hi]`` of an outer one (made by :func:`span`).

    ``span_(fraction, stage=None)`` calls ``outer(lo + (hi - lo) * fraction, stage + suffix)``
    with ``fraction`` clamped to [0, 1] (fraction 1 reports ``hi`` exactly); a call without a stage (a kernel's
    ``progress(fraction)``) reports the span's own ``stage``. Whatever the outer callback
    raises (a cancel) passes through.
    """

    __slots__ = ("outer", "lo", "hi", "stage", "suffix")

    def __init__(self, outer: Progress, lo: float, hi: float, stage: str | None = None, suffix: str = "") -> None:
        self.outer, self.lo, self.hi = outer, float(lo), float(hi)
        self.stage, self.suffix = stage, suffix

    def __call__(self, fraction: float, stage: str | None = None) -> None:
        text = stage if stage is not None else self.stage if self.stage is not None else DEFAULT_STAGE
        f = _clamp(fraction)
        # fraction 1 reports hi itself (0.2 + (0.9 - 0.2) * 1 rounds to 0.8999999999999999), and
        # nothing above it (a later report at hi, e.g. "writing" 0.9, is then no step back)
        self.outer(self.hi if f == 1.0 else min(self.hi, self.lo + (self.hi - self.lo) * f), text + self.suffix)

    def __repr__(self) -> str:
        return f"span({self.outer!r}, {self.lo:g}, {self.hi:g}, stage={self.stage!r}, suffix={self.suffix!r})"


@overload
def span(progress: Progress, lo: float, hi: float, stage: str | None = None, *, suffix: str = "") -> Span: ...


@overload
def span(progress: None, lo: float, hi: float, stage: str | None = None, *, suffix: str = "") -> None: ...


def span(progress: Progress | None, lo: float, hi: float, stage: str | None = None, *,
         suffix: str = "") -> Span | None:
    """The part ``[lo, hi]`` of ``progress``: a callback whose fraction 0 reports ``lo`` and 1
    reports ``hi`` to ``progress`` (fractions outside [0, 1] are clamped).

    Parameters
    ----------
    progress : the outer :data:`Progress`, or None (no one listens).
    lo, hi : the outer fractions the part covers, ``0 <= lo <= hi <= 1``.
    stage : the stage reported when the inner caller gives none (the one-argument form
        ``progress(fraction)`` of the kernels); default :data:`DEFAULT_STAGE`.
    suffix : text appended to every stage reported (e.g. ``" (wavelength 2/3)"``).

    Returns
    -------
    A :class:`Span` (callable as ``(fraction, stage=None)``), or None when ``progress`` is
    None, so that ``if progress is not None`` in a kernel still skips the work of reporting.

    Raises
    ------
    ValueError when ``lo``, ``hi`` are not ``0 <= lo <= hi <= 1``; calling the span with a
    NaN fraction is a ValueError too.
    """
    lo_f, hi_f = float(lo), float(hi)
    if not 0.0 <= lo_f <= hi_f <= 1.0:
        raise ValueError(f"a progress span needs 0 <= lo <= hi <= 1, got lo={lo!r}, hi={hi!r}")
    if progress is None:
        return None
    return Span(progress, lo_f, hi_f, stage, suffix)


class Rising:
    """A kernel's one-argument ``progress(fraction)`` as a :data:`Progress` (made by
    :func:`rising`): ``rising_(fraction, stage=None)`` calls ``progress(fraction)`` when
    ``fraction`` is above every fraction passed on before (the stage is dropped: a kernel's
    callback takes none), else nothing. Whatever ``progress`` raises (a cancel) passes through.
    """

    __slots__ = ("progress", "last")

    def __init__(self, progress: Fraction) -> None:
        self.progress = progress
        self.last = -math.inf

    def __call__(self, fraction: float, stage: str | None = None) -> None:
        f = float(fraction)
        if f > self.last:
            self.last = f
            self.progress(f)

    def __repr__(self) -> str:
        return f"rising({self.progress!r})"


@overload
def rising(progress: Fraction) -> Rising: ...


@overload
def rising(progress: None) -> None: ...


def rising(progress: Fraction | None) -> Rising | None:
    """The outer callback of a kernel's spans: ``progress`` (the kernel's one-argument
    ``progress(fraction)``, fractions in [0, 1]) called with strictly increasing fractions only.

    Parameters
    ----------
    progress : the kernel's callback, or None (no one listens).

    Returns
    -------
    A :class:`Rising` (a :data:`Progress`: ``(fraction, stage=None)``, to hand to :func:`span`
    for each step of the kernel), or None when ``progress`` is None.

    Examples
    --------
    >>> seen = []
    >>> report = rising(seen.append)
    >>> report(0.1); report(0.1); report(0.05, "a step back"); report(0.3)
    >>> seen
    [0.1, 0.3]
    """
    return None if progress is None else Rising(progress)
