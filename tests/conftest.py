"""Shared test fixtures: where the shared reference data lives."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FPSCAN_SHARED", REPO_ROOT.parent / "shared"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of k-Wave reference data (``$FPSCAN_SHARED/data``, by default in the folder
    ``shared`` beside the repository); skips if absent."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"shared reference data not found at {path} (set FPSCAN_SHARED)")
    return path


def _seconds(tests: list[pytest.Item]) -> float:
    """A test file's ``long`` mark (its measured wall time in s), 0 where it has none."""
    mark = tests[0].get_closest_marker("long")
    return float(mark.args[0]) if mark else 0.0


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Order the test files longest first (marked ``long``, by their seconds), then by their
    number of tests (pytest-xdist's own order), then as collected; a file's tests keep their order.

    scripts/test.sh hands the files to its workers in this order (``--dist loadfile
    --no-loadscope-reorder``): a long file started last would run on alone while the other
    workers sit idle, so the longest start first, as in longest-processing-time-first
    scheduling."""
    files: dict[str, list[pytest.Item]] = {}
    for item in items:
        files.setdefault(item.nodeid.split("::")[0], []).append(item)
    ordered = sorted(files.values(), key=lambda tests: (-_seconds(tests), -len(tests)))  # stable
    items[:] = [item for tests in ordered for item in tests]
