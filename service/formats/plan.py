"""Plan (JSON text, :mod:`driver.plan`): what the scanner acquires → the checked plan
dict (``driver.plan.load_plan``). Not data to reconstruct: scan it first.
"""
from __future__ import annotations

import json
from typing import Any

from service.formats._registry import Format, Source

__all__ = ["FORMAT", "sniff", "load"]


def sniff(source: Source) -> bool:
    """True for a file whose first non-blank character is ``{`` (JSON object text)."""
    return source.head.lstrip().startswith(b"{")


def load(source: Source, **_: Any) -> dict:
    """The plan, checked (``driver.plan.check_plan``). Raises ValueError naming the
    first problem (not UTF-8 JSON, what ``check_plan`` refuses)."""
    from driver.plan import load_plan

    assert source.fh is not None
    try:
        plan = json.loads(source.fh.read().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"plan is not valid JSON: {exc}") from None
    return load_plan(plan)


FORMAT = Format(name="plan", title="fpscan plan (JSON)", container="file", sniff=sniff, load=load, order=20,
                noun="a plan (JSON)",
                refuse="this is a plan (JSON), not data to reconstruct: scan it first (`fpscan scan --plan ...`) "
                       "and reconstruct the scan file")
