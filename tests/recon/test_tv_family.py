"""The phantom family of tv's quality gate (`benchmarks/tv_family.py`, joined to
`benchmarks/bench_tv_matrix.py`): seeded and deterministic, every mask × noise combination, the
objects' depths and radii in their ranges, a vessel's chain of balls dense enough, a record that
reaches the last echo, and A-lines that are the exact superposition of each ball's N-wave (checked
against `fpscan.physics.ball_alines` over the whole record, and one ball's N-wave against a
numerical quadrature of its formula)."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from fpscan.physics import Ball, ball_alines, ball_p0
from fpscan.physics.axes import centred_axis

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def family():
    return _load("tv_family")


def _every_member(family):
    for name in family.MEMBERS:
        index, scale = family.member(name)
        yield index, scale, family.member_seed(index, scale)


def test_the_family_is_seeded_and_covers_every_mask_and_noise(family):
    assert family.HALF >= 20 and family.FULL == 3
    seeds = [seed for _, _, seed in _every_member(family)]
    assert len(set(seeds)) == len(seeds)
    first, again = family.family_objects(seeds[3])[0], family.family_objects(seeds[3])[0]
    assert first == again  # the same seed, the same balls
    assert first != family.family_objects(seeds[4])[0]
    combos = {(m, n) for m in (4, 11) for n in ("peak20", "peak30", "peak40", "rms30")}
    assert {family.member_scan(i, 0.5) for i in range(family.HALF)} == combos
    assert family.member("family-full-2") == (2, 1.0) and family.member("family-07") == (7, 0.5)
    with pytest.raises(ValueError, match="not a member"):
        family.member(f"family-{family.HALF}")
    # the held-out members: the same rules, their own seeds, every mask × noise once
    held = [family.member(f"family-holdout-{j}") for j in range(family.HOLDOUT)]
    assert held[2] == (family.HALF + 2, 0.5) and family.HOLDOUT == len(combos)
    assert {family.member_scan(i, s) for i, s in held} == combos
    assert family.family_case(*held[0])["name"] == "family-holdout-0"
    with pytest.raises(ValueError, match="not a member"):
        family.member(f"family-holdout-{family.HOLDOUT}")


def test_every_member_mixes_balls_and_vessels_in_range_with_a_record_that_reaches_them(family):
    depths = []
    for _, scale, seed in _every_member(family):
        balls, objects = family.family_objects(seed, scale)
        kinds = [o["kind"] for o in objects]
        assert "ball" in kinds and "vessel" in kinds
        half_side = round(226 * scale) * family.PITCH / 4
        assert all(1.5e-3 <= b.z <= 6e-3 and abs(b.x) <= half_side and abs(b.y) <= half_side for b in balls)
        start = kinds.count("ball")
        for o in objects:
            depths.extend(o["depth"])
            if o["kind"] == "ball":
                assert 0.1e-3 <= o["radius"] <= 0.4e-3
                continue
            assert 0.05e-3 <= o["radius"] <= 0.2e-3 and 1e-3 <= o["length"] <= 3.2e-3
            chain = np.array([(b.x, b.y, b.z) for b in balls[start:start + o["balls"]]])
            assert all(b.radius == o["radius"] for b in balls[start:start + o["balls"]])
            assert np.linalg.norm(np.diff(chain, axis=0), axis=1).max() <= o["radius"] / 2 * (1 + 1e-9)
            start += o["balls"]
        n = round(226 * scale)
        corner = (n - 1) / 2 * family.PITCH
        n_t = family.record_length(balls, scale)
        for b in balls:  # the far side of every ball from the farthest corner lies inside the record
            far = math.hypot(abs(b.x) + corner, abs(b.y) + corner, b.z) + b.radius
            assert far < family.C * family.DT * (n_t - 1)
    assert min(depths) < 2e-3 and max(depths) > 5.5e-3  # the family spans the depths


def _n_wave_by_quadrature(r: float, radius: float, amplitude: float, t: np.ndarray, dt: float, c: float) -> np.ndarray:
    """Each sample's mean of A (r - c t) / (2 r) on |r - c t| <= R over [t - dt/2, t + dt/2], by the
    midpoint rule on 4000 sub-intervals (independent of ball_alines' closed form)."""
    sub = (np.arange(4000) + 0.5) / 4000 - 0.5
    u = r - c * (t[:, None] + sub * dt)
    return (amplitude * u / (2 * r) * (np.abs(u) <= radius)).mean(axis=1)


def test_a_members_a_line_is_the_sum_of_its_balls_exact_n_waves(family):
    case = family.family_case(7)
    n_t, n = case["clean"].shape[0], round(226 * 0.5)
    assert case["clean"].shape == (n_t, n, n) and n_t == family.record_length(case["balls"], 0.5)
    assert (case["mask"], case["noise"]) == family.member_scan(7, 0.5)
    x = centred_axis(n, family.PITCH)
    for iy, ix in ((0, 0), (56, 56), (112, 5)):  # a corner, the centre, an edge
        direct = ball_alines(np.array([[x[ix], x[iy]]]), case["balls"], family.DT, n_t, family.C)[0]
        np.testing.assert_allclose(case["clean"][:, iy, ix], direct, rtol=0, atol=1e-12 * np.abs(direct).max())
        assert np.abs(direct).max() > 0
    # one ball of the member, at the corner: its N-wave against the formula by quadrature
    b = case["balls"][0]
    r = math.hypot(x[0] - b.x, x[0] - b.y, b.z)
    t = family.DT * np.arange(n_t)
    one = ball_alines(np.array([[x[0], x[0]]]), b, family.DT, n_t, family.C)[0]
    np.testing.assert_allclose(one, _n_wave_by_quadrature(r, b.radius, b.amplitude, t, family.DT, family.C),
                               atol=1e-3 * np.abs(one).max())


def test_ball_alines_per_point_t0_is_the_records_window():
    pos = np.array([[0.0, 0.0], [1e-3, -0.5e-3], [2e-3, 2e-3]])
    ball = Ball(0.2e-3, 0.1e-3, 2e-3, 0.15e-3, 0.8)
    dt, c = 8e-9, 1500.0
    whole = ball_alines(pos, ball, dt, 400, c)
    first = np.array([150, 170, 210])
    window = ball_alines(pos, ball, dt, 40, c, t0=first * dt)
    for k in range(len(pos)):
        np.testing.assert_allclose(window[k], whole[k, first[k]:first[k] + 40], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="t0 must be a number or have shape"):
        ball_alines(pos, ball, dt, 40, c, t0=np.zeros(2))
    with pytest.raises(ValueError, match="t0 must be finite"):
        ball_alines(pos, ball, dt, 40, c, t0=np.array([0.0, np.nan, 0.0]))


def test_balls_p0_is_ball_p0(family):
    balls, _ = family.family_objects(family.member_seed(13, 0.5))
    z = 1.2e-3 + 60e-6 * np.arange(90)
    x = centred_axis(113, 60e-6)
    np.testing.assert_allclose(family.balls_p0(balls, z, x, x), ball_p0(balls, z, x, x, supersample=2), atol=1e-12)


def test_the_matrix_runs_the_family_and_gates_its_stop_and_full_size_budget():
    bench = _load("bench_tv_matrix")
    assert bench.family_members(["family"]) == [f"family-{i:02d}" for i in range(24)]  # not the held-out ones
    assert bench.family_members(["family-holdout", "family-01"]) == ["family-01"] + [
        f"family-holdout-{j}" for j in range(8)]
    assert bench.family_members(["family-full", "family-03", "family"])[-3:] == [
        "family-full-0", "family-full-1", "family-full-2"]
    row = dict(case="family-full-0", mask=4, noise="peak20", tv=0.95, ner=0.8, converged=True, iterations=60,
               pairs=63, tv_s=100.0, ner_s=1.0, scale=1.0, cc300=0.96)
    assert bench.gate(row) == []
    assert bench.gate({**row, "converged": False, "stop": "iterations"}) == [
        "not converged (iterations after 60 iterations)"]
    assert bench.gate({**row, "pairs": 80, "tv_s": 151.0}) == ["80 operator pairs > 75", "tv 151 x NER > 150"]
    assert bench.gate({**row, "scale": 0.5, "pairs": 80, "tv_s": 151.0}) == []  # half size: no budget
    assert bench.gate({**row, "cc300": 0.97}) == ["300 iterations 0.9700 - tv 0.9500 > 0.015"]
