"""The model-based solver on small 2-D cases: 64 x 96 pixels of
50 µm, 24 equiangular sensors on a 96-point line, exact grid data (`forward_grid`) with
seeded white noise 20/30/40 dB below the signal; oracles the true p0 (CC, least-squares
amplitude) and, for the branch contrast, the NEDNER image of the noise alone.

- the default stopping rule (the image's change) is met, and the result is within 0.005 CC
  of a 150-iteration run, in 2-D and 3-D; within 30 operator pairs is not, nor within 0.5 %
  (relative distance) of a 300-iteration run (strict xfails: targets not met);
- the automatic λ is within 0.01 CC of the best of a sweep ×1/8 … ×8 (default suite: blobs
  and vessels at 30 dB; 20 and 40 dB and the 3-D cases, 24 x 40 x 40 voxels on 10 % and
  3.3 % equi-steradian masks, are marked slow);
- every vessel branch 2 voxels or wider keeps its centre line ≥ 3 noise σ above the local
  background;
- ``debias`` raises tv's amplitude, to at least NEDNER's;
- λ continues from λ D₀ down to λ (the rule waits for λ), and on a 3.3 % 3-D mask the rule
  then stops no later, nearer a long solve and with a higher CC than without.
"""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.experiments.phantoms import VESSEL_WIDTHS, vessel_phantom, vessel_tree
from fpscan.experiments.vessels import branch_contrasts
from fpscan.physics import Ball, ball_p0
from fpscan.physics.forward import forward_grid
from fpscan.service.metrics import correlation_coefficient
from fpscan.service.plans import Lattice, equiangular_mask, equisteradian_mask
from fpscan.service.progress import IterationStage
from fpscan.service.recon import reconstruct_points
from fpscan.service.recon.tv import reconstruct_tv
from fpscan.service.recon.tv.lam import REACH_FLOOR

pytestmark = pytest.mark.long(85)

C, DX = 1500.0, 50e-6
DT = DX / C
N_Z, N_X, N_SENSORS = 64, 96, 24
SWEEP = (1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0, 8.0)
_CASES: dict = {}


def make_case(kind: str, snr_db: float, dims: int = 2, points: int = 160) -> dict:
    """Phantom, noisy data at the mask's sensors, the noise alone there, and the solver's
    keyword arguments (cached per module: several tests share a case). 3-D: 24 x 40 x 40
    voxels, an equi-steradian mask of ``points`` of the 1600 lattice points (160: 10 %; 53:
    3.3 %), float32."""
    key = (kind, snr_db, dims, points)
    if key in _CASES:
        return _CASES[key]
    n_z, n_x = (N_Z, N_X) if dims == 2 else (24, 40)
    shape = (n_z, n_x) if dims == 2 else (n_z, n_x, n_x)
    x = (np.arange(n_x) - (n_x - 1) / 2) * DX
    z = np.arange(n_z) * DX
    if kind == "vessels":
        p0 = vessel_phantom(shape)
    elif dims == 2:
        balls = [Ball(-12 * DX, 0, 30 * DX, 8 * DX), Ball(14 * DX, 0, 22 * DX, 5 * DX, 0.7),
                 Ball(2 * DX, 0, 45 * DX, 4 * DX, 0.5)]
        p0 = ball_p0(balls, z, x, supersample=2)
    else:
        balls = [Ball(0.0, 0.0, 12 * DX, 4 * DX), Ball(7 * DX, -5 * DX, 16 * DX, 3 * DX, 0.7),
                 Ball(-8 * DX, 4 * DX, 9 * DX, 2.5 * DX, 0.5)]
        p0 = ball_p0(balls, z, x, x, supersample=2)
    n_t = int(np.hypot(n_z, n_x if dims == 2 else n_x / np.sqrt(2))) + 8
    clean = forward_grid(p0, DX, DX, DT, n_t, C)
    rms = float(np.sqrt(np.mean(clean**2)))
    noise = np.random.default_rng(0).standard_normal(clean.shape) * rms / 10 ** (snr_db / 20)
    if dims == 2:
        mask = equiangular_mask(Lattice(n_x, 1, DX), n_z * DX / 2, N_SENSORS)
        idx = np.asarray(mask.indices)[:, 0]
        alines, noise_at = (clean + noise)[:, idx].T, noise[:, idx].T
        kw = dict(positions=np.asarray(mask.positions, float)[:, :1], grid=(x,))
    else:
        mask = equisteradian_mask(Lattice(n_x, n_x, DX), 12 * DX, points)
        ix, iy = np.asarray(mask.indices).T
        alines, noise_at = (clean + noise)[:, iy, ix].T, noise[:, iy, ix].T
        kw = dict(positions=np.asarray(mask.positions, float)[:, :2], grid=(x, x), dtype=np.float32)
    kw.update(weights=np.asarray(mask.weights, float), n_z=n_z, dz=DX)
    case = dict(p0=p0, alines=alines, noise=noise_at, kw=kw)
    _CASES[key] = case
    return case


