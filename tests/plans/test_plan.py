"""Plans: JSON and HDF5 round trips, the content id, orderings, scan time, preview."""
from __future__ import annotations

import copy
import hashlib
import io
import json

import h5py
import numpy as np
import pytest
from PIL import Image

from fpscan.service.plans import (
    Lattice,
    Plan,
    make_mask,
    make_plan,
    nearest_neighbour_order,
    plan_from_spec,
    preview_png,
)

PITCH = 60e-6
LAT = Lattice(64, 64, PITCH)


@pytest.fixture(scope="module")
def es_plan():
    mask = make_mask("equisteradian", LAT, depth=1.5e-3, n_points=300, poi=[0.3e-3, -0.2e-3])
    return make_plan(mask, n_t=512, dt=1e-8, averages=2, wavelengths=[7.5e-7, 8.0e-7], prf=100.0)


def _independent_id(d):
    body = {k: v for k, v in d.items() if k != "id"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def test_plan_json_has_the_fixed_format(es_plan):
    d = json.loads(es_plan.to_json())
    assert set(d) == {"format", "id", "lattice", "mask", "points", "order", "acquisition"}
    assert d["format"] == "fpscan-plan/1"
    assert d["lattice"] == {"n_x": 64, "n_y": 64, "pitch": PITCH}
    assert set(d["mask"]) == {"kind", "params", "requested_points", "obtained_points", "weight_ratio"}
    assert d["mask"]["kind"] == "equisteradian"
    assert d["mask"]["params"] == {"depth": 1.5e-3, "n_points": 300, "poi": [0.3e-3, -0.2e-3]}
    assert d["mask"]["obtained_points"] == len(d["points"]["indices"]) == len(d["points"]["weights"])
    assert set(d["acquisition"]) == {"n_t", "dt", "averages", "wavelengths", "prf", "sound_speed"}
    assert d["order"] == "rings"
    assert d["id"] == _independent_id(d)
    # positions are the centred lattice coordinates of the indices
    idx = np.array(d["points"]["indices"])
    pos = np.array(d["points"]["positions"])
    np.testing.assert_array_equal(pos, (idx - 31.5) * PITCH)


def test_json_round_trip_file(es_plan, tmp_path):
    path = tmp_path / "plan.json"
    es_plan.to_json(path)
    back = Plan.from_json(path)
    assert back == es_plan
    assert back.id == es_plan.id
    np.testing.assert_array_equal(back.weights_array(), es_plan.weights_array())
    np.testing.assert_array_equal(back.positions_array(), es_plan.positions_array())


def _reverse_keys(obj):
    if isinstance(obj, dict):
        return {k: _reverse_keys(obj[k]) for k in reversed(list(obj))}
    if isinstance(obj, list):
        return [_reverse_keys(v) for v in obj]
    return obj


def test_id_stable_under_key_order_and_formatting(es_plan):
    d = json.loads(es_plan.to_json())
    text = json.dumps(_reverse_keys(d), indent=3)  # different key order and whitespace
    back = Plan.from_json(text)
    assert back.id == es_plan.id


@pytest.mark.parametrize(
    "change",
    [
        lambda d: d["points"]["weights"].__setitem__(0, d["points"]["weights"][0] * (1 + 1e-15) + 1e-30),
        lambda d: d["acquisition"].__setitem__("averages", 3),
        lambda d: d["acquisition"].__setitem__("prf", 99.0),
        lambda d: d["acquisition"]["wavelengths"].append(9e-7),
        lambda d: d.__setitem__("order", "nearest"),
        lambda d: d["points"]["indices"].reverse() or d["points"]["positions"].reverse() or d["points"]["weights"].reverse(),
        lambda d: d["mask"]["params"].__setitem__("n_points", 301),
    ],
)
def test_any_real_change_changes_the_id(es_plan, change):
    d = json.loads(es_plan.to_json())
    changed = copy.deepcopy(d)
    change(changed)
    assert changed != d
    new_id = _independent_id(changed)
    assert new_id != d["id"]
    with pytest.raises(ValueError, match="content hash"):
        Plan.from_dict(changed)  # the old id no longer matches
    changed["id"] = new_id
    assert Plan.from_dict(changed).id == new_id


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d.__setitem__("format", "fpscan-plan/2"), "format"),
        (lambda d: d["points"]["indices"].__setitem__(0, [64, 0]), "outside"),
        (lambda d: d["points"]["positions"].__setitem__(0, [1.0, 1.0]), "lattice positions"),
        (lambda d: d["points"]["weights"].__setitem__(0, -1.0), "weights"),
        (lambda d: d["points"]["weights"].pop(), r"weights must be \(\d+,\)"),  # fpscan.driver.plan.check_plan
        (lambda d: d["acquisition"].__setitem__("dt", 0.0), "dt"),
        (lambda d: d.__setitem__("extra", 1), "extra"),
    ],
)
def test_invalid_plans_are_rejected(es_plan, mutate, match):
    d = json.loads(es_plan.to_json())
    mutate(d)
    d["id"] = _independent_id(d)
    with pytest.raises(ValueError, match=match):
        Plan.from_dict(d)


