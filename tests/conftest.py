"""Shared test fixtures: where the shared reference data lives."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FPSCAN_SHARED", REPO_ROOT.parent / "shared"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of k-Wave reference data (``../shared/data``); skips if absent."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"shared reference data not found at {path} (set FPSCAN_SHARED)")
    return path


def _file_seconds(items: list[pytest.Item]) -> dict[str, float]:
    """Each test file's ``long`` mark (its measured wall time in s), 0 where it has none."""
    seconds: dict[str, float] = {}
    for item in items:
        mark = item.get_closest_marker("long")
        seconds[item.nodeid.split("::")[0]] = float(mark.args[0]) if mark else 0.0
    return seconds


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Order the test files longest first (marked ``long``, by their seconds), then by their
    number of tests (pytest-xdist's own order); a file's tests keep their order.

    scripts/test.sh hands the files to its workers in this order (``--dist loadfile
    --no-loadscope-reorder``): a long file started last would run on alone while the other
    workers sit idle (the two-minute stream test, which mostly waits, ran last and left a core
    idle for most of its 130 s), so the longest start first, as in longest-processing-time-first
    scheduling."""
    seconds = _file_seconds(items)
    counts: dict[str, int] = {}
    for item in items:
        path = item.nodeid.split("::")[0]
        counts[path] = counts.get(path, 0) + 1
    rank = {path: i for i, path in enumerate(counts)}  # collection order breaks ties

    def key(item: pytest.Item) -> tuple[float, int, int]:
        path = item.nodeid.split("::")[0]
        return -seconds[path], -counts[path], rank[path]

    items.sort(key=key)  # stable: a file's tests keep their order
