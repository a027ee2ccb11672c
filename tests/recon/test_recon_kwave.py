"""k-Wave drop-ins against the stored Octave/k-Wave reconstructions."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from service.recon import kspace_line_recon, kspace_plane_recon, kwave, reconstruct_grid
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
    # same physics, same output grid: NER and k-Wave's linear mode agree on the targets
    d = kwave2d
    n_t = 1200
    ner = reconstruct_grid(d["data"][:n_t], d["dx"], d["dt"], d["c"]).p0[:854]
    kw = kspace_line_recon(d["data"][:n_t], d["dx"], d["dt"], d["c"], interp="*linear")[:854]
    cc = np.corrcoef(ner.ravel(), kw.ravel())[0, 1]
    assert cc > 0.8


# above kwave.MATRIX_MAX_N time samples the real-even transforms run as FFTs, up to it as products
_BY_FFT = kwave.MATRIX_MAX_N + 9


@pytest.mark.parametrize("interp", ["*nearest", "*linear", "cubic"])
@pytest.mark.parametrize("shape", [(17, 10, 9), (16, 8, 12), (21, 7, 6), (33, 20), (30, 19), (_BY_FFT, 7, 6), (_BY_FFT, 12)])
def test_kspace_recon_matches_literal_kwave_transcription(shape, interp):
    """The symmetric (rfft, half-spectrum, compiled) implementation gives the literal
    algorithm's numbers at odd and even sizes, 2-D and 3-D, with its time and depth
    transforms as matrix products and as FFTs (the stored k-Wave data are 2-D with an even
    sensor count and 3519 samples only)."""
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


@pytest.mark.parametrize("n_t", [64, _BY_FFT])
def test_kspace_plane_recon_float32_matches_float64(n_t):
    """float32 runs its products (sgemm) and FFTs in single precision: the relative error
    stays at the float32 level for both transforms."""
    p = np.random.default_rng(7).standard_normal((n_t, 12, 10))
    for interp in ("*linear", "*nearest"):
        ref = kspace_plane_recon(p, 1e-4, 1e-4, 2e-8, 1500.0, interp=interp)
        out = kspace_plane_recon(p.astype(np.float32), 1e-4, 1e-4, 2e-8, 1500.0, interp=interp, dtype=np.float32)
        assert out.dtype == np.float32
        assert np.abs(out - ref).max() <= 1e-5 * np.abs(ref).max(), interp
