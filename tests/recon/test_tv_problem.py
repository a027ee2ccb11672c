"""tv's problem in public (`fpscan.tv_problem`): the operator, data, warm start, grid and λ that
`fpscan.reconstruct(ds, "tv")` works on, handed to pylops and pyproximal.

Oracles: tv's own result on the same dataset (its λ, grid and axes, and its iterates' J through
`reconstruct_tv`'s callback), pylops' dot test of the operator, J summed independently (numpy
differences, pyproximal's L21 on pylops' gradient), and pyproximal's PrimalDual lowering J."""
from __future__ import annotations

import numpy as np
import pylops
import pyproximal
import pytest
from pylops.utils import dottest
from pyproximal.optimization.primaldual import PrimalDual

import fpscan
from fpscan.service.recon.checks import OptionError

pytestmark = pytest.mark.long(20)

C, PITCH, DT, N_T, N = 1500.0, 100e-6, 20e-9, 128, 20
BALLS = [fpscan.Ball(x=0.0, y=0.2e-3, z=0.9e-3, radius=0.25e-3, amplitude=1.0),
         fpscan.Ball(x=-0.6e-3, y=-0.4e-3, z=0.6e-3, radius=0.15e-3, amplitude=0.8)]


@pytest.fixture(scope="module")
def scan():
    """Two balls (exact A-lines) on a 20 × 20 lattice, noise 30 dB below the peak, an
    equi-steradian mask of 30 % of it."""
    lattice = fpscan.Lattice(N, N, PITCH)
    clean = fpscan.ball_alines(fpscan.make_mask("full", lattice).positions, BALLS, DT, N_T, C).T.reshape(N_T, N, N)
    noisy = clean + np.random.default_rng(0).standard_normal(clean.shape) * np.abs(clean).max() / 10 ** 1.5
    dense = fpscan.GridDataset(noisy, dx=PITCH, dt=DT, sound_speed=C)
    return fpscan.subsample(dense, fpscan.make_mask("equisteradian", lattice, depth=0.8e-3, n_points=120))


@pytest.fixture(scope="module")
def problem(scan):
    return fpscan.tv_problem(scan)


def _tv_by_numpy(p: np.ndarray) -> float:
    """Σ |∇p|₂ with forward differences, 0 across the last index of each axis."""
    grads = []
    for axis in range(p.ndim):
        d = np.diff(p.astype(np.float64), axis=axis)
        pad = [(0, 0)] * p.ndim
        pad[axis] = (0, 1)
        grads.append(np.pad(d, pad))
    return float(np.sqrt(sum(g * g for g in grads)).sum())


def test_the_problem_is_the_one_tv_solves(scan, problem):
    rec = fpscan.reconstruct(scan, "tv", max_iter=3, tol=0.0, quiet=True)
    p = rec.params
    assert isinstance(problem.operator, pylops.LinearOperator)
    assert problem.lam == p["lam"] > 0 and problem.params["lam_auto"] and problem.positivity
    assert problem.operator.dims == rec.p0.shape == problem.warm_start.shape
    assert problem.data.shape == (scan.alines.shape[0], p["operator_n_t"]) == tuple(problem.operator.dimsd)
    assert problem.grid.n_t == p["operator_n_t"] and problem.grid.band == p["band"]
    assert problem.grid.record_n_t == p["record_n_t"] and problem.grid.dz == pytest.approx(float(rec.z[1] - rec.z[0]))
    for ours, tvs in ((problem.z, rec.z), (problem.x, rec.x), (problem.y, rec.y)):
        np.testing.assert_allclose(ours, tvs)
    assert problem.operator.dtype == problem.warm_start.dtype == np.float32  # tv's default precision
    assert problem.warm_start.min() >= 0
    assert problem.params["warm_discrepancy"] == p["warm_discrepancy"]


