"""A job's events stream hears of a committed event at once (`JobStore.add_listener` ->
`fpscan.service.api.jobs.EventWakeups`), not at its next poll: a real SQLite file, a real event
loop, the change committed from another thread as the job threads do."""
from __future__ import annotations

import asyncio
import sqlite3
import threading

import pytest

from fpscan.service.api.jobs import EventWakeups
from fpscan.service.jobs.store import JobStore


def test_listeners_hear_committed_events_only(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    heard: list[tuple[str, list[str]]] = []

    def listener(job_id):
        # called after the commit: another connection to the file already sees the event
        with sqlite3.connect(tmp_path / "jobs.sqlite") as other:
            states = [r[0] for r in other.execute("SELECT data FROM events WHERE job_id = ? ORDER BY seq", (job_id,))]
        heard.append((job_id, states))

    def broken(job_id):
        raise RuntimeError("a listener's own failure")

    store.add_listener(broken)  # logged and ignored: the change stands, the next listener hears it
    store.add_listener(listener)
    job, _ = store.create_job("recon", {"method": "ner"})
    jid = job["id"]
    assert heard == [(jid, ['{"state": "queued"}'])]
    assert store.claim(jid, "me", lease_s=60) is not None
    assert heard[-1][0] == jid and heard[-1][1][-1] == '{"state": "running"}'
    n = len(heard)
    with pytest.raises(ZeroDivisionError):  # a transaction rolled back records nothing, tells no one
        store._tx(lambda db: (store._event(db, jid, "state", {"state": "nowhere"}), 1 / 0))
    assert len(heard) == n and store.events_after(jid, 0)[-1]["data"] == '{"state": "running"}'
    store.remove_listener(listener)
    store.set_state(jid, "succeeded", only_from=("running",))
    assert len(heard) == n
    store.close()


def test_a_commit_in_another_thread_wakes_the_watching_stream(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    job, _ = store.create_job("recon", {"method": "ner"})
    jid = job["id"]

    async def main():
        wakeups = EventWakeups(asyncio.get_running_loop())
        store.add_listener(wakeups.notify)
        with wakeups.watch(jid) as woken, wakeups.watch("someone-else") as other:
            woken.clear()
            thread = threading.Thread(target=store.claim, args=(jid, "me", 60.0))
            thread.start()
            await asyncio.wait_for(woken.wait(), 120)  # the guard only: the wake comes with the commit
            thread.join()
            assert not other.is_set()
        assert wakeups._waiting == {}  # a stream that ended leaves nothing behind
        wakeups.notify(jid)  # no stream on it: nothing scheduled

    asyncio.run(main())
    store.close()
