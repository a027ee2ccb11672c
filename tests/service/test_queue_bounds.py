"""Bounded queues: a client address may have ``queued_per_client``
reconstructions queued; the next is refused with 429 saying the cap, the queue's length and
its estimated wait, while another address still gets in; an idempotent repeat is answered
with its job. A re-queued job's timings restart, the cut-off attempt recorded (the store
here; a killed worker on a real server: tests/service/test_worker_death.py)."""
from __future__ import annotations

import io
import re
import time

import httpx
import numpy as np
import pytest

from fpscan.service.jobs.store import JobStore, QueueFull
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.waits import HANG_S

CAP = 3


def test_a_requeued_job_starts_its_timing_anew_and_keeps_the_earlier_attempt(tmp_path):
    from fpscan.service.api.jobs import job_view

    store = JobStore(tmp_path / "jobs.sqlite")
    job, _ = store.create_job("recon", {"method": "ner"})
    first = store.claim(job["id"], "srv-a", 10.0)
    assert store.requeue(job["id"], "the worker process died")
    waiting = store.get(job["id"])
    assert waiting["state"] == "queued" and waiting["started"] is None
    [cut] = waiting["earlier_attempts"]
    assert cut["attempt"] == 1 and cut["started"] == first["started"] and cut["ended"] >= first["started"]
    assert cut["reason"] == "the worker process died"
    second = store.claim(job["id"], "srv-a", 10.0)
    assert second["started"] >= cut["ended"] and second["attempts"] == 2
    # a restart cuts the second one off: recorded too, with the restart's reason
    assert store.recover("srv-b", max_attempts=5)["requeued"] == [job["id"]]
    third = store.claim(job["id"], "srv-b", 10.0)
    assert store.set_state(job["id"], "succeeded", only_from=("running",))
    view = job_view(store.get(job["id"])).timings
    # run_s is on the store's monotonic time: the wall times' difference while the wall clock did not step
    assert view.started == third["started"] and view.run_s == pytest.approx(view.finished - third["started"], abs=1e-3)
    assert [(a.attempt, a.reason) for a in view.earlier_attempts] == [(1, "the worker process died"),
                                                                     (2, "server restarted")]
    assert view.earlier_attempts[1].started == second["started"]
    assert view.earlier_attempts[1].run_s == pytest.approx(view.earlier_attempts[1].ended - second["started"], abs=1e-3)
    store.close()


def test_an_older_job_database_gains_the_attempts_sequence_and_store_time_columns(tmp_path):
    import sqlite3

    db = tmp_path / "jobs.sqlite"
    with sqlite3.connect(db) as con:  # the jobs table as earlier versions made it
        con.execute("CREATE TABLE jobs (id TEXT PRIMARY KEY, kind TEXT NOT NULL, state TEXT NOT NULL, params TEXT "
                    "NOT NULL, progress TEXT NOT NULL, idempotency_key TEXT UNIQUE, created REAL NOT NULL, started "
                    "REAL, finished REAL, lease_owner TEXT, lease_until REAL, heartbeat REAL, attempts INTEGER NOT "
                    "NULL DEFAULT 0, result_path TEXT, error TEXT, memory_bytes INTEGER NOT NULL DEFAULT 0, "
                    "cancel_requested INTEGER NOT NULL DEFAULT 0, control TEXT)")
        con.execute("INSERT INTO jobs (id, kind, state, params, progress, created, started, attempts) VALUES "
                    "('old', 'recon', 'running', '{}', '{}', 1.0, 2.0, 1)")
        con.execute("INSERT INTO jobs (id, kind, state, params, progress, created, started, finished, attempts) "
                    "VALUES ('older', 'recon', 'succeeded', '{}', '{}', 0.5, 0.75, 1.5, 1)")
    store = JobStore(db)
    assert store.get("old")["earlier_attempts"] == []
    # its jobs keep their order (the sequence from SQLite's rowid) and their durations (the wall times)
    assert [j["id"] for j in store.list()] == ["older", "old"]
    older = store.get("older")
    assert (older["created_mono"], older["started_mono"], older["finished_mono"]) == (0.5, 0.75, 1.5)
    new, _ = store.create_job("recon", {})  # after them: in sequence, and on the store's time
    assert [j["id"] for j in store.list()] == [new["id"], "older", "old"] and new["created_mono"] > 1.5
    assert store.requeue("old", "the worker process died")
    assert store.get("old")["earlier_attempts"][0]["started"] == 2.0
    store.close()


