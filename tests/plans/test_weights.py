"""Clipped Voronoi weights (fpscan.physics.weights) against exact oracles."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics.weights import infer_pitch, voronoi_weights

PITCH = 60e-6


def grid(nx, ny, pitch=PITCH, step=1, offset=(0, 0)):
    x = (np.arange(0, nx, step) + offset[0] - (nx - 1) / 2) * pitch
    y = (np.arange(0, ny, step) + offset[1] - (ny - 1) / 2) * pitch
    gx, gy = np.meshgrid(x, y)
    return np.column_stack((gx.ravel(), gy.ravel()))


@pytest.mark.parametrize("pitch_arg", [PITCH, None])
def test_full_lattice_every_cell_is_pitch_squared(pitch_arg):
    pos = grid(37, 24)
    w = voronoi_weights(pos, pitch_arg)
    np.testing.assert_allclose(w, PITCH**2, rtol=1e-12)
    # clipped to the lattice's own area: the raster path, not the shortcut
    hx, hy = 18 * PITCH, 11.5 * PITCH
    w2 = voronoi_weights(pos, PITCH, bounds=((-hx - PITCH / 2, hx + PITCH / 2), (-hy - PITCH / 2, hy + PITCH / 2)))
    np.testing.assert_allclose(w2, PITCH**2, rtol=1e-12)


@pytest.mark.parametrize("pitch_arg", [PITCH, None])
def test_subgrid_cells_are_interval_pitch_squared(pitch_arg):
    # every 5th point of a 226 x 226 lattice, 41 x 41 (the paper's comparison grid)
    s = 5
    idx = 12 + s * np.arange(41)
    x = (idx - 112.5) * PITCH
    gx, gy = np.meshgrid(x, x)
    pos = np.column_stack((gx.ravel(), gy.ravel()))
    lat_bounds = ((-113 * PITCH, 113 * PITCH),) * 2
    for b in (None, lat_bounds):
        w = voronoi_weights(pos, pitch_arg, bounds=b)
        np.testing.assert_allclose(w, (s * PITCH) ** 2, rtol=1e-12)
        assert w.sum() == pytest.approx(41 * 41 * (s * PITCH) ** 2, rel=1e-12)


def test_line_exact_intervals():
    x = np.array([0.0, 1.0, 3.0, 7.0, 8.0]) * PITCH
    w = voronoi_weights(x[:, None], PITCH)
    # mid-points 0.5, 2, 5, 7.5; NN distances d = [1, 1, 2, 1, 1], d_med = 1, so the
    # ends are widened by d_med/2; the reach 3*max(d_i, d_med) clips nothing here
    lo, hi = -0.5, 8.5
    edges = np.array([lo, 0.5, 2.0, 5.0, 7.5, hi])
    # sensor 3 at 7: reach 3*max(1,1)=3 -> [4, 10]: no clip; sensor 2 at 3: reach 6 -> none
    expected = np.diff(edges) * PITCH
    np.testing.assert_allclose(w, expected, rtol=1e-12)
    full = voronoi_weights(((np.arange(100) - 49.5) * PITCH)[:, None])
    np.testing.assert_allclose(full, PITCH, rtol=1e-9)


def _polygon_area(poly):
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _clip_halfplane(poly, n, c):
    """Keep {p : n·p <= c} of a convex polygon (Sutherland-Hodgman, one edge)."""
    out = []
    k = len(poly)
    for i in range(k):
        p, q = poly[i], poly[(i + 1) % k]
        fp, fq = n @ p - c, n @ q - c
        if fp <= 0:
            out.append(p)
        if fp * fq < 0:
            t = fp / (fp - fq)
            out.append(p + t * (q - p))
    return np.array(out) if out else np.zeros((0, 2))


def exact_cells(pos, box):
    """Exact Voronoi cell areas clipped to a box, by half-plane clipping against every
    other sensor (O(n^2)); the independent oracle."""
    (x0, x1), (y0, y1) = box
    areas = []
    for i, p in enumerate(pos):
        poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
        for j, q in enumerate(pos):
            if i == j or len(poly) == 0:
                continue
            n = q - p
            c = 0.5 * (q @ q - p @ p)
            poly = _clip_halfplane(poly, n, c)
        areas.append(_polygon_area(poly) if len(poly) >= 3 else 0.0)
    return np.array(areas)


def test_irregular_cells_match_exact_polygons():
    rng = np.random.default_rng(7)
    base = grid(12, 12, pitch=1.0, step=1)
    pos = base + rng.uniform(-0.3, 0.3, base.shape)
    w = voronoi_weights(pos, 1.0)
    # the documented covered box: bounding box widened by half the median NN distance
    d = np.sqrt(((pos[:, None] - pos[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    half = 0.5 * np.median(d.min(1))
    box = ((pos[:, 0].min() - half, pos[:, 0].max() + half), (pos[:, 1].min() - half, pos[:, 1].max() + half))
    oracle = exact_cells(pos, box)
    np.testing.assert_allclose(w, oracle, rtol=0.03)
    # edge raster cells are cut exactly by the box: the total is the box area
    assert w.sum() == pytest.approx(oracle.sum(), rel=1e-9)
    assert oracle.sum() == pytest.approx(np.prod([b[1] - b[0] for b in box]), rel=1e-9)


def test_sparse_disc_does_not_claim_far_corners():
    # a ring of sensors inside a big box: each cell is limited to 3 x its NN distance
    phi = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    pos = np.column_stack((np.cos(phi), np.sin(phi))) * 1e-3
    box = ((-0.1, 0.1), (-0.1, 0.1))
    w = voronoi_weights(pos, 1e-5, bounds=box)
    d = 2 * 1e-3 * np.sin(np.pi / 16)
    assert np.all(w > 0)
    assert np.all(w <= np.pi * (3 * d) ** 2)


def test_infer_pitch():
    assert infer_pitch(grid(10, 10)) == pytest.approx(PITCH, rel=1e-12)
    assert infer_pitch(grid(20, 20, step=4)) == pytest.approx(4 * PITCH, rel=1e-12)
    assert infer_pitch(np.array([[0.0, 0.0], [1.0, 0.3], [0.25, 0.7]])) == pytest.approx(0.05)  # 20 x 14 grid
    assert infer_pitch(np.array([[0.0, 0.0], [1.0, np.sqrt(0.1)], [0.25, 0.7]])) is None


@pytest.mark.parametrize(
    "pos, pitch, match",
    [
        (np.array([[0.0, 0.0], [np.nan, 1.0]]), None, "non-finite"),
        (np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]]), None, "duplicated"),
        (np.array([[0.0, 0.0], [1.0, 1.0]]), 0.0, "pitch"),
        (np.array([[0.0, 0.0], [1.0, 1.0]]), -1.0, "pitch"),
        (np.array([[0.0, 0.0], [1.0, 1.0]]), np.inf, "pitch"),
        (np.zeros((3, 3)), None, "shape"),
        (np.zeros((0, 2)), None, "at least one"),
    ],
)
def test_bad_input(pos, pitch, match):
    with pytest.raises(ValueError, match=match):
        voronoi_weights(pos, pitch)


@pytest.mark.parametrize("step", [1, 3])
def test_raster_path_is_exact_away_from_a_hole(step):
    # a lattice (or sub-grid) with one interior point missing: no shortcut; cells not
    # touching the hole stay exact squares, the hole's area goes to its neighbours
    pos = grid(31, 31, step=step)
    spacing = step * PITCH
    centre = np.argmin(np.hypot(pos[:, 0], pos[:, 1]))
    hole = pos[centre]
    pos = np.delete(pos, centre, axis=0)
    w = voronoi_weights(pos, PITCH)
    far = np.max(np.abs(pos - hole), axis=1) > 1.5 * spacing
    np.testing.assert_allclose(w[far], spacing**2, rtol=1e-12)
    n_side = len(np.unique(pos[:, 0]))
    assert w.sum() == pytest.approx(n_side**2 * spacing**2, rel=1e-12)
    # the hole's square goes to its four axis neighbours, a quarter each
    gain = np.sort(w[~far] / spacing**2 - 1)
    np.testing.assert_allclose(gain, [0] * 4 + [0.25] * 4, atol=1e-12)


def test_infer_pitch_of_a_sparse_lattice_subset():
    rng = np.random.default_rng(3)
    full = grid(60, 60)
    # keep points whose x index is even and y index a multiple of 3: closest coordinates
    # are 2 and 3 pitches apart; the common lattice is 1 pitch
    ix = np.round(full[:, 0] / PITCH + 29.5).astype(int)
    iy = np.round(full[:, 1] / PITCH + 29.5).astype(int)
    sub = full[(ix % 2 == 0) & (iy % 3 == 0)]
    sub = sub[rng.permutation(len(sub))[:200]]
    assert infer_pitch(sub) == pytest.approx(PITCH, rel=1e-9)