def run_tv(case: dict, **kw):
    """tv on the case; with no keyword the default run (automatic λ, default stopping rule),
    computed once per case: the solver is deterministic, and four tests start from it."""
    if not kw:
        if "auto" not in case:
            case["auto"] = reconstruct_tv(case["alines"], DT, C, **case["kw"])
            case["auto"].p0.flags.writeable = False  # shared: no test may change it
        return case["auto"]
    return reconstruct_tv(case["alines"], DT, C, **case["kw"], **kw)


def _nedner(case: dict, alines) -> np.ndarray:
    kw = {k: v for k, v in case["kw"].items() if k not in ("positions", "dtype")}
    if alines is case["alines"]:  # the NEDNER image of the data: computed once per case
        if "nedner" not in case:
            case["nedner"] = reconstruct_points(alines, case["kw"]["positions"], DT, C, **kw).p0
            case["nedner"].flags.writeable = False
        return case["nedner"]
    return reconstruct_points(alines, case["kw"]["positions"], DT, C, **kw).p0


def _cc(img, case) -> float:
    return correlation_coefficient(img, case["p0"])


def _amplitude(img, case) -> float:
    """Least-squares scale of the image against the true p0: argmin_a ‖img − a p0‖."""
    p0 = case["p0"]
    return float(np.vdot(img, p0) / np.vdot(p0, p0))


def test_vessel_phantom_is_a_tree_of_tubes_1_to_4_voxels_wide():
    for shape in ((N_Z, N_X), (24, 40, 40)):
        p0 = vessel_phantom(shape)
        segments = vessel_tree(shape)
        assert p0.shape == shape and p0.min() == 0.0 and p0.max() == 1.0
        assert len(segments) == 15 and sorted({w for _, _, w in segments}) == sorted(VESSEL_WIDTHS)
        for start, end, width in segments:  # every centre line is inside a vessel of its width
            mid = np.rint(0.5 * (start + end) + np.r_[0.0, (np.array(shape[1:]) - 1) / 2]).astype(int)
            # the nearest voxel is up to √3/2 voxel off a 1-voxel line (partial volume)
            assert p0[tuple(mid)] >= (0.5 if width >= 2 else 0.1), (start, end, width)
    # the 2-D widths across a horizontal-ish segment: count of voxels >= 0.5 on its column
    p0 = vessel_phantom((N_Z, N_X))
    trunk_start, trunk_end, width = vessel_tree((N_Z, N_X))[0]
    col = int(round(0.5 * (trunk_start[1] + trunk_end[1]) + (N_X - 1) / 2))
    assert width == 4 and 3 <= np.count_nonzero(p0[:, col] >= 0.5) <= 5
    with pytest.raises(ValueError, match="vessel phantom"):
        vessel_phantom((8, 20))


@pytest.mark.parametrize("dims", [2, 3])
def test_the_default_rule_stops_where_the_image_has_converged(dims):
    """The rule on the image's change: the result is within 0.005 CC of a 150-iteration run.
    The objective's rule (until 2026-11-24: its last decrease below 1e-3 of its decrease
    since the warm start) stopped the 3-D case at 20 iterations, 0.958 against 0.978 after
    100."""
    case = make_case("vessels", 30, dims)
    rec = run_tv(case)
    p = rec.params
    assert p["stop_reason"] == "converged" and p["converged"] is True, p
    assert p["iterations"] < p["max_iter"] and p["iterations"] <= p["operator_pairs"], p
    assert 0 <= p["iterate_change"] < p["tol"]
    assert p["lam_auto"] and p["lam"] > 0 and p["noise_sigma"] > 0 and p["image_noise"] > 0
    assert p["residual"] < 1.5 * p["noise_share"]  # near the discrepancy principle's level
    longer = run_tv(case, max_iter=150, tol=0.0)
    assert longer.params["stop_reason"] == "iterations" and longer.params["iterations"] == 150
    assert _cc(rec.p0, case) >= _cc(longer.p0, case) - 0.005
    assert _cc(rec.p0, case) > _cc(_nedner(case, case["alines"]), case) + 0.05


