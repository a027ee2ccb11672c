"""The wall clock set back an hour mid-run: durations stay true, "newest first" stays newest
first, the queue keeps its order.

A real ``fpscan serve`` runs under libfaketime (``LD_PRELOAD``, the ``libfaketime`` wheel's
own build), which shifts the wall clock (``CLOCK_REALTIME``: ``time.time()``) by the offset
read from a file at every call and leaves the monotonic clock alone
(``DONT_FAKE_MONOTONIC=1``), as NTP or ``date -s`` stepping the clock would. The test writes
``-1h`` to that file once the first scan has measured a point: the server's code is not
touched. The simulated scanner runs in the test's own process, on the true clock.

Scans A and B of one plan are submitted before the step (B waits for the scanner behind A),
C and a plan after it, while A runs. The stored wall times prove the step fell where it
should (A finished "before" it started; B started "before" it was created); the oracle for
the durations is the test's own monotonic clock around the run.

The wall clock set forward past the datasets' maximum age between two uploads: retention by
age, on the store's time, deletes nothing.
"""
from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import pytest

from tests.service.service_servers import Server, needs_recon, wait_job
from tests.waits import HANG_S

driver_sim = pytest.importorskip("fpscan.driver.simulator")


def _libfaketime() -> Path | None:
    """The ``libfaketime`` wheel's shared library (not imported: its module needs more)."""
    spec = importlib.util.find_spec("libfaketime")
    if spec is None or not spec.submodule_search_locations:
        return None
    lib = Path(list(spec.submodule_search_locations)[0]) / "vendor" / "libfaketime" / "src" / "libfaketime.so.1"
    return lib if lib.is_file() else None


LIB = _libfaketime()

pytestmark = [needs_recon, pytest.mark.slow,
              pytest.mark.skipif(LIB is None, reason="libfaketime (pip install libfaketime) not installed")]

HOUR = 3600.0
N = 8  # 64 points at 40 Hz: 1.6 s a scan


def plan_body(seed: int) -> dict:
    return {"lattice": {"n_x": N, "n_y": N, "pitch": 1e-4 * (1 + seed)},
            "points": [[i, j] for j in range(N) for i in range(N)],
            "acquisition": {"n_t": 64, "dt": 2e-8, "prf": 40}}


@pytest.fixture
def sim():
    s = driver_sim.SimulatedScanner(prf=40.0, seed=3).start()
    yield s
    s.stop()


def test_durations_and_order_survive_the_wall_clock_set_back_an_hour(tmp_path, sim):
    offset = tmp_path / "faketime"
    offset.write_text("+0\n")
    env = {"LD_PRELOAD": str(LIB), "FAKETIME_TIMESTAMP_FILE": str(offset), "FAKETIME_NO_CACHE": "1",
           "DONT_FAKE_MONOTONIC": "1"}
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}, env=env).start()
    try:
        with srv.client() as c:
            p1 = c.post("/api/plans", json=plan_body(0))
            assert p1.status_code == 201, p1.text
            t0 = time.monotonic()
            a = c.post("/api/scans", json={"plan_id": p1.json()["id"], "scanner_id": "sim"}).json()["id"]
            b = c.post("/api/scans", json={"plan_id": p1.json()["id"], "scanner_id": "sim"}).json()["id"]
            deadline = time.monotonic() + HANG_S
            while (c.get(f"/api/jobs/{a}").json()["progress"].get("points_done") or 0) == 0:
                assert time.monotonic() < deadline, "scan A measured nothing"
                time.sleep(0.02)
            offset.write_text("-1h\n")  # the wall clock steps back an hour, A running, B waiting
            p2 = c.post("/api/plans", json=plan_body(1))
            assert p2.status_code == 201, p2.text
            cj = c.post("/api/scans", json={"plan_id": p2.json()["id"], "scanner_id": "sim"}).json()["id"]
            jobs = {k: wait_job(c, j) for k, j in (("a", a), ("b", b), ("c", cj))}
            elapsed = time.monotonic() - t0
            for job in jobs.values():
                assert job["state"] == "succeeded", job
            ta, tb, tc = (jobs[k]["timings"] for k in "abc")
            # the step fell where the test put it (the wall times as stored)
            assert ta["finished"] < ta["started"] - HOUR / 2, ta
            assert tb["started"] < tb["created"] - HOUR / 2, tb
            assert tc["created"] < ta["created"] - HOUR / 2, (tc, ta)
            # durations on the monotonic clock: positive, and within the test's own span
            for t in (ta, tb, tc):
                assert 0 <= t["queued_s"] <= elapsed and 0 < t["run_s"] <= elapsed, t
            assert ta["run_s"] + tb["run_s"] + tc["run_s"] <= elapsed
            # B waited for A's run: from B's submission (after A's, both before the step, so their
            # wall times compare) to A's end (a loaded machine took 0.9 s between the two POSTs)
            assert tb["queued_s"] >= 0.9 * (ta["queued_s"] + ta["run_s"] - (tb["created"] - ta["created"])), (ta, tb)
            # newest first by submission; the queue in submission order (B ran before C)
            listed = [j["id"] for j in c.get("/api/jobs").json()]
            assert listed == [cj, b, a], listed
            assert tc["started"] > tb["finished"], (tb, tc)
            plans = [p["id"] for p in c.get("/api/plans").json()]
            assert plans == [p2.json()["id"], p1.json()["id"]], plans
    finally:
        srv.stop()


def _upload(c, seed: int) -> str:
    import io

    import numpy as np

    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal((32, 8, 8)).astype(np.float32))
    r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
               files={"file": (f"d{seed}.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


def test_a_wall_clock_set_forward_past_the_datasets_max_age_deletes_no_dataset(tmp_path):
    """Retention by age (``datasets_max_age_s`` one hour) counts on the store's monotonic time:
    the wall clock set forward two hours between two uploads deletes nothing at the second
    upload's retention (today's main compared wall times and deleted the first dataset, idle for
    seconds). The stored wall times show the step."""
    offset = tmp_path / "faketime"
    offset.write_text("+0\n")
    env = {"LD_PRELOAD": str(LIB), "FAKETIME_TIMESTAMP_FILE": str(offset), "FAKETIME_NO_CACHE": "1",
           "DONT_FAKE_MONOTONIC": "1"}
    srv = Server(tmp_path / "srv", env=env).start()
    try:
        with srv.client() as c:
            r = c.put("/api/retention", json={"datasets_max_age_s": HOUR})
            assert r.status_code == 200, r.text
            first = _upload(c, 1)
            offset.write_text("+2h\n")  # the wall clock steps forward two hours
            second = _upload(c, 2)  # retention runs after it
            rows = {d["dataset_id"]: d for d in c.get("/api/datasets").json()}
            assert set(rows) == {first, second}, rows
            assert rows[second]["created"] - rows[first]["created"] > 1.5 * HOUR, rows  # the step, as stored
    finally:
        srv.stop()
