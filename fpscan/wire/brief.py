"""Short reprs for notebooks and logs: one line of at most :data:`REPR_MAX` characters that
says what an object is and its key sizes, ids and state, never its arrays or point lists;
and the small HTML table a notebook shows instead (``_repr_html_``).

Shared by every layer (the plan models, the HTTP wire models, the results): it imports
nothing of fpscan.
"""
from __future__ import annotations

import html
from collections.abc import Iterable
from typing import Any

__all__ = ["REPR_MAX", "brief", "one_line", "fields_repr", "html_table"]

#: the longest repr of a public object, characters
REPR_MAX = 200


def brief(value: Any, width: int = 40) -> str:
    """A value in a few characters: its repr when that is short and on one line, else what
    it is and its size (``[256 items]``, ``{3 keys}``, ``ndarray (64, 8) float32``).

    Parameters
    ----------
    value : any
        The value.
    width : int, optional
        The longest repr shown as it is (default 40 characters).

    Returns
    -------
    str
        One line of at most about ``width`` characters.

    Examples
    --------
    >>> from fpscan.wire.brief import brief
    >>> brief([1, 2]), brief(list(range(100))), brief({"a": "x" * 50})
    ('[1, 2]', '[100 items]', '{1 key}')
    """
    shape = getattr(value, "shape", None)
    if shape is not None and hasattr(value, "dtype"):  # an array: never its numbers
        return f"{type(value).__name__} {tuple(shape)} {value.dtype}"
    text = repr(value)
    if len(text) <= width and "\n" not in text:
        return text
    if isinstance(value, (list, tuple, set, frozenset)):
        n = len(value)
        return f"[{n} item{'s' if n != 1 else ''}]"
    if isinstance(value, dict):
        n = len(value)
        return f"{{{n} key{'s' if n != 1 else ''}}}"
    if isinstance(value, str):
        return repr(value[: max(width - 5, 1)] + "…")
    return type(value).__name__


def one_line(text: str, limit: int = REPR_MAX) -> str:
    """``text`` on one line of at most ``limit`` characters (newlines become spaces; a longer
    text is cut, ending in ``…)``).

    Parameters
    ----------
    text : str
        A repr.
    limit : int, optional
        The longest result (default :data:`REPR_MAX`).

    Returns
    -------
    str

    Examples
    --------
    >>> from fpscan.wire.brief import one_line
    >>> one_line("A(x=1," + chr(10) + "  y=2)")
    'A(x=1,   y=2)'
    >>> len(one_line("B(" + "x" * 300 + ")"))
    200
    """
    text = " ".join(text.splitlines())
    return text if len(text) <= limit else text[: limit - 2] + "…)"


def fields_repr(name: str, fields: Iterable[tuple[str, Any]], width: int = 40, *, skip_none: bool = True) -> str:
    """``name(field=value, ...)`` with each value :func:`brief` (values that are None left out
    unless ``skip_none`` is False), on one line of at most :data:`REPR_MAX` characters.

    Parameters
    ----------
    name : str
        The class's name.
    fields : iterable of (str, any)
        The fields and their values, in order.
    width : int, optional
        Of each value (:func:`brief`).
    skip_none : bool, optional
        Leave out the fields whose value is None (default True).

    Returns
    -------
    str

    Examples
    --------
    >>> from fpscan.wire.brief import fields_repr
    >>> fields_repr("Points", [("indices", [(0, 0)] * 64), ("note", None), ("n", 64)])
    'Points(indices=[64 items], n=64)'
    """
    parts = ", ".join(f"{k}={brief(v, width)}" for k, v in fields if v is not None or not skip_none)
    return one_line(f"{name}({parts})")


def html_table(title: str, rows: Iterable[tuple[str, Any]]) -> str:
    """A small HTML table of ``rows`` under a caption, for a notebook's ``_repr_html_``.

    Parameters
    ----------
    title : str
        The caption (escaped).
    rows : iterable of (str, any)
        Label and value of each row; values are shown by ``str`` (escaped); None rows left out.

    Returns
    -------
    str
        ``<table>`` HTML.

    Examples
    --------
    >>> from fpscan.wire.brief import html_table
    >>> html_table("Job j1", [("state", "running"), ("error", None)])
    '<table><caption>Job j1</caption><tr><th style="text-align:left">state</th><td style="text-align:left">running</td></tr></table>'
    """
    cells = "".join(f'<tr><th style="text-align:left">{html.escape(str(k))}</th>'
                    f'<td style="text-align:left">{html.escape(str(v))}</td></tr>'
                    for k, v in rows if v is not None)
    return f"<table><caption>{html.escape(title)}</caption>{cells}</table>"
