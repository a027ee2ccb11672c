"""fpscan.physics.nufft_plans: planned lateral NUFFTs reused per sensor mask."""
import numpy as np
import pytest

from fpscan.physics import nufft_plans
from fpscan.physics.nufft_plans import lateral_plan


def _direct_type1(coords, strengths, modes, isign):
    """Σ_j c_j exp(isign·i·Σ_d k_d x_{d,j}) at FFT-ordered modes k_d (direct sum)."""
    ks = [np.fft.fftfreq(n, 1.0 / n) for n in modes]
    grids = np.meshgrid(*ks, indexing="ij")
    phase = sum(g[..., None] * x for g, x in zip(grids, coords))  # (*modes, n_points)
    return np.einsum("tj,...j->t...", strengths, np.exp(isign * 1j * phase))


@pytest.mark.parametrize("modes", [(9,), (6, 7)])
def test_planned_transforms_match_direct_sums_and_are_reused(modes):
    rng = np.random.default_rng(3)
    n_pts, n_trans = 23, 3
    coords = tuple(rng.uniform(-np.pi, np.pi, n_pts) for _ in modes)
    c = rng.standard_normal((n_trans, n_pts)) + 1j * rng.standard_normal((n_trans, n_pts))
    nufft_plans.clear_plans()
    plan = lateral_plan(1, coords, modes, n_trans, eps=1e-12, isign=-1, dtype=np.complex128)
    want = _direct_type1(coords, c, modes, -1)
    assert np.allclose(plan.execute(c), want, rtol=0, atol=1e-9 * np.abs(want).max())
    # the same mask again: the same planned object; another mask or size: a new plan
    assert lateral_plan(1, tuple(x.copy() for x in coords), modes, n_trans, eps=1e-12, isign=-1,
                        dtype=np.complex128) is plan
    other = lateral_plan(1, tuple(x + 0.1 for x in coords), modes, n_trans, eps=1e-12, isign=-1,
                         dtype=np.complex128)
    assert other is not plan
    # type 2 is the adjoint of type 1 with the opposite sign: <A c, f> = <c, A^H f>
    f = rng.standard_normal((n_trans, *modes)) + 1j * rng.standard_normal((n_trans, *modes))
    t2 = lateral_plan(2, coords, modes, n_trans, eps=1e-12, isign=1, dtype=np.complex128)
    lhs = np.vdot(f, plan.execute(c))
    rhs = np.vdot(t2.execute(f), c)
    assert abs(lhs - rhs) <= 1e-9 * abs(lhs)


def test_the_cache_is_bounded_and_bad_input_is_refused():
    nufft_plans.clear_plans()
    x = np.linspace(-1, 1, 5)
    for k in range(nufft_plans.MAX_PLANS + 3):
        lateral_plan(1, (x + 0.01 * k,), (8,), 1, eps=1e-6, isign=-1, dtype=np.complex128)
    assert len(nufft_plans._plans) == nufft_plans.MAX_PLANS
    with pytest.raises(ValueError, match="finite"):
        lateral_plan(1, (np.array([0.0, np.nan]),), (8,), 1, eps=1e-6, isign=-1, dtype=np.complex128)
    with pytest.raises(ValueError, match="one coordinate array per mode"):
        lateral_plan(1, (x,), (8, 8), 1, eps=1e-6, isign=-1, dtype=np.complex128)
    with pytest.raises(ValueError, match="n_trans"):
        lateral_plan(1, (x,), (8,), 0, eps=1e-6, isign=-1, dtype=np.complex128)
    nufft_plans.clear_plans()