def test_hdf5_round_trip(es_plan, tmp_path):
    path = tmp_path / "plan.h5"
    with h5py.File(path, "w") as f:
        es_plan.to_hdf5(f.create_group("plan"))
    with h5py.File(path, "r") as f:
        g = f["plan"]
        assert g["indices"].shape == (es_plan.n_points, 2)
        assert g["weights"].dtype == np.float64
        back = Plan.from_hdf5(g)
    assert back == es_plan and back.id == es_plan.id
    with h5py.File(path, "a") as f:
        del f["plan"]["weights"]
        with pytest.raises(ValueError, match="missing"):
            Plan.from_hdf5(f["plan"])


def test_expected_scan_time(es_plan):
    n = es_plan.n_points
    assert es_plan.expected_scan_time_s == pytest.approx(n * 2 * 2 / 100.0)
    full = make_plan(make_mask("full", Lattice(226, 226, PITCH)))
    # the paper's full scan: 51076 points at 50 Hz = 17 minutes
    assert full.expected_scan_time_s == pytest.approx(51076 / 50)
    assert 16.9 < full.expected_scan_time_s / 60 < 17.1


def test_serpentine_order_on_a_subgrid():
    mask = make_mask("subgrid", LAT, interval=3, n_per_side=[7, 5])
    plan = make_plan(mask, order="serpentine")
    idx = plan.indices_array()
    steps = np.abs(np.diff(idx, axis=0)).sum(axis=1)
    assert np.all(steps == 3)  # every move is to an adjacent sub-grid point
    rows = idx[:, 1].reshape(5, 7)
    assert np.all(rows == rows[:, :1])
    xs = idx[:, 0].reshape(5, 7)
    assert np.all(np.diff(xs[0::2], axis=1) > 0) and np.all(np.diff(xs[1::2], axis=1) < 0)
    assert sorted(map(tuple, idx)) == sorted(map(tuple, mask.indices))


def test_ring_order_alternates(es_plan):
    mask = make_mask("equisteradian", LAT, depth=1.5e-3, n_points=300)
    plan = make_plan(mask)
    assert plan.order == "rings"
    pos = plan.positions_array()
    rho = np.hypot(pos[:, 0], pos[:, 1])
    # ring numbers from the mask, mapped through the positions
    ring_of = {tuple(i): r for i, r in zip(map(tuple, mask.indices), mask.rings)}
    rings = np.array([ring_of[tuple(i)] for i in plan.indices_array()])
    assert np.all(np.diff(rings) >= 0)
    assert rho[0] == rho.min()
    directions = []
    for r in np.unique(rings):
        sel = pos[rings == r]
        if len(sel) < 3:
            continue
        az = np.unwrap(np.arctan2(sel[:, 1], sel[:, 0]))
        d = np.sign(np.diff(az))
        assert np.all(d == d[0])  # monotone within the ring
        directions.append(d[0])
    assert np.all(np.array(directions[1:]) == -np.array(directions[:-1]))


def test_nearest_neighbour_order_against_brute_force():
    rng = np.random.default_rng(1)
    pos = rng.uniform(0, 1, (150, 2))
    order = nearest_neighbour_order(pos, start=7)
    assert sorted(order) == list(range(150)) and order[0] == 7
    unvisited = set(range(150)) - {7}
    cur = 7
    for nxt in order[1:]:
        cand = np.array(sorted(unvisited))
        d = np.hypot(*(pos[cand] - pos[cur]).T)
        assert nxt == cand[np.argmin(d)]
        unvisited.remove(nxt)
        cur = nxt
    # and it shortens galvo travel against the serpentine order of a random mask
    mask = make_mask("random", LAT, n_points=400, seed=2)
    length = {}
    for order_name in ("serpentine", "nearest"):
        p = make_plan(mask, order=order_name).positions_array()
        length[order_name] = np.hypot(*np.diff(p, axis=0).T).sum()
    assert length["nearest"] < length["serpentine"]


