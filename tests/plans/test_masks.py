"""Sensor masks: properties of every kind, the paper's configurations, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fpscan.physics.weights import voronoi_weights
from fpscan.service.plans import (
    Lattice,
    equiangular_mask,
    equisteradian_mask,
    equisteradian_rings,
    make_mask,
)

PITCH = 60e-6
SQ = Lattice(61, 61, PITCH)  # odd: the centre is a lattice point
LINE = Lattice(201, 1, PITCH)

CASES = [
    ("full", SQ, {}),
    ("subgrid", SQ, {"interval": 4, "n_per_side": 13}),
    ("hexagonal", SQ, {"spacing": 4.5 * PITCH}),
    ("random", SQ, {"n_points": 300, "seed": 3}),
    ("poisson", SQ, {"min_distance": 3.2 * PITCH, "seed": 5}),
    ("points", SQ, {"points": [[0.0, 0.0], [3.1 * PITCH, -7.9 * PITCH], [-30 * PITCH, 30 * PITCH]]}),
    ("equisteradian", SQ, {"depth": 1.2e-3, "n_points": 400}),
    ("equiangular", LINE, {"depth": 40 * PITCH, "n_points": 24}),
    ("full", LINE, {}),
    ("subgrid", LINE, {"interval": 7}),
]


@pytest.mark.parametrize("kind, lattice, params", CASES, ids=[f"{c[0]}-{c[1].n_y}" for c in CASES])
def test_mask_properties(kind, lattice, params):
    m = make_mask(kind, lattice, **params)
    idx = m.indices
    n = idx.shape[0]
    assert n == m.obtained_points >= 1
    assert idx.shape == (n, 2) and m.positions.shape == (n, 2) and m.weights.shape == (n,)
    # inside the lattice, no duplicates
    assert idx[:, 0].min() >= 0 and idx[:, 0].max() < lattice.n_x
    assert idx[:, 1].min() >= 0 and idx[:, 1].max() < lattice.n_y
    assert np.unique(idx, axis=0).shape[0] == n
    # positions are the centred lattice coordinates of the indices
    np.testing.assert_allclose(m.positions[:, 0], (idx[:, 0] - (lattice.n_x - 1) / 2) * PITCH)
    np.testing.assert_allclose(m.positions[:, 1], (idx[:, 1] - (lattice.n_y - 1) / 2) * PITCH)
    # weights positive, summing to the covered area (the clipped Voronoi total)
    assert np.all(m.weights > 0) and np.all(np.isfinite(m.weights))
    rp = m.recon_positions()
    assert rp.shape == (n, 1 if lattice.is_line else 2)
    covered = voronoi_weights(rp, PITCH).sum()
    # (the r^2 / r^3 laws are normalised on a coarser raster: the disc-clipped total
    # agrees to raster accuracy)
    rel = 1e-3 if kind in ("equisteradian", "equiangular") else 1e-12
    assert m.weights.sum() == pytest.approx(covered, rel=rel)
    # the covered box: the sensors' bounding box widened by half the median NN distance
    if n > 1:
        half = 0.5 * np.median(cKDTree(rp).query(rp, k=2)[0][:, 1])
        box = np.prod(np.ptp(rp, axis=0) + 2 * half)
        assert covered <= box * (1 + 1e-9)
    assert m.weight_ratio > 0


def test_subgrid_reaching_the_lattice_edge_keeps_uniform_weights():
    # 57 x 57 at interval 4 spans the whole 226 lattice: still (4 pitch)^2 each, as
    # reconstruct_points' default weights and a uniform grid of spacing 4 pitch
    sub = make_mask("subgrid", Lattice(226, 226, PITCH), interval=4)
    assert sub.obtained_points == 57 * 57
    np.testing.assert_allclose(sub.weights, (4 * PITCH) ** 2, rtol=1e-12)


def test_full_and_subgrid_weights_are_exact():
    full = make_mask("full", SQ)
    assert full.obtained_points == 61 * 61
    np.testing.assert_allclose(full.weights, PITCH**2, rtol=1e-12)
    assert full.covered_area == pytest.approx(SQ.area, rel=1e-12)
    sub = make_mask("subgrid", Lattice(226, 226, PITCH), interval=5, n_per_side=41)
    assert sub.obtained_points == 41 * 41
    np.testing.assert_allclose(sub.weights, (5 * PITCH) ** 2, rtol=1e-12)
    # centred: 41 points at interval 5 span 200 pitches; 226 - 1 - 200 = 25 -> start 12
    assert sub.indices[:, 0].min() == 12 and sub.indices[:, 0].max() == 212


def _mirror(idx, lat, how):
    ix, iy = idx[:, 0], idx[:, 1]
    if how == "x":
        return np.column_stack((lat.n_x - 1 - ix, iy))
    if how == "y":
        return np.column_stack((ix, lat.n_y - 1 - iy))
    return np.column_stack((iy, ix))  # swap (square lattices)


def _as_map(idx, w):
    return {(int(a), int(b)): float(v) for (a, b), v in zip(idx, w)}


@pytest.mark.parametrize(
    "kind, lattice, params, symmetries",
    [
        ("full", SQ, {}, "xys"),
        ("subgrid", SQ, {"interval": 4, "n_per_side": 15}, "xys"),
        ("hexagonal", SQ, {"spacing": 4.5 * PITCH}, "xy"),
        ("equisteradian", SQ, {"depth": 1.2e-3, "n_points": 400}, "xys"),
        ("equisteradian", Lattice(101, 101, PITCH), {"depth": 3e-3, "n_points": 777}, "xys"),
        ("equiangular", LINE, {"depth": 40 * PITCH, "n_points": 24}, "x"),
        ("equiangular", LINE, {"depth": 40 * PITCH, "n_points": 25}, "x"),
    ],
)
def test_centred_masks_keep_the_lattice_symmetries(kind, lattice, params, symmetries):
    m = make_mask(kind, lattice, **params)
    ref = _as_map(m.indices, m.weights)
    for how in symmetries:
        got = _as_map(_mirror(m.indices, lattice, how), m.weights)
        assert set(got) == set(ref), f"mask not symmetric under {how}"
        for key, w in got.items():
            assert w == pytest.approx(ref[key], rel=1e-6), f"weights not symmetric under {how}"


# --- equi-steradian -------------------------------------------------------------------

def test_equisteradian_ring_design_follows_the_appendix():
    r0, rho_max, n = 3.6e-3, 112.5 * PITCH, 1625
    rings = equisteradian_rings(r0, rho_max, n)
    t_max = math.atan(rho_max / r0)
    omega = 2 * math.pi * (1 - math.cos(t_max)) / n
    counts = [r.count for r in rings]
    assert counts[0] == 1 and rings[0].theta == 0.0
    assert all(c & (c - 1) == 0 for c in counts), "ring sizes must be powers of two"
    assert all(b >= a for a, b in zip(counts, counts[1:])), "ring sizes must not decrease"
    # ring 1 encloses exactly one unit solid angle
    assert 2 * math.pi * (1 - math.cos(rings[0].theta_hi)) == pytest.approx(omega, rel=1e-12)
    for prev, ring in zip(rings[:-1], rings[1:-1]):
        # band areas: omega * j_k = 2 pi (cos theta_{k-1} - cos theta_k), points at mid angle
        band = 2 * math.pi * (math.cos(prev.theta_hi) - math.cos(ring.theta_hi))
        assert band == pytest.approx(omega * ring.count, rel=1e-9)
        assert ring.theta_lo == prev.theta_hi
        assert ring.theta == pytest.approx(0.5 * (ring.theta_lo + ring.theta_hi), rel=1e-12)
        assert ring.theta_hi < t_max
        # staggered azimuths: phi_{0,k} = phi_{0,k-1} + pi / j_k
        assert ring.phi0 == pytest.approx(prev.phi0 + math.pi / ring.count, rel=1e-12)
    # the last ring sits on the aperture's edge
    assert rings[-1].theta == pytest.approx(t_max, rel=1e-12)
    # the doubling rule holds on every ring: r_s <= 1.8 r_k
    prev_xy = np.zeros((1, 2))
    for ring in rings[1:]:
        rho = r0 * math.tan(ring.theta)
        phi = ring.azimuths()
        xy = np.column_stack((rho * np.cos(phi), rho * np.sin(phi)))
        r_k = np.min(np.linalg.norm(xy[:, None] - prev_xy[None], axis=-1))
        r_s = np.linalg.norm(xy[0] - xy[1])
        assert r_s <= 1.8 * r_k * (1 + 1e-12)
        prev_xy = xy


def test_equisteradian_paper_configuration():
    lat = Lattice(226, 226, PITCH)
    m = equisteradian_mask(lat, 3.6e-3, 1625)
    # the paper: 1625 points, outer/inner weight 9.7, edge angle of incidence 62 degrees
    assert math.degrees(m.design["theta_max"]) == pytest.approx(62.0, abs=0.1)
    assert m.requested_points == 1625
    assert abs(m.obtained_points - 1625) / 1625 < 0.03
    assert m.weight_ratio == pytest.approx(9.7, rel=0.01)
    # weights follow r^3 about the point of interest
    r = np.sqrt((m.positions**2).sum(1) + 3.6e-3**2)
    np.testing.assert_allclose(m.weights / m.weights[0], (r / r[0]) ** 3, rtol=1e-12)
    # the mask is a disc of radius rho_max (+ snapping)
    rho = np.hypot(m.positions[:, 0], m.positions[:, 1])
    assert rho.max() <= 112.5 * PITCH + PITCH / math.sqrt(2)


def test_equisteradian_off_centre_poi():
    lat = Lattice(120, 120, PITCH)
    poi = (1.0e-3, -0.5e-3)
    m = equisteradian_mask(lat, 2e-3, 300, poi=poi)
    d = np.hypot(m.positions[:, 0] - poi[0], m.positions[:, 1] - poi[1])
    rho_max = 59.5 * PITCH - 1.0e-3
    assert d.max() <= rho_max + PITCH
    assert d.min() <= PITCH  # ring 1 sits at the point of interest
    assert m.rings is not None and m.rings.shape == (m.obtained_points,)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    n=st.integers(15, 90),
    depth_pitches=st.floats(3, 150),
    frac=st.floats(0.002, 0.3),
    px=st.floats(-0.4, 0.4),
    py=st.floats(-0.4, 0.4),
)
def test_equisteradian_always_valid(n, depth_pitches, frac, px, py):
    lat = Lattice(n, n, PITCH)
    h = (n - 1) / 2 * PITCH
    n_points = max(1, int(frac * n * n))
    m = equisteradian_mask(lat, depth_pitches * PITCH, n_points, poi=(px * h, py * h))
    assert np.unique(m.indices, axis=0).shape[0] == m.obtained_points
    assert m.indices.min() >= 0 and m.indices.max() < n
    assert np.all(m.weights > 0)


# --- equiangular ----------------------------------------------------------------------

def test_equiangular_equal_angles_before_snapping():
    lat = Lattice(400, 1, PITCH)
    r0, n, xc = 50 * PITCH, 17, 20 * PITCH
    m = equiangular_mask(lat, r0, n, poi=xc)
    theta = np.asarray(m.design["theta"])
    assert theta.shape == (n,)
    np.testing.assert_allclose(np.diff(theta), np.diff(theta)[0], rtol=1e-12)
    rho_max = 199.5 * PITCH - xc  # to the nearer end
    assert theta[-1] == pytest.approx(math.atan(rho_max / r0), rel=1e-12)
    assert theta[0] == pytest.approx(-theta[-1], rel=1e-12)
    # snapped positions are the nearest lattice points of x_c + r0 tan(theta)
    x = xc + r0 * np.tan(theta)
    assert m.obtained_points == n
    assert np.max(np.abs(m.positions[:, 0] - x)) <= PITCH / 2 + 1e-15
    r = np.sqrt((m.positions[:, 0] - xc) ** 2 + r0**2)
    np.testing.assert_allclose(m.weights / m.weights[0], (r / r[0]) ** 2, rtol=1e-12)


def test_equiangular_paper_configuration():
    lat = Lattice(1024, 1, PITCH)
    m = equiangular_mask(lat, 128 * PITCH, 32)
    assert m.obtained_points == 32
    # paper: the outermost weight is 17 times the centremost
    assert m.weight_ratio == pytest.approx(17.0, rel=0.01)
    # covered length: the outermost sensors (the line's ends) widened by half the
    # median gap on each side
    x = np.sort(m.positions[:, 0])
    assert x[0] == pytest.approx(-511.5 * PITCH) and x[-1] == pytest.approx(511.5 * PITCH)
    gaps = np.diff(x)
    nn = np.minimum(np.r_[np.inf, gaps], np.r_[gaps, np.inf])
    assert m.covered_area == pytest.approx(1023 * PITCH + np.median(nn), rel=1e-12)


def test_snapping_drops_duplicates_and_reports_it():
    lat = Lattice(21, 1, PITCH)
    m = equiangular_mask(lat, 1 * PITCH, 21)  # steep fan: many angles map to the ends
    assert m.requested_points == 21
    assert m.obtained_points < 21
    assert np.unique(m.indices, axis=0).shape[0] == m.obtained_points


# --- bad input --------------------------------------------------------------------------

BIG = Lattice(50, 50, PITCH)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: equisteradian_mask(BIG, 1e-3, 100, poi=(5e-3, 0.0)), "outside the lattice"),
        (lambda: equisteradian_mask(BIG, 1e-3, 100, poi=(24.5 * PITCH, 0.0)), "edge"),
        (lambda: equisteradian_mask(BIG, 0.0, 100), "depth"),
        (lambda: equisteradian_mask(BIG, -1e-3, 100), "depth"),
        (lambda: equisteradian_mask(BIG, float("nan"), 100), "finite"),
        (lambda: equisteradian_mask(BIG, 1e-3, 0), "n_points"),
        (lambda: equisteradian_mask(BIG, 1e-3, 2501), "more than the lattice holds"),
        (lambda: equisteradian_mask(BIG, 1e-3, 10, poi=(float("inf"), 0.0)), "finite"),
        (lambda: equisteradian_mask(LINE, 1e-3, 10), "2-D lattice"),
        (lambda: equiangular_mask(LINE, 1e-3, 10, poi=1.0), "outside the lattice"),
        (lambda: equiangular_mask(LINE, 0.0, 10), "depth"),
        (lambda: equiangular_mask(LINE, 1e-3, 202), "more than the lattice holds"),
        (lambda: equiangular_mask(LINE, 1e-3, -3), "n_points"),
        (lambda: equiangular_mask(BIG, 1e-3, 10), "line lattice"),
        (lambda: Lattice(10, 10, 0.0), "pitch"),
        (lambda: Lattice(10, 10, -1e-5), "pitch"),
        (lambda: Lattice(10, 10, float("nan")), "finite"),
        (lambda: Lattice(0, 10, 1e-5), "n_x"),
        (lambda: make_mask("subgrid", BIG, interval=0), "interval"),
        (lambda: make_mask("subgrid", BIG, interval=5, n_per_side=11), "do not fit"),
        (lambda: make_mask("hexagonal", BIG, spacing=-1.0), "spacing"),
        (lambda: make_mask("random", BIG, n_points=2501), "more than the lattice holds"),
        (lambda: make_mask("poisson", BIG, min_distance=float("nan")), "finite"),
        (lambda: make_mask("points", BIG, points=[[0.0, 0.0], [1.0, 0.0]]), "outside the"),
        (lambda: make_mask("points", BIG, points=[[0.0, float("nan")]]), "non-finite"),
        (lambda: make_mask("points", BIG, indices=[[0, 50]]), "outside"),
        (lambda: make_mask("points", BIG), "exactly one"),
        (lambda: make_mask("nosuch", BIG), "unknown mask kind"),
        (lambda: make_mask("equisteradian", BIG, depth=1e-3), "needs parameter"),
        (lambda: make_mask("full", BIG, depth=1e-3), "unknown parameter"),
    ],
)
def test_bad_input_raises_value_error_with_reason(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@settings(max_examples=12, deadline=None, derandomize=True)
@given(
    data=st.data(),
    n_x=st.integers(5, 40),
    square=st.booleans(),
    kind=st.sampled_from(["subgrid", "hexagonal", "random", "poisson", "points"]),
)
def test_every_kind_valid_on_random_lattices(data, n_x, square, kind):
    lat = Lattice(n_x, n_x if square else 1, PITCH)
    if kind == "hexagonal" and lat.is_line:
        kind = "subgrid"
    if kind == "subgrid":
        params = {"interval": data.draw(st.integers(1, max(1, (n_x - 1) // 2)))}
    elif kind == "hexagonal":
        params = {"spacing": data.draw(st.floats(1.0, n_x / 3)) * PITCH}
    elif kind == "random":
        params = {"n_points": data.draw(st.integers(1, lat.n_points)), "seed": data.draw(st.integers(0, 99))}
    elif kind == "poisson":
        params = {"min_distance": data.draw(st.floats(0.5, n_x / 2)) * PITCH, "seed": data.draw(st.integers(0, 99))}
    else:
        h = np.array(lat.half_extent) + PITCH / 2 * (1 - 1e-9)
        k = data.draw(st.integers(1, 30))
        pts = np.column_stack((data.draw(st.lists(st.floats(-1, 1), min_size=k, max_size=k)),
                               data.draw(st.lists(st.floats(-1, 1), min_size=k, max_size=k)))) * h
        params = {"points": pts}
    m = make_mask(kind, lat, **params)
    n = m.obtained_points
    assert 1 <= n <= m.requested_points
    assert np.unique(m.indices, axis=0).shape[0] == n
    assert m.indices[:, 0].max() < lat.n_x and m.indices[:, 1].max() < lat.n_y and m.indices.min() >= 0
    assert np.all(m.weights > 0) and np.all(np.isfinite(m.weights))
    assert m.weights.sum() == pytest.approx(voronoi_weights(m.recon_positions(), PITCH).sum(), rel=1e-12)
