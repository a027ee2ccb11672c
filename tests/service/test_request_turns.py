"""Requests start a few per event-loop iteration, in arrival order (``fpscan.service.api.lanes.RequestTurns``,
health's lane under load), on a real asyncio event loop: the loop's iterations
are counted by a callback of the test's own that re-schedules itself once per iteration."""
from __future__ import annotations

import asyncio

import pytest

from fpscan.service.api.lanes import RequestTurns


def _loop_run(loop: str, coro) -> None:
    """Run ``coro`` on an asyncio event loop of the kind ``loop``: "asyncio" or "uvloop" (what
    ``fpscan serve`` runs on when it is installed)."""
    if loop == "uvloop":
        pytest.importorskip("uvloop").run(coro)
    else:
        asyncio.run(coro)


def _run(loop: str, per_iteration: int, n_requests: int, late: int = 0):
    """``n_requests`` HTTP requests sent at once through ``RequestTurns`` (and ``late`` more
    once the first has started), each working over two loop iterations; returns
    (the iteration each started in, by request; the order they started in)."""
    started: dict[int, int] = {}
    order: list[int] = []
    state = {"iteration": 0, "running": True}

    async def scenario():
        loop = asyncio.get_running_loop()

        def tick():  # once per loop iteration
            state["iteration"] += 1
            if state["running"]:
                loop.call_soon(tick)

        async def app(scope, receive, send):
            started[scope["n"]] = state["iteration"]
            order.append(scope["n"])
            if scope["n"] == 0 and late:
                tasks.extend(loop.create_task(turns({"type": "http", "n": n_requests + i}, None, None))
                             for i in range(late))
            await asyncio.sleep(0)  # a request goes on working after its start

        turns = RequestTurns(app, per_iteration=per_iteration)
        loop.call_soon(tick)
        tasks = [loop.create_task(turns({"type": "http", "n": i}, None, None)) for i in range(n_requests)]
        while len(order) < n_requests + late:
            await asyncio.sleep(0)
        await asyncio.gather(*tasks)
        assert turns.waiting == 0
        state["running"] = False

    _loop_run(loop, scenario())
    return started, order


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
@pytest.mark.parametrize("per_iteration", [1, 4])
def test_at_most_so_many_start_per_iteration_first_come_first_started(loop, per_iteration):
    started, order = _run(loop, per_iteration, 30, late=5)
    assert len(started) == 35
    per = {}
    for it in started.values():
        per[it] = per.get(it, 0) + 1
    assert max(per.values()) <= per_iteration, per
    assert order == sorted(order), order  # the late ones after all that came before them
    # none is held back longer than its place in the queue needs: 35 requests, per_iteration a turn
    assert len(per) <= -(-35 // per_iteration) + 2, per


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
def test_a_request_starts_without_waiting_while_its_iteration_has_turns_left(loop):
    async def scenario():
        turns = RequestTurns(None, per_iteration=2)
        for _ in range(2):  # the turn is given without suspending (the coroutine ends at its first step)
            with pytest.raises(StopIteration):
                turns.turn().send(None)
        third = turns.turn()
        waiter = third.send(None)  # the third of this iteration waits (suspends on its future)
        assert turns.waiting == 1 and not waiter.done()
        await asyncio.sleep(0)  # the next iteration gives it its turn
        assert waiter.done() and turns.waiting == 0
        with pytest.raises(StopIteration):
            third.send(None)

    _loop_run(loop, scenario())


def test_per_iteration_must_be_positive():
    with pytest.raises(ValueError, match="per_iteration must be >= 1"):
        RequestTurns(None, per_iteration=0)


def test_an_app_served_again_on_a_new_loop_starts_afresh():
    """Requests left waiting when a loop stopped (a test client closed, a server restarted
    in-process) neither hold back nor block those of the next loop."""
    turns = RequestTurns(None, per_iteration=1)

    async def leave_one_waiting():
        with pytest.raises(StopIteration):
            turns.turn().send(None)  # takes the iteration's turn
        for _ in range(2):  # wait: one gets the next iteration's turn, its loop stops before the other's
            assert not turns.turn().send(None).done()

    async def next_loop():
        await asyncio.wait_for(turns.turn(), 5)
        await asyncio.wait_for(turns.turn(), 5)  # the next iteration's turn

    old = asyncio.new_event_loop()
    try:  # stopped as soon as the coroutine is done, before another iteration
        old.run_until_complete(leave_one_waiting())
        assert turns.waiting == 1
    finally:
        old.close()
    asyncio.run(next_loop())
