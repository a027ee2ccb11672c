"""Mask kinds declared once: the API schema, the CLI and `GET /api/plans/kinds` offer the
same kinds and parameters; a plan JSON made by `fpscan plan` is accepted by
`POST /api/plans` under its own id."""
from __future__ import annotations

import argparse
import json

import pytest

from fpscan.clients.cli import build_parser, main

LATTICE = {"n_x": 8, "n_y": 8, "pitch": 1e-4}


def api_kinds(openapi: dict) -> dict[str, set[str]]:
    """kind -> parameter names, read from the request schema of POST /api/plans."""
    schemas = openapi["components"]["schemas"]

    def deref(s):
        return schemas[s["$ref"].rsplit("/", 1)[1]] if "$ref" in s else s

    body = openapi["paths"]["/api/plans"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    out = {}
    for variant in map(deref, deref(body)["oneOf"]):
        if "kind" not in variant["properties"]:
            continue  # the plan JSON variant
        kind_schema = variant["properties"]["kind"]
        kind = kind_schema.get("const") or kind_schema["enum"][0]
        params = variant["properties"]["params"]
        refs = [deref(o) for o in params.get("anyOf", [params]) if o.get("type") != "null"]
        out[kind] = set(refs[0].get("properties", {}))
    return out


def cli_kinds() -> dict[str, set[str]]:
    """kind -> parameter names, read from `fpscan plan`'s argparse parser."""
    def sub_action(p):
        return next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))

    plan = sub_action(build_parser()).choices["plan"]
    out, seen = {}, set()
    for name, parser in sub_action(plan).choices.items():
        if id(parser) in seen:
            continue  # an alias
        seen.add(id(parser))
        out[name] = {a.dest[2:] for a in parser._actions if a.dest.startswith("p_")}
    return out


def test_cli_kinds_endpoint_and_api_schema_agree(shared_api):
    from_api = api_kinds(shared_api.get("/openapi.json").json())
    listed = shared_api.get("/api/plans/kinds").json()
    from_endpoint = {k["kind"]: {f["name"] for f in k["fields"]} for k in listed}
    assert from_api == from_endpoint == cli_kinds()
    assert {"equisteradian", "equiangular", "equispaced", "full", "points"} <= set(from_api)
    assert from_api["equisteradian"] == {"depth", "n_points", "poi"}
    depth = next(f for f in listed[0]["fields"] if f["name"] == "depth")
    assert depth["unit"] == "m" and depth["required"]


def test_plan_json_from_the_cli_is_accepted_with_its_id(shared_api, tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert main(["plan", "equisteradian", "--n-x", "24", "--pitch", "1e-4", "--depth", "1e-3",
                 "--n-points", "60", "--n-t", "128", "--out", str(out)]) == 0
    capsys.readouterr()
    doc = json.loads(out.read_text())
    r = shared_api.post("/api/plans", json=doc)
    assert r.status_code == 201, r.text
    assert r.json()["id"] == doc["id"] and r.json()["n_points"] == len(doc["points"]["indices"])
    assert shared_api.get(f"/api/plans/{doc['id']}/plan.json").json() == doc
    # the same plan asked for by kind and params on the server has the same id
    same = shared_api.post("/api/plans/preview", json={
        "kind": "equisteradian", "lattice": {"n_x": 24, "n_y": 24, "pitch": 1e-4},
        "params": {"depth": 1e-3, "n_points": 60}, "acquisition": {"n_t": 128}})
    assert same.status_code == 200 and same.json()["points"] == len(doc["points"]["indices"])
    # a tampered plan JSON is refused with the reason
    bad = json.loads(out.read_text())
    bad["points"]["weights"][0] *= 2
    r = shared_api.post("/api/plans", json=bad)
    assert r.status_code == 422 and "content hash" in r.json()["detail"]


@pytest.mark.parametrize("body, reason", [
    ({"kind": "equisteradian", "lattice": LATTICE, "params": {"depth": 1e-3}}, "n_points"),
    ({"kind": "equisteradian", "lattice": LATTICE, "params": {"depth": 1e-3, "n_points": 9, "x": 1}}, "x"),
    ({"kind": "banana", "lattice": LATTICE}, "mask kind"),
    ({"kind": "grid", "lattice": LATTICE, "params": {"interval": 0}}, "interval"),
    ({"kind": "points", "lattice": LATTICE, "params": {"indices": [[0, 0]]}, "points": [[1, 1]]}, "not both"),
])
def test_kind_parameters_are_checked_by_their_model(shared_api, body, reason):
    r = shared_api.post("/api/plans/preview", json=body)
    assert r.status_code == 422, r.text
    assert reason in r.json()["detail"]
