"""Fixtures for the storage tests: real scan files written with fpscan.driver.scanfile."""
from __future__ import annotations

import pytest

from fpscan.driver.scanfile import ScanFile
from tests.storage.storage_helpers import meta, samples


@pytest.fixture
def make_scan(tmp_path):
    """``make_scan(name, plan, points=None)`` writes a scan file holding ``points`` (default:
    all) and returns its path."""
    def make(name: str, plan: dict, points=None):
        path = tmp_path / name
        n, n_t = len(plan["points"]["indices"]), plan["acquisition"]["n_t"]
        with ScanFile.create(path, plan, instrument={"idn": "fpscan,simFP,42,1.0"},
                             software_version="test") as sf:
            for k in (range(n) if points is None else points):
                sf.append(int(k), samples(int(k), n_t), meta(int(k)))
        return path
    return make
