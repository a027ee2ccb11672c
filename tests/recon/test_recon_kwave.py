"""k-Wave drop-ins against the stored Octave/k-Wave reconstructions."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.physics import fft_engine
from fpscan.service.recon import kspace_line_recon, kspace_plane_recon, kwave_dft, reconstruct_grid
from tests.recon import kwave_transcription as literal

INTERP = {"starlinear": "*linear", "nearest": "nearest", "cubic": "cubic"}


@pytest.fixture(scope="module")
def kwave2d(shared_data):
    with h5py.File(shared_data / "kwave2d_points.h5", "r") as f:
        recons = {name: f["recon/clean"][name][:] for name in f["recon/clean"]}
        return dict(data=f["sensor_data/clean"][:], dx=float(f.attrs["dx_m"]), dt=float(f.attrs["dt_s"]),
                    c=float(f.attrs["c_m_per_s"]), recons=recons)


@pytest.mark.parametrize("interp", ["starlinear", "nearest", "cubic"])
def test_kspace_line_recon_matches_kwave(kwave2d, interp):
    d = kwave2d
    out0 = kspace_line_recon(d["data"], d["dx"], d["dt"], d["c"], interp=INTERP[interp])
    out1 = kspace_line_recon(d["data"].T, d["dx"], d["dt"], d["c"], data_order="yt", interp=INTERP[interp], pos_cond=True)
    assert out0.shape == d["data"].shape
    for out, pc in ((out0, 0), (out1, 1)):
        ref = d["recons"][f"recon_{interp}_poscond{pc}"]
        err = np.abs(out[: ref.shape[0]] - ref).max() / np.abs(ref).max()
        assert err <= 1e-5, (interp, pc, err)


def test_kspace_plane_recon_reduces_to_line_recon_for_uniform_z():
    rng = np.random.default_rng(5)
    line = rng.standard_normal((40, 12))
    plane = np.repeat(line[:, :, None], 6, axis=2)
    for interp in ("*nearest", "linear", "cubic"):
        a = kspace_line_recon(line, 1e-4, 2e-8, 1500.0, interp=interp)
        b = kspace_plane_recon(plane, 1e-4, 1e-4, 2e-8, 1500.0, interp=interp)
        np.testing.assert_allclose(b, np.repeat(a[:, :, None], 6, axis=2), atol=1e-10 * np.abs(a).max())
    c = kspace_plane_recon(np.transpose(plane, (1, 2, 0)), 1e-4, 1e-4, 2e-8, 1500.0, data_order="yzt")
    np.testing.assert_allclose(c, kspace_plane_recon(plane, 1e-4, 1e-4, 2e-8, 1500.0))


def test_ner_agrees_with_kwave_where_interpolation_is_accurate(kwave2d):
    # same physics, same output grid (k-Wave's: n_t rows of c·dt): NER and k-Wave's linear mode agree on the targets
    d = kwave2d
    n_t = 1200
    ner = reconstruct_grid(d["data"][:n_t], d["dx"], d["dt"], d["c"], dz=d["c"] * d["dt"], n_z=n_t).p0[:854]
    kw = kspace_line_recon(d["data"][:n_t], d["dx"], d["dt"], d["c"], interp="*linear")[:854]
    cc = np.corrcoef(ner.ravel(), kw.ravel())[0, 1]
    assert cc > 0.8


# up to kwave_dft.MATRIX_MAX_N time samples the real-even transforms run as matrix products; above it by
# the prime-factor algorithm where 2 N - 1 has a coprime split (kwave_dft.PFA_MAX_SUM), else as FFTs
_BY_PFA = kwave_dft.MATRIX_MAX_N + 9  # 817 = 19·43
_BY_FFT = next(n for n in range(kwave_dft.MATRIX_MAX_N + 1, 2 * kwave_dft.MATRIX_MAX_N)
               if kwave_dft._coprime_split(2 * n - 1) is None)


@pytest.mark.parametrize("interp", ["*nearest", "*linear", "cubic"])
@pytest.mark.parametrize("shape", [(17, 10, 9), (16, 8, 12), (21, 7, 6), (33, 20), (30, 19), (_BY_FFT, 7, 6),
                                   (_BY_FFT, 12), (_BY_PFA, 7, 6), (_BY_PFA, 5, 37), (1024, 74)])
def test_kspace_recon_matches_literal_kwave_transcription(shape, interp):
    """The symmetric (rfft, half-spectrum, compiled) implementation gives the literal
    algorithm's numbers at odd and even sizes, 2-D and 3-D, with its time and depth
    transforms as matrix products, by the prime-factor algorithm (817 = 19·43; 2047 = 23·89,
    k-Wave's 1024 samples) and as FFTs (a prime 2 N - 1), and its lateral real DFT as a
    matrix product (37 and 74 = 2·37 columns, `kwave_dft.product_length`) or an FFT (the stored
    k-Wave data are 2-D with an even sensor count and 3519 samples only)."""
    assert kwave_dft._coprime_split(2 * _BY_PFA - 1) == (19, 43)
    assert kwave_dft.product_length(shape[-1]) == (shape[-1] in (37, 74))
    if kwave_dft.product_length(shape[-1]):  # large enough for the product (small arrays run in numpy.fft)
        assert np.prod(shape) > fft_engine.SMALL_ELEMENTS
    p = np.random.default_rng(5).standard_normal(shape)
    if len(shape) == 3:
        out = kspace_plane_recon(p, 1e-4, 1.2e-4, 2e-8, 1500.0, interp=interp, pos_cond=True)
        ref = literal.recon(p, 2e-8, 1500.0, (1e-4, 1.2e-4), interp, pos_cond=True)
    else:
        out = kspace_line_recon(p, 1e-4, 2e-8, 1500.0, interp=interp)
        ref = literal.recon(p, 2e-8, 1500.0, (1e-4,), interp)
    assert np.abs(out - ref).max() <= 1e-12 * np.abs(ref).max()


def test_kspace_line_recon_float32_matches_kwave(kwave2d):
    d = kwave2d
    out = kspace_line_recon(d["data"], d["dx"], d["dt"], d["c"], interp="*linear", dtype=np.float32)
    assert out.dtype == np.float32
    ref = d["recons"]["recon_starlinear_poscond0"]
    assert np.abs(out[: ref.shape[0]] - ref).max() / np.abs(ref).max() <= 1e-5


@pytest.mark.parametrize("n_t, n_x", [(64, 10), (_BY_FFT, 10), (_BY_PFA, 37)])
def test_kspace_plane_recon_float32_matches_float64(n_t, n_x):
    """float32 runs its products (sgemm), prime-factor stages, lateral products and FFTs in
    single precision: the relative error stays at the float32 level for each."""
    p = np.random.default_rng(7).standard_normal((n_t, 12, n_x))
    for interp in ("*linear", "*nearest"):
        ref = kspace_plane_recon(p, 1e-4, 1e-4, 2e-8, 1500.0, interp=interp)
        out = kspace_plane_recon(p.astype(np.float32), 1e-4, 1e-4, 2e-8, 1500.0, interp=interp, dtype=np.float32)
        assert out.dtype == np.float32
        assert np.abs(out - ref).max() <= 1e-5 * np.abs(ref).max(), interp


@pytest.mark.parametrize("parts", [1, 2, 3, 5])
@pytest.mark.parametrize(("k", "m", "step_rows"), [(38, 37, 4), (228, 226, 7), (12, 12, 3), (20, 11, 1000)])
def test_rows_product_written_over_its_input_equals_the_product(monkeypatch, parts, k, m, step_rows):
    """`kwave_dft._rows_over` (the lateral inverse's rows written over the spectrum) gives
    ``X @ C`` as computed into fresh memory, for row splits over 1-5 threads whose heads
    reach into the previous thread's rows, blocks of a few rows or all of them, and output
    rows as long as the input's (m = k) or much shorter."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(3)
    n_rows = 97
    X = rng.standard_normal((n_rows, k))
    C = rng.standard_normal((k, m))
    want = X @ C
    monkeypatch.setattr(kwave_dft, "_OVER_BYTES", step_rows * k * X.itemsize)
    out = X.reshape(-1)[: n_rows * m].reshape(n_rows, m)
    cuts = [n_rows * i // parts for i in range(parts + 1)]
    with ThreadPoolExecutor(parts) as pool:
        kwave_dft._rows_over(pool, C, X, out, cuts)
    assert np.shares_memory(out, X)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-12 * np.abs(want).max())
