"""Progress reporting of the reconstructions: strictly increasing fractions ending at 1,
and the same image whether or not a callback is given."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.service.recon import kspace_line_recon, kspace_plane_recon, reconstruct_grid, reconstruct_points


def _data(shape, seed=0):
    return np.random.default_rng(seed).standard_normal(shape)


def _check(fractions):
    assert len(fractions) >= 5, fractions
    assert all(b > a for a, b in zip(fractions, fractions[1:])), fractions
    assert 0 < fractions[0] and fractions[-1] == pytest.approx(1.0)


@pytest.mark.parametrize("method", ["ner", "linear"])
@pytest.mark.parametrize("shape", [(40, 24), (40, 12, 10)])
def test_grid_progress(method, shape):
    data = _data(shape)
    seen: list[float] = []
    with_cb = reconstruct_grid(data, 1e-4, 2e-8, method=method, progress=seen.append)
    _check(seen)
    np.testing.assert_array_equal(with_cb.p0, reconstruct_grid(data, 1e-4, 2e-8, method=method).p0)


@pytest.mark.parametrize("d", [1, 2])
def test_points_progress(d):
    rng = np.random.default_rng(1)
    n = 30
    pos = rng.uniform(-5e-4, 5e-4, (n, d))
    alines = rng.standard_normal((n, 32))
    seen: list[float] = []
    with_cb = reconstruct_points(alines, pos, 2e-8, progress=seen.append)
    _check(seen)
    np.testing.assert_array_equal(with_cb.p0, reconstruct_points(alines, pos, 2e-8).p0)


def test_kwave_progress():
    seen: list[float] = []
    data = _data((20, 16))
    out = kspace_line_recon(data, 1e-4, 2e-8, 1500.0, progress=seen.append)
    assert seen and all(b > a for a, b in zip(seen, seen[1:])) and seen[-1] == 1.0
    np.testing.assert_array_equal(out, kspace_line_recon(data, 1e-4, 2e-8, 1500.0))
    seen.clear()
    kspace_plane_recon(_data((12, 6, 5)), 1e-4, 1e-4, 2e-8, 1500.0, progress=seen.append)
    assert seen and seen[-1] == 1.0


def test_float32_nedner_without_finufft_warnings(capfd):
    """FINUFFT prints "ns reducing ... catastrophic cancellation" to stderr (and warns)
    when asked for a tolerance single precision cannot honour; none may appear."""
    import warnings

    rng = np.random.default_rng(2)
    pos = rng.uniform(-1e-3, 1e-3, (150, 2))
    alines = rng.standard_normal((150, 48))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f32 = reconstruct_points(alines, pos, 2e-8, dtype=np.float32, eps=1e-6)
    err = capfd.readouterr().err
    assert "ns reducing" not in err and "catastrophic" not in err, err
    f64 = reconstruct_points(alines, pos, 2e-8, eps=1e-6)
    rel = np.linalg.norm(f32.p0 - f64.p0) / np.linalg.norm(f64.p0)
    assert rel < 1e-4, rel
