"""NER's work arrays share memory: each step writes its result into memory an earlier step has
already written (`fpscan.service.recon.planar._reuse`), so that a reconstruction's peak is its fine
temporal grid and one spectrum, not those and two more arrays of the spectrum's size."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.fft

from fpscan.physics import fft_engine
from fpscan.service.recon import reconstruct_grid, reconstruct_points

PEAK_SCRIPT = r"""
import json, sys
import numpy as np
from fpscan.physics import nufft
from fpscan.service.recon import reconstruct_grid

def rss():
    with open("/proc/self/status") as fh:
        return {l.split(":")[0]: int(l.split()[1]) * 1024 for l in fh if l.startswith(("VmRSS", "VmHWM"))}

n_t, n = 512, 128
dtype = np.dtype(sys.argv[1])
data = np.random.default_rng(0).standard_normal((n_t, n, n)).astype(dtype)
args = (data, 1e-4, 1e-4 / 1500, 1500.0)
want = reconstruct_grid(*args, dtype=dtype).p0  # compiles and plans
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")
before = rss()["VmRSS"]
r = reconstruct_grid(*args, dtype=dtype)
peak = rss()["VmHWM"] - before
item = 2 * dtype.itemsize  # complex
spectrum = max(n_t, r.params["depth_rows"]) * n * (n // 2 + 1) * item
fine = n * (n // 2 + 1) * nufft.make_grid(n_t, "nufft", 1e-6).L * item
print(json.dumps({"peak": peak, "spectrum": spectrum, "fine": fine, "same": bool(np.array_equal(r.p0, want))}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc")
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_ner_peak_is_the_fine_grid_and_one_spectrum(dtype):
    """Peak RSS of NER at 512 x 128² above the RSS before, in a fresh interpreter: the fine
    grid and one spectrum (measured: float64 205 MB = 136 MB + 68 MB, float32 103 MB). With
    each step's result in fresh memory it was 273 MB in float64, a spectrum more."""
    r = subprocess.run([sys.executable, "-c", PEAK_SCRIPT, dtype], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["same"]
    assert m["peak"] < m["fine"] + 1.5 * m["spectrum"], m


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_slabs_do_not_change_the_image(dtype, monkeypatch):
    """The lateral transforms written slab by slab into the shared memory give the image that
    one slab gives, bit for bit (each line is transformed alone either way), on the grid
    (upsampled: the image then takes fresh memory) and at lattice sensors, and the image of
    the whole-array transforms to rounding."""
    rng = np.random.default_rng(4)
    data = rng.standard_normal((96, 20, 18)).astype(dtype)
    args = (data, 1e-4, 1e-4 / 1500, 1500.0)
    ix, iy = np.meshgrid(np.arange(0, 18, 3), np.arange(0, 20, 2))
    x, y = (np.arange(18) - 8.5) * 1e-4, (np.arange(20) - 9.5) * 1e-4
    pos = np.column_stack([x[ix.ravel()], y[iy.ravel()]])
    al = data[:, iy.ravel(), ix.ravel()].T.copy()
    whole = reconstruct_grid(*args, dtype=dtype, upsample=2).p0, reconstruct_points(
        al, pos, 1e-4 / 1500, 1500.0, grid=(x, y), dtype=dtype).p0
    monkeypatch.setattr(fft_engine, "SMALL_ELEMENTS", 0)
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", 1)  # one row a slab
    sliced = reconstruct_grid(*args, dtype=dtype, upsample=2).p0, reconstruct_points(
        al, pos, 1e-4 / 1500, 1500.0, grid=(x, y), dtype=dtype).p0
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", 1 << 40)  # one slab
    single = reconstruct_grid(*args, dtype=dtype, upsample=2).p0, reconstruct_points(
        al, pos, 1e-4 / 1500, 1500.0, grid=(x, y), dtype=dtype).p0
    for a, b, w in zip(sliced, single, whole):
        assert a.dtype == dtype and np.array_equal(a, b)
        tol = 1e-4 if dtype == np.float32 else 1e-10
        assert np.linalg.norm(a - w) <= tol * np.linalg.norm(w)


@pytest.mark.parametrize("slab_planes", [1, 3, 1000])
@pytest.mark.parametrize(("shape", "keep"), [((9, 16, 16), (13, 11)), ((6, 1, 20), (1, 17)), ((5, 12, 12), (12, 12))])
def test_the_inverse_lateral_fft_keeps_the_grid_asked_for(shape, keep, slab_planes, monkeypatch):
    """`irfft_lateral`'s ``keep`` (NER's crop of the padded transform grid to the grid asked
    for) against scipy.fft.irfftn's whole image cut the same way, written over the
    spectrum's own memory, a slab of planes at a time (one plane a slab: each slab's output
    overlaps spectrum planes it has just read)."""
    from fpscan.physics.lateral import irfft_lateral

    monkeypatch.setattr(fft_engine, "SMALL_ELEMENTS", 0)  # scipy.fft and its slabs, at any size
    image = np.random.default_rng(6).standard_normal(shape)
    K = scipy.fft.rfftn(image, axes=(1, 2))
    want = image[:, : keep[0], : keep[1]]
    monkeypatch.setattr(fft_engine, "SLAB_BYTES", slab_planes * keep[0] * keep[1] * image.itemsize)
    out = K.reshape(-1).view(np.float64)[: shape[0] * keep[0] * keep[1]].reshape(shape[0], *keep)
    got = irfft_lateral(K, shape[1:], out=out, keep=keep)
    assert got is out and np.shares_memory(got, K)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(image).max())
    with pytest.raises(ValueError, match="keep"):
        irfft_lateral(K, shape[1:], keep=(shape[1] + 1, 1))
