"""Health's own lane through a busy event loop (CONTRIBUTING.md, "Longer checks": ``/api/health`` p99 ≤ 250 ms
under 50 clients of mixed requests).

Every request is handled on the one event loop, a step at a time: a loop iteration runs
the next step of every request that is ready. Under 50 clients that each send the next
request as soon as the last is answered, some 50 requests start in each iteration, at
about 2 ms of routing, validation and serialisation each, and a health request waited
for its turn behind all of them (p99 0.3-0.9 s). Two ASGI middlewares give it a lane:

- :class:`RequestTurns`: at most :data:`STARTS_PER_ITERATION` requests start per loop
  iteration; the others wait their turn in arrival order, parked (costing the loop
  nothing) until a later iteration. The loop therefore gets back to its sockets every few
  milliseconds instead of every 100, whatever the number of clients; throughput is
  unchanged (the same work, in the same order). Requests already started (waiting for a
  thread, a body, a child process) are not held back.
- :class:`HealthLane`: ``GET /api/health`` is answered before that queue, from
  ``document`` (in-memory figures and the cached disk usage: well under a millisecond),
  after the same access rules as every other request (:class:`~fpscan.service.api.access.AccessGate`:
  Host, then the bearer token when one is configured; a refused health request goes on to
  the gate, which refuses it with its reason and logs it).
"""
from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from starlette.types import ASGIApp, Receive, Scope, Send

from fpscan.service.settings import Settings

if TYPE_CHECKING:
    from fpscan.service.api.access import TokenFailures

__all__ = ["STARTS_PER_ITERATION", "HEALTH_PATH", "RequestTurns", "HealthLane"]

#: requests that may start in one event-loop iteration (the rest wait for the next ones)
STARTS_PER_ITERATION = 4
#: the path answered by :class:`HealthLane`
HEALTH_PATH = "/api/health"


class RequestTurns:
    """ASGI middleware: HTTP requests start at most ``per_iteration`` per event-loop
    iteration, in arrival order (first come, first started); the others wait, parked on a
    future, for a later iteration. Placed inside the access gate, so that a request
    refused for its Host or token never waits in this queue nor delays one that is not.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.
    per_iteration : int, optional
        Requests that may start per loop iteration, >= 1; default
        :data:`STARTS_PER_ITERATION` (4).

    Attributes
    ----------
    app : ASGI application
        As given.
    per_iteration : int
        As given.
    waiting : int
        Requests waiting for their turn now (property).

    Raises
    ------
    ValueError
        If ``per_iteration`` is below 1.
    """

    def __init__(self, app: ASGIApp, per_iteration: int = STARTS_PER_ITERATION) -> None:
        if per_iteration < 1:
            raise ValueError(f"per_iteration must be >= 1, got {per_iteration}")
        self.app = app
        self.per_iteration = per_iteration
        self._started = 0  # requests started in the current iteration
        self._waiting: deque[asyncio.Future] = deque()
        self._tick_due = False  # a call of _next_iteration is scheduled
        self._loop: asyncio.AbstractEventLoop | None = None  # the loop the counts are of

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            await self.turn()
        return await self.app(scope, receive, send)

    async def turn(self) -> None:
        """Return when this request may start: at once while fewer than ``per_iteration``
        have started in this iteration and none waits, else in a later iteration."""
        loop = asyncio.get_running_loop()
        if loop is not self._loop:  # a new event loop (an app served again): nothing carries over
            self._loop, self._started, self._waiting, self._tick_due = loop, 0, deque(), False
        if not self._tick_due:
            self._tick_due = True
            loop.call_soon(self._next_iteration)  # runs in the next iteration
        if self._started < self.per_iteration and not self._waiting:
            self._started += 1
            return
        waiter = loop.create_future()
        self._waiting.append(waiter)
        await waiter  # cancelled (server shutdown): its turn is simply not taken

    def _next_iteration(self) -> None:
        """A new loop iteration: let the next ``per_iteration`` waiting requests start."""
        self._started = 0
        while self._waiting and self._started < self.per_iteration:
            waiter = self._waiting.popleft()
            if not waiter.done():
                waiter.set_result(None)
                self._started += 1
        self._tick_due = bool(self._waiting)
        if self._tick_due:
            asyncio.get_running_loop().call_soon(self._next_iteration)

    @property
    def waiting(self) -> int:
        """Requests waiting for their turn now."""
        return sum(1 for w in self._waiting if not w.done())


class HealthLane:
    """ASGI middleware: answer ``GET /api/health`` at once, ahead of the :class:`RequestTurns` queue.

    The request first passes the access gate's rules (``gate(scope)`` is
    :meth:`fpscan.service.api.access.AccessGate.refusal` of the app's settings); a request they
    refuse, and every other request, goes on to ``app`` (so does health before the app has
    started and has no context).

    Parameters
    ----------
    app : ASGI application
        The application it wraps.
    settings : Settings
        The service's settings (the access rules).
    document : callable
        ``document(context)``: an awaitable of the ``Health`` model, given the app's ``Context``.
    failures : TokenFailures or None, optional
        The access gate's count of wrong tokens per address
        (:class:`fpscan.service.api.access.TokenFailures`): a wrong token from an address that
        must wait is a refusal here too, passed on to the gate, which holds it until the wait is
        over and answers 429; the right token is answered here at once, from every address;
        default None: a count of its own.

    Attributes
    ----------
    app : ASGI application
        As given.
    document : callable
        As given.
    gate : callable
        ``gate(scope) -> (status, reason) or None``, the access gate's rules.
    """

    def __init__(self, app: ASGIApp, settings: Settings, document: Callable[[Any], Awaitable[Any]],
                 failures: TokenFailures | None = None) -> None:
        from fpscan.service.api.access import AccessGate

        self.app = app
        self.document = document
        self.gate = AccessGate(app, settings, failures=failures).refusal

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (scope["type"] != "http" or scope.get("path") != HEALTH_PATH or scope.get("method") != "GET"
                or self.gate(scope) is not None):
            return await self.app(scope, receive, send)
        context = getattr(getattr(scope.get("app"), "state", None), "ctx", None)
        if context is None:  # not started (no lifespan): the route answers
            return await self.app(scope, receive, send)
        body = (await self.document(context)).model_dump_json().encode()
        await send({"type": "http.response.start", "status": 200,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})