def test_the_store_counts_a_client_s_queue_in_the_insert(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    for _ in range(CAP):
        store.create_job("recon", {"client": "10.0.0.1"}, max_queued=CAP)
    with pytest.raises(QueueFull) as refused:
        store.create_job("recon", {"client": "10.0.0.1"}, max_queued=CAP)
    assert (refused.value.queued, refused.value.limit) == (CAP, CAP)
    store.create_job("recon", {"client": "10.0.0.2"}, max_queued=CAP)  # another client's queue
    started = store.queued("recon")[0]
    store.claim(started["id"], "srv", 10.0)  # one of its jobs runs: room for one more
    store.create_job("recon", {"client": "10.0.0.1"}, max_queued=CAP)
    store.close()


def _upload(api, data: np.ndarray) -> str:
    buf = io.BytesIO()
    np.save(buf, data)
    r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                 files={"file": ("d.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    return r.json()["dataset_id"]


@needs_recon
@pytest.mark.timeout(300)
def test_a_client_over_its_queue_cap_gets_429_with_the_cap_the_queue_and_the_wait(tmp_path):
    srv = Server(tmp_path / "data", env={"FPSCAN_QUEUED_PER_CLIENT": str(CAP), "FPSCAN_WORKERS": "1"}).start()
    blocker = None
    try:
        with srv.client() as api:
            small = _upload(api, np.random.default_rng(1).standard_normal((32, 8, 8)).astype(np.float32))
            long = _upload(api, np.random.default_rng(6).standard_normal((256, 32, 32)).astype(np.float32))
            # the one worker busy with a tv job that iterates until cancelled (tol 0)
            r = api.post("/api/reconstructions", json={"dataset_id": long, "method": "tv",
                                                       "params": {"iterations": 100000, "lam": 0.0, "tol": 0}})
            assert r.status_code == 202, r.text
            blocker = r.json()["id"]
            deadline = time.monotonic() + HANG_S
            while api.get(f"/api/jobs/{blocker}").json()["state"] == "queued" and time.monotonic() < deadline:
                time.sleep(0.05)
            assert api.get(f"/api/jobs/{blocker}").json()["state"] == "running"
            body = {"dataset_id": small, "method": "ner"}
            queued = [api.post("/api/reconstructions", json=body, headers={"Idempotency-Key": f"k{i}"})
                      for i in range(CAP)]
            assert [q.status_code for q in queued] == [202] * CAP, [q.text for q in queued]
            assert "client" not in queued[0].json()["params"]  # the address counts the queue; it is not shown
            again = api.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "new"})
            assert again.status_code == 429, again.text
            detail = again.json()["detail"]
            print(detail, "Retry-After:", again.headers["retry-after"])
            assert f"this client has {CAP} reconstructions queued" in detail and f"queued_per_client = {CAP}" in detail
            assert f"the queue holds {CAP} queued and 1 running" in detail, detail
            # the wait: the queued jobs' work estimates at least, their sum with the running one's at most
            jobs = [api.get(f"/api/jobs/{q.json()['id']}").json() for q in queued]
            ahead = sum(j["params"]["work_estimate_s"] for j in jobs)
            running = api.get(f"/api/jobs/{blocker}").json()["params"]["work_estimate_s"]
            wait = float(re.search(r"an estimated (\d+) s of work", detail).group(1))
            assert ahead - 1 <= wait <= ahead + running + 1, (wait, ahead, running)
            assert 1 <= int(again.headers["retry-after"]) <= running + 1
            # another address (the loopback network's 127.0.0.2) has its own queue
            other = httpx.Client(base_url=srv.url, headers=srv.headers(), timeout=30,
                                 transport=httpx.HTTPTransport(local_address="127.0.0.2"))
            with other:
                r = other.post("/api/reconstructions", json=body)
                assert r.status_code == 202, r.text
            # a repeat of an accepted request is answered with its job, cap or not
            first = queued[0]
            repeat = api.post("/api/reconstructions", json=body, headers={"Idempotency-Key": "k0"})
            assert repeat.status_code == 202 and repeat.json()["id"] == first.json()["id"], repeat.text
            # once the running job ends, the next queued one starts and there is room again
            assert api.post(f"/api/jobs/{blocker}/cancel").status_code == 200
            assert wait_job(api, blocker)["state"] == "cancelled"
            assert wait_job(api, first.json()["id"], states=("running", "succeeded"))["state"] in ("running",
                                                                                                    "succeeded")
            r = api.post("/api/reconstructions", json=body)
            assert r.status_code == 202, r.text
    finally:
        srv.stop()
