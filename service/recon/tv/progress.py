"""tv's progress: increasing fractions and stages, and the polls that let a cancel act.

`Reporter` passes increasing fractions on to the caller's ``progress(fraction, stage)``
(the pipeline's contract, `fpscan.service.progress`) and repeats the last one at most every
`POLL_S` seconds from inside long steps (the operator's checkpoints, the proximal map's
inner steps), so that a ``progress`` that raises to cancel is heard within about a second
even when one iteration takes minutes. The stages: "warm start", "norm estimate",
"iteration k/max_iter" (`fpscan.service.recon.tv.stopping`) and the last one, `final_stage`.
"""
from __future__ import annotations

import time

from fpscan.service.progress import Progress

__all__: list[str] = []

POLL_S = 0.2  # a cancel is polled at least this often (s) inside long steps


class Reporter:
    """``report(fraction, stage)``: passes increasing fractions on to ``progress``;
    ``poll()``: the same fraction and stage again, at most every `POLL_S` seconds, so that
    a ``progress`` that raises to cancel (the pipeline's ``should_stop``) is heard inside
    long steps too (the operator's checkpoints, the proximal map's inner iterations)."""

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


def _reporter(progress: Progress | None) -> Reporter:
    return Reporter(progress)


def final_stage(stop_reason: str, iterations: int) -> str:
    """The last stage: "converged after k iterations" or "stopped after k iterations (time
    limit)" / "(iteration limit)"."""
    return (("converged" if stop_reason == "converged" else "stopped") + f" after {iterations} iterations"
            + {"time limit": " (time limit)", "iterations": " (iteration limit)"}.get(stop_reason, ""))