def test_lambda_continues_from_the_warm_starts_discrepancy_down_to_lambda():
    """λ_k starts at λ D₀ (D₀ the warm start's discrepancy in noise norms) and falls by 0.9 an
    iteration to λ; the stopping rule's window holds iterations at λ only; a given λ continues
    from the same D₀ (the same warm start), and ``continuation=False`` steps at λ throughout."""
    case = make_case("vessels", 30)
    p = run_tv(case).params
    f0, n = p["lam_start_factor"], p["continuation_iterations"]
    assert f0 == pytest.approx(max(1.0, p["warm_discrepancy"]), rel=1e-12) and f0 > 2, p
    assert f0 * 0.9 ** (n - 1) > 1 >= f0 * 0.9 ** n, (f0, n)
    assert p["converged"] and p["iterations"] >= n + 3, p
    given = run_tv(case, lam=p["lam"], max_iter=2 * n + 2, tol=0.0).params
    assert given["lam_start_factor"] == pytest.approx(f0, rel=1e-9) and given["continuation_iterations"] == n
    off = run_tv(case, continuation=False, max_iter=5, tol=0.0).params
    assert off["lam_start_factor"] == 1.0 and off["continuation_iterations"] == 0
    # the progress says so: the tolerance throughout, the rule not armed while λ still falls (it
    # cannot stop the run there: the line shows the tolerance, "once λ has settled")
    stages: list = []
    run_tv(case, progress=lambda f, stage: stages.append(stage))  # the default run again, watched
    seen = {s.k: (s.tol, s.armed) for s in stages if isinstance(s, IterationStage)}
    assert sorted(seen) == list(range(1, p["iterations"] + 1)), sorted(seen)
    assert all(seen[k] == (p["tol"], False) for k in range(1, n + 3)), seen
    assert all(seen[k] == (p["tol"], True) for k in range(n + 3, p["iterations"] + 1)), seen


def test_continuation_stops_nearer_the_minimiser_on_a_sparse_3d_mask():
    """On 3.3 % of the lattice (balls, 30 dB) the rule stops no later with continuation than
    without, nearer a 300-iteration solve at the same λ, and with a higher CC with the true p0
    (docs/history/measurements.md, "λ continuation — the paper's scan at the rule": 58 against 66 iterations,
    7 % against 9 %)."""
    case = make_case("balls", 30, 3, 53)
    on = run_tv(case)
    off = run_tv(case, continuation=False)
    assert on.params["converged"] and off.params["converged"]
    longer = run_tv(case, lam=on.params["lam"], continuation=False, max_iter=300, tol=0.0).p0

    def distance(rec) -> float:
        return float(np.linalg.norm(rec.p0 - longer) / np.linalg.norm(longer))

    assert on.params["iterations"] <= off.params["iterations"], (on.params["iterations"], off.params["iterations"])
    assert distance(on) < distance(off), (distance(on), distance(off))
    assert _cc(on.p0, case) > _cc(off.p0, case)


@pytest.mark.xfail(strict=True, reason="target not met: converged by the rule on the "
                   "image, tv takes 29-39 iterations on 2-D lines (34.5 pairs here) and 41-66 on 3-D masks of 3-10 %; "
                   "at the paper's size 30 pairs buy CC 0.940 against 0.980 at the rule (bench_tv_paper.py "
                   "--max-iter 27)")
def test_the_default_rule_converges_within_30_operator_pairs():
    p = run_tv(make_case("vessels", 30)).params
    assert p["stop_reason"] == "converged" and p["operator_pairs"] <= 30, p


@pytest.mark.xfail(strict=True, reason="target not met: at the rule's stop the image is 2.9 % (2-D "
                   "vessels) to 8.7 % (2-D balls) from a long run at the same λ, and even tol = 2e-4 (74-247 "
                   "iterations, before λ continuation) stopped 0.8-1.9 % from it (bench_tv_solver.py --rule)")