def test_plan_from_spec_and_errors():
    spec = {
        "lattice": {"n_x": 40, "n_y": 40, "pitch": PITCH},
        "mask": {"kind": "subgrid", "params": {"interval": 4}},
        "acquisition": {"prf": 200.0},
    }
    plan = plan_from_spec(spec)
    assert plan.mask.obtained_points == 100 and plan.acquisition.prf == 200.0
    assert plan.order == "serpentine"
    bad = [
        ({**spec, "mask": {"kind": "bogus"}}, "unknown mask kind"),
        ({**spec, "lattice": {"n_x": 40, "n_y": 40, "pitch": -1.0}}, "pitch"),
        ({**spec, "order": "zigzag"}, "unknown order"),
        ({**spec, "acquisition": {"prf": -1.0}}, "prf"),
        ({k: v for k, v in spec.items() if k != "mask"}, "needs"),
        ({**spec, "wat": 1}, "unknown plan request field"),
    ]
    for s, match in bad:
        with pytest.raises(ValueError, match=match):
            plan_from_spec(s)


def test_line_plan_recon_positions():
    mask = make_mask("equiangular", Lattice(256, 1, PITCH), depth=32 * PITCH, n_points=16)
    plan = make_plan(mask)
    rp = plan.recon_positions()
    assert rp.shape == (16, 1)
    assert np.all(np.diff(rp[:, 0]) > 0)
    np.testing.assert_array_equal(rp, mask.recon_positions()[np.argsort(mask.recon_positions()[:, 0])])


def test_preview_png(es_plan, tmp_path):
    path = tmp_path / "mask.png"
    data = preview_png(es_plan, path)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.read_bytes() == data
    img = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
    assert img.shape[0] > 100 and img.shape[1] > 100
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # points in colour, not blank
    line = make_mask("equiangular", Lattice(256, 1, PITCH), depth=32 * PITCH, n_points=16)
    assert preview_png(line)[:4] == b"\x89PNG"
    with pytest.raises(ValueError):
        preview_png("not a mask")


def test_make_plan_from_kind_as_the_http_layer_calls_it():
    lattice = {"n_x": 50, "n_y": 50, "pitch": PITCH}
    acq = {"n_t": 256, "dt": 1e-8, "averages": 1, "wavelengths": [7.5e-7], "prf": 0.0, "sound_speed": 1500.0}
    a = make_plan(kind="equisteradian", lattice=lattice, params={"depth": 1e-3, "n_points": 120}, acquisition=acq)
    b = make_plan(make_mask("equisteradian", Lattice(50, 50, PITCH), depth=1e-3, n_points=120), acquisition=acq)
    c = make_plan("equisteradian", lattice=Lattice(50, 50, PITCH), params={"depth": 1e-3, "n_points": 120},
                  acquisition=acq)
    assert a.id == b.id == c.id
    assert a.expected_scan_time_s is None  # prf 0: unthrottled, the plan cannot say
    g = make_plan(kind="grid", lattice=lattice, params={"interval": 7}, order="nearest")
    assert g.mask.kind == "equispaced" and g.order == "nearest"  # "grid", "subgrid": aliases
    with pytest.raises(ValueError, match="unknown parameter"):
        make_plan(kind="full", lattice=lattice, params={"depth": 1.0})
    with pytest.raises(ValueError):
        make_plan(kind="full", lattice=lattice, acquisition={"colour": "red"})


def test_driver_reads_the_plan_json_without_service(es_plan, tmp_path):
    """The contract with the scanner side: fpscan.driver.plan parses our JSON and gets our id."""
    driver_plan = pytest.importorskip("fpscan.driver.plan")
    load_plan = getattr(driver_plan, "load_plan", None)
    plan_id_of = getattr(driver_plan, "plan_id_of", None)
    if load_plan is None or plan_id_of is None:
        pytest.skip("fpscan.driver.plan has no load_plan/plan_id_of")
    path = tmp_path / "plan.json"
    es_plan.to_json(path)
    d = load_plan(str(path))
    assert plan_id_of(d) == es_plan.id == d["id"]
