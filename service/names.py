"""The names a person reads for the quantities code names otherwise (``fpscan.constants``:
the speed of sound is ``c`` in code, ``sound_speed`` over HTTP, on the command line and in
files).

:func:`person_names` renames a job's stored and returned parameters (``params``, the
input's ``shape``, the ``result`` summary with its ``params_used`` and ``autofocus``) from
the code names to the person's; :func:`code_names` is its inverse, for the worker that
calls the library. Both accept either spelling, so a job stored by an older server (with
``c``) reads back as ``sound_speed``.

Examples
--------
>>> person_names({"params": {"c": 1500.0, "dz": 3e-5}, "result": {"autofocus": {"c_range": [1450, 1600]}}})
{'params': {'sound_speed': 1500.0, 'dz': 3e-05}, 'result': {'autofocus': {'sound_speed_range': [1450, 1600]}}}
>>> code_names({"sound_speed": "auto", "c_range": [1470, 1530]})
{'c': 'auto', 'c_range': [1470, 1530]}
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

__all__ = ["PERSON_NAMES", "person_names", "code_names", "renamed_words"]

#: code name → the name a person reads (HTTP fields, stored job parameters, CLI flags)
PERSON_NAMES: dict[str, str] = {"c": "sound_speed", "c_range": "sound_speed_range",
                                "c_values": "sound_speed_values"}
_CODE_NAMES = {v: k for k, v in PERSON_NAMES.items()}


def _renamed(obj: Any, names: dict[str, str]) -> Any:
    if isinstance(obj, dict):
        return {names.get(k, k): _renamed(v, names) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_renamed(v, names) for v in obj]
    return obj


def person_names(obj: Any) -> Any:
    """``obj`` (dicts and lists, nested) with every key of :data:`PERSON_NAMES` renamed to
    the person's name (``c`` → ``sound_speed``); other keys and all values unchanged. A
    new object; ``obj`` is not modified.

    Parameters
    ----------
    obj : object
        A JSON-like value: dicts and lists are walked, anything else is returned as is.

    Returns
    -------
    object
        A copy of ``obj`` (new dicts and lists) with the keys renamed.
    """
    return _renamed(obj, PERSON_NAMES)


def code_names(obj: Any) -> Any:
    """The inverse of :func:`person_names`: ``sound_speed`` → ``c`` (nested), for the
    library's keyword arguments. A new object.

    Parameters
    ----------
    obj : object
        A JSON-like value: dicts and lists are walked, anything else is returned as is.

    Returns
    -------
    object
        A copy of ``obj`` (new dicts and lists) with the person's names renamed to the code's.
    """
    return _renamed(obj, _CODE_NAMES)


def renamed_words(text: str, names: Mapping[str, str]) -> str:
    """``text`` (an error message naming options) with each option name of ``names`` that
    stands as a word of its own (not part of a longer name, not followed by ``=`` or a quote)
    replaced by the caller's word for it: the JSON field over HTTP (:data:`PERSON_NAMES`:
    ``c`` → ``sound_speed``), the flag on the command line (``lam`` → ``--lambda``).

    Parameters
    ----------
    text : str
        The message.
    names : Mapping[str, str]
        Option name → the word to show.

    Returns
    -------
    str
        The message reworded.

    Examples
    --------
    >>> renamed_words("method 'ner' takes no option lam (its options: c, eps, n_z)", {"c": "sound_speed"})
    "method 'ner' takes no option lam (its options: sound_speed, eps, n_z)"
    >>> renamed_words("c_range needs c='auto', got c=None", {"c": "--sound-speed", "c_range": "--sound-speed-range"})
    "--sound-speed-range needs c='auto', got c=None"
    """
    if not names:
        return text
    words = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    pattern = re.compile(rf"(?<![\w'\"=.-])({words})(?![\w'\"=-])")
    return pattern.sub(lambda m: names[m.group(1)], text)
