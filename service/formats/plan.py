"""Plan (JSON text, :mod:`fpscan.driver.plan`): what the scanner acquires → the checked plan
dict (``fpscan.driver.plan.load_plan``). Not data to reconstruct: scan it first.

:func:`read_plan` is the plan loader of the library (``fpscan.load_plan``) and the CLI:
``fpscan.driver.plan.load_plan`` with a file of another format named by the registry ("this is
a scan file, not a plan": :func:`not_a_plan`).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from fpscan.service.formats.registry import Format, Source, describe

__all__ = ["FORMAT", "sniff", "load", "read_plan", "not_a_plan"]


def not_a_plan(source: Any) -> str | None:
    """The message for a file of another format given as a plan.

    ``"<source>: this is a scan file, not a plan (...)"`` when ``source`` names a file of
    another format (:func:`fpscan.service.formats.describe`).

    Parameters
    ----------
    source : object
        What was given as a plan: a path, JSON text or a dict.

    Returns
    -------
    str or None
        The message; None for a plan file, a file of no known format, JSON text, a dict or a
        missing file.
    """
    if not isinstance(source, (str, os.PathLike)) or str(source).lstrip().startswith("{") \
            or not Path(source).is_file():
        return None
    what = describe(source, unless=("plan",))
    return f"{source}: this is {what}, not a plan (a plan is the JSON that `fpscan plan` writes)" if what else None


def read_plan(source: Any) -> dict:
    """Read and check a plan: a path to plan JSON, a JSON string or a parsed dict
    (``fpscan.driver.plan.load_plan``).

    Parameters
    ----------
    source : str, os.PathLike or dict
        A path to plan JSON, a JSON string or a parsed dict.

    Returns
    -------
    dict
        The checked plan.

    Raises
    ------
    ValueError
        Naming the first problem, and for a file of another format what it is
        (:func:`not_a_plan`).
    OSError
        The file cannot be read.

    Examples
    --------
    >>> read_plan("{not json")
    Traceback (most recent call last):
    ...
    ValueError: plan is not valid JSON: Expecting property name enclosed in double quotes: line 1 column 2 (char 1)
    """
    from fpscan.driver.plan import load_plan

    try:
        return load_plan(source)
    except ValueError:
        named = not_a_plan(source)
        if named is None:
            raise
        raise ValueError(named) from None


def sniff(source: Source) -> bool:
    """True for a file whose first non-blank character is ``{`` (JSON object text).

    Parameters
    ----------
    source : Source
        The opened file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.head.lstrip().startswith(b"{")


def load(source: Source, **_: Any) -> dict:
    """The plan, checked (``fpscan.driver.plan.load_plan``).

    Parameters
    ----------
    source : Source
        The opened file (``source.fh``).
    **_
        Other loading options, ignored.

    Returns
    -------
    dict
        The checked plan.

    Raises
    ------
    ValueError
        Naming the first problem: not UTF-8 JSON, or what ``fpscan.driver.plan.check_plan`` refuses.
    """
    from fpscan.driver.plan import load_plan

    assert source.fh is not None
    try:
        plan = json.loads(source.fh.read().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"plan is not valid JSON: {exc}") from None
    return load_plan(plan)


FORMAT = Format(rank=90, name="plan", title="fpscan plan (JSON)", container="file", sniff=sniff, load=load, order=20,
                noun="a plan (JSON)",
                refuse="this is a plan (JSON), not data to reconstruct: scan it first (`fpscan scan --plan ...`) "
                       "and reconstruct the scan file")
