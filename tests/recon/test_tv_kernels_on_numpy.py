"""tv's array-expression kernels (the GPU run's, `fpscan.service.recon.tv.kernels`) on NumPy against the
compiled ones the CPU runs: each kernel, then the whole solver loop with each set."""
from __future__ import annotations

import time

import numpy as np
import pytest

from fpscan.physics.forward import forward_points
from fpscan.service.recon.tv import fista, prox, stores
from fpscan.service.recon.tv.geometry import geometry_numbers
from fpscan.service.recon.tv.kernels import array_kernels
from fpscan.service.recon.tv.problem import Model, start_image, warm_start, working_record

XK = array_kernels(np)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))


@pytest.mark.parametrize("shape", [(12, 20), (8, 10, 12)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_each_kernel_matches_the_compiled_one(shape: tuple, dtype: type) -> None:
    rng = np.random.default_rng(0)
    v, gy, xn = (rng.standard_normal(shape).astype(dtype) for _ in range(3))
    b_last = rng.integers(-30000, 30000, v.size).astype(np.int16)
    args = (xn.ravel(), v.ravel(), gy.ravel(), 0.3, b_last, 1e-5)
    assert np.allclose(XK.moves(*args, 0.94), fista.moves(*args, 0.94), rtol=1e-9)
    m1, m2 = XK.store_move(*args, 2.0), stores.store_move(*args, 2.0)
    assert m1[1] == m2[1] and np.abs(m1[0].astype(int) - m2[0]).max() <= 1
    y1, y2 = xn.ravel().copy(), xn.ravel().copy()
    XK.extrapolate_fixed(y1, b_last, 1e-5)
    stores.extrapolate_fixed(y2, b_last, 1e-5)
    assert _rel(y1, y2) <= 1e-6
    a1, a2 = v.ravel().copy(), v.ravel().copy()
    XK.axpy(a1, gy.ravel(), -0.7)
    fista.axpy(a2, gy.ravel(), -0.7)
    assert _rel(a1, a2) <= 1e-6
    g1, g2 = XK.store_gradient(gy), stores.store_gradient(gy)
    assert g1[1] == g2[1] and np.abs(g1[0].astype(int) - g2[0]).max() <= 1
    assert XK.gain_lower_bound(v.ravel(), g2) == pytest.approx(stores.gain_lower_bound(v.ravel(), g2), rel=1e-6)
    assert XK.tv_norm(v) == pytest.approx(prox.tv_norm(v), rel=1e-5)


@pytest.mark.parametrize("shape", [(12, 20), (8, 10, 12)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("positivity, supported", [(True, False), (False, True)])
def test_the_proximal_map_matches_the_compiled_sweeps(shape: tuple, dtype: type, positivity: bool,
                                                       supported: bool) -> None:
    rng = np.random.default_rng(1)
    v = rng.standard_normal(shape).astype(dtype)
    support = rng.random(shape) > 0.3 if supported else None
    stored1: list = [None]
    stored2: list = [None]
    for _ in range(3):  # warm-started from the last call's stored dual, as the solver calls it
        x1, d1 = XK.tv_prox_stored(v, 0.2, positivity, support, stored1)
        x2, d2 = prox.tv_prox_stored(v, 0.2, positivity, support, stored2)
        stored1, stored2 = [d1], [d2]
        assert x1.dtype == x2.dtype and x1.shape == x2.shape and d1.dtype == d2.dtype
        assert _rel(x1, x2) <= 1e-4
        assert np.abs(d1.astype(np.float64) - d2.astype(np.float64)).max() <= 2 * (1 if d1.dtype == np.int16 else 1e-5)


@pytest.mark.parametrize("exact", [False, True], ids=["preconditioned", "exact phase"])
def test_the_solver_loop_gives_one_image_with_either_kernel_set(exact: bool) -> None:
    p0 = np.zeros((24, 40))
    p0[10:14, 15:22] = 1.0
    p0[17, 30] = 2.0
    x = (np.arange(40) - 19.5) * 1e-4
    pos = x[::2, None]
    al = forward_points(p0, positions=pos, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=60, c=1500.0)
    al = al + 0.02 * np.abs(al).max() * np.random.default_rng(2).standard_normal(al.shape)
    record = working_record(al, 1e-4 / 1500, 1500.0, None, pos, (x,), bandwidth=None, dz=1e-4, n_z=24, t0=0.0,
                     whole_record=True)
    warm, centred = warm_start(record, 1500.0, None, pos, None, (x,), dtype=np.float32, t0=0.0, eps=1e-6,
                                positivity=True, memory_limit=None, progress=None, device="cpu")
    model = Model(record, warm, 1500.0, centred, t0=0.0, eps=1e-6, dtype=np.dtype(np.float32), periodic=False,
                   checkpoint=None, memory_limit=None)
    gain, _, _ = geometry_numbers(model, lambda fraction: None)
    images = []
    n = 80 if exact else 40
    for kernels in (None, XK):
        solved = fista.run_fista(model.forward, model.B, record.g, [start_image(warm, np.dtype(np.float32), True)],
                              0.05 * gain, fista.MARGIN * gain, True, n, 0.0, time.monotonic(), 3600.0, None,
                              model.residual, kernels=kernels, precondition=model.precondition if exact else None)
        assert solved.iterations == n and (solved.exact_from is not None) == exact, solved.exact_from
        images.append(solved.x)
    cc = float(np.corrcoef(images[0].ravel(), images[1].ravel())[0, 1])
    assert cc >= 0.9999, cc
