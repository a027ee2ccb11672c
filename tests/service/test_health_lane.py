"""``GET /api/health`` answered by health's lane (``fpscan.service.api.lanes.HealthLane``) on
a real server: the answer is the contract the OpenAPI schema states for the route, its disk
figures are the data folder's (counted here with ``os.walk``), and whatever the lane does not
answer (another method, a refused request) reaches the app and its rules as before."""
from __future__ import annotations

import os

import httpx


def _folder_bytes(path) -> int:
    return sum(os.lstat(os.path.join(root, f)).st_size for root, _, files in os.walk(path) for f in files)


def test_the_lane_answers_the_routes_contract(server, api):
    r = api.get("/api/health")
    assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    body = r.json()
    schema = api.get("/openapi.json").json()
    ref = schema["paths"]["/api/health"]["get"]["responses"]["200"]["content"]["application/json"]["schema"]["$ref"]
    health = schema["components"]["schemas"][ref.rsplit("/", 1)[1]]
    assert set(body) == set(health["properties"]) and set(health.get("required", [])) <= set(body)
    assert body["status"] == "ok" and body["jobs_running"] == 0
    disk = schema["components"]["schemas"]["DiskUse"]
    assert set(body["disk"]) == set(disk["properties"])
    # the figures are the data folder's as this test counts them (the database may grow
    # between the answer and the count: only the parts it does not hold are compared exactly)
    data = server.data_dir
    for part in ("scans", "results", "datasets", "exports"):
        assert body["disk"][f"{part}_bytes"] == (_folder_bytes(data / part) if (data / part).is_dir() else 0), part
    assert body["disk"]["total_bytes"] >= body["disk"]["other_bytes"] > 0  # the job database


def test_what_the_lane_does_not_answer_reaches_the_app(server, api):
    r = api.post("/api/health")
    assert r.status_code == 405 and r.headers["allow"] == "GET", (r.status_code, r.headers, r.text)
    with httpx.Client(base_url=server.url, timeout=30) as anon:
        r = anon.get("/api/health")
        assert r.status_code == 401 and r.json()["detail"] == "missing bearer token"
        assert r.headers["www-authenticate"] == "Bearer"
        r = anon.get("/api/health", headers={"Authorization": f"Bearer {server.token}", "Host": "evil.example"})
        assert r.status_code == 403 and "--allowed-host" in r.json()["detail"]
