"""Hostile inputs against a real server (issue 14): every row of ``hostile_cases`` is
answered with its status and reason, without a hang (client-side time-outs), while
``/api/health`` keeps answering, and a refused upload leaves nothing on disk."""
from __future__ import annotations

import threading

import httpx
import pytest

from tests.service.hostile_cases import UPLOADS, plan_cases
from tests.service.service_servers import Server

BY_NAME = {case.name: case for case in UPLOADS}
#: Client-side bounds: a request not answered by then counts as hung.
ANSWER_S = 15.0
HEALTH_S = 5.0


class HealthWatch:
    """Polls ``/api/health`` in a thread; records every miss."""

    def __init__(self, url: str):
        self.url = url
        self.misses: list[str] = []
        self.polls = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(timeout=HEALTH_S) as c:
            while not self._stop.is_set():
                try:
                    r = c.get(self.url + "/api/health")
                    if r.status_code != 200:
                        self.misses.append(f"status {r.status_code}")
                except httpx.HTTPError as exc:
                    self.misses.append(type(exc).__name__)
                self.polls += 1
                self._stop.wait(0.2)

    def __enter__(self) -> HealthWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=HEALTH_S + 1)


@pytest.fixture(scope="module")
def hostile_server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("hostile") / "data",
                 env={"FPSCAN_IMPORT_TIMEOUT_S": "4", "FPSCAN_UPLOAD_LIMIT": str(64 * 2**20),
                      "FPSCAN_MEMORY_LIMIT": str(2 * 2**30)}).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return tmp_path_factory.mktemp("hostile-files")


@pytest.mark.timeout(300)
def test_hostile_uploads_are_refused_in_bounded_time(hostile_server, files):
    results = []
    with hostile_server.client(timeout=ANSWER_S) as api, HealthWatch(hostile_server.url) as health:
        for case in UPLOADS:
            path = case.make(files)
            with open(path, "rb") as fh:
                try:
                    r = api.post("/api/datasets", files={"file": (path.name, fh)},
                                 data={"format": case.fmt, **case.form})
                except httpx.TimeoutException:
                    results.append((case.name, "no answer", ""))
                    continue
            results.append((case.name, r.status_code, r.json().get("detail", "")))
        # a valid scan file is still accepted by the same server afterwards
        from tests.service.hostile_cases import scan_file

        with open(scan_file(files), "rb") as fh:
            ok = api.post("/api/datasets", files={"file": ("scan.h5", fh)}, data={"format": "fpscan"})
    wrong = [(name, status, detail, case.status, case.reason) for (name, status, detail), case
             in zip(results, UPLOADS) if status != case.status or case.reason.lower() not in detail.lower()]
    assert not wrong, wrong
    assert ok.status_code == 201, ok.text
    assert health.polls > 0 and not health.misses, health.misses
    # nothing of the refused uploads is left: only the accepted one
    left = sorted(p.name for p in (hostile_server.data_dir / "datasets").iterdir())
    assert left == [ok.json()["dataset_id"]], left
    secret = (files / "server-secret.bin").read_bytes()[:20]
    for p in (hostile_server.data_dir / "datasets").rglob("*"):
        assert not p.is_file() or secret not in p.read_bytes()


@pytest.mark.timeout(300)
def test_every_plan_parameter_at_hostile_values(hostile_server):
    cases = plan_cases()
    wrong = []
    with hostile_server.client(timeout=ANSWER_S) as api, HealthWatch(hostile_server.url) as health:
        for name, body, status in cases:
            try:
                r = api.post("/api/plans/preview", content=_json(body),
                             headers={"Content-Type": "application/json"})
            except httpx.TimeoutException:
                wrong.append((name, "no answer"))
                continue
            if r.status_code != status:
                wrong.append((name, r.status_code, r.text[:200]))
            elif status == 422 and ("http" in r.text or not r.json()["detail"]):
                wrong.append((name, "reason", r.text[:200]))
    assert not wrong, wrong
    assert not health.misses, health.misses


def _json(body: dict) -> str:
    """JSON with NaN/Infinity literals (what Python's json writes; the server must cope)."""
    import json

    return json.dumps(body, allow_nan=True)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("body, fragment", [
    ({"kind": "equisteradian", "lattice": {"n_x": 64, "n_y": 64, "pitch": 6e-5},
      "params": {"depth": 1e5, "n_points": 500}}, "depth"),
    ({"kind": "equisteradian", "lattice": {"n_x": 64, "n_y": 64, "pitch": 6e-5},
      "params": {"depth": 1e300, "n_points": 500}}, "depth"),
    ({"kind": "poisson", "lattice": {"n_x": 1024, "n_y": 1024, "pitch": 6e-5},
      "params": {"min_distance": 1e-12}}, "lattice points"),
    ({"kind": "full", "lattice": {"n_x": 1000, "n_y": 1000, "pitch": 6e-5}, "params": {}}, "lattice points"),
])
def test_unbounded_plan_requests_are_refused_with_the_reason(hostile_server, body, fragment):
    with hostile_server.client(timeout=ANSWER_S) as api:
        r = api.post("/api/plans/preview", json=body)
        assert r.status_code == 422, r.text
        assert fragment in r.json()["detail"]
        # the preview does work: it needs the token like every other such route
        anon = httpx.post(hostile_server.url + "/api/plans/preview", json=body, timeout=ANSWER_S)
        assert anon.status_code == 401


@pytest.mark.timeout(300)
@pytest.mark.parametrize("make, fragment", [
    (BY_NAME["truncated 50 %"].make, "truncated"),  # half a scan file (used to hang, ignoring Ctrl-C)
    (BY_NAME["external storage"].make, "external storage"),  # would read another file here
], ids=["truncated", "external-storage"])
def test_cli_refuses_hostile_files_with_the_reason(files, make, fragment):
    """``fpscan recon`` and ``fpscan export`` on a hostile file: exit 1 with the reason,
    answered (the client-side time-out counts a hang)."""
    import subprocess
    import sys

    path = make(files)
    for cmd in (["recon", str(path), "--out", str(files / "out"), "--quiet"],
                ["export", str(path), "--out", str(files / "x.h5")]):
        r = subprocess.run([sys.executable, "-m", "clients", *cmd], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode != 0, (cmd, r.stdout, r.stderr)
        if cmd[0] == "recon":  # export reads scan files only: its reason may be the format's
            assert fragment in r.stderr, r.stderr
