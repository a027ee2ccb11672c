"""The ``UploadLimit`` ASGI middleware: every request body within its size limit (413), at a
rate a client means (408), and uploads and plan requests admitted by their slots (429)
before their body is read."""
from __future__ import annotations

import asyncio
import logging
import time
from collections import deque

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from fpscan.service.api.context import Slots
from fpscan.service.api.logcaps import shown

__all__ = ["MIN_BODY_RATE", "MULTIPART_ALLOWANCE", "UploadLimit"]

log = logging.getLogger("fpscan.api")

#: Slowest body (bytes/s, averaged over ``Settings.body_rate_window_s``) a request may
#: send (``Settings.body_min_rate``, whose default this is): a trickle would hold an upload
#: or plan slot, or a connection, for hours.
MIN_BODY_RATE = 100 * 1024
#: Bytes of multipart framing an upload's body may hold besides its file (on top of the
#: upload limit).
MULTIPART_ALLOWANCE = 1_000_000


class UploadLimit:
    """ASGI middleware: every request body within its limit, at a rate a client means.

    - **Size** (413, by ``Content-Length`` up front and by counting for chunked bodies):
      ``limit`` bytes for an upload (``POST /api/datasets``, plus multipart overhead),
      ``json_limit`` for a plan request (``PLAN_ROUTES``: parsed in the plan worker; a plan
      JSON of the largest lattice is 15-32 MiB), ``request_json_limit`` for any other body
      (JSON parsed and validated on the event loop before a route sees it: a body must stay
      as small as its schema can need, kilobytes).
    - **Time** (408, ``Connection: close``): a body that sends nothing for
      ``body_timeout_s``, and any body that arrives slower than ``min_rate`` bytes/s
      averaged over ``rate_window_s`` (after its first window), so a slow client cannot hold
      a slot or a connection for long (nginx's ``client_body_timeout`` with a minimum rate).
      A request without a body (no ``Content-Length`` above 0, no ``Transfer-Encoding``: a
      GET, an event stream) is not timed here: its answer may last as long as its job.
    - **Slots** (``slots``, :func:`~fpscan.service.api.context.default_slots`): uploads and plan
      requests (``ADMITTED``) are counted in, per client address first, before their body
      is read, and refused with 429 when too many are in progress (the form parser spools
      every upload to a temporary file, and a JSON body is parsed, before the route runs);
      the route then waits for its turn.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.
    limit : int
        The largest upload body in bytes (``POST /api/datasets``; 1 MB of multipart overhead
        is allowed on top).
    json_limit : int or None, optional
        The largest plan request body in bytes (at most ``limit``); default None: ``limit``.
    slots : dict of str to Slots or None, optional
        ``{"uploads": ..., "plans": ...}``: the slots that admit those requests; default
        None: none (no 429).
    body_timeout_s : float, optional
        Seconds a body may send nothing; default 30.
    request_json_limit : int or None, optional
        The largest body of any other request in bytes (at most the plan limit); default
        None: the plan limit.
    min_rate : float, optional
        The slowest body in bytes/s; default :data:`MIN_BODY_RATE` (100 KiB/s).
    rate_window_s : float, optional
        Seconds the rate is averaged over; default 10.

    Attributes
    ----------
    app : ASGI application
        As given.
    upload_limit : int
        ``limit``.
    json_limit, request_json_limit : int
        The effective limits in bytes.
    body_timeout_s, min_rate, rate_window_s : float
        As given.
    slots : dict of str to Slots
        As given (empty: none).
    ADMITTED : dict
        ``(method, path) -> slots name``: the requests slots admit (class attribute).
    PLAN_ROUTES : frozenset
        The ``(method, path)`` pairs whose body may be up to ``json_limit`` (class attribute).
    """

    #: (method, path) -> the slots that admit it
    ADMITTED = {("POST", "/api/datasets"): "uploads", ("POST", "/api/plans"): "plans",
                ("POST", "/api/plans/preview"): "plans"}
    #: the routes whose JSON body may be up to ``json_limit`` (parsed in the plan worker)
    PLAN_ROUTES = frozenset({("POST", "/api/plans"), ("POST", "/api/plans/preview")})

    def __init__(self, app: ASGIApp, limit: int, json_limit: int | None = None, slots: dict[str, Slots] | None = None,
                 body_timeout_s: float = 30.0, request_json_limit: int | None = None,
                 min_rate: float = MIN_BODY_RATE, rate_window_s: float = 10.0) -> None:
        self.app = app
        self.body_timeout_s = body_timeout_s
        self.upload_limit = limit
        self.json_limit = min(limit, json_limit) if json_limit else limit
        self.request_json_limit = min(self.json_limit, request_json_limit) if request_json_limit else self.json_limit
        self.min_rate = float(min_rate)
        self.rate_window_s = float(rate_window_s)
        self.slots = slots or {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        key = (scope.get("method", ""), scope.get("path", "").rstrip("/"))
        if key == ("POST", "/api/datasets"):
            limit = self.upload_limit + MULTIPART_ALLOWANCE
        else:
            limit = self.json_limit if key in self.PLAN_ROUTES else self.request_json_limit
        if not _has_body(scope):  # a GET, an event stream: nothing to time (its answer may last hours)
            return await self.app(scope, receive, send)
        slots = self.slots.get(self.ADMITTED.get(key, ""))
        if slots is None:
            return await self._limited(scope, receive, send, limit, self.min_rate)
        client = (scope.get("client") or ("?", 0))[0]
        if not slots.enter(client):
            resp = JSONResponse({"detail": slots.busy_reason(client)}, 429,  # its body is never read: close
                                headers={"Retry-After": str(slots.retry_after_s), "Connection": "close"})
            return await resp(scope, receive, send)
        left = False

        def leave_once() -> None:
            nonlocal left
            if not left:
                left = True
                slots.leave(client)

        async def send_then_leave(message: Message) -> None:
            # The slot is free once the answer's last byte goes out: uvicorn reads a kept-alive
            # client's next request right then, before this app returns (its background tasks,
            # the upload's file clean-up), and that request must find the slot free.
            if message["type"] == "http.response.body" and not message.get("more_body", False):
                leave_once()
            await send(message)

        try:
            return await self._limited(scope, receive, send_then_leave, limit, self.min_rate)
        finally:
            leave_once()  # a request that ended without an answer

    async def _limited(self, scope: Scope, receive: Receive, send: Send, limit: int, min_rate: float = 0.0) -> None:
        """Pass the request on, refusing a body over ``limit`` bytes (413), one that stalls
        ``body_timeout_s`` s or, with ``min_rate`` (bytes/s), arrives slower than that over
        ``rate_window_s`` (408): :class:`_BodyWatch`."""
        if _declared_length(scope) > limit:
            return await _too_large(limit)(scope, receive, send)
        t0 = time.perf_counter()
        watch = _BodyWatch(receive, limit, self.body_timeout_s, min_rate, self.rate_window_s)
        status = {"code": 0}
        sent_refusal = False

        async def refuse(resp: JSONResponse) -> None:
            nonlocal sent_refusal
            if not sent_refusal and not status["code"]:  # once, and only before an answer started
                sent_refusal = True
                await resp(scope, receive, send)

        async def logging_send(message: Message) -> None:
            if watch.refusal is not None:
                # the body was refused: whatever the route made of the cut-off body (a
                # form parser answers 400), the client gets the refusal
                return await refuse(watch.refusal)
            if message["type"] == "http.response.start":
                status["code"] = message["status"]
            await send(message)

        try:
            await self.app(scope, watch.receive, logging_send)
            if log.isEnabledFor(logging.DEBUG):
                log.debug("request method=%s path=%s status=%s ms=%.1f", scope["method"], shown(scope["path"]),
                          status["code"], 1e3 * (time.perf_counter() - t0))
        except _Refused:
            assert watch.refusal is not None
            await refuse(watch.refusal)


class _BodyWatch:
    """The ``receive`` of one request, watched: its body within ``limit`` bytes (else
    413), no wait for its next part longer than ``idle_s`` and, with ``min_rate``
    (bytes/s), at least that rate over the last ``window`` s once the body has been
    arriving that long (else 408). A refusal sets :attr:`refusal` (the answer) and raises
    ``_Refused``; once the body is complete, ``receive`` is the server's own."""

    def __init__(self, receive: Receive, limit: int, idle_s: float, min_rate: float, window: float) -> None:
        self._receive = receive
        self.limit, self.idle_s, self.min_rate, self.window = limit, idle_s, min_rate, window
        self.refusal: JSONResponse | None = None
        self.seen = 0
        self.done = False
        self.t0 = time.perf_counter()
        self.marks: deque[tuple[float, int]] = deque([(self.t0, 0)])  # (time, bytes seen): the rate's window

    def too_slow(self, now: float) -> bool:
        """Whether the body's rate over the last window is under ``min_rate``."""
        if not self.min_rate or now - self.t0 < self.window:
            return False
        while len(self.marks) > 1 and self.marks[1][0] <= now - self.window:
            self.marks.popleft()
        since, then = self.marks[0]
        return self.seen - then < self.min_rate * (now - since)

    def _refuse(self, resp: JSONResponse) -> _Refused:
        self.refusal = resp
        return _Refused()

    async def receive(self) -> Message:
        if self.done:
            return await self._receive()
        last = time.perf_counter()
        slow = f"request body arriving slower than {self.min_rate:g} bytes/s over {self.window:g} s"
        while True:
            wait = self.idle_s - (time.perf_counter() - last)
            if self.min_rate:
                wait = min(wait, max(self.window / 4, 0.05))  # look at the rate while nothing comes
            try:
                message = await asyncio.wait_for(self._receive(), max(wait, 0.0))
                break
            except TimeoutError:
                now = time.perf_counter()
                if now - last >= self.idle_s:
                    raise self._refuse(_too_slow(f"no request body data for {self.idle_s:g} s")) from None
                if self.too_slow(now):
                    raise self._refuse(_too_slow(slow)) from None
        if message["type"] != "http.request":
            self.done = True  # a disconnect: nothing more to time
            return message
        self.seen += len(message.get("body", b""))
        self.done = not message.get("more_body", False)
        if self.seen > self.limit:
            raise self._refuse(_too_large(self.limit))
        now = time.perf_counter()
        self.marks.append((now, self.seen))
        if not self.done and self.too_slow(now):
            raise self._refuse(_too_slow(slow))
        return message


def _too_large(limit: int) -> JSONResponse:
    return JSONResponse({"detail": f"request body larger than the limit of {limit} bytes"}, 413,
                        headers={"Connection": "close"})  # the rest of its body is never read


def _has_body(scope: Scope) -> bool:
    """Whether the request declares a body (``Content-Length`` above 0, or ``Transfer-Encoding``)."""
    headers = dict(scope.get("headers") or [])
    return b"transfer-encoding" in headers or _declared_length(scope) > 0


def _declared_length(scope: Scope) -> int:
    """The request's ``Content-Length`` (0 when absent or not a number)."""
    try:
        return int(dict(scope.get("headers") or []).get(b"content-length", b"0"))
    except ValueError:
        return 0


def _too_slow(why: str) -> JSONResponse:
    return JSONResponse({"detail": f"{why}; send the body at once"}, 408, headers={"Connection": "close"})


class _Refused(Exception):
    pass
