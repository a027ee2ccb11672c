"""Wall time per named step of a reconstruction or an operator application, when asked for.

The reconstructions (`fpscan.service.recon.planar`) and the model-based operator pair
(`fpscan.service.recon.operator`) wrap each of their steps in :func:`step`; nothing is recorded
unless a caller opens :func:`recording` around the call (`benchmarks/bench_cpu_scaling.py`
prints the steps' times at 1 and 2 threads and Amdahl's serial fraction from them). Outside a
recording a step costs one context-variable read (under a microsecond; a step runs
milliseconds). The recording follows the calling thread and its asyncio task (a context
variable), so that concurrent calls in other threads do not mix their steps into it.
"""
from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

__all__ = ["step", "recording"]

_RECORD: ContextVar[dict[str, float] | None] = ContextVar("fpscan_step_times", default=None)


@contextmanager
def step(name: str) -> Iterator[None]:
    """Add the wall time of the block to ``name`` in the open recording, if any.

    Parameters
    ----------
    name : str
        The step's name (times of equal names add up).

    Examples
    --------
    >>> from fpscan.physics.step_times import recording, step
    >>> with recording() as times:
    ...     with step("sum"):
    ...         total = sum(range(1000))
    >>> list(times), times["sum"] >= 0.0
    (['sum'], True)
    """
    times = _RECORD.get()
    if times is None:
        yield
        return
    t0 = time.perf_counter()
    try:
        yield
    finally:
        times[name] = times.get(name, 0.0) + time.perf_counter() - t0


@contextmanager
def recording() -> Iterator[dict[str, float]]:
    """Record the steps run inside the block: a dict of step name to seconds (s), in the
    order the steps first ran, filled as they run.

    Returns
    -------
    contextmanager yielding dict of str to float
        The steps' wall times, s.

    Examples
    --------
    >>> from fpscan.physics.step_times import recording, step
    >>> with recording() as times:
    ...     for _ in range(2):
    ...         with step("a"):
    ...             pass
    >>> len(times)
    1
    """
    times: dict[str, float] = {}
    token = _RECORD.set(times)
    try:
        yield times
    finally:
        _RECORD.reset(token)
