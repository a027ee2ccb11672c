"""The progress bar of library calls in a Jupyter notebook.

:func:`fpscan.service.pipeline.reconstruct` called without a ``progress`` callback in a Jupyter
kernel (IPython's ``ZMQInteractiveShell``) shows one bar in the cell's output, updated in
place (IPython's ``display(..., display_id=True)`` and ``update``, the mechanism tqdm's and
rich's notebook bars build on, here without ipywidgets): an HTML ``<progress>`` element with
the stage (an iterative method's stopping rule against its tolerance, ``fpscan.service.progress``),
the percentage and the time left, and a plain-text form for consoles and saved notebooks. It
ends on how the work ended. Outside a notebook, with a callback, or with ``quiet=True``
nothing is shown. IPython is imported only inside a notebook, where it is already loaded.

The HTTP client's waits (``Client.wait``, ``AsyncClient.wait``) draw the same bar from the
progress the server sends (``fpscan.clients.http.notebook``): the client never imports ``service``
(the import contracts in ``pyproject.toml``), so it has its own copy of the drawing; a change
to the bar's look is made in both.
"""
from __future__ import annotations

import html
import sys
import time
from typing import Any

from fpscan.service.progress import Eta, describe_iteration, iteration_fields, parse_iteration

__all__ = ["in_notebook", "NotebookBar", "notebook_bar"]

#: the shortest time between two redraws of a bar, s (the last report is always drawn)
REDRAW_S = 0.2


def in_notebook() -> bool:
    """Whether this process is a Jupyter kernel (IPython's ``ZMQInteractiveShell``).

    Returns
    -------
    bool
        True in a Jupyter notebook (or JupyterLab, VS Code's notebooks); False in a terminal's
        IPython, a script or a server worker.
    """
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython()
    return shell is not None and type(shell).__name__ == "ZMQInteractiveShell"


class NotebookBar:
    """One progress bar in a notebook cell's output, a ``fpscan.service.progress.Progress``:
    ``bar(fraction, stage)`` redraws it (at most every :data:`REDRAW_S` s), :meth:`close`
    draws its end.

    Parameters
    ----------
    label : str
        What the bar is of (``"nedner"``).
    """

    def __init__(self, label: str) -> None:
        from IPython.display import display

        self.label = label
        self._eta = Eta()
        self._drawn_at = 0.0
        self._last: tuple[float, str, float | None] = (0.0, "starting", None)
        self._handle = display(self._bundle(0.0, "starting", None), raw=True, display_id=True)

    def _bundle(self, fraction: float, text: str, eta_s: float | None) -> dict[str, str]:
        """The display's MIME bundle: HTML with a ``<progress>`` element, and plain text."""
        pct = f"{100 * fraction:.0f}%"
        left = "" if eta_s is None else f", about {eta_s:.0f} s left"
        plain = f"{self.label}: {text}  {pct}{left}"
        bar = (f'<progress value="{fraction:.4f}" max="1" style="width: 24em"></progress> '
               f"<code>{html.escape(self.label)}: {html.escape(text)}  {pct}{html.escape(left)}</code>")
        return {"text/plain": plain, "text/html": bar}

    def __call__(self, fraction: float, stage: Any = None) -> None:
        f = min(max(float(fraction), 0.0), 1.0)
        stage = stage if stage is not None else "reconstructing"
        it = parse_iteration(stage)
        text = (describe_iteration(iteration_fields(it)) or str(stage)) if it is not None else str(stage)
        eta_s = self._eta(f, stage)
        self._last = (f, text, eta_s)
        now = time.monotonic()
        if now - self._drawn_at >= REDRAW_S or f >= 1.0:
            self._drawn_at = now
            self._handle.update(self._bundle(f, text, eta_s), raw=True)

    def close(self, ended: str | None = None) -> None:
        """Draw the bar's end: at 100 % with ``ended`` (how the work ended), or, without it
        (the work raised), where it stopped.

        Parameters
        ----------
        ended : str, optional
            The final text (``"done"``, an iterative method's outcome).
        """
        f, text, _ = self._last
        self._handle.update(self._bundle(1.0, ended, None) if ended is not None
                            else self._bundle(f, f"stopped at {text}", None), raw=True)


def notebook_bar(label: str) -> NotebookBar | None:
    """A :class:`NotebookBar` where this process is a Jupyter kernel (:func:`in_notebook`),
    else None.

    Parameters
    ----------
    label : str
        What the bar is of.

    Returns
    -------
    NotebookBar or None
        The bar, shown in the running cell's output; None outside a notebook.
    """
    return NotebookBar(label) if in_notebook() else None
