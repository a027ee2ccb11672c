"""The FFT engine (`fpscan.physics.fft_engine`): numpy.fft for small arrays and scipy.fft
for the rest give the same transforms, against scipy.fft's own functions (the oracle) and,
for the DCT-I, against its defining cosine sum."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft

from fpscan.physics import fft_engine

rng = np.random.default_rng(5)


def _tol(dtype):
    return 2e-6 if np.dtype(dtype) in (np.float32, np.complex64) else 1e-12


def _close(got, want, dtype):
    assert got.shape == want.shape, (got.shape, want.shape)
    assert got.dtype == want.dtype, (got.dtype, want.dtype)
    assert np.linalg.norm(got - want) <= _tol(dtype) * np.linalg.norm(want)


def _data(shape, dtype):
    x = rng.standard_normal(shape)
    if np.dtype(dtype).kind == "c":
        x = x + 1j * rng.standard_normal(shape)
    return x.astype(dtype)


@pytest.mark.parametrize("n", [2, 3, 9, 16])
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.complex64, np.complex128])
@pytest.mark.usefixtures("engine")
def test_dct1_is_the_cosine_sum(n, dtype):
    x = _data((3, n, 4), dtype)
    j = np.arange(n)
    weight = np.where((j == 0) | (j == n - 1), 1.0, 2.0)
    basis = weight[None, :] * np.cos(np.pi * np.outer(j, j) / max(n - 1, 1))  # (k, j)
    want = np.einsum("kj,ajb->akb", basis, x.astype(np.complex128 if np.iscomplexobj(x) else np.float64))
    got = fft_engine.dct1(x.copy(), axis=1, overwrite_x=True)
    assert got.dtype == x.dtype and got.shape == x.shape
    assert np.linalg.norm(got - want) <= 10 * _tol(dtype) * np.linalg.norm(want)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(4, 6, 8), (5, 300, 250)])  # below and above SMALL_ELEMENTS
def test_rfft2_and_fft_are_scipys(dtype, shape):
    x = _data(shape, dtype)
    _close(fft_engine.rfft2(x, s=(shape[1] + 2, shape[2] - 1), axes=(1, 2)),
           scipy.fft.rfft2(x, s=(shape[1] + 2, shape[2] - 1), axes=(1, 2)), dtype)
    z = _data(shape, np.complex64 if dtype == np.float32 else np.complex128)
    _close(fft_engine.fft(z.copy(), axis=-1, overwrite_x=True), scipy.fft.fft(z, axis=-1), dtype)


def test_small_is_a_size_and_nothing_else():
    assert fft_engine.is_small(fft_engine.SMALL_ELEMENTS)
    assert not fft_engine.is_small(fft_engine.SMALL_ELEMENTS + 1)


@pytest.mark.usefixtures("engine")
def test_dct1_refuses_fewer_than_two_samples_on_either_path():
    with pytest.raises(ValueError, match="at least 2 samples"):
        fft_engine.dct1(np.ones((3, 1)), axis=1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(4, 6, 8), (9, 60, 50)])
@pytest.mark.parametrize("slab_rows", [1, 4, 100])  # one slab a row, a short last slab, one slab
@pytest.mark.usefixtures("engine")
def test_rfft2_and_irfft_write_into_out_slab_by_slab(dtype, shape, slab_rows, monkeypatch):
    """With ``out`` the transforms run slab by slab of leading rows into it: the same values
    as scipy.fft's whole-array transforms, in the array given."""
    x = _data(shape, dtype)
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", slab_rows * x[:1].nbytes)
    s = (shape[1] + 2, shape[2] + 3)  # zero-padded, as NER pads to fast lengths
    ctype = np.complex64 if dtype == np.float32 else np.complex128
    out = np.full((shape[0], s[0], s[1] // 2 + 1), np.nan, ctype)
    got = fft_engine.rfft2(x, s=s, axes=(1, 2), out=out)
    assert got is out
    _close(got, scipy.fft.rfft2(x, s=s, axes=(1, 2)), dtype)
    spectrum = got.copy()
    real = np.full((shape[0], s[0], s[1]), np.nan, dtype)
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", slab_rows * spectrum[:1].nbytes)
    assert fft_engine.irfft(got, s[1], 2, overwrite_x=True, out=real) is real
    _close(real, scipy.fft.irfft(spectrum, s[1], axis=2), dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("slab_rows", [1, 3, 100])  # one slab a row, a short last slab, one slab
@pytest.mark.usefixtures("engine")
def test_irfft_keeps_its_leading_samples_and_may_write_over_its_input(dtype, slab_rows, monkeypatch):
    """``keep``: scipy.fft's whole transform cut to its first samples (an image cropped to the
    grid asked for); with and without ``out``, and with ``out`` at the start of the
    spectrum's own memory (each slab is read whole before it is written)."""
    x = _data((9, 13, 11), np.complex64 if dtype == np.float32 else np.complex128)  # 20 samples' half spectrum
    want = scipy.fft.irfft(x, 20, axis=2)[:, :, :17]
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", slab_rows * x[:1].nbytes)
    _close(fft_engine.irfft(x.copy(), 20, 2, keep=17), want, dtype)
    work = x.copy()
    out = work.reshape(-1).view(dtype)[: 9 * 13 * 17].reshape(9, 13, 17)
    assert fft_engine.irfft(work, 20, 2, overwrite_x=True, out=out, keep=17) is out
    _close(out, want, dtype)
    for bad in (0, 21):
        with pytest.raises(ValueError, match="keep must be 1..20"):
            fft_engine.irfft(x, 20, 2, keep=bad)


@pytest.mark.usefixtures("engine")
def test_out_that_cannot_take_the_slabs_is_refused():
    x = _data((4, 6, 8), np.float64)
    for bad in (np.empty((3, 6, 5), complex), np.empty((4, 6, 10), complex)[:, :, ::2],
                np.empty((4, 6, 5), np.complex64), np.empty((4, 6, 4), complex)):
        with pytest.raises(ValueError, match="C-contiguous"):
            fft_engine.rfft2(x, axes=(1, 2), out=bad)
    with pytest.raises(ValueError, match="C-contiguous"):
        fft_engine.irfft(np.ones((4, 5), complex), 8, 1, out=np.empty((4, 8), np.float32))
    with pytest.raises(ValueError, match="untransformed leading axis"):
        fft_engine.rfft2(x, axes=(0, 2), out=np.empty((4, 6, 5), complex))
    with pytest.raises(ValueError, match="untransformed leading axis"):
        fft_engine.irfft(np.ones((5, 3), complex), 8, 0, out=np.empty((8, 3)))
