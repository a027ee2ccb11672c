"""Smaller contracts on a real server: a method a path does not take is a
405 whose ``Allow`` names every method the path takes; the retention bound the schema
states is the one the server enforces (no schema-valid value refused)."""
from __future__ import annotations

import pytest


@pytest.mark.parametrize(("path", "allowed"), [
    ("/api/health", {"GET"}), ("/api/plans", {"GET", "POST"}), ("/api/retention", {"GET", "PUT"}),
    ("/api/jobs/abc", {"GET", "DELETE"}), ("/api/reconstructions", {"POST"}),
])
def test_options_and_other_methods_get_405_with_every_allowed_method(shared_api, path, allowed):
    for method in ("OPTIONS", "PATCH"):
        r = shared_api.request(method, path)
        assert r.status_code == 405, (method, path, r.text)
        assert set(r.headers["allow"].split(", ")) == allowed, r.headers
        assert method in r.json()["detail"]


def test_retention_keep_bytes_bound_is_the_schema_bound(shared_api):
    schema = shared_api.get("/openapi.json").json()["components"]["schemas"]["Retention"]
    number = next(o for o in schema["properties"]["keep_bytes"]["anyOf"] if o.get("type") == "integer")
    bound = number["maximum"]
    assert int(bound) == bound and str(int(bound)) == f"{bound:.0f}"  # written exactly (no float rounding up)
    for value, status in ((int(bound), 200), (int(bound) - 1, 200), (int(bound) + 1, 422), (2**63 + 5, 422)):
        r = shared_api.put("/api/retention", json={"keep_bytes": value})
        assert r.status_code == status, (value, r.text)
        if status == 200:
            assert r.json()["keep_bytes"] == value
    shared_api.put("/api/retention", json={})
