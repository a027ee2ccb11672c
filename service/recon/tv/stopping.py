"""tv's stopping rule: the image's relative change per iteration, over a window of iterations.

The rule's value at iteration k is ‖x_k − x_{k−1}‖ / ‖x_k‖ (free: summed with the momentum's
test, `fpscan.service.recon.tv.fista.moves`); the run has converged when it was below ``tol`` in
each of the last `_WINDOW` = 3 iterations at λ itself (none of the λ continuation's,
`fpscan.service.recon.tv.lam.Continuation`). Otherwise it stops at ``max_iter`` iterations
("iterations") or at the time limit ("time limit"). Why the rule is on the image, not on
the objective: docs/tv-measurements.md, "Stopping rule".
"""
from __future__ import annotations

import math
from collections import deque

from fpscan.service.progress import IterationStage

__all__: list[str] = []

_WINDOW = 3  # the stopping rule's window of iterations


class StoppingRule:
    """The rule of one solver run (`fpscan.service.recon.tv.fista.run_fista`): ``observe(bb, nn)`` takes
    an iteration's ‖x_k − x_{k−1}‖² and ‖x_k‖²; ``change`` is the rule's value (the largest
    relative change of the last `_WINDOW` iterations; NaN until there are that many);
    ``verdict(k, elapsed)`` the stop reason at iteration k after ``elapsed`` s ("converged",
    "time limit", "iterations") or None to go on; ``stage(k)`` the progress stage carrying the
    rule's value so far. ``falling`` iterations at the start have λ_k > λ (the continuation's):
    the window must hold none of them before the rule can stop the run."""

    def __init__(self, tol: float, max_iter: int, time_limit: float, falling: int = 0) -> None:
        self.tol, self.max_iter, self.time_limit, self.falling = tol, max_iter, time_limit, falling
        self.steps: deque[float] = deque(maxlen=_WINDOW)  # ‖x_k − x_{k−1}‖ / ‖x_k‖ of the last iterations
        self.change = float("nan")

    def observe(self, bb: float, nn: float) -> None:
        self.steps.append(math.sqrt(bb / nn) if nn > 0 else (0.0 if bb == 0 else math.inf))
        if len(self.steps) == _WINDOW:
            self.change = max(self.steps)

    def at_lambda(self, k: int) -> bool:
        """Whether the window at iteration k holds iterations at λ only (always, where λ does
        not fall)."""
        return self.falling == 0 or k - self.falling >= _WINDOW

    def stage(self, k: int) -> IterationStage:
        # the stage "iteration k/N" carries the rule's value (its window so far) and tol, not yet
        # armed while λ still falls (the rule cannot stop the run there)
        waiting = not self.at_lambda(k) and self.tol > 0
        return IterationStage(k, self.max_iter, max(self.steps), self.tol, armed=not waiting)

    def verdict(self, k: int, elapsed: float) -> str | None:
        if 0.0 <= self.change < self.tol and self.at_lambda(k):
            return "converged"
        if elapsed >= self.time_limit and k < self.max_iter:
            return "time limit"
        if k == self.max_iter:
            return "iterations"
        return None
