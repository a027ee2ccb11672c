"""One set of plan limits: the scanner side (``fpscan.driver.plan.load_plan``, the contract's
owner), the service's model (``fpscan.service.plans.Plan``) and ``POST /api/plans`` (a real
server) refuse the same hostile acquisition values, each naming the field, and accept the
same plan with every acquisition setting at its limit.

Oracles: the limits as numbers written here (8 to 65536 samples, 4096 averages, 100 kHz,
16 wavelengths, 100-10000 m/s, 1 ms), and each plan's id recomputed independently
(sha256 of the canonical JSON) so that only the value under test can be the reason."""
from __future__ import annotations

import copy
import hashlib
import json

import pytest

from fpscan.driver.plan import load_plan
from fpscan.service.plans import Plan, make_plan
from tests.service.service_servers import Server

AT_LIMIT = {"n_t": 65536, "averages": 4096, "prf": 1e5, "sound_speed": 10000.0,
            "wavelengths": [(500 + 50 * i) * 1e-9 for i in range(16)], "wavelength_order": "per_pass"}

HOSTILE = [  # (field, value): just past a limit, or of the wrong kind
    ("n_t", 7), ("n_t", 65537), ("n_t", 2.5), ("n_t", True),
    ("averages", 0), ("averages", 4097),
    ("prf", -1.0), ("prf", 100000.5),
    ("sound_speed", 100.0), ("sound_speed", 10000.5), ("sound_speed", "fast"),
    ("dt", 0.0), ("dt", -8e-9), ("dt", 2e-3),
    ("wavelengths", [(500 + 50 * i) * 1e-9 for i in range(17)]), ("wavelengths", []),
    ("wavelength_order", "banana"),
]


def _with_id(plan: dict) -> dict:
    body = {k: v for k, v in plan.items() if k != "id"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return {**body, "id": hashlib.sha256(text.encode()).hexdigest()}


def _plan(**acquisition) -> dict:
    base = make_plan(kind="points", lattice={"n_x": 5, "n_y": 5, "pitch": 1e-4},
                     params={"indices": [[0, 0], [2, 2], [4, 1]]},
                     acquisition={"n_t": 64, "dt": 8e-9, "prf": 0}).to_dict()
    plan = copy.deepcopy(base)
    plan["acquisition"].update(acquisition)
    return _with_id(plan)


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("limits") / "data").start()
    try:
        with srv.client() as c:
            yield c
    finally:
        srv.stop()


def test_a_plan_at_every_limit_is_accepted_by_all(api):
    plan = _plan(**AT_LIMIT)
    assert load_plan(plan) is plan  # the scanner side
    assert Plan.from_dict(plan).id == plan["id"]  # the service's model
    r = api.post("/api/plans", json=plan)
    assert r.status_code == 201, r.text
    assert r.json()["id"] == plan["id"]


@pytest.mark.parametrize(("field", "value"), HOSTILE, ids=[f"{f}={v!r}"[:40] for f, v in HOSTILE])
def test_hostile_acquisition_values_are_refused_alike(api, field, value):
    plan = _plan(**{field: value})
    named = "wavelength" if field.startswith("wavelength") else field
    with pytest.raises(ValueError, match=named):
        load_plan(plan)
    with pytest.raises(ValueError):
        Plan.from_dict(plan)
    r = api.post("/api/plans", json=plan)
    assert r.status_code == 422, (field, value, r.text)
    assert named in r.text, r.text


def test_service_model_takes_the_drivers_reason():
    """The model does not check the limits itself: its message is the driver's."""
    plan = _plan(n_t=65537)
    with pytest.raises(ValueError) as driver_err:
        load_plan(plan)
    with pytest.raises(ValueError) as model_err:
        Plan.from_dict(plan)
    assert str(driver_err.value) in str(model_err.value)
