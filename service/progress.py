"""Progress of long work: the one callback shape and the one remap helper.

A :data:`Progress` is ``progress(fraction, stage)``: ``fraction`` in [0, 1], non-decreasing
over one piece of work (a step may repeat its fraction, e.g. so that a cancel raised from the
callback is heard), ``stage`` a short text for a person (``"reconstructing"``,
``"iteration 3/50"``, ``"autofocus"``). Everything that reports progress to the job's
progress file, the SSE events or the CLI's progress bar takes this shape
(:func:`fpscan.service.pipeline.reconstruct`, :func:`fpscan.service.spectral.reconstruct_wavelengths`,
:func:`fpscan.service.autofocus.focus_then_reconstruct`, ``reconstruct_tv``).

A part of a larger piece of work reports through :func:`span`, which maps its own [0, 1]
onto ``[lo, hi]`` of the outer callback. The callable :func:`span` returns also takes the
kernels' one-argument form ``progress(fraction)`` (``fpscan.service.recon.planar``,
``fpscan.service.recon.kwave``, ``fpscan.physics.nufft``, ``fpscan.service.autofocus.autofocus``), then
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
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, overload

__all__ = ["Progress", "Fraction", "Span", "span", "Rising", "rising", "Forward", "forward", "DEFAULT_STAGE", "IterationStage",
           "parse_iteration", "iteration_fields", "stage_of", "describe_iteration", "SETUP_STAGES", "stage_kind", "LOW_S", "Countdown", "Eta",
           "NEAR_TOL", "PAST_TYPICAL", "PAST_SHARE",
           "Shown", "outcome"]

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

    Parameters
    ----------
    outer : Progress
        The callback ``outer(fraction, stage)`` the span reports to.
    lo, hi : float
        The part of ``outer``'s range this span covers: its fraction 0 reports ``lo``, 1
        reports ``hi``.
    stage : str, optional
        The stage reported for a call without one (default :data:`DEFAULT_STAGE`).
    suffix : str, optional
        Text appended to every stage reported (e.g. ``" (wavelength 2/3)"``).

    Attributes
    ----------
    outer, lo, hi, stage, suffix
        As given (``lo`` and ``hi`` as floats).
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
        self.outer(self.hi if f == 1.0 else min(self.hi, self.lo + (self.hi - self.lo) * f),
                   text + self.suffix if self.suffix else text)  # an IterationStage stays one

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

    Parameters
    ----------
    progress : Fraction
        The kernel's callback ``progress(fraction)``.

    Attributes
    ----------
    progress : Fraction
        As given.
    last : float
        The largest fraction passed on so far (``-inf`` before the first).
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


class Forward:
    """A :data:`Progress` that only moves forward (made by :func:`forward`): the one guard every
    reconstruction's progress passes through (``fpscan.service.pipeline.reconstruct`` and
    ``run_file``), so that what a job, the CLI, the web page or a notebook shows never steps back.

    ``forward_(fraction, stage)`` calls ``progress`` with the largest fraction reported so far
    (a lower one is raised to it) and with ``stage``, unless ``stage`` is of a kind
    (:func:`stage_kind`) already left behind and the fraction has not risen: then the current
    stage again (the pipeline's closing ``"reconstructing"`` after tv's ``"converged after 53
    iterations"`` at the same fraction; the next wavelength's ``"warm start"`` at a higher
    fraction is new work, and passes). Every report is passed on, so a cancel raised from
    ``progress`` is still heard; whatever it raises passes through.

    Parameters
    ----------
    progress : Progress
        The callback ``progress(fraction, stage)``.

    Attributes
    ----------
    progress : Progress
        As given.
    fraction : float
        The largest fraction passed on (``-inf`` before the first).
    stage : str or None
        The stage last passed on (None before the first).
    """

    __slots__ = ("progress", "fraction", "stage", "_left")

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.fraction = -math.inf
        self.stage: str | None = None
        self._left: set[str] = set()  # the stage kinds left behind

    def __call__(self, fraction: float, stage: str) -> None:
        f = float(fraction)
        if self.stage is not None:
            now, kind = stage_kind(self.stage), stage_kind(stage)
            if kind != now:
                if kind in self._left and not f > self.fraction:
                    stage = self.stage  # back to a stage left behind, with no progress: the current one
                else:
                    self._left.add(now)
        self.fraction, self.stage = max(f, self.fraction), stage
        self.progress(self.fraction, stage)

    def __repr__(self) -> str:
        return f"forward({self.progress!r})"


@overload
def forward(progress: Progress) -> Forward: ...


@overload
def forward(progress: None) -> None: ...


def forward(progress: Progress | None) -> Forward | None:
    """``progress`` guarded so that its fraction and its stage only move forward (:class:`Forward`).

    Parameters
    ----------
    progress : the :data:`Progress` to guard, or None (no one listens).

    Returns
    -------
    A :class:`Forward` (a :data:`Progress`), ``progress`` itself when it is one already, or None
    when ``progress`` is None.

    Examples
    --------
    >>> seen = []
    >>> report = forward(lambda f, stage: seen.append((f, stage)))
    >>> report(0.2, "reconstructing"); report(0.5, "iteration 9/100"); report(0.9, "converged after 9 iterations")
    >>> report(0.9, "reconstructing")  # back to a stage left behind, at the same fraction
    >>> report(0.8, "writing")  # a new stage; its fraction no lower than the last
    >>> seen[3:]
    [(0.9, 'converged after 9 iterations'), (0.9, 'writing')]
    """
    if progress is None or isinstance(progress, Forward):
        return progress
    return Forward(progress)


# ------------------------------------------------------------------ iterative methods
class IterationStage(str):
    """The stage of an iterative method at iteration ``k`` of at most ``n``: the text
    ``"iteration k/n"`` (what a person reads, and every consumer of a stage takes it as
    text) carrying the numbers: ``k``, ``n``, the stopping rule's current value ``rule``
    and its tolerance ``tol`` (the method stops once the rule is below it; None while
    unknown), and the rule's name ``rule_name``. A :class:`Span`'s suffix keeps it one
    (``stage + " (wavelength 2/3)"``); :func:`iteration_fields` gives the numbers as the
    job's progress fields.

    Parameters
    ----------
    k : int
        The current iteration.
    n : int
        The iteration limit.
    rule : float, optional
        The stopping rule's current value; None (or a value that is not finite) while unknown.
    tol : float, optional
        The rule's tolerance; None (or a value that is not finite) while unknown.
    rule_name : str, optional
        The stopping rule's name (default ``"image change"``).
    armed : bool, optional
        Whether the rule can stop the work now (default True; tv: False while its λ still
        falls, when the tolerance is known but not yet applied).
    waits_for : str, optional
        What the rule waits for while not armed, in words its method declares
        (``fpscan.service.recon.methods.Method.stop_waits_for``; tv: ``"λ has settled"``); default "".
    armed_at : int, optional
        The first iteration at which the rule can stop the work, known in advance (tv: its λ
        continuation's K iterations + the rule's window of 3); None (default): unknown, or the
        rule never stops it (a tolerance of 0). The iterations before it are certain:
        :class:`Eta` counts at least those.
    typical_stop : int, optional
        The iteration at which the method's runs typically stop at this tolerance, a figure the
        method measured on its own runs (tv: `fpscan.service.recon.tv.stopping.typical_stop`);
        :class:`Eta` takes it while the rule's value is still far from the tolerance, where its
        fall says little of the stop. None (default): not known.
    text : str, optional
        The text itself (default ``"iteration k/n"``); :meth:`__add__` passes the text with
        its suffix.

    Attributes
    ----------
    k, n : int
        The iteration and the limit.
    rule, tol : float or None
        The rule's value and tolerance (None while unknown).
    rule_name : str
        The rule's name.
    armed : bool
        As given.
    waits_for : str
        As given.
    armed_at : int or None
        As given.
    typical_stop : int or None
        As given.

    Examples
    --------
    >>> s = IterationStage(7, 100, rule=0.021, tol=0.005)
    >>> s, s == "iteration 7/100", (s + " (wavelength 2/3)").k
    ('iteration 7/100', True, 7)
    >>> describe_iteration(iteration_fields(s))
    'iteration 7/100, image change 0.021 (stops below 0.005)'
    """

    k: int
    n: int
    rule: float | None
    tol: float | None
    rule_name: str
    armed: bool
    waits_for: str
    armed_at: int | None
    typical_stop: int | None

    def __new__(cls, k: int, n: int, rule: float | None = None, tol: float | None = None, *,
                rule_name: str = "image change", text: str | None = None, armed: bool = True,
                waits_for: str = "", armed_at: int | None = None, typical_stop: int | None = None) -> IterationStage:
        self = super().__new__(cls, text if text is not None else f"iteration {int(k)}/{int(n)}")
        self.k, self.n = int(k), int(n)
        self.rule = float(rule) if rule is not None and math.isfinite(float(rule)) else None
        self.tol = float(tol) if tol is not None and math.isfinite(float(tol)) else None
        self.rule_name, self.armed, self.waits_for = rule_name, bool(armed), str(waits_for)
        self.armed_at = None if armed_at is None else int(armed_at)
        self.typical_stop = None if typical_stop is None else int(typical_stop)
        return self

    def _with(self, **changes: Any) -> IterationStage:
        """The same stage with ``changes`` to its keyword fields."""
        keywords = {"rule_name": self.rule_name, "text": str(self), "armed": self.armed, "waits_for": self.waits_for,
                    "armed_at": self.armed_at, "typical_stop": self.typical_stop, **changes}
        return IterationStage(self.k, self.n, self.rule, self.tol, **keywords)

    def __add__(self, other: str) -> IterationStage:
        return self._with(text=str(self) + other)

    def __getnewargs_ex__(self) -> tuple[tuple, dict]:
        return (self.k, self.n, self.rule, self.tol), {"rule_name": self.rule_name, "text": str(self),
                                                       "armed": self.armed, "waits_for": self.waits_for,
                                                       "armed_at": self.armed_at, "typical_stop": self.typical_stop}

    def waiting_for(self, words: str) -> IterationStage:
        """The same stage with ``waits_for`` = ``words`` (what its method declares its rule waits
        for: ``fpscan.service.recon.methods.Method.stop_waits_for``)."""
        return self._with(waits_for=words)


_ITERATION = re.compile(r"iteration (\d+)/(\d+)")


def parse_iteration(stage: Any) -> IterationStage | None:
    """``stage`` as an :class:`IterationStage` (itself, or the text ``"iteration k/n..."``
    without the rule's numbers); None for any other stage.

    Parameters
    ----------
    stage : object
        A stage as a progress callback receives it: an :class:`IterationStage`, a str, or
        None.

    Returns
    -------
    IterationStage or None
        The stage with its iteration numbers (``rule`` and ``tol`` None when read from text),
        or None when ``stage`` does not start with ``"iteration k/n"``.
    """
    if isinstance(stage, IterationStage):
        return stage
    m = _ITERATION.match(str(stage or ""))
    return IterationStage(int(m[1]), int(m[2]), text=str(stage)) if m else None


def iteration_fields(stage: Any) -> dict[str, Any]:
    """The job progress fields of an iteration stage: ``iteration`` (k), ``iterations_max``
    (n), ``stop_rule`` (its name), ``stop_value`` (the rule's value, None while unknown),
    ``stop_tol`` (the tolerance), ``stop_armed`` (whether the rule can stop the work yet),
    ``stop_armed_at`` (the first iteration at which it can, where known in advance),
    ``stop_typical_at`` (the iteration at which the method's runs typically stop, where it says)
    and, while it cannot and the stage says what it waits for, ``stop_waits_for`` (the method's
    words: tv's ``"λ has settled"``); ``{}`` for any other stage. :func:`stage_of` reads them back.

    Parameters
    ----------
    stage : object
        A stage (:func:`parse_iteration`).

    Returns
    -------
    dict of str to object
        The fields above, or an empty dict when ``stage`` is no iteration stage.
    """
    it = parse_iteration(stage)
    if it is None:
        return {}
    fields: dict[str, Any] = {"iteration": it.k, "iterations_max": it.n, "stop_rule": it.rule_name,
                              "stop_value": it.rule, "stop_tol": it.tol, "stop_armed": it.armed}
    if it.armed_at is not None:
        fields["stop_armed_at"] = it.armed_at
    if it.typical_stop is not None:
        fields["stop_typical_at"] = it.typical_stop
    if not it.armed and it.waits_for:
        fields["stop_waits_for"] = it.waits_for
    return fields


def stage_of(progress: Mapping[str, Any]) -> Any:
    """A job progress's stage as a report gave it: an :class:`IterationStage` with the rule's
    numbers where the progress holds :func:`iteration_fields`, else the stage itself, so that an
    :class:`Eta` fed from a job's progress (the CLI's) estimates as the worker's does.

    Parameters
    ----------
    progress : Mapping of str to object
        A job's progress (``stage`` and, while an iterative method iterates, its fields).

    Returns
    -------
    IterationStage or object
        The stage with its numbers, or ``progress["stage"]`` (None where it has none).

    Examples
    --------
    >>> s = stage_of({"stage": "iteration 7/100 (λ continuation 7/50)", **iteration_fields(
    ...     IterationStage(7, 100, rule=0.02, tol=0.005, armed=False, armed_at=53))})
    >>> s, s.k, s.rule, s.tol, s.armed, s.armed_at
    ('iteration 7/100 (λ continuation 7/50)', 7, 0.02, 0.005, False, 53)
    >>> stage_of({"stage": "writing"})
    'writing'
    """
    stage = progress.get("stage")
    k, n = progress.get("iteration"), progress.get("iterations_max")
    if k is None or n is None:
        return stage
    return IterationStage(int(k), int(n), progress.get("stop_value"), progress.get("stop_tol"),
                          rule_name=progress.get("stop_rule") or "image change", text=str(stage),
                          armed=bool(progress.get("stop_armed", True)), waits_for=progress.get("stop_waits_for") or "",
                          armed_at=progress.get("stop_armed_at"), typical_stop=progress.get("stop_typical_at"))


def describe_iteration(fields: Mapping[str, Any]) -> str | None:
    """One line of the iteration fields (:func:`iteration_fields`, or a job's progress):
    ``"iteration 7/100, image change 0.021 (stops below 0.005)"``; None without them.
    The web page writes the same (``clients/web/app.js``, ``iterationText``).

    Parameters
    ----------
    fields : Mapping of str to object
        ``iteration``, ``iterations_max`` and optionally ``stop_rule``, ``stop_value``,
        ``stop_tol``, ``stop_armed``, ``stop_armed_at`` and ``stop_waits_for`` (``stop_armed``
        False: "once" and what the rule waits for, the method's words: tv's "once λ has
        settled", and "from iteration N" where N is known).

    Returns
    -------
    str or None
        The line (the rule's value only when known; ``"(tol 0: no early stop)"`` for a zero
        tolerance), or None when ``iteration`` or ``iterations_max`` is missing.

    Examples
    --------
    >>> describe_iteration({"iteration": 7, "iterations_max": 100, "stop_rule": "image change", "stop_value": 0.021,
    ...                     "stop_tol": 0.005, "stop_armed": False, "stop_armed_at": 53, "stop_waits_for": "λ has settled"})
    'iteration 7/100, image change 0.021 (stops below 0.005 once λ has settled, from iteration 53)'
    """
    k, n = fields.get("iteration"), fields.get("iterations_max")
    if k is None or n is None:
        return None
    text = f"iteration {k}/{n}"
    value, tol = fields.get("stop_value"), fields.get("stop_tol")
    if value is not None:
        text += f", {fields.get('stop_rule') or 'stopping rule'} {value:.2g}"
        if tol is not None:
            later = ""
            if not fields.get("stop_armed", True):
                later = f" once {fields.get('stop_waits_for') or 'armed'}"
                if fields.get("stop_armed_at") is not None:
                    later += f", from iteration {fields['stop_armed_at']}"
            text += f" (stops below {tol:.2g}{later})" if tol > 0 else " (tol 0: no early stop)"
    return text


#: stages of an iterative method before its first iteration (tv: its warm start and the
#: estimate of the operator's norm): no estimate of the time left is honest there, since
#: the iterations' cost is not measured yet
SETUP_STAGES = frozenset({"warm start", "norm estimate"})


def stage_kind(stage: Any) -> str:
    """A stage without its counters: ``"iteration"`` for an iteration stage, else the text
    without trailing words that hold digits (``"chunk 3/8"`` -> ``"chunk"``): the step that
    starts a new progress line and a new rate estimate.

    Parameters
    ----------
    stage : object
        A stage (a str, an :class:`IterationStage` or None).

    Returns
    -------
    str
        ``"iteration"``, or the stage's text without its trailing counter words (``""`` for
        None).
    """
    if parse_iteration(stage) is not None:
        return "iteration"
    words = str(stage or "").split()
    while words and any(ch.isdigit() for ch in words[-1]):
        words.pop()
    return " ".join(words)


#: an estimate of the time left under this many seconds is shown for at most as long at a
#: stretch (:class:`Countdown`): after that the work has outrun it, and no figure is shown until
#: a new estimate of at least this much
LOW_S = 5.0


class Countdown:
    """The time left as shown between estimates: the last estimate counted down by the time
    since, in s; under :data:`LOW_S` for at most :data:`LOW_S` s at a stretch, then None (the
    work has outrun its estimate: no figure is honest until a new estimate of at least
    :data:`LOW_S`). ``set(estimate, now)`` takes a new estimate (None: none) and returns what
    to show now; ``read(now)`` what to show later. Both :class:`Eta` and the CLI's progress
    lines between reports (``fpscan.clients.cli.common.ProgressBar``) show through one.

    Attributes
    ----------
    estimate : float or None
        The last estimate, s.
    at : float
        When it was made (the caller's clock, s).

    Examples
    --------
    >>> c = Countdown()
    >>> c.set(8.0, now=0.0), c.read(now=3.0), c.read(now=7.5)  # under 5 s from t = 3
    (8.0, 5.0, 0.5)
    >>> c.read(now=8.0), c.set(2.0, now=8.5)  # from t = 8 it has shown under 5 s for 5 s
    (None, None)
    >>> c.set(6.0, now=9.0), c.read(now=10.5)  # a new estimate above 5 s shows again
    (6.0, 4.5)
    """

    def __init__(self) -> None:
        self.estimate: float | None = None
        self.at = 0.0
        self._low_since: float | None = None  # when the figure shown went under LOW_S

    def _crossing(self) -> float:
        """When the current estimate, counted down, went (or goes) under :data:`LOW_S`."""
        assert self.estimate is not None
        return self.at + max(self.estimate - LOW_S, 0.0)

    def set(self, estimate: float | None, now: float) -> float | None:
        if estimate is None:
            self.estimate, self._low_since = None, None
            return None
        if estimate >= LOW_S:
            self._low_since = None
        elif self._low_since is None:  # under LOW_S since the old countdown went under it, or from now
            old = self.estimate is not None and self.estimate - (now - self.at) < LOW_S
            self._low_since = self._crossing() if old else now
        self.estimate, self.at = float(estimate), now
        return self.read(now)

    def read(self, now: float) -> float | None:
        if self.estimate is None:
            return None
        left = max(self.estimate - (now - self.at), 0.0)
        if left >= LOW_S:
            return left
        since = self._low_since if self._low_since is not None else self._crossing()
        return None if now - since >= LOW_S else left


class Eta:
    """The time left of a piece of work from its progress reports, in s (or None):
    ``eta(fraction, stage)`` at each report.

    - In an iteration stage (:func:`parse_iteration`): the iterations expected until the
      stopping rule ends the work × the measured time per iteration (an exponential moving
      average, weight ``smoothing``, of the time between iteration reports, shown once
      ``settle`` intervals are measured: the first iteration carries set-up work). Once the
      rule can stop the work and its value is within `NEAR_TOL` × the tolerance, the
      iterations expected come from the rate at which the value falls: a straight line fitted
      to log(value) over the last iterations (a geometric fall, as a convergent solver's
      image change shows near its end), extended to the tolerance. Farther from it, or while
      the rule cannot stop the work yet, or where the value does not fall, the fall says little
      of the stop (tv's image change falls fast while λ falls, then stalls for tens of
      iterations before it falls again), so where the stage gives the method's typical stop
      (``typical_stop``, a figure the method measured on its own runs) they are the iterations
      to it, but at least `PAST_SHARE` of those run (and `PAST_TYPICAL`); near the tolerance,
      the fitted fall's where it comes sooner. Without a typical stop, where the value
      does not fall (or no value or tolerance is known) they are the n − k left to the
      iteration limit. They are never fewer than the iterations before the rule can stop the
      work (``armed_at`` − k: tv's λ continuation and the rule's window, known in advance; until
      the fall is measured, they are those: a lower bound, :attr:`basis` ``"earliest stop"``)
      and never more than n − k: :attr:`bound_iterations`, the bound that always holds
      (:attr:`limit_s` is their time at the measured rate, itself an estimate).
    - In :data:`SETUP_STAGES`: None (the iterations are not measured yet).
    - In any other stage: the fraction's rate since the stage began,
      ``(elapsed in stage) × (1 − f) / (f − f at the stage's start)``.

    Within a stage, an estimate never moves by more than 2× from the one before counted
    down by the time since (at least 1 s): ``e_new`` in ``[e/2, 2e]`` for
    ``e = max(e_prev − elapsed, 1)``, so a slow or a fast iteration shifts the estimate
    gradually (tqdm's and rich's smoothed rates do the same in spirit); except that it never
    falls below the certain iterations' time (``armed_at`` − k of them) and is taken afresh
    once the work has outrun the one before. A new stage kind (:func:`stage_kind`) starts
    afresh. What is shown is a :class:`Countdown`: under :data:`LOW_S` s for at most
    :data:`LOW_S` s at a stretch. ``clock``: the time source (s; a test's own).

    Parameters
    ----------
    smoothing : float, optional
        Weight of the newest interval in the moving average of the time per iteration,
        in (0, 1] (default 0.3).
    settle : int, optional
        Iteration intervals measured before an estimate is shown, >= 1 (default 2).
    clock : callable, optional
        ``clock()`` -> the time in s (default ``time.monotonic``).

    Attributes
    ----------
    smoothing : float
        As given.
    settle : int
        As given.
    clock : callable
        As given.
    bound_iterations : int or None
        In an iteration stage with an estimate, the iterations left at most (n − k, the
        iteration limit's); None otherwise.
    limit_s : float or None
        Their time at the measured time per iteration, s (an estimate; None otherwise).
    basis : str or None
        What the last iteration estimate counts to: ``"stopping rule"`` (the rule's fall
        extended to the tolerance, at least to ``armed_at``), ``"earliest stop"`` (``armed_at``,
        before the rule's fall is measured: a lower bound) or ``"iteration limit"``.

    Raises
    ------
    ValueError
        ``smoothing`` outside (0, 1] or ``settle`` < 1.

    Examples
    --------
    >>> t = [0.0]
    >>> eta = Eta(clock=lambda: t[0])
    >>> for k in range(1, 5):
    ...     t[0] = 2.0 * k  # two seconds per iteration
    ...     print(eta(k / 10, IterationStage(k, 10)))
    None
    None
    14.0
    12.0

    An image change falling tenfold every 4 iterations reaches the tolerance 1e-3 at
    iteration 12, long before the limit of 100:

    >>> t, eta = [0.0], Eta(clock=lambda: t[0])
    >>> for k in range(1, 7):
    ...     t[0] = 2.0 * k
    ...     left = eta(k / 100, IterationStage(k, 100, rule=10 ** (-k / 4), tol=1e-3))
    >>> round(left), eta.basis, eta.bound_iterations, round(eta.limit_s)  # 6 iterations of 2 s; at most 94
    (12, 'stopping rule', 94, 188)

    The same while the rule cannot stop the work before iteration 40 (tv's λ continuation):
    34 iterations are certain.

    >>> t, eta = [0.0], Eta(clock=lambda: t[0])
    >>> for k in range(1, 7):
    ...     t[0] = 2.0 * k
    ...     left = eta(k / 100, IterationStage(k, 100, rule=10 ** (-k / 4), tol=1e-3, armed=False, armed_at=40))
    >>> round(left)
    68
    """

    def __init__(self, *, smoothing: float = 0.3, settle: int = 2, clock: Callable[[], float] = time.monotonic):
        if not 0 < smoothing <= 1 or settle < 1:
            raise ValueError(f"Eta needs 0 < smoothing <= 1 and settle >= 1, got {smoothing}, {settle}")
        self.smoothing, self.settle, self.clock = float(smoothing), int(settle), clock
        self._kind: str | None = None
        self._t0 = self._f0 = 0.0
        self._last_k: int | None = None
        self._last_k_at = 0.0
        self._per_iteration: float | None = None
        self._intervals = 0
        self._shown: tuple[float, float] | None = None  # (estimate, when): the smoothing's
        self._countdown = Countdown()  # what is shown
        self._rule: list[tuple[int, float, bool]] = []  # (k, log of the rule's value, armed): its fall
        self.bound_iterations: int | None = None
        self.limit_s: float | None = None
        self.basis: str | None = None

    def __call__(self, fraction: float, stage: Any) -> float | None:
        now = self.clock()
        kind = stage_kind(stage)
        if kind != self._kind:
            self._kind, self._t0, self._f0 = kind, now, float(fraction)
            self._last_k, self._per_iteration, self._intervals, self._shown = None, None, 0, None
            self._rule = []
            self._countdown.set(None, now)
        it = parse_iteration(stage)
        self.bound_iterations = self.limit_s = None
        floor = 0.0  # the certain part of the estimate (s)
        if it is not None:
            raw, floor = self._iterations(it, now)
        elif kind in SETUP_STAGES:
            raw = None
        else:
            f = float(fraction)
            raw = None if f <= self._f0 or f >= 1.0 else (now - self._t0) * (1.0 - f) / (f - self._f0)
        if raw is None:
            return self._countdown.read(now)
        if self._shown is not None:
            left = self._shown[0] - (now - self._shown[1])
            if left > 0:  # not outrun: moved gradually from it
                base = max(left, 1.0)
                raw = min(max(raw, base / 2), 2 * base)
        raw = max(raw, floor)  # the certain iterations' time, whatever the smoothing says
        if self.limit_s is not None:  # the smoothing's floor never lifts it past the iteration limit
            raw = min(raw, self.limit_s)
        self._shown = (raw, now)
        return self._countdown.set(raw, now)

    def read(self) -> float | None:
        """What to show now, between reports: the last estimate counted down (:class:`Countdown`)."""
        return self._countdown.read(self.clock())

    def _iterations(self, it: IterationStage, now: float) -> tuple[float | None, float]:
        """The estimate in an iteration stage and its certain part, s (None, 0 while unmeasured)."""
        if self._last_k is not None and it.k > self._last_k:
            step = (now - self._last_k_at) / (it.k - self._last_k)
            a = self.smoothing
            self._per_iteration = step if self._per_iteration is None else (1 - a) * self._per_iteration + a * step
            self._intervals += 1
        if self._last_k is None or it.k > self._last_k:
            self._last_k, self._last_k_at = it.k, now
        if it.rule is not None and it.rule > 0 and (not self._rule or it.k > self._rule[-1][0]):
            if self._rule and math.log(it.rule) == self._rule[-1][1]:  # the same value held (a window's largest): kept at its first k
                self._rule[-1] = (self._rule[-1][0], self._rule[-1][1], it.armed)
            else:
                self._rule = [*self._rule[-(_FIT - 1):], (it.k, math.log(it.rule), it.armed)]
        if self._per_iteration is None or self._intervals < self.settle:
            return None, 0.0
        cap = max(it.n - it.k, 0)
        self.bound_iterations, self.limit_s = cap, cap * self._per_iteration
        certain = 0
        if it.armed_at is not None and it.tol is not None and it.tol > 0:
            certain = min(max(it.armed_at - it.k, 0), cap)
        fitted = self._to_rule(it)
        left: float
        far = not it.armed or it.rule is None or it.tol is None or it.rule >= NEAR_TOL * it.tol
        if it.typical_stop is not None and it.tol is not None and it.tol > 0:
            # the method's typical stop, and once past it a few iterations more: the rule's fall says
            # little of the stop while its value is far from the tolerance (tv's image change stalls,
            # then falls); near it, the fall extended to the tolerance where that comes sooner (a fit
            # over a stall and a fall is too shallow); never fewer than the certain iterations
            left = max(it.typical_stop - it.k, max(PAST_TYPICAL, PAST_SHARE * it.k) if it.armed else 0)
            if not far and fitted is not None:
                left = min(left, fitted)
            left = min(max(left, certain), cap)
            self.basis = "iteration limit" if left >= cap else "stopping rule"
        elif fitted is None and certain:  # no fall measured yet: at least to the first stop the rule can make
            left, self.basis = certain, "earliest stop"
        else:
            left = cap if fitted is None else min(max(fitted, certain), cap)
            self.basis = "iteration limit" if left >= cap else "stopping rule"
        return left * self._per_iteration, certain * self._per_iteration

    def _to_rule(self, it: IterationStage) -> float | None:
        """Iterations until the rule's value, falling as fitted, is below the tolerance; None
        where that cannot be told (no tolerance, too few values, a value that does not fall).
        The fit: a straight line to log(value) over the last `_FIT` values (a geometric fall, as
        a convergent solver's image change shows; a value held over several iterations, the
        largest of a window, counts once, at its first)."""
        if it.tol is None or it.tol <= 0 or len(self._rule) < _FIT_MIN:
            return None
        ks = [float(k) for k, _, _ in self._rule]
        vs = [v for _, v, _ in self._rule]
        k_mean, v_mean = sum(ks) / len(ks), sum(vs) / len(vs)
        sxx = sum((k - k_mean) ** 2 for k in ks)
        if not sxx > 0:
            return None
        slope = sum((k - k_mean) * (v - v_mean) for k, v in zip(ks, vs, strict=True)) / sxx
        if not slope < 0:
            return None
        now = v_mean + slope * (it.k - k_mean)  # the fitted log value at k
        return max((math.log(it.tol) - now) / slope, 1.0)


#: the fewest values the ETA's fit of the rule's fall takes
_FIT_MIN = 3
#: the ETA extends the rule's fall to the tolerance once the value is within NEAR_TOL × tol of it,
#: and before that (where the stage has one) takes the method's typical stop (`Eta`)
NEAR_TOL = 2.0
#: with a typical stop, the ETA counts at least PAST_TYPICAL more iterations and PAST_SHARE of those
#: run (a run that has lasted long is likely to last longer), which passes the typical stop from
#: k = typical / (1 + PAST_SHARE) on. NEAR_TOL and PAST_SHARE were chosen on tv's k-Wave rows and
#: judged on the phantom family (docs/results.md, "tv's ETA against the actual end")
PAST_TYPICAL = 5
PAST_SHARE = 0.5
#: iterations of the rule's value the ETA's fit of its fall looks back over
_FIT = 8


@dataclass(frozen=True)
class Shown:
    """One field of a result's parameters that a method declares for its summary
    (``fpscan.service.recon.methods.Method.summary``): :func:`outcome` (the CLI's last line, the
    notebook bar's) writes ``"<label> <value>"``, the web page a row ``title`` with the value
    (``clients/web/app.js``, ``shownText``: the same words, from ``GET
    /api/reconstructions/methods``).

    Parameters
    ----------
    key : str
        The parameter shown (``"lam"``).
    label : str
        The word before the value in the line (``"λ"``).
    title : str, optional
        The web page's row heading (default ``label``).
    id : str, optional
        The web page's row: the element ``summary-<id>`` (default ``key``).
    format : {"number", "percent"}, optional
        ``"number"``: three significant digits (``0.0123``); ``"percent"``: a share as a
        percentage with two (``3.1 %``, ``0.042 %``).
    flag : str, optional
        A boolean parameter whose word follows the value in parentheses (``"lam_auto"``).
    words : (str, str), optional
        The flag's words for false and true (default ``("no", "yes")``).
    note : str, optional
        A text parameter appended as ``": <note>"`` when the flag is true and the value 0.
    suffix : str, optional
        Text after the value (and the flag's words): ``" of the data"``.
    also : tuple of (str, str), optional
        Further parameters (key, label) in the same format, each appended as
        ``", <label> <value>"`` when present.

    Attributes
    ----------
    key, label, title, id, format, flag, words, note, suffix, also
        As given.

    Examples
    --------
    >>> lam = Shown("lam", "λ", flag="lam_auto", words=("given", "automatic"), note="lam_note")
    >>> lam.text({"lam": 0.0123, "lam_auto": True}), lam.text({"lam": 0.0, "lam_auto": True, "lam_note": "no noise"})
    ('λ 0.0123 (automatic)', 'λ 0 (automatic): no noise')
    >>> Shown("residual", "residual", format="percent", suffix=" of the data", also=(("noise_share", "noise"),)).text(
    ...     {"residual": 0.031, "noise_share": 0.00042})
    'residual 3.1 % of the data, noise 0.042 %'
    >>> lam.text({}) is None
    True
    """

    key: str
    label: str
    title: str = ""
    id: str = ""
    format: str = "number"
    flag: str = ""
    words: tuple[str, str] = ("no", "yes")
    note: str = ""
    suffix: str = ""
    also: tuple[tuple[str, str], ...] = ()

    def _format(self, value: Any) -> str:
        return _percent(value) if self.format == "percent" else f"{value:.3g}"

    def value_text(self, params: Mapping[str, Any]) -> str | None:
        """The value in words (``"0.0123 (automatic)"``); None when ``params`` lacks it."""
        value = params.get(self.key)
        if value is None:
            return None
        text = self._format(value)
        if self.flag:
            on = bool(params.get(self.flag))
            text += f" ({self.words[on]})"
            if on and value == 0 and self.note and params.get(self.note):
                text += f": {params[self.note]}"
        text += self.suffix
        for key, label in self.also:
            if params.get(key) is not None:
                text += f", {label} {self._format(params[key])}"
        return text

    def text(self, params: Mapping[str, Any]) -> str | None:
        """``"<label> <value>"`` (:meth:`value_text`); None when ``params`` lacks the value."""
        value = self.value_text(params)
        return None if value is None else f"{self.label} {value}"

    def as_dict(self) -> dict[str, Any]:
        """The declaration as JSON for the web page (``title`` and ``id`` filled in)."""
        return {**asdict(self), "title": self.title or self.label, "id": self.id or self.key,
                "words": list(self.words), "also": [list(a) for a in self.also]}


def outcome(params: Mapping[str, Any], method: str | None = None, shown: Sequence[Shown] = ()) -> str | None:
    """One line on how an iterative reconstruction ended, from its ``params`` (a
    ``Reconstruction``'s, or a result's ``params_used``): converged or not (and why it
    stopped), the iterations, the stopping rule against its tolerance, then each field the
    method declares (``shown``; tv's: λ and whether it was automatic, with the reason when it
    is 0, and the residual against the data's noise level). None for a method without
    iterations. The web page writes the same (``clients/web/app.js``, ``outcomeOf``);
    ``fpscan.service.recon.methods.outcome`` passes the method's own ``shown``.

    Parameters
    ----------
    params : Mapping of str to object
        The reconstruction's parameters: ``iterations``, ``converged``, and optionally
        ``method``, ``max_iter``, ``stop_reason``, ``iterate_change``, ``tol``,
        ``stop_armed_at`` (the first iteration the rule could stop at: said when it stopped
        there) and the
        declared fields' (tv: ``lam``, ``lam_auto``, ``lam_note``, ``residual`` and
        ``noise_share``, shares of the data's norm).
    method : str, optional
        The name the line starts with (default ``params["method"]``, else
        ``"reconstruction"``).
    shown : sequence of Shown, optional
        The fields the method declares for its summary (``Method.summary``), in order.

    Returns
    -------
    str or None
        The line, its parts joined by ``"; "``; None when ``params`` has no ``iterations`` or
        no ``converged``.

    Examples
    --------
    >>> lam = Shown("lam", "λ", flag="lam_auto", words=("given", "automatic"), note="lam_note")
    >>> outcome({"method": "tv", "converged": True, "stop_reason": "converged", "iterations": 37,
    ...          "max_iter": 100, "iterate_change": 0.0041, "tol": 0.005, "lam": 0.0123, "lam_auto": True}, shown=[lam])
    'tv: converged after 37 iterations (image change 0.0041 < 0.005); λ 0.0123 (automatic)'
    >>> outcome({"method": "tv", "converged": True, "iterations": 53, "stop_armed_at": 53, "iterate_change": 0.00083,
    ...          "tol": 0.005})
    'tv: converged after 53 iterations, the earliest the rule can stop (image change 0.00083 < 0.005)'
    >>> outcome({"method": "ner"}) is None
    True
    """
    if params.get("iterations") is None or "converged" not in params:
        return None
    name = method or params.get("method") or "reconstruction"
    n, limit = int(params["iterations"]), params.get("max_iter")
    change, tol = params.get("iterate_change"), params.get("tol")
    rule = ""
    if change is not None and tol is not None:
        rule = f" (image change {change:.2g} {'<' if change < tol else '>='} {tol:.2g})"
    if params.get("converged"):
        # at the first iteration the rule could stop at (tv: after λ's continuation): a smaller
        # tolerance already met there stops no later
        earliest = ", the earliest the rule can stop" if params.get("stop_armed_at") == n else ""
        head = f"converged after {n} iterations{earliest}{rule}"
    elif params.get("stop_reason") == "time limit":
        head = f"not converged: stopped at the time limit after {n} iterations{rule}"
    else:
        head = f"not converged: stopped at the iteration limit, {n}{f' of {limit}' if limit else ''} iterations{rule}"
    parts = [f"{name}: {head}"]
    for field in shown:
        text = field.text(params)
        if text is not None:
            parts.append(text)
    return "; ".join(parts)


def _percent(share: float) -> str:
    """A share as a percentage with two significant digits: ``"3.1 %"``, ``"0.042 %"``."""
    v = 100 * float(share)
    return f"{v:.1f} %" if abs(v) >= 1 else f"{v:.2g} %"