def test_the_rules_image_is_within_half_a_percent_of_a_300_iteration_run():
    case = make_case("vessels", 30)
    rec = run_tv(case)
    longer = run_tv(case, lam=rec.params["lam"], max_iter=300, tol=0.0)
    distance = np.linalg.norm(rec.p0 - longer.p0) / np.linalg.norm(longer.p0)
    assert distance <= 0.005, distance


@pytest.mark.parametrize(("kind", "snr_db", "dims", "points"), [
    ("balls", 30, 2, 0), ("vessels", 30, 2, 0),
    pytest.param("balls", 20, 2, 0, marks=pytest.mark.slow), pytest.param("vessels", 20, 2, 0, marks=pytest.mark.slow),
    pytest.param("balls", 40, 2, 0, marks=pytest.mark.slow), pytest.param("vessels", 40, 2, 0, marks=pytest.mark.slow),
    pytest.param("balls", 30, 3, 160, marks=pytest.mark.slow),
    pytest.param("vessels", 30, 3, 160, marks=pytest.mark.slow),
    pytest.param("vessels", 30, 3, 53, marks=pytest.mark.slow),
    pytest.param("balls", 40, 3, 53, marks=pytest.mark.slow),
])
def test_automatic_lambda_is_within_0_01_cc_of_the_best_of_a_sweep(kind, snr_db, dims, points):
    """3-D at 10 % of the lattice's points and (vessels) at 3.3 % as well; on the six
    3.3 % cases of `benchmarks/bench_tv_solver.py` (balls and vessels, 20/30/40 dB) the
    automatic λ loses at most 0.0051 CC (docs/results.md). The balls at 3.3 % and 40 dB are
    where the reach floor sets λ (`fpscan.service.recon.tv.lam.REACH_FLOOR`: 1.56 times the
    noise level's rule there)."""
    case = make_case(kind, snr_db, dims, points or 160)
    auto = run_tv(case)
    lam = auto.params["lam"]
    if (kind, snr_db, points) == ("balls", 40, 53):
        assert auto.params["lam_floored"] and auto.params["prox_reach"] == pytest.approx(REACH_FLOOR), auto.params
    ccs = [_cc((auto if f == 1.0 else run_tv(case, lam=f * lam)).p0, case) for f in SWEEP]
    assert ccs[SWEEP.index(1.0)] >= max(ccs) - 0.01, dict(zip(SWEEP, ccs))


@pytest.mark.parametrize(("snr_db", "dims"), [(30, 2), (30, 3), pytest.param(20, 2, marks=pytest.mark.slow)])
def test_every_vessel_branch_2_voxels_or_wider_keeps_its_contrast(snr_db, dims):
    """Each branch 2 voxels or wider keeps its centre line >= 3 noise σ (the NEDNER image of
    the noise alone) and >= half the true p0's own contrast, measured the same way (the
    sampled centre voxels of a 2-voxel tube are partly outside it), above its local background."""
    case = make_case("vessels", snr_db, dims)
    img = run_tv(case).p0
    sigma = float(np.std(_nedner(case, case["noise"])))  # the noise σ of the image, by NEDNER
    contrasts = branch_contrasts(img, case["p0"])  # the experiment's measure (fpscan.experiments.vessels)
    assert len(contrasts) == 7  # the trunk (4), its two children (3) and four grandchildren (2)
    for c in contrasts:
        assert c["contrast"] >= 3 * sigma, (c, sigma)
        assert c["contrast"] >= 0.5 * c["true_contrast"], c


def test_debias_raises_the_amplitude_to_at_least_nedners():
    case = make_case("vessels", 30)
    plain = run_tv(case)
    refit = run_tv(case, debias=True)
    assert refit.params["debias"] is True and plain.params["debias"] is False
    assert refit.params["operator_pairs"] > plain.params["operator_pairs"]
    a_tv, a_refit = _amplitude(plain.p0, case), _amplitude(refit.p0, case)
    a_nedner = _amplitude(_nedner(case, case["alines"]), case)
    assert a_refit > a_tv and a_refit >= a_nedner, (a_refit, a_tv, a_nedner)
    assert _cc(refit.p0, case) >= _cc(plain.p0, case) - 0.005
