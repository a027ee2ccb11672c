"""The client against a server that misbehaves (tests/clients/hostile_server.py, a real socket on
127.0.0.1): every call ends in bounded time and memory, with an error that says why."""
from __future__ import annotations

import asyncio

import pytest

from fpscan.clients.http import AsyncClient, Client
from fpscan.clients.http.errors import WaitTimeout
from fpscan.clients.http.waiting import MAX_EVENT_BYTES
from tests.clients.hostile_server import RUNNING, Request, hostile_server


def running_job_then(events):
    """A server whose job J1 runs for ever, its event stream answered by ``events(request)``."""
    def route(req: Request) -> None:
        if req.path.startswith("/api/jobs/J1/events"):
            req.head(200, {"Content-Type": "text/event-stream"})
            events(req)
        elif req.path.startswith("/api/jobs/J1"):
            req.json(RUNNING)
        else:
            req.json({"detail": f"no route {req.path}"}, 404)
    return route


def keepalives(req: Request) -> None:
    """What the real server sends while a job makes no event (every 15 s there; 0.2 s here)."""
    while req.send(b": keep-alive\n\n"):
        req.hung_up.wait(0.2)


def endless_line(req: Request) -> None:
    """One event line that never ends."""
    req.send(b"data: ")
    while req.send(b"x" * 65536):
        pass


@pytest.mark.timeout(120)
def test_wait_ends_at_its_timeout_while_the_stream_sends_only_keepalives():
    """A keep-alive comment is no event: the wait checked its deadline on events alone, so
    ``wait(timeout=...)`` (and ``fpscan jobs wait --timeout``) never ended while a job was quiet."""
    with hostile_server(running_job_then(keepalives)) as (url, _):
        with Client(url) as api, pytest.raises(WaitTimeout, match="still running after 1.5 s"):
            api.wait("J1", timeout=1.5)

        async def main() -> None:
            async with AsyncClient(url) as api:
                await api.wait("J1", timeout=1.5)

        with pytest.raises(WaitTimeout, match="still running after 1.5 s"):
            asyncio.run(main())


@pytest.mark.timeout(120)
def test_an_event_line_that_never_ends_is_dropped_after_a_bounded_read():
    """A stream that sends one line for ever: the client stops reading after
    ``MAX_EVENT_BYTES`` without an event (it read all of it into memory before) and polls the job
    instead, until its timeout."""
    with hostile_server(running_job_then(endless_line)) as (url, requests):
        with Client(url) as api, pytest.raises(WaitTimeout):
            api.wait("J1", timeout=3)
    streams = [r for r in requests if r.path.endswith("/events")]
    assert streams and all(r.hung_up.is_set() for r in streams), [(r.path, r.sent) for r in streams]
    # what the client read, plus what the sockets' buffers held when it hung up
    assert max(r.sent for r in streams) < MAX_EVENT_BYTES + (16 << 20), [r.sent for r in streams]
    assert any(r.path == "/api/jobs/J1" for r in requests[requests.index(streams[0]) + 1:])  # then it polled
