"""The planar operator pair: the adjoint is the true adjoint of the forward model (dot
test, every variant), and the forward model is `forward_grid` / `forward_points`."""
from __future__ import annotations

import numpy as np
import pylops
import pytest

from driver.physics.forward import forward_grid, forward_points
from service.recon.operator import PlanarOperator

C, DT = 1500.0, 20e-9
DZ = C * DT
DX = 40e-6
rng = np.random.default_rng(11)


def assert_adjoint(op: PlanarOperator, tol: float = 1e-10) -> None:
    """⟨A x, y⟩ = ⟨x, Aᴴ y⟩ for random x, y, to ``tol`` relative."""
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    lhs, rhs = np.vdot(op.forward(x), y), np.vdot(x, op.adjoint(y))
    assert abs(lhs - rhs) <= tol * abs(lhs), (lhs, rhs)


def _positions(shape, n=7):
    """Sensors off the grid, some beyond its lateral extent."""
    extent = np.array(shape[1:][::-1], dtype=float) * DX
    return rng.uniform(-0.6, 0.6, (n, len(shape) - 1)) * extent


@pytest.mark.parametrize("periodic", [False, True])
@pytest.mark.parametrize("sensors", ["grid", "points"])
@pytest.mark.parametrize("shape", [(16, 9), (12, 10), (10, 5, 6), (9, 6, 7)], ids=["2d-odd", "2d-even", "3d-even-odd", "3d-odd-even"])
def test_dot_test(shape, sensors, periodic):
    pos = None if sensors == "grid" else _positions(shape)
    for t0 in (0.0, 3e-8):
        op = PlanarOperator(shape, DX, DZ, DT, 14, C, positions=pos, t0=t0, eps=1e-12, periodic=periodic)
        assert_adjoint(op)


@pytest.mark.parametrize("shape", [(14, 9), (10, 6, 7)])
def test_forward_is_the_forward_model(shape):
    p0 = rng.standard_normal(shape)
    op = PlanarOperator(shape, DX, DZ, DT, 18, C, eps=1e-9)
    np.testing.assert_array_equal(op.forward(p0), forward_grid(p0, DX, DZ, DT, 18, C, eps=1e-9))
    pos = _positions(shape, 5)
    op = PlanarOperator(shape, DX, DZ, DT, 18, C, positions=pos, t0=2e-8, eps=1e-9)
    np.testing.assert_array_equal(op.forward(p0), forward_points(p0, DX, DZ, pos, DT, 18, C, t0=2e-8, eps=1e-9))


def test_pylops_operator_matches_and_solves():
    """As a pylops LinearOperator: matvec/rmatvec are forward/adjoint on flat vectors,
    pylops' own dottest passes and a pylops solver (CGLS) reduces the residual."""
    shape = (8, 7)
    op = PlanarOperator(shape, DX, DZ, DT, 10, C, eps=1e-12, periodic=True)
    assert op.shape == (10 * 7, 8 * 7) and op.ishape == shape and op.oshape == (10, 7)
    x = rng.standard_normal(shape)
    np.testing.assert_array_equal(op @ x.ravel(), op.forward(x).ravel())
    assert pylops.utils.dottest(op, *op.shape, rtol=1e-10)
    y = op.forward(x)
    sol = pylops.optimization.basic.cgls(op, y.ravel(), niter=15, tol=0)[0]
    assert np.linalg.norm(op.forward(np.reshape(sol, shape)) - y) <= 1e-2 * np.linalg.norm(y)


def test_float32_and_bad_input():
    op = PlanarOperator((8, 5, 6), DX, DZ, DT, 9, C, dtype=np.float32)
    assert op.forward(np.ones((8, 5, 6))).dtype == np.float32
    assert op.adjoint(np.ones((9, 5, 6))).dtype == np.float32
    with pytest.raises(ValueError, match="p0 must have shape"):
        op.forward(np.ones((8, 6, 5)))
    with pytest.raises(ValueError, match="data contains NaN"):
        op.adjoint(np.full((9, 5, 6), np.nan))
    with pytest.raises(ValueError, match="positions must have shape"):
        PlanarOperator((8, 5), DX, DZ, DT, 9, C, positions=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="dt must be"):
        PlanarOperator((8, 5), DX, DZ, -1.0, 9, C)
    with pytest.raises(ValueError, match="dtype"):
        PlanarOperator((8, 5), DX, DZ, DT, 9, C, dtype=np.complex64)
