"""The model-based solver's TV part and its set-up cost: the compiled kernels
against independent oracles, their memory (numpy's allocations, traced), and the operator
pairs spent before the first iteration.

- the proximal map's compiled sweeps against the same dual gradient projection written with
  numpy's ``np.diff`` (`_numpy_prox`), and against the adjoint identity ⟨∇x, q⟩ = ⟨x, ∇ᵀq⟩;
- `tv_norm` against the whole-volume formula;
- `tv_prox` (warm-started dual) against the closed form of 1-D TV denoising of a step,
  with and without positivity; its traced peak: no image of work with the dual given (it is
  stepped in place), one for a new x;
- a tv run spends 3 operator pairs before its first iteration (two power steps, the noise
  image, A of the warm start; no separate Aᵀg), half of one on a geometry it has seen (the
  same image as a fresh process), and the default rule converges before its
  iteration limit on the 2-D and the 3-D balls of tests/recon/test_recon_tv_solver.py (the
  vessels are tested there).
"""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from fpscan.service.recon.tv import fista, geometry, preconditioner, prox, stores
from tests.recon.test_recon_tv_solver import make_case, run_tv


def _diff_oracle(x: np.ndarray, a: int) -> np.ndarray:
    """Forward difference along axis a, 0 at the last index (np.diff with the last value appended)."""
    return np.diff(x, axis=a, append=np.take(x, [-1], axis=a))


def _grad(x: np.ndarray) -> np.ndarray:
    return np.stack([_diff_oracle(x, a) for a in range(x.ndim)])


def _grad_t(q: np.ndarray) -> np.ndarray:
    """−div q: the transpose of `_grad` (differences of q with 0 before the first index and
    after the last, along each axis)."""
    out = np.zeros(q.shape[1:], dtype=np.float64)
    for a in range(q.shape[0]):
        qa = np.moveaxis(q[a].astype(np.float64), a, 0)
        t = np.zeros_like(qa)
        t[:-1] -= qa[:-1]
        t[1:] += qa[:-1]
        out += np.moveaxis(t, 0, a)
    return out


def _numpy_prox(v, gamma, positivity, support, dual, inner):
    """Gradient projection on the dual (Chambolle 2005), whole arrays at a time, in float64
    numpy (the oracle)."""
    def project(x):
        x = np.maximum(x, 0) if positivity else x
        return np.where(support, x, 0) if support is not None else x

    q, step = dual.astype(np.float64), 1.0 / (4.0 * v.ndim * gamma)
    for _ in range(inner):
        w = project(v - gamma * _grad_t(q))
        q = q + step * _grad(w)
        q /= np.maximum(1.0, np.sqrt(np.sum(q * q, axis=0)))
    return project(v - gamma * _grad_t(q)), q


