"""The plan contract has one owner (fpscan.driver.plan) and one builder (fpscan.service.plans.make_plan):
point lists are ordered and validated like every mask; one weight-ratio definition."""
from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from fpscan.driver.plan import canonical_json, check_plan, load_plan, plan_id_of
from fpscan.service.plans import Lattice, make_plan, weight_ratio


def test_weight_ratio_is_outer_over_inner_by_hand():
    # distances from the centre: 0, 1, 3, 3 -> outer = mean(5, 7) = 6, inner = 1
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [0.0, 3.0]])
    w = np.array([1.0, 2.0, 5.0, 7.0])
    assert weight_ratio(pos, w) == 6.0
    # about another centre (1, 0): distances 1, 0, 2, sqrt(10) -> 7 / 2
    assert weight_ratio(pos, w, centre=(1.0, 0.0)) == 3.5


def test_point_list_plan_uses_the_same_weight_ratio_and_order():
    lat = {"n_x": 9, "n_y": 9, "pitch": 1e-4}
    # scrambled on purpose; the centre (4, 4) is in the list, the corners are the outermost
    listed = [[8, 8], [4, 4], [0, 0], [2, 6], [6, 1], [0, 8]]
    plan = make_plan(kind="points", lattice=lat, params={"indices": listed}, order="serpentine").to_dict()
    # serpentine by hand: rows i_y = 0, 1, 4, 6, 8; x up on rows 0, 2, 4 of those, down on 1, 3
    assert plan["points"]["indices"] == [[0, 0], [6, 1], [4, 4], [2, 6], [0, 8], [8, 8]]
    assert plan["order"] == "serpentine"
    pos = np.asarray(plan["points"]["positions"])
    w = np.asarray(plan["points"]["weights"])
    d = np.hypot(pos[:, 0], pos[:, 1])
    outer, inner = w[np.isclose(d, d.max())].mean(), w[np.isclose(d, d.min())].mean()
    assert plan["mask"]["weight_ratio"] == pytest.approx(outer / inner, rel=1e-12)
    assert outer / inner != pytest.approx(w.max() / w.min())  # not the max/min definition
    # the user's order is the default for a point list ("given")
    given = make_plan(kind="points", lattice=lat, params={"indices": listed}).to_dict()
    assert given["points"]["indices"] == listed and given["order"] == "given"


@pytest.mark.parametrize("order", ["banana", "", "SERPENTINE"])
def test_bad_order_is_a_value_error_naming_it(order):
    lat = {"n_x": 5, "n_y": 5, "pitch": 1e-4}
    if order == "":
        assert make_plan(kind="full", lattice=lat, order=order).order == "serpentine"  # empty = auto
        return
    with pytest.raises(ValueError, match=f"unknown order '{order}'"):
        make_plan(kind="points", lattice=lat, params={"indices": [[0, 0], [1, 1]]}, order=order)


def test_one_hash_one_canonical_form():
    plan = make_plan(kind="full", lattice={"n_x": 3, "n_y": 2, "pitch": 1e-4}, n_t=16).to_dict()
    body = {k: v for k, v in plan.items() if k != "id"}
    independent = hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    assert plan_id_of(plan) == independent == plan["id"]
    assert load_plan(json.dumps(plan, indent=2)) == plan
    with pytest.raises(ValueError, match="NaN or infinity"):
        canonical_json({"x": float("nan")})
    bad = json.loads(json.dumps(plan))
    bad["acquisition"]["sound_speed"] = float("inf")
    with pytest.raises(ValueError, match="sound_speed"):
        check_plan(bad)


@pytest.mark.parametrize("wavelengths, reason", [
    ([], "at least one"),
    ([350e-9], "400 nm to 2000 nm"),
    ([2100e-9], "400 nm to 2000 nm"),
    ([750e-9, 800e-9, 750e-9], "repeat"),
    (["750nm"], "number"),
])
def test_wavelengths_checked_once_for_driver_and_service(wavelengths, reason):
    lat = Lattice(3, 3, 1e-4)
    with pytest.raises(ValueError, match=reason):
        make_plan(kind="full", lattice=lat, wavelengths=wavelengths)
    plan = make_plan(kind="full", lattice=lat, wavelengths=[750e-9, 1064e-9]).to_dict()
    plan["acquisition"]["wavelengths"] = wavelengths
    plan["id"] = plan_id_of(plan)
    with pytest.raises(ValueError, match=reason):
        check_plan(plan)
