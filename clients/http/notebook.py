"""A job's progress bar in a Jupyter notebook, for the HTTP client's waits.

:meth:`fpscan.clients.http.Client.wait` and :meth:`fpscan.clients.http.AsyncClient.wait` called without an
``on_progress`` callback in a Jupyter kernel (IPython's ``ZMQInteractiveShell``) show one bar
in the cell's output, updated in place (IPython's ``display(..., display_id=True)`` and
``update``, as ``fpscan.service.notebook``'s bar of the library's ``reconstruct``, and drawn the same
way: an HTML ``<progress>`` element and a plain-text form for consoles and saved notebooks).
It shows what the server sends in the job's progress (``stage``, an iterative method's
``iteration``/``iterations_max``/``stop_value``/``stop_tol``, ``fraction`` and ``eta_s``) and
ends on the job's final state (``succeeded``, ``failed: why``, ``cancelled``), or where the
wait stopped. Outside a notebook, with a callback, or with ``quiet=True`` nothing is shown.
IPython is imported only inside a notebook, where it is already loaded.

The HTTP client never imports ``service`` (the import contracts in ``pyproject.toml``), so
this module reads the job's progress fields itself rather than ``fpscan.service.progress``'s.
"""
from __future__ import annotations

import html
import sys
import time
from collections.abc import Mapping
from typing import Any

from fpscan.clients.http.calls import field_of, to_dict

__all__ = ["in_notebook", "describe", "JobBar", "job_bar", "REDRAW_S"]

#: the shortest time between two redraws of a bar, s (the job's end is always drawn)
REDRAW_S = 0.2


def in_notebook() -> bool:
    """Whether this process is a Jupyter kernel (IPython's ``ZMQInteractiveShell``).

    Returns
    -------
    bool
        True in a Jupyter notebook (or JupyterLab, VS Code's notebooks); False in a terminal's
        IPython or a script.

    Examples
    --------
    >>> from fpscan.clients.http.notebook import in_notebook
    >>> in_notebook()
    False
    """
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython()
    return shell is not None and type(shell).__name__ == "ZMQInteractiveShell"


def describe(progress: Mapping[str, Any]) -> str:
    """The text of one progress update: an iterative method's iteration and stopping rule
    (``"iteration 7/100, image change 0.021 (stops below 0.005)"``, as the CLI and the web
    page write it), else the stage.

    Parameters
    ----------
    progress : Mapping of str to object
        A job's progress fields (``stage``; ``iteration``, ``iterations_max``, ``stop_rule``,
        ``stop_value``, ``stop_tol``, ``stop_armed``, ``stop_armed_at`` and ``stop_waits_for``
        while a method iterates).

    Returns
    -------
    str

    Examples
    --------
    >>> from fpscan.clients.http.notebook import describe
    >>> describe({"stage": "acquiring"})
    'acquiring'
    >>> describe({"stage": "iteration 7/100", "iteration": 7, "iterations_max": 100,
    ...           "stop_rule": "image change", "stop_value": 0.021, "stop_tol": 0.005})
    'iteration 7/100, image change 0.021 (stops below 0.005)'
    >>> describe({"stage": "iteration 3/100", "iteration": 3, "iterations_max": 100, "stop_rule": "image change",
    ...           "stop_value": 0.2, "stop_tol": 0.005, "stop_armed": False, "stop_waits_for": "λ has settled"})
    'iteration 3/100, image change 0.2 (stops below 0.005 once λ has settled)'
    >>> describe({"stage": "iteration 3/100 (λ continuation 3/50)", "iteration": 3, "iterations_max": 100,
    ...           "stop_rule": "image change", "stop_value": 0.2, "stop_tol": 0.005, "stop_armed": False,
    ...           "stop_armed_at": 53, "stop_waits_for": "λ has settled"})
    'iteration 3/100, image change 0.2 (stops below 0.005 once λ has settled, from iteration 53)'
    """
    k, n = progress.get("iteration"), progress.get("iterations_max")
    if k is None or n is None:
        return str(progress.get("stage") or "running")
    text = f"iteration {k}/{n}"
    value, tol = progress.get("stop_value"), progress.get("stop_tol")
    if value is not None:
        text += f", {progress.get('stop_rule') or 'stopping rule'} {value:.2g}"
        if tol is not None:
            # what the rule waits for in its method's words (tv: "λ has settled"), as the server's line
            later = ""
            if not progress.get("stop_armed", True):
                later = f" once {progress.get('stop_waits_for') or 'armed'}"
                if progress.get("stop_armed_at") is not None:
                    later += f", from iteration {progress['stop_armed_at']}"
            text += f" (stops below {tol:.2g}{later})" if tol > 0 else " (tol 0: no early stop)"
    return text


