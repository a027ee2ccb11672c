"""Fixtures of the reconstruction tests."""
from __future__ import annotations

import pytest

from fpscan.physics import fft_engine


@pytest.fixture(params=["numpy", "compiled"])
def engine(request, monkeypatch):
    """Run the test once with small transforms in numpy (the default for the sizes these
    tests use) and once with every transform in scipy.fft and the numba kernels (what a
    real-size reconstruction runs): `fpscan.physics.fft_engine.SMALL_ELEMENTS` set to 0."""
    if request.param == "compiled":
        monkeypatch.setattr(fft_engine, "SMALL_ELEMENTS", 0)
    return request.param
