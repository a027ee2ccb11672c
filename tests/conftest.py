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