def _label(job: Any) -> str:
    """What a job's bar is of: its method (or kind) and its id's first 8 characters."""
    params = field_of(job, "params") or {}
    what = (params.get("method") if isinstance(params, Mapping) else None) or field_of(job, "kind") or "job"
    return f"{what} (job {str(field_of(job, 'id') or '?')[:8]})"


class JobBar:
    """One job's progress bar in a notebook cell's output, an ``on_progress`` callback:
    ``bar(progress)`` redraws it (at most every :data:`REDRAW_S` s), :meth:`close` draws its
    end.

    Parameters
    ----------
    job : Job or dict
        The job's record when the wait began (its ``id``, ``kind``, ``params.method`` and
        ``progress`` label and start the bar).
    """

    def __init__(self, job: Any) -> None:
        from IPython.display import display

        self.label = _label(job)
        progress = to_dict(field_of(job, "progress")) or {}
        self._last: tuple[float, str, float | None] = self._read(progress)
        self._drawn_at = time.monotonic()
        self._handle = display(self._bundle(*self._last), raw=True, display_id=True)

    @staticmethod
    def _read(progress: Mapping[str, Any]) -> tuple[float, str, float | None]:
        """``(fraction in [0, 1], text, eta_s or None)`` of a progress update."""
        f = progress.get("fraction")
        fraction = min(max(float(f), 0.0), 1.0) if isinstance(f, (int, float)) else 0.0
        eta = progress.get("eta_s")
        return fraction, describe(progress), float(eta) if isinstance(eta, (int, float)) else None

    def _bundle(self, fraction: float, text: str, eta_s: float | None) -> dict[str, str]:
        """The display's MIME bundle: HTML with a ``<progress>`` element, and plain text."""
        pct = f"{100 * fraction:.0f}%"
        left = "" if eta_s is None else f", about {eta_s:.0f} s left"
        plain = f"{self.label}: {text}  {pct}{left}"
        bar = (f'<progress value="{fraction:.4f}" max="1" style="width: 24em"></progress> '
               f"<code>{html.escape(self.label)}: {html.escape(text)}  {pct}{html.escape(left)}</code>")
        return {"text/plain": plain, "text/html": bar}

    def __call__(self, progress: Mapping[str, Any]) -> None:
        self._last = self._read(progress)
        now = time.monotonic()
        if now - self._drawn_at >= REDRAW_S or self._last[0] >= 1.0:
            self._drawn_at = now
            self._handle.update(self._bundle(*self._last), raw=True)

    def close(self, job: Any = None) -> None:
        """Draw the bar's end: the job's final state (``succeeded`` at 100 %, ``failed: why``,
        ``cancelled``) or, without a job that ended (the wait timed out or raised), where it
        stopped.

        Parameters
        ----------
        job : Job or dict, optional
            The job's final record.
        """
        fraction, text, _ = self._last
        state = field_of(job, "state") if job is not None else None
        if state == "succeeded":
            end = self._bundle(1.0, "succeeded", None)
        elif state == "failed":
            end = self._bundle(fraction, f"failed: {field_of(job, 'error') or 'no reason given'}", None)
        elif state == "cancelled":
            end = self._bundle(fraction, "cancelled", None)
        else:
            end = self._bundle(fraction, f"stopped waiting at {text}", None)
        self._handle.update(end, raw=True)


def job_bar(job: Any, *, on_progress: Any = None, quiet: bool = False) -> JobBar | None:
    """A :class:`JobBar` for a wait on ``job`` where this process is a Jupyter kernel
    (:func:`in_notebook`) and the wait has neither a callback nor ``quiet``; else None.

    Parameters
    ----------
    job : Job or dict
        The job's record when the wait began.
    on_progress : callable, optional
        The wait's own callback (a bar only without one).
    quiet : bool, optional
        True: no bar.

    Returns
    -------
    JobBar or None
        The bar, shown in the running cell's output; None otherwise.

    Examples
    --------
    >>> from fpscan.clients.http.notebook import job_bar
    >>> job_bar({"id": "j1", "state": "running"}) is None  # not a notebook
    True
    """
    if on_progress is not None or quiet or not in_notebook():
        return None
    return JobBar(job)
