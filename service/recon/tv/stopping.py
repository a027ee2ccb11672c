"""tv's stopping rule: the image's relative change per iteration, over a window of iterations.

The rule's value at iteration k is ‖x_k − x_{k−1}‖ / ‖x_k‖ (free: summed with the momentum's
test, `fpscan.service.recon.tv.fista.moves`); the run has converged when it was below ``tol`` in
each of the last `WINDOW` = 3 iterations at λ itself (none of the λ continuation's,
`fpscan.service.recon.tv.lam.Continuation`). Otherwise it stops at ``max_iter`` iterations
("iterations") or at the time limit ("time limit"). Why the rule is on the image, not on
the objective: docs/tv-measurements.md, "Stopping rule". Each iteration's progress stage carries
the rule's value, its first possible stop and tv's typical stop (`typical_stop`), from which the
progress's ETA counts (`fpscan.service.progress.Eta`).
"""
from __future__ import annotations

import math
from collections import deque

from fpscan.service.progress import IterationStage
from fpscan.service.recon.limits import DEFAULT_TOL

__all__ = ["WINDOW", "TYPICAL_STOP", "TYPICAL_STOP_FLOORED", "TYPICAL_POWER", "typical_stop", "StoppingRule"]

#: the stopping rule's window of iterations
WINDOW = 3
#: the iteration at which tv's runs typically stop at the default ``tol`` (`typical_stop`), and how it
#: grows as ``tol`` falls: TYPICAL_STOP × (DEFAULT_TOL / tol) ** TYPICAL_POWER (measured on k-Wave's
#: scans: docs/tv-measurements.md, "The waiting phase, and what `tol` changes")
TYPICAL_STOP = 50
#: the same where the reach floor set λ (`fpscan.service.recon.tv.lam.REACH_FLOOR`): those runs take a
#: stronger weight at low noise and stop later (measured on k-Wave's scans, as TYPICAL_STOP)
TYPICAL_STOP_FLOORED = 60
TYPICAL_POWER = 0.25


def typical_stop(tol: float, armed_at: int, floored: bool = False) -> int | None:
    """The iteration at which tv's runs typically stop at ``tol`` (`TYPICAL_STOP` at the default,
    `TYPICAL_STOP_FLOORED` where the reach floor set λ, × (default / ``tol``) ** `TYPICAL_POWER`),
    never before ``armed_at``, the first iteration the rule can stop at; None at ``tol`` 0 (the rule
    never stops the run). What the progress's ETA takes while the image change is far from ``tol``
    (`fpscan.service.progress.Eta`).

    Parameters
    ----------
    tol : float
        The stopping rule's threshold (>= 0).
    armed_at : int
        The first iteration at which the rule can stop the run.
    floored : bool, optional
        The reach floor set the run's λ (`fpscan.service.recon.tv.lam.DiscrepancyRule.floored`).

    Returns
    -------
    int or None
        The iteration.

    Examples
    --------
    >>> from fpscan.service.recon.tv.stopping import typical_stop
    >>> typical_stop(0.005, 10), typical_stop(0.0025, 10), typical_stop(0.005, 53), typical_stop(0.0, 10)
    (50, 59, 53, None)
    >>> typical_stop(0.005, 10, floored=True)
    60
    """
    if not tol > 0:
        return None
    typical = TYPICAL_STOP_FLOORED if floored else TYPICAL_STOP
    return max(int(armed_at), round(typical * (DEFAULT_TOL / tol) ** TYPICAL_POWER))


