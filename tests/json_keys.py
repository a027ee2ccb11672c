"""Every key of a nested JSON value (dicts and lists): the tests that check which names
fpscan writes (a file's params, a job's stored record) look for old names with it."""
from __future__ import annotations


def all_keys(obj) -> set[str]:
    """The keys of every dict inside ``obj``, at any depth."""
    if isinstance(obj, dict):
        return set(obj) | set().union(*(all_keys(v) for v in obj.values()))
    if isinstance(obj, list):
        return set().union(*(all_keys(v) for v in obj))
    return set()
