"""The temporal NUFFT's kernel taps by Horner's rule match the ES kernel formula."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from fpscan.physics import nufft_kernels
from fpscan.physics.nufft import kernel_params, kernel_polynomials, make_grid


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-6, 1e-9, 1e-12, 1e-14])
def test_tap_polynomials_match_the_kernel_to_a_fraction_of_eps(eps):
    w, beta = kernel_params(eps)
    coef = kernel_polynomials(w, beta)
    assert coef.shape[0] == w
    x = np.linspace(0.0, 1.0, 2001, endpoint=False)  # offset of the first tap in [0, 1)
    for k in range(w):
        u = (x + k - 0.5 * w) * (2.0 / w)
        phi = np.exp(beta * (np.sqrt(1.0 - u * u) - 1.0))  # the ES kernel itself
        approx = np.polyval(coef[k], 2.0 * x - 1.0)
        assert np.max(np.abs(approx - phi)) <= max(eps / 10, 1e-14), (k, np.max(np.abs(approx - phi)))


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-6, 1e-9, 1e-12])
@pytest.mark.parametrize("inversion", [True, False])
def test_compiled_taps_match_the_kernel_formula_and_numpy_trigonometry(eps, inversion):
    """`nufft_kernels.group_taps` (the Nyquist cut, Horner's rule four coefficients a pass,
    the phase's cosine and sine without libm) against the ES kernel
    formula and numpy's cos/sin, at every tap width's remainder of the pass length and at
    phases from 0 to ~5e3 rad."""
    n_t, c, dt, t0 = 3000, 1500.0, 1e-8, 3e-7  # samples, m/s, s, s
    grid = make_grid(n_t, "nufft", eps)
    w, h = grid.w, 2.0 * np.pi / grid.L
    kz = np.linspace(0.0, 1.2 * np.pi / (c * dt), 2049)  # rad/m, past the temporal Nyquist
    qw = np.linspace(0.5, 1.5, kz.size)
    for k2 in (0.0, (0.3 * np.pi / (c * dt)) ** 2):  # rad²/m²: phases from 0, and large ones
        base, wts, t, ar, ai = nufft_kernels.tap_arrays(kz.size, w)
        nj = nufft_kernels.group_taps(k2, kz, qw, c, dt, t0, h, 0, w, grid.horner, grid.shift, inversion,
                                      base, wts, t, ar, ai)
        om = c * np.sqrt(k2 + kz**2)
        th = om * dt
        expect_nj = int(np.count_nonzero(th <= np.pi * (1.0 + 1e-12))) if inversion else kz.size
        assert nj == expect_nj and (nj < kz.size) == inversion
        th, om, s = th[:nj], om[:nj], th[:nj] / h
        x = 0.5 * (t[:nj] + 1.0)  # the first tap's offset in [0, 1), as the compiled code took it
        assert np.all((x >= -1e-9) & (x < 1.0 + 1e-9))
        assert np.max(np.abs(x - (base[:nj] - s + 0.5 * w))) <= 1e-9  # base = ceil(s - w/2), to rounding
        u = x[None, :] + np.arange(w)[:, None] - 0.5 * w  # tap offsets from the point, in fine-grid steps
        phi = np.exp(grid.beta * (np.sqrt(np.clip(1.0 - (2.0 * u / w) ** 2, 0.0, None)) - 1.0))
        assert np.max(np.abs(wts[:w, :nj] - phi)) <= max(eps / 10, 1e-13)
        assert not np.any(wts[w:])  # the rows a fixed-count read pads with weigh nothing
        # k_z / omega, with its limit 1/c at omega = 0
        sc = qw[:nj] * np.where(om > 0, kz[:nj] / np.where(om > 0, om, 1.0), 1.0 / c) if inversion else qw[:nj]
        ph = grid.shift * th + om * t0
        assert np.min(ph) < 1e-9 if k2 == 0.0 else np.max(ph) > 4e3
        tol = np.abs(sc) * (4 * np.finfo(float).eps * ph + 1e-15)  # the phase's own rounding, per element
        assert np.all(np.abs(ar[:nj] - sc * np.cos(ph)) <= tol)
        assert np.all(np.abs(ai[:nj] - sc * np.sin(ph)) <= tol)


_KERNEL_RUN = r"""
import hashlib, json
import numpy as np
from fpscan.physics import nufft, nufft_kernels
from fpscan.physics.nufft_kernels import interp_kernel, spread_kernel
from fpscan.service.recon import reconstruct_grid
n_t, n, dx, dt, c = 256, 32, 60e-6, 8e-9, 1500.0
grid = nufft.make_grid(n_t, "nufft", 1e-6)
kx, ky = 2 * np.pi * np.fft.rfftfreq(n, dx), 2 * np.pi * np.fft.fftfreq(n, dx)
gv, gp, order = nufft.group_columns((ky[:, None] ** 2 + kx[None, :] ** 2).ravel())
kz = np.pi / (n_t * 2 * c * dt) * np.arange(n_t + 1)
U = np.random.default_rng(0).standard_normal((len(order), grid.L, 2)).view(complex)[..., 0]
out = np.empty((len(order), kz.size), complex)
args = (gv, gp, order, kz, np.ones(kz.size), c, dt, 3e-7, 2 * np.pi / grid.L, grid.L, 0, grid.w, grid.horner,
        grid.shift)
interp_kernel(U, *args, True, out)
R = np.empty_like(U)
spread_kernel(out, *args, R)
data = np.zeros((32, 64, 64), dtype=np.float32)  # above the small-transform size: the compiled kernels run
data[3, 2, 2] = 1.0
p0 = reconstruct_grid(data, 1e-4, 2e-8, dz=3e-5, dtype="float32").p0  # n_t rows of c dt
names = ("interp_kernel", "spread_kernel", "place_columns", "scatter_columns")
stats = {name: getattr(nufft_kernels, name).stats for name in names}
print(json.dumps({"bits": hashlib.sha256(out.tobytes() + R.tobytes() + p0.tobytes()).hexdigest(),
                  "cache": {name: [sum(s.cache_hits.values()), sum(s.cache_misses.values())]
                            for name, s in stats.items()}}))
"""


def test_kernels_compiled_afresh_are_cached_and_loaded_with_the_same_bits(tmp_path):
    """numba's cache (``cache=True``): a new installation compiles the kernels and writes the
    cache, the next interpreter loads them from it without compiling again (a job worker starts
    so), and both give the same result to the bit (the local and the server result compared
    exactly, `tests/service/test_recon_jobs.py`), including where a tap base sits on a rounding
    boundary. Here in a fresh ``NUMBA_CACHE_DIR``."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    first, second = (json.loads(subprocess.run([sys.executable, "-c", _KERNEL_RUN], capture_output=True, text=True,
                                                env=env, check=True, timeout=600).stdout.splitlines()[-1])
                     for _ in range(2))
    assert any(tmp_path.rglob("*.nbc")), "the first run wrote no cache"
    assert all(misses > 0 for _, misses in first["cache"].values()), first["cache"]
    assert all(hits > 0 and misses == 0 for hits, misses in second["cache"].values()), second["cache"]
    assert first["bits"] == second["bits"]
