"""The in-place inverse lateral FFT (`fpscan.physics.lateral.irfft_lateral`) against scipy's
own ``irfftn`` (the oracle: the same transform, computed with its copy), and the temporal
interpolation's refusal of an inversion at descending kz."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft

from fpscan.physics import nufft
from fpscan.physics.lateral import irfft_lateral

# every test twice: small transforms in numpy, and everything in scipy.fft + numba (conftest)
pytestmark = pytest.mark.usefixtures("engine")


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize(("spectrum", "shape", "axes"), [
    ((5, 12, 7), (12, 12), (1, 2)),    # a volume (n_z, n_y, n_x//2+1)
    ((5, 9, 6), (9, 11), (1, 2)),      # odd lengths
    ((5, 1, 9), (1, 16), (1, 2)),      # a line held as (n_z, 1, n_xr)
    ((6, 9), (16,), (1,)),             # a line (n_z, n_xr)
    ((3, 8, 5, 4), (8, 5, 6), (1, 2, 3)),
])
def test_irfft_lateral_is_irfftn(dtype, spectrum, shape, axes):
    rng = np.random.default_rng(7)
    K = (rng.standard_normal(spectrum) + 1j * rng.standard_normal(spectrum)).astype(dtype)
    want = scipy.fft.irfftn(K, s=shape, axes=axes)
    got = irfft_lateral(K.copy(), shape, axes)
    assert got.shape == want.shape and got.dtype == want.dtype
    tol = 1e-5 if dtype == np.complex64 else 1e-12
    assert np.linalg.norm(got - want) <= tol * np.linalg.norm(want)


def test_irfft_lateral_keeps_its_input_when_asked():
    K = scipy.fft.rfft2(np.random.default_rng(1).standard_normal((4, 6, 8)), axes=(1, 2))
    before = K.copy()
    irfft_lateral(K, (6, 8), overwrite=False)
    assert np.array_equal(K, before)


def test_irfft_lateral_refuses_mismatched_axes():
    with pytest.raises(ValueError, match="same, non-zero length"):
        irfft_lateral(np.zeros((2, 3, 4), complex), (3, 6), (2,))


def test_inversion_refuses_descending_kz():
    grid = nufft.make_grid(16)
    U = nufft.to_fine_grid(np.ones((16, 2)), grid, t0_is_zero=True)
    with pytest.raises(ValueError, match="ascending"):
        nufft.evaluate(U, grid, np.zeros(2), np.array([2e5, 1e5, 0.0]), np.ones(3), 1500.0, 1e-8, 0.0,
                       inversion=True)


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_irfft_lateral_writes_into_out(dtype):
    rng = np.random.default_rng(3)
    K = (rng.standard_normal((5, 9, 6)) + 1j * rng.standard_normal((5, 9, 6))).astype(dtype)
    want = scipy.fft.irfftn(K, s=(9, 10), axes=(1, 2))
    out = np.full(want.shape, np.nan, want.dtype)
    assert irfft_lateral(K.copy(), (9, 10), out=out) is out
    tol = 1e-5 if dtype == np.complex64 else 1e-12
    assert np.linalg.norm(out - want) <= tol * np.linalg.norm(want)


def test_evaluate_writes_into_out_and_refuses_one_that_does_not_fit():
    grid = nufft.make_grid(16)
    a = np.random.default_rng(2).standard_normal((16, 3))
    U = nufft.to_fine_grid(a, grid, t0_is_zero=True)
    kz = np.array([0.0, 1e5, 2e5])
    args = (U, grid, np.array([0.0, 1e9, 4e9]), kz, np.ones(3), 1500.0, 1e-8, 0.0)
    want = nufft.evaluate(*args, inversion=True)
    out = np.full(want.shape, np.nan, want.dtype)
    assert nufft.evaluate(*args, inversion=True, out=out) is out
    assert np.array_equal(out, want)
    for bad in (np.empty((3, 4), want.dtype), np.empty((3, 3), np.complex64), np.empty((3, 6), want.dtype)[:, ::2]):
        with pytest.raises(ValueError, match="out must be"):
            nufft.evaluate(*args, inversion=True, out=bad)
