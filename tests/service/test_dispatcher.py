"""The jobs' one dispatcher (fpscan.service.jobs.dispatcher), the loop the reconstruction queue, the
scan runner and the live preview share: FIFO with a held head, passing over a busy slot, a job
another server claimed, a failing round or job body logged and survived, no round after a
stop. Against a real SQLite job store; every wait is for an event (a state, a thread)."""
from __future__ import annotations

import doctest
import logging
import threading

import pytest

from fpscan.service.jobs import dispatcher as dispatcher_module
from fpscan.service.jobs.dispatcher import SKIP, START, WAIT, Dispatcher, Loop
from fpscan.service.jobs.store import JobStore
from tests.waits import HANG_S

#: so long that only an explicit wake (or a direct ``dispatch()``) makes a round
NEVER = 3600.0


@pytest.fixture
def store(tmp_path):
    s = JobStore(tmp_path / "jobs.sqlite")
    yield s
    s.close()


class Bodies:
    """Job bodies that run until released: ``started`` (ids, in start order) and a release
    event per job; a released body ends its job ``succeeded``."""

    def __init__(self, store: JobStore):
        self.store = store
        self.started: list[str] = []
        self.release: dict[str, threading.Event] = {}
        self.ended: dict[str, threading.Event] = {}

    def launch(self, job):
        jid = job["id"]
        self.release[jid], self.ended[jid] = threading.Event(), threading.Event()
        self.started.append(jid)

        def body():
            assert self.release[jid].wait(HANG_S)
            self.store.set_state(jid, "succeeded", only_from=("running",))
            self.ended[jid].set()

        return f"test-{jid[:8]}", body

    def finish(self, jid: str) -> None:
        self.release[jid].set()
        assert self.ended[jid].wait(HANG_S)


def _dispatcher(store, bodies, admit, **kw):
    return Dispatcher(store, "recon", owner="me", lease_s=30.0, admit=admit, launch=bodies.launch,
                      name="test-dispatcher", period=NEVER, **kw)


def test_one_at_a_time_fifo_holds_the_line_and_claims_with_a_lease(store):
    jobs = [store.create_job("recon", {"n": i})[0]["id"] for i in range(3)]
    bodies = Bodies(store)
    seen: list[tuple[str, int]] = []

    def admit(job, running):
        seen.append((job["id"], running))
        return START if running == 0 else WAIT

    d = _dispatcher(store, bodies, admit)
    try:
        d.dispatch()
        assert bodies.started == jobs[:1]
        assert seen == [(jobs[0], 0), (jobs[1], 1)]  # the second held: the third is not even asked
        first = store.get(jobs[0])
        assert first["state"] == "running" and first["lease_owner"] == "me" and first["attempts"] == 1
        assert first["lease_until"] > first["heartbeat"]
        assert [store.get(j)["state"] for j in jobs[1:]] == ["queued", "queued"]
        assert d.running() == 1
        d.dispatch()  # still busy: nothing new
        assert bodies.started == jobs[:1]
        bodies.finish(jobs[0])
        d.join(HANG_S)
        assert d.running() == 0
        d.dispatch()
        assert bodies.started == jobs[:2]  # oldest first
        bodies.finish(jobs[1])
        d.join(HANG_S)
        d.dispatch()
        assert bodies.started == jobs
        bodies.finish(jobs[2])
        d.join(HANG_S)
    finally:
        for ev in bodies.release.values():
            ev.set()
    assert [store.get(j)["state"] for j in jobs] == ["succeeded"] * 3


def test_a_skipped_job_stays_queued_while_later_ones_start(store):
    busy, free = (store.create_job("scan", {"scanner_id": s})[0]["id"] for s in ("a", "b"))
    bodies = Bodies(store)
    d = Dispatcher(store, "scan", owner="me", lease_s=60.0, launch=bodies.launch, name="test-scans",
                   period=NEVER, admit=lambda job, running: SKIP if job["params"]["scanner_id"] == "a" else START)
    d.dispatch()
    try:
        assert bodies.started == [free]
        assert store.get(busy)["state"] == "queued" and store.get(free)["state"] == "running"
    finally:
        bodies.finish(free)
        d.join(HANG_S)


def test_only_its_own_kind_is_dispatched(store):
    scan = store.create_job("scan", {"scanner_id": "a"})[0]["id"]
    bodies = Bodies(store)
    _dispatcher(store, bodies, lambda job, running: START).dispatch()
    assert bodies.started == [] and store.get(scan)["state"] == "queued"


def test_a_job_another_server_claimed_meanwhile_is_passed_over(store):
    taken, mine = (store.create_job("recon", {"n": i})[0]["id"] for i in range(2))
    bodies = Bodies(store)

    def admit(job, running):
        if job["id"] == taken:  # another server wins the race between the listing and the claim
            assert store.claim(taken, "other-server", lease_s=30.0) is not None
        return START

    d = _dispatcher(store, bodies, admit)
    d.dispatch()
    try:
        assert bodies.started == [mine]
        assert store.get(taken)["lease_owner"] == "other-server" and store.get(taken)["attempts"] == 1
    finally:
        bodies.finish(mine)
        d.join(HANG_S)


def test_the_loop_survives_a_failing_round_and_a_failing_body_and_wakes_when_a_job_ends(store, caplog):
    first, second = (store.create_job("recon", {"n": i})[0]["id"] for i in range(2))
    failed_round, second_started = threading.Event(), threading.Event()

    def admit(job, running):
        if not failed_round.is_set():
            failed_round.set()
            raise RuntimeError("a round that fails")
        return START if running == 0 else WAIT  # one job at a time

    def launch(job):
        def body():
            if job["id"] == first:
                raise RuntimeError("a body that fails")
            second_started.set()
            store.set_state(job["id"], "succeeded", only_from=("running",))
        return "test-job", body

    d = Dispatcher(store, "recon", owner="me", lease_s=30.0, admit=admit, launch=launch, name="test-loop",
                   period=NEVER)
    with caplog.at_level(logging.ERROR, logger="fpscan.jobs"):
        d.start()
        try:
            d.wake()
            assert failed_round.wait(HANG_S)
            # the next round starts the first job and holds the second; only the end of the
            # first job's body can wake the loop again (the period is never reached)
            d.wake()
            assert second_started.wait(HANG_S)
        finally:
            d.stop()
            d.join(HANG_S)
    messages = [r.getMessage() for r in caplog.records]
    assert any("test-loop error" in m for m in messages), messages
    assert any(f"job={first} ended with an error" in m for m in messages), messages
    assert store.get(first)["state"] == "running"  # its body decides how it ends; this one never did
    assert store.get(second)["state"] == "succeeded"


def test_no_round_after_a_stop_and_a_stop_before_the_start_is_fine(store):
    job = store.create_job("recon", {})[0]["id"]
    ticks: list[int] = []
    loop = Loop("test-stop", lambda: ticks.append(1), period=NEVER)
    loop.stop()  # never started: nothing to join
    assert loop.stopping
    d = Dispatcher(store, "recon", owner="me", lease_s=30.0, admit=lambda job, running: START,
                   launch=lambda job: ("never", lambda: None), name="test-stopped", period=NEVER)
    d.start()
    d.stop()
    assert d.wait_stop(0.0)
    d.wake()
    d._thread.join(HANG_S)
    assert not d._thread.is_alive()
    assert store.get(job)["state"] == "queued" and ticks == []


def test_a_period_must_be_positive():
    with pytest.raises(ValueError, match="period must be > 0"):
        Loop("bad", lambda: None, period=0.0)


def test_module_examples_run():
    result = doctest.testmod(dispatcher_module, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