def test_the_operator_and_its_adjoint_pass_pylops_dot_test(scan):
    pb = fpscan.tv_problem(scan, dtype="float64", eps=1e-12)  # the NUFFTs to 1e-12: the pair's own accuracy
    A = pb.operator
    assert A.dtype == np.float64 and dottest(A, A.shape[0], A.shape[1], rtol=1e-9)
    P = pb.preconditioner
    v = np.random.default_rng(1).standard_normal(P.shape[1])
    assert float(v @ P.matvec(v)) > 0 and dottest(P, P.shape[0], P.shape[1], rtol=1e-9)  # symmetric positive


def test_objective_is_J_summed_independently(problem):
    p = np.maximum(problem.warm_start + np.random.default_rng(2).standard_normal(problem.warm_start.shape)
                   .astype(np.float32) * 0.01, 0)
    r = problem.operator.matvec(p.ravel()).astype(np.float64) - problem.data.ravel()
    tv = _tv_by_numpy(p)
    J = 0.5 * float(r @ r) + problem.lam * tv
    assert problem.total_variation(p) == pytest.approx(tv, rel=1e-5)
    assert problem.objective(p) == pytest.approx(J, rel=1e-6)
    l21 = pyproximal.L21(ndim=p.ndim, sigma=problem.lam)(problem.gradient.matvec(p.ravel()).astype(np.float64))
    assert l21 == pytest.approx(problem.lam * tv, rel=1e-5)  # the gradient handed out is TV's
    with pytest.raises(ValueError, match="values"):
        problem.objective(np.zeros(5))


def test_tv_lowers_the_problems_J_and_reports_it_per_iteration(scan, problem):
    from fpscan.service.recon.methods.tv import Options, problem_arguments
    from fpscan.service.recon.tv import reconstruct_tv

    seen: list[tuple[int, float]] = []
    last: list[np.ndarray] = []

    def callback(k, x, J):
        seen.append((k, J))
        last[:] = [x.copy()]

    rec = reconstruct_tv(**problem_arguments(scan, C, Options()), max_iter=12, tol=0.0, callback=callback)
    assert [k for k, _ in seen] == list(range(1, 13))
    np.testing.assert_array_equal(last[0], rec.p0)  # the last iterate is the image
    assert seen[-1][1] == pytest.approx(problem.objective(rec.p0), rel=1e-6)  # J, exact and free
    assert seen[-1][1] < 0.5 * problem.objective(problem.warm_start)


def test_pyproximal_primaldual_runs_on_the_problem(problem):
    A, grad = problem.operator, problem.gradient
    K = pylops.VStack([A, grad])
    g = pyproximal.VStack([pyproximal.L2(b=problem.data.ravel().astype(A.dtype)),
                           pyproximal.L21(ndim=len(A.dims), sigma=problem.lam)], nn=[problem.data.size, grad.shape[0]])
    x = np.random.default_rng(0).standard_normal(A.shape[1]).astype(A.dtype)
    for _ in range(8):
        x = A.rmatvec(A.matvec(x))
        norm2 = float(np.linalg.norm(x))
        x /= norm2
    norm_k = np.sqrt(norm2 + 4 * len(A.dims))
    p = PrimalDual(pyproximal.Box(lower=0.0), g, K, x0=problem.warm_start.ravel().copy(), tau=np.sqrt(0.9 * 100) / norm_k,
                   mu=np.sqrt(0.9 / 100) / norm_k, niter=40)
    assert p.min() >= 0
    assert problem.objective(p) < 0.5 * problem.objective(problem.warm_start)


def test_options_of_the_solver_and_auto_speed_are_refused(scan):
    with pytest.raises(OptionError, match="max_iter, tol sets? its solver|max_iter, tol set its solver"):
        fpscan.tv_problem(scan, max_iter=10, tol=0.01)
    with pytest.raises(OptionError, match="not 'auto'"):
        fpscan.tv_problem(scan, sound_speed="auto")
    with pytest.raises(OptionError, match="upsample"):
        fpscan.tv_problem(scan, upsample=2)