@pytest.mark.parametrize("shape", [(7, 9), (6, 5, 8), (1, 5, 4), (9, 1)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_transpose_is_the_adjoint_of_the_differences(shape, dtype):
    """With γ = 1 and no projection, the primal sweep gives v − ∇ᵀq: ⟨∇x, q⟩ = ⟨x, ∇ᵀq⟩."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal(shape).astype(dtype)
    q = rng.standard_normal((len(shape),) + shape).astype(dtype)
    out = np.full(shape, np.nan, dtype=dtype)  # every element written
    zero = np.zeros(shape, dtype=dtype)
    prox.primal_step(zero, q, 1.0, out=out)
    gt = -out.astype(np.float64)
    np.testing.assert_allclose(gt, _grad_t(q), rtol=0, atol=1e-5 if dtype == np.float32 else 1e-12)
    lhs = float(np.vdot(_grad(x).astype(np.float64), q.astype(np.float64)))
    rhs = float(np.vdot(x.astype(np.float64), gt))
    assert abs(lhs - rhs) <= (1e-5 if dtype == np.float32 else 1e-12) * np.sqrt(x.size) * 4


@pytest.mark.parametrize("shape", [(12, 15), (6, 7, 8), (5, 1, 6)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize(("positivity", "with_support"), [(False, False), (True, False), (True, True)])
def test_the_compiled_proximal_map_is_the_numpy_algorithm(shape, dtype, positivity, with_support):
    rng = np.random.default_rng(4)
    v = rng.standard_normal(shape)
    dual = np.clip(rng.standard_normal((len(shape),) + shape) * 0.3, -0.5, 0.5)
    support = rng.random(shape) > 0.3 if with_support else None
    want, want_dual = _numpy_prox(v, 0.3, positivity, support, dual, prox.PROX_ITER)
    got, got_dual = prox.tv_prox(v.astype(dtype), 0.3, positivity, support, dual.astype(dtype))
    tol = 2e-5 if dtype == np.float32 else 1e-12
    assert got.dtype == dtype and got_dual.dtype == dtype
    np.testing.assert_allclose(got, want, rtol=0, atol=tol)
    np.testing.assert_allclose(got_dual, want_dual, rtol=0, atol=tol)


@pytest.mark.parametrize("shape", [(9, 4, 5), (11, 6), (1, 5, 4), (7, 1)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_tv_norm_is_the_whole_volume_formula(shape, dtype):
    x = np.random.default_rng(1).standard_normal(shape).astype(dtype)
    squares = sum(_diff_oracle(x, a).astype(np.float64) ** 2 for a in range(x.ndim))
    assert prox.tv_norm(x) == pytest.approx(float(np.sum(np.sqrt(squares))), rel=1e-12)


@pytest.mark.parametrize("positivity", [False, True])
def test_tv_prox_is_the_closed_form_of_a_denoised_step(positivity):
    """½‖x − v‖² + γ TV(x) for a step of a low and b high samples along axis 0 (the other axis
    of length 1): for small γ the two levels move towards each other by γ/a and γ/b."""
    a, b, low, high, gamma = 12, 20, -0.5, 2.0, 0.9
    v = np.r_[np.full(a, low), np.full(b, high)].reshape(-1, 1)
    x, dual = None, None
    # warm-started calls of `PROX_ITER` inner steps, 1600 in all (the momentum restarts at each
    # call, so shorter calls need more steps: at 5 a call, 800 left 3.4e-3, 1600 1.3e-4)
    for _ in range(1600 // prox.PROX_ITER):
        x, dual = prox.tv_prox(v.copy(), gamma, positivity, None, dual)
    expected = np.r_[np.full(a, max(low + gamma / a, 0.0) if positivity else low + gamma / a),
                     np.full(b, high - gamma / b)].reshape(-1, 1)
    if positivity:  # the low level clipped at 0: the high one still moves by γ/b
        assert np.all(x >= 0)
    np.testing.assert_allclose(x, expected, atol=1e-3)
    assert dual.shape == (2, a + b, 1) and np.all(np.abs(dual) <= 1 + 1e-12)


def test_tv_prox_keeps_to_the_support_and_works_in_place():
    rng = np.random.default_rng(2)
    v = rng.standard_normal((8, 9, 10)).astype(np.float32)
    support = rng.random(v.shape) > 0.5
    work = v.copy()
    x, dual = prox.tv_prox(work, 0.2, True, support, None)
    assert x is work and x.dtype == np.float32 and dual.dtype == np.float32
    assert np.all(x[~support] == 0) and np.all(x >= 0) and np.any(x > 0)
    # the proximal point beats v itself and 0 on its objective
    def objective(u):
        return 0.5 * float(np.sum((u.astype(np.float64) - v) ** 2)) + 0.2 * prox.tv_norm(u)
    assert objective(x) < objective(np.where(support, np.maximum(v, 0), 0)) and objective(x) < objective(0 * v)


def test_tv_prox_and_tv_norm_memory():
    """Traced numpy allocations: `tv_prox` with its dual given steps it in place and needs no
    image of work (the primal lives a few planes at a time: 12 planes, 0.19 of this 64-plane
    volume); ``in_place=False`` (the solver's call) one image more, the new x, and leaves v as
    it was with the in-place result; `tv_norm` none."""
    v = np.random.default_rng(3).standard_normal((64, 48, 48)).astype(np.float32)
    dual = np.random.default_rng(4).uniform(-0.5, 0.5, (3,) + v.shape).astype(np.float32)

    def traced_peak(call):
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        out = call()
        return tracemalloc.get_traced_memory()[1] - base, out

    tracemalloc.start()
    try:
        work, d1 = v.copy(), dual.copy()
        in_place_peak, (x1, _) = traced_peak(lambda: prox.tv_prox(work, 0.1, True, None, d1))
        d2 = dual.copy()
        new_peak, (x2, _) = traced_peak(lambda: prox.tv_prox(v, 0.1, True, None, d2, in_place=False))
        norm_peak, _ = traced_peak(lambda: prox.tv_norm(v))
    finally:
        tracemalloc.stop()
    assert x1 is work and x2 is not v
    np.testing.assert_array_equal(x2, x1)
    np.testing.assert_array_equal(d2, d1)  # both duals stepped in place alike
    assert not np.array_equal(v, x1)  # v kept (x1 overwrote its copy)
    assert in_place_peak < 0.25 * v.nbytes, in_place_peak / v.nbytes
    assert v.nbytes <= new_peak < 1.25 * v.nbytes, new_peak / v.nbytes
    assert norm_peak < 0.01 * v.nbytes, norm_peak


def test_three_operator_pairs_before_the_first_iteration_and_half_of_one_for_a_geometry_seen():
    """A new geometry: the power iterations (2 pairs), the noise image (an adjoint) and A of the
    warm start (a forward) before the first iteration. The same geometry again (a scan plan
    repeated): only A of the warm start, and the very image a fresh process makes."""
    case = make_case("vessels", 30)
    geometry.GEOMETRY.clear()
    for n, setup, kept in ((1, 3, False), (3, 0.5, True)):
        p = run_tv(case, max_iter=n, tol=0.0).params
        assert p["iterations"] == n and p["operator_pairs"] == n + setup and p["geometry_kept"] is kept, p
    again = run_tv(case, max_iter=3, tol=0.0).p0
    geometry.GEOMETRY.clear()
    fresh = run_tv(case, max_iter=3, tol=0.0)
    assert fresh.params["geometry_kept"] is False
    np.testing.assert_array_equal(again, fresh.p0)


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "dims"), [("balls", 2), ("balls", 3)])
def test_the_default_rule_converges_on_every_case(kind, dims):
    p = run_tv(make_case(kind, 30, dims)).params
    assert p["stop_reason"] == "converged" and p["iterations"] < p["max_iter"], p


def _dct2_matrix(n: int) -> np.ndarray:
    """The orthonormal DCT-II as a dense (n, n) matrix from its cosine formula (the oracle)."""
    k, m = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    q = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * m + 1) / (2 * n))
    q[0] /= np.sqrt(2.0)
    return q


@pytest.mark.parametrize("shape", [(11, 13), (7, 5, 6), (8, 10)])
def test_preconditioner_runs_on_fast_lengths_and_is_the_padded_dense_map(shape):
    """P (`ner_weight`) lives on the image zero-padded to fast real lengths (226 -> 240 at the
    paper's size), and `apply_weight` is crop(Qᵀ diag(k_z / |k|) Q pad(x)) with Q the
    orthonormal DCT-II of the padded grid, both built here from their formulas as dense
    matrices: symmetric and positive definite on the image. A grid already at fast lengths is
    not padded."""
    from fpscan.physics.fast_lengths import fast_length

    dx, dz = 60e-6, 12e-6
    P = preconditioner.ner_weight(shape, dx, dz)
    grid = tuple(fast_length(n, real=True) for n in shape)
    assert P.shape == grid
    if shape == (8, 10):
        assert grid == shape
    # the weight k_z / |k| on the padded DCT-II grid: k = π j / (N d), depth shifted by half a bin
    ks = [np.pi * (np.arange(n) + (0.5 if a == 0 else 0.0)) / (n * (dz if a == 0 else dx))
          for a, n in enumerate(grid)]
    kk = np.meshgrid(*ks, indexing="ij")
    D = (kk[0] / np.sqrt(sum(k * k for k in kk))).ravel()
    assert np.all(D > 0) and np.all(D <= 1)
    Q = np.ones((1, 1))
    for n in grid:
        Q = np.kron(Q, _dct2_matrix(n))
    pad = np.zeros(grid, bool)
    pad[tuple(slice(0, n) for n in shape)] = True
    C = np.eye(Q.shape[0])[pad.ravel()]  # (image voxels, padded voxels): the crop
    M = C @ Q.T @ (D[:, None] * Q) @ C.T
    np.testing.assert_allclose(M, M.T, atol=1e-12)
    assert np.linalg.eigvalsh(M).min() > 0
    x = np.random.default_rng(3).standard_normal(shape)
    np.testing.assert_allclose(preconditioner.apply_weight(P, x.copy()), (M @ x.ravel()).reshape(shape), atol=1e-12)
    x32 = x.astype(np.float32)
    got = preconditioner.apply_weight(P, x32)
    assert got.dtype == np.float32 and got.shape == shape
    np.testing.assert_allclose(got, (M @ x.ravel()).reshape(shape), atol=1e-5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_dual_waits_at_half_the_bytes_and_comes_back(dtype):
    """`store_dual` / `restore_dual` (the dual between FISTA's iterations): float32 as int16
    fixed point, round(q · 32767), float64 as float32; back to within half a step of the
    storage (numpy's own rounding is the oracle) and clipped at ±1 (a projected component
    may exceed 1 by rounding)."""
    rng = np.random.default_rng(5)
    q = rng.uniform(-1, 1, (3, 7, 8, 9)).astype(dtype)
    q[0, 0, 0, :3] = [1.0, -1.0, 0.0]
    q[1, 0, 0, 0] = np.nextafter(dtype(1), dtype(2))  # just above 1
    stored = stores.store_dual(q)
    assert stored.shape == q.shape and stored.itemsize * 2 == q.itemsize
    back = stores.restore_dual(stored, dtype)
    assert back.dtype == dtype and back.shape == q.shape
    if dtype == np.float32:
        assert stored.dtype == np.int16
        want = np.rint(np.clip(q.astype(np.float64), -1, 1) * 32767)
        assert np.max(np.abs(stored - want)) <= 1  # rounding ties may go either way
        np.testing.assert_allclose(back, np.clip(q, -1, 1), rtol=0, atol=0.5 / 32767 + 1e-7)
        assert stored[0, 0, 0, :3].tolist() == [32767, -32767, 0] and stored[1, 0, 0, 0] == 32767
    else:
        np.testing.assert_array_equal(stored, q.astype(np.float32))
        np.testing.assert_array_equal(back, q.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_last_gradient_waits_as_16_bits_and_its_gain_stays_a_lower_bound(dtype):
    """`store_gradient` keeps G(A y − g) for the next iteration's gain test as int16 with the
    quantum max|G| / 32767, each value within half a quantum (numpy's rounding is the
    oracle); `gain_lower_bound` never exceeds the true ‖G − G_prev‖ (the solver must not
    raise L on rounding) and falls short of it by at most the rounding's whole reach, q √N.
    A gradient of zeros is kept as zeros."""
    rng = np.random.default_rng(6)
    g_prev = (rng.standard_normal(5000) * np.exp(rng.uniform(-6, 3, 5000))).astype(dtype)  # a wide range
    values, quantum = stores.store_gradient(g_prev)
    assert values.dtype == np.int16 and values.shape == g_prev.shape
    assert quantum == pytest.approx(np.abs(g_prev.astype(np.float64)).max() / 32767, rel=1e-12)
    assert np.max(np.abs(values * quantum - g_prev)) <= 0.5 * quantum * (1 + 1e-6)
    reach = quantum * np.sqrt(g_prev.size)
    for size in (1e-6, 1e-3, 1.0):  # from below the rounding's reach to far above it
        g = (g_prev + size * np.abs(g_prev).max() * rng.standard_normal(g_prev.size)).astype(dtype)
        true = float(np.linalg.norm(g.astype(np.float64) - g_prev.astype(np.float64)))
        bound = stores.gain_lower_bound(g, (values, quantum))
        assert 0.0 <= bound <= true and bound >= true - reach, (size, bound, true, reach)
    zeros = np.zeros(10, dtype=dtype)
    values, quantum = stores.store_gradient(zeros)
    assert not values.any() and stores.gain_lower_bound(zeros + 1, (values, quantum)) == pytest.approx(
        np.sqrt(10) - 0.5 * np.sqrt(10) * (1 + 1e-6))


def test_the_last_move_waits_as_16_bits_and_x_is_read_back_from_y():
    """`moves` / `store_move` / `extrapolate_fixed` (FISTA keeps y and the last move b =
    x − x_prev as int16, not x): the sums against numpy in float64 (x = y − β q b_last, y =
    v + gy / L), the move within half a quantum of x_new − x, and y = x_new + β q round(b / q)
    read back as y − β q round(b / q) = x_new to float32's rounding."""
    rng = np.random.default_rng(7)
    n, inv_l, beta = 4000, 0.37, 0.94
    xn, v, gy = (rng.standard_normal(n).astype(np.float32) for _ in range(3))
    b_last = rng.integers(-32767, 32768, n).astype(np.int16)
    scale_last = 2e-5
    y = v.astype(np.float64) + inv_l * gy.astype(np.float64)
    x = y - scale_last * b_last
    a, b = xn - y, xn - x
    ab, aa, cc, bb, nn, top = fista.moves(xn, v, gy, inv_l, b_last, scale_last, beta)
    want = (a @ b, a @ a, (a + beta * b) @ (a + beta * b), b @ b, xn.astype(np.float64) @ xn, np.abs(b).max())
    np.testing.assert_allclose((ab, aa, cc, bb, nn, top), want, rtol=1e-9)
    values, quantum = stores.store_move(xn, v, gy, inv_l, b_last, scale_last, top)
    assert values.dtype == np.int16 and quantum == pytest.approx(top / 32767, rel=1e-12)
    assert np.max(np.abs(values * quantum - b)) <= 0.5 * quantum * (1 + 1e-6)
    y_new = xn.copy()
    stores.extrapolate_fixed(y_new, values, beta * quantum)
    np.testing.assert_allclose(y_new - beta * quantum * values.astype(np.float64), xn, rtol=0, atol=1e-6)
    np.testing.assert_allclose(y_new, xn + beta * b, rtol=0, atol=beta * quantum * 0.5 + 1e-6)
    values, quantum = stores.store_move(xn, v, gy, inv_l, b_last, scale_last, 0.0)  # no move: zeros, q = 0
    assert quantum == 0.0 and not values.any()
