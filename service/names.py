"""Reading what an earlier release wrote: job records and files whose keys name the speed of
sound ``c`` (and ``c_range``, ``c_values``), which every part of fpscan now calls
``sound_speed`` (k-Wave's ``medium.sound_speed``; ``sound_speed_range``,
``sound_speed_values``).

:func:`current_names` renames those keys, nested, when a job record is read from the store
(``fpscan.service.jobs.store``) and when a result or unmixing file is read
(``fpscan.service.formats``); nothing new is written with them. Requests with the old names are
accepted for one release with a ``DeprecationWarning`` by the options models themselves
(``fpscan.service.recon.methods.options.DEPRECATED_NAMES``). :func:`renamed_words` shows the
option names of a message in the words of the caller's door (the command line's flags).

Examples
--------
>>> current_names({"params": {"c": 1500.0, "dz": 3e-5}, "result": {"autofocus": {"c_range": [1450, 1600]}}})
{'params': {'sound_speed': 1500.0, 'dz': 3e-05}, 'result': {'autofocus': {'sound_speed_range': [1450, 1600]}}}
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

__all__ = ["OLD_NAMES", "current_names", "renamed_words"]

#: an earlier release's key → today's, in stored job records and files (read only)
OLD_NAMES: dict[str, str] = {"c": "sound_speed", "c_range": "sound_speed_range", "c_values": "sound_speed_values"}


def current_names(obj: Any) -> Any:
    """``obj`` (dicts and lists, nested) with every key of :data:`OLD_NAMES` renamed to today's
    name (``c`` → ``sound_speed``); other keys and all values unchanged. A new object; ``obj`` is
    not modified.

    Parameters
    ----------
    obj : object
        A JSON-like value: dicts and lists are walked, anything else is returned as is.

    Returns
    -------
    object
        A copy of ``obj`` (new dicts and lists) with the keys renamed.
    """
    if isinstance(obj, dict):
        return {OLD_NAMES.get(k, k): current_names(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [current_names(v) for v in obj]
    return obj


def renamed_words(text: str, names: Mapping[str, str]) -> str:
    """``text`` (an error message naming options) with each option name of ``names`` that
    stands as a word of its own (not part of a longer name, not followed by ``=`` or a quote)
    replaced by the caller's word for it: the flag on the command line (``lam`` → ``--lam``).

    Parameters
    ----------
    text : str
        The message.
    names : Mapping[str, str]
        Option name -> the word to show.

    Returns
    -------
    str
        The message reworded.

    Examples
    --------
    >>> renamed_words("method 'ner' takes no option lam (its options: sound_speed, eps, n_z)",
    ...               {"sound_speed": "--sound-speed", "lam": "--lam"})
    "method 'ner' takes no option --lam (its options: --sound-speed, eps, n_z)"
    >>> renamed_words("sound_speed_range needs sound_speed='auto'", {"sound_speed_range": "--sound-speed-range"})
    "--sound-speed-range needs sound_speed='auto'"
    """
    if not names:
        return text
    words = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    pattern = re.compile(rf"(?<![\w'\"=.-])({words})(?![\w'\"=-])")
    return pattern.sub(lambda m: names[m.group(1)], text)
