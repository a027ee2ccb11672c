"""tv's progress: increasing fractions and stages, and the polls that let a cancel act.

`Reporter` passes increasing fractions on to the caller's ``progress(fraction, stage)``
(the pipeline's contract, `fpscan.service.progress`) and repeats the last one at most every
`POLL_S` seconds from inside long steps (the operator's checkpoints, the proximal map's
inner steps), so that a ``progress`` that raises to cancel is heard within about a second
even when one iteration takes minutes. The stages: "warm start", "norm estimate",
"iteration k/max_iter" ("iteration k/max_iter (λ continuation k/K)" while λ still falls, with the
first iteration the stopping rule can stop at, K + 3, known from the first: `fpscan.service.recon.tv.stopping`)
and the last one, `final_stage`. The pipeline keeps the last one as the stage until the result
is written (`fpscan.service.progress.Forward`).
"""
from __future__ import annotations

import time

from fpscan.service.progress import Progress

__all__ = ["POLL_S", "Reporter", "final_stage"]

POLL_S = 0.2  # a cancel is polled at least this often (s) inside long steps


class Reporter:
    """tv's progress: ``report(fraction, stage)`` passes increasing fractions on to
    ``progress``; ``poll()`` repeats the same fraction and stage, at most every `POLL_S`
    seconds, so that a ``progress`` that raises to cancel (the pipeline's ``should_stop``) is
    heard inside long steps too (the operator's checkpoints, the proximal map's inner steps).

    Parameters
    ----------
    progress : callable or None
        ``progress(fraction, stage)`` (`fpscan.service.progress.Progress`); None: silent.

    Attributes
    ----------
    progress : callable or None
        As given.
    fraction : float
        The last fraction passed on (0 before any).
    stage : str
        Its stage ("warm start" before any).
    at : float
        When it was passed on (`time.monotonic`, s).

    Examples
    --------
    >>> from fpscan.service.recon.tv.progress import Reporter
    >>> seen = []
    >>> report = Reporter(lambda f, stage: seen.append((f, stage)))
    >>> report(0.1, "warm start"); report(0.05, "warm start"); report(0.2, "norm estimate")
    >>> seen  # only increasing fractions
    [(0.1, 'warm start'), (0.2, 'norm estimate')]
    """

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress
        self.fraction, self.stage, self.at = 0.0, "warm start", time.monotonic()

    def __call__(self, f: float, stage: str) -> None:
        if self.progress is not None and f > self.fraction:
            self.fraction, self.stage, self.at = f, stage, time.monotonic()
            self.progress(f, stage)

    def poll(self) -> None:
        if self.progress is not None and time.monotonic() - self.at >= POLL_S:
            self.at = time.monotonic()
            self.progress(self.fraction, self.stage)


def final_stage(stop_reason: str, iterations: int) -> str:
    """The last progress stage of a run.

    Parameters
    ----------
    stop_reason : str
        "converged", "iterations" or "time limit".
    iterations : int
        The iterations run.

    Returns
    -------
    str
        "converged after k iterations", or "stopped after k iterations (time limit)" /
        "(iteration limit)".

    Examples
    --------
    >>> from fpscan.service.recon.tv.progress import final_stage
    >>> final_stage("converged", 42)
    'converged after 42 iterations'
    >>> final_stage("time limit", 7)
    'stopped after 7 iterations (time limit)'
    """
    return (("converged" if stop_reason == "converged" else "stopped") + f" after {iterations} iterations"
            + {"time limit": " (time limit)", "iterations": " (iteration limit)"}.get(stop_reason, ""))