class StoppingRule:
    """The stopping rule of one solver run (`fpscan.service.recon.tv.fista.run_fista`, module doc).

    ``observe(bb, nn)`` takes an iteration's ‖x_k − x_{k−1}‖² and ‖x_k‖²; ``verdict(k, elapsed)``
    gives the stop reason at iteration k after ``elapsed`` s ("converged", "time limit",
    "iterations") or None to go on; ``stage(k)`` the progress stage carrying the rule's value so
    far, the tolerance and `armed_at` (`fpscan.service.progress.IterationStage`; while λ still
    falls its text is "iteration k/N (λ continuation k/K)"); ``at_lambda(k)`` whether the window
    holds iterations at λ only. The rule cannot stop the run before iteration `armed_at` =
    ``falling`` + `WINDOW`, which the progress and its ETA count as certain.

    Parameters
    ----------
    tol : float
        The threshold of the relative change (>= 0; 0: never "converged").
    max_iter : int
        Iterations at most.
    time_limit : float
        Wall-time limit, s.
    falling : int, optional
        The first iterations with λ_k > λ (the continuation's): the window must hold none of them
        before the rule can stop the run.
    floored : bool, optional
        The reach floor set λ: the stages' typical stop is `TYPICAL_STOP_FLOORED`'s (`typical_stop`).

    Attributes
    ----------
    tol, max_iter, time_limit, falling, floored
        As given.
    steps : deque of float
        The relative changes of the last `WINDOW` iterations.
    change : float
        The rule's value: the largest of them (NaN until there are `WINDOW`).

    Examples
    --------
    >>> from fpscan.service.recon.tv.stopping import StoppingRule
    >>> rule = StoppingRule(tol=0.01, max_iter=10, time_limit=60.0)
    >>> for k in (1, 2, 3):
    ...     rule.observe(1e-6, 1.0)  # a relative change of 0.001
    >>> round(rule.change, 6), rule.verdict(3, elapsed=1.0)
    (0.001, 'converged')
    >>> StoppingRule(0.01, 10, 60.0).verdict(10, elapsed=1.0), StoppingRule(0.01, 10, 60.0).verdict(4, 61.0)
    ('iterations', 'time limit')
    >>> waiting = StoppingRule(0.01, 100, 60.0, falling=50)  # λ falls in iterations 1-50
    >>> waiting.observe(1e-6, 1.0); stage = waiting.stage(7)
    >>> waiting.armed_at, stage, stage.armed, stage.armed_at
    (53, 'iteration 7/100 (λ continuation 7/50)', False, 53)
    """

    def __init__(self, tol: float, max_iter: int, time_limit: float, falling: int = 0, floored: bool = False) -> None:
        self.tol, self.max_iter, self.time_limit, self.falling = tol, max_iter, time_limit, falling
        self.floored = floored
        self.steps: deque[float] = deque(maxlen=WINDOW)  # ‖x_k − x_{k−1}‖ / ‖x_k‖ of the last iterations
        self.change = float("nan")

    def observe(self, bb: float, nn: float) -> None:
        self.steps.append(math.sqrt(bb / nn) if nn > 0 else (0.0 if bb == 0 else math.inf))
        if len(self.steps) == WINDOW:
            self.change = max(self.steps)

    def at_lambda(self, k: int) -> bool:
        """Whether the window at iteration k holds iterations at λ only (always, where λ does
        not fall)."""
        return self.falling == 0 or k - self.falling >= WINDOW

    @property
    def armed_at(self) -> int:
        """The first iteration at which the rule can stop the run: the continuation's
        iterations and a window at λ after them, known before the first iteration."""
        return self.falling + WINDOW

    def stage(self, k: int) -> IterationStage:
        # the stage "iteration k/N" carries the rule's value (its window so far) and tol, not yet
        # armed while λ still falls (the rule cannot stop the run there), and the iteration from
        # which it can; while λ falls its text says so: "iteration k/N (λ continuation k/K)"
        waiting = not self.at_lambda(k) and self.tol > 0
        text = f"iteration {k}/{self.max_iter} (λ continuation {k}/{self.falling})" if k <= self.falling else None
        return IterationStage(k, self.max_iter, max(self.steps), self.tol, armed=not waiting, text=text,
                              armed_at=self.armed_at if self.tol > 0 else None,
                              typical_stop=typical_stop(self.tol, self.armed_at, self.floored))

    def verdict(self, k: int, elapsed: float) -> str | None:
        if 0.0 <= self.change < self.tol and self.at_lambda(k):
            return "converged"
        if elapsed >= self.time_limit and k < self.max_iter:
            return "time limit"
        if k == self.max_iter:
            return "iterations"
        return None