def test_the_axes_are_on_the_datas_lateral_coordinates(scan):
    import dataclasses

    shifted = dataclasses.replace(scan, lateral_shift=(1e-3, -2e-3))
    pb = fpscan.tv_problem(shifted, lam=0.0, n_z=8)
    rec = fpscan.reconstruct(shifted, "tv", lam=0.0, n_z=8, max_iter=1, quiet=True)
    np.testing.assert_allclose(pb.x, rec.x)
    np.testing.assert_allclose(pb.y, rec.y)
    assert pb.lam == 0.0 and not pb.params["lam_auto"] and pb.warm_start.shape[0] == 8


@pytest.fixture(scope="module")
def line_scan():
    """Two blocks on a 24-sensor line (exact data, 3 % noise), every third sensor: a problem small
    enough for an independent solver to reach J's minimiser."""
    from fpscan.physics.forward import forward_grid

    dx = 1e-4
    p0 = np.zeros((16, 24))
    p0[5:9, 8:12] = 1.0
    p0[10:12, 15:20] = 0.6
    g = forward_grid(p0, dx=dx, dz=dx, dt=dx / C, n_t=48, c=C)
    g = g + np.random.default_rng(0).standard_normal(g.shape) * 0.03 * np.abs(g).max()
    keep = np.arange(0, 24, 3)
    pos = ((np.arange(24) - 11.5) * dx)[keep][:, None]
    return dict(data=g[:, keep].T, dt=dx / C, c=C, positions=pos, n_z=16, dtype=np.float64)


def test_tv_reaches_the_minimiser_of_J(line_scan):
    """J at tv's image after 400 iterations (tol 0) equals J's minimum, found by pyproximal's
    PrimalDual (Chambolle & Pock 2011) in 4000 iterations; before, tv stalled at the fixed point of
    its preconditioned step, J 0.5 % above it."""
    from fpscan.service.recon.tv import reconstruct_tv, tv_problem

    pb = tv_problem(**line_scan)
    A, grad = pb.operator, pb.gradient
    K = pylops.VStack([A, grad])
    g = pyproximal.VStack([pyproximal.L2(b=pb.data.ravel()), pyproximal.L21(ndim=2, sigma=pb.lam)],
                          nn=[pb.data.size, grad.shape[0]])
    x = np.random.default_rng(0).standard_normal(A.shape[1])
    for _ in range(30):
        x = A.rmatvec(A.matvec(x))
        norm2 = float(np.linalg.norm(x))
        x /= norm2
    norm_k = np.sqrt(norm2 + 8)
    best = PrimalDual(pyproximal.Box(lower=0.0), g, K, x0=pb.warm_start.ravel().copy(), tau=np.sqrt(0.99 * 100) / norm_k,
                      mu=np.sqrt(0.99 / 100) / norm_k, niter=4000)
    J_min = pb.objective(best)
    assert J_min < 0.6 * pb.objective(pb.warm_start)
    rec = reconstruct_tv(**line_scan, max_iter=400, tol=0.0)
    assert pb.objective(rec.p0) == pytest.approx(J_min, rel=1e-5)
    assert rec.params["exact_from"] is not None


def test_a_run_to_the_default_rule_ends_where_the_exact_phase_begins(line_scan):
    """The default tol stops in the preconditioned phase (the image of the same iterations at tol 0,
    bit for bit); a run asked to go on takes exact steps from the next iteration."""
    from fpscan.service.recon.tv import DEFAULT_TOL, reconstruct_tv

    default = reconstruct_tv(**line_scan)
    n = default.params["iterations"]
    assert default.params["converged"] and default.params["tol"] == DEFAULT_TOL and default.params["exact_from"] is None
    same = reconstruct_tv(**line_scan, max_iter=n, tol=0.0)
    np.testing.assert_array_equal(same.p0, default.p0)
    on = reconstruct_tv(**line_scan, max_iter=n + 5, tol=0.0)
    assert on.params["exact_from"] == n + 1
