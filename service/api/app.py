"""The FastAPI application factory: ``create_app(settings) -> FastAPI``.

Wires the job store (SQLite, WAL), restart recovery, the executor (local process pool or
dask.distributed), the reconstruction queue, the scan manager, the routes (docs/api.md),
error handling (every error is ``{"detail": "<reason>"}``; internals stay in the log),
the upload size limit and the static web page (``settings.web_root``).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import sqlite3
import time
import uuid
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, MutableMapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import BaseRoute
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from driver.acquire import software_version
from service.api.context import Context, Slots, capped, ctx, default_slots, read_access, validation_reason
from service.api.logcaps import RefusalLog, shown
from service.api.models import AuthInfo, Error, Health
from service.disk import is_disk_full
from service.settings import Settings

if TYPE_CHECKING:
    from service.jobs.store import JobStore
    from service.storage.usage import DiskUsage

__all__ = [
    "VERSION", "PROCESS_START", "ERROR_RESPONSES", "allowed_methods", "UploadLimit", "MIN_BODY_RATE",
    "ShortIds", "warm_routes", "freeze_startup_objects", "create_app",
    "internal_error", "InternalErrors", "client_gone", "health_problems",
]

log = logging.getLogger("fpscan.api")

VERSION = software_version()
#: When this server process started (UNIX time): files older than it are a previous run's.
PROCESS_START = time.time()

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": Error, "description": "bad request"},
    401: {"model": Error, "description": "missing or invalid bearer token"},
    403: {"model": Error, "description": "refused: a Host name the server does not answer to, or (no token "
                                         "configured) a state-changing request from another origin"},
    404: {"model": Error, "description": "not found"},
    409: {"model": Error, "description": "conflict with the resource's state"},
    408: {"model": Error, "description": "an upload or plan request body stalled (FPSCAN_BODY_TIMEOUT_S)"},
    413: {"model": Error, "description": "upload too large"},
    422: {"model": Error, "description": "invalid input (the reason is in detail)"},
    429: {"model": Error, "description": "too many expensive requests (uploads, plans) in progress; "
                                         "retry after Retry-After seconds"},
    503: {"model": Error, "description": "the data folder's disk is full; free space, then retry"},
}


def allowed_methods(app: FastAPI, scope: Scope) -> list[str]:
    """The HTTP methods the routes matching ``scope``'s path take, for a 405's ``Allow`` header.

    RFC 9110 §15.5.6; included routers are walked too.

    Parameters
    ----------
    app : FastAPI
        The application.
    scope : dict
        The request's ASGI scope (its path is matched; its method is not).

    Returns
    -------
    list of str
        The methods, sorted (with HEAD where GET is, as the routes declare them).
    """
    from starlette.routing import Match

    methods: set[str] = set()
    probe = {**scope, "method": "GET"}

    def walk(routes: Iterable[BaseRoute]) -> None:
        for route in routes:
            inner = getattr(route, "original_router", None)  # an included router (FastAPI wraps them)
            if inner is not None:
                walk(inner.routes)
                continue
            route_methods = getattr(route, "methods", None)
            if not route_methods:
                continue
            try:
                match, _ = route.matches(probe)
            except Exception:  # a route type that cannot judge this scope: not ours
                continue
            if match != Match.NONE:
                methods.update(route_methods)

    walk(app.router.routes)
    return sorted(methods)


#: Slowest body (bytes/s, averaged over ``Settings.body_rate_window_s``) a request may
#: send (``Settings.body_min_rate``, whose default this is): a trickle would hold an upload
#: or plan slot, or a connection, for hours.
MIN_BODY_RATE = 100 * 1024


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
    - **Slots** (``slots``, :func:`~service.api.context.default_slots`): uploads and plan
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
            limit = self.upload_limit + 1_000_000
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


class ShortIds:
    """ASGI middleware: a unique prefix of a job id works wherever a job id is in the path.

    A prefix of 4 to 31 hex characters (as the CLI and the web page show ids) in
    ``/api/jobs/…``, ``/api/scans/…`` or ``/api/reconstructions/…`` is rewritten to the full
    id; an ambiguous prefix is a 409 naming the matches; a prefix of no job is passed on as
    it is.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.

    Attributes
    ----------
    app : ASGI application
        As given.
    PATH : re.Pattern
        The paths it rewrites (class attribute).
    """

    PATH = re.compile(r"^/api/(jobs|scans|reconstructions)/([0-9a-fA-F]{4,31})(/.*)?$")

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            m = self.PATH.match(scope.get("path", ""))
            ctx_ = getattr(getattr(scope.get("app"), "state", None), "ctx", None)
            if m and ctx_ is not None:
                import anyio

                found = await anyio.to_thread.run_sync(ctx_.store.resolve, m.group(2))
                if len(found) > 1:
                    resp = JSONResponse({"detail": f"job id prefix {m.group(2)!r} matches several jobs "
                                                   f"({', '.join(found)}, ...): give more characters"}, 409)
                    return await resp(scope, receive, send)
                if len(found) == 1:
                    path = f"/api/{m.group(1)}/{found[0]}{m.group(3) or ''}"
                    scope = dict(scope, path=path, raw_path=path.encode())
        return await self.app(scope, receive, send)


async def warm_routes(app: FastAPI, settings: Settings) -> None:
    """Match one request against every route before the first client comes.

    FastAPI builds a route's request and response models at its first match, on the event
    loop (measured: up to 0.2 s on a loaded 2-core machine, in front of every request then
    waiting, health included). The request (``GET /api/.routes-warm-up``, from loopback with
    the token) goes through the whole ASGI stack in-process, matches no route (404) and so
    has tried them all; nothing is reserved or written. A failure is logged, not raised.

    Parameters
    ----------
    app : FastAPI
        The application.
    settings : Settings
        The service's settings (the token the request carries).

    Raises
    ------
    ValueError
        When the token file cannot be read (``Settings.token_value``).
    """
    token = settings.token_value()
    headers = [(b"host", b"127.0.0.1")]
    if token is not None:
        headers.append((b"authorization", f"Bearer {token}".encode()))
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET",
             "scheme": "http", "path": "/api/.routes-warm-up", "raw_path": b"/api/.routes-warm-up",
             "root_path": "", "query_string": b"", "headers": headers, "client": ("127.0.0.1", 0),
             "server": ("127.0.0.1", 0), "state": {}}

    async def receive() -> dict:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: MutableMapping[str, Any]) -> None:
        pass

    try:
        await app(scope, receive, send)
    except Exception:  # a warm-up only: the first real request then pays for it
        log.exception("route warm-up failed")


def freeze_startup_objects() -> None:
    """Collect, then move every object alive after start-up (modules, routes, models: some
    10^5 objects) out of the cyclic garbage collector's reach (``gc.freeze``). A full
    collection walks every tracked object and holds the event loop meanwhile: measured
    0.2-0.4 s per collection under the 50-client soak, in front of every request waiting,
    health included; after the freeze a full collection walks only what was made since.
    Objects alive at start-up live as long as the server anyway."""
    import gc

    gc.collect()
    gc.freeze()


def create_app(settings: Settings | None = None, *, start_workers: bool = True, executor: Any = None) -> FastAPI:
    """The service app: its routes, middleware, error handlers and web page.

    Parameters
    ----------
    settings : Settings or None, optional
        The service's settings; default None: ``Settings.load()``.
    start_workers : bool, optional
        Start the queue and scan threads at start-up; default True (False builds the app
        without them, for schema inspection).
    executor : LocalExecutor or DaskExecutor or None, optional
        The reconstruction executor the queue uses (``fpscan serve`` starts the local pool's
        workers before it imports this module, so they warm up while the server loads;
        closed with the app); default None: made from ``settings`` at start-up
        (:func:`service.jobs.executors.make_executor`).

    Returns
    -------
    FastAPI
        The application.
    """
    settings = settings or Settings.load()
    slots = default_slots(settings)
    app = FastAPI(title="fpscan", version=VERSION, lifespan=_lifespan(settings, slots, start_workers, executor),
                  responses=ERROR_RESPONSES,
                  description="Planar Fabry-Perot photoacoustic scanning: plans, scans, reconstructions as jobs.")
    _add_error_handlers(app)
    from service.api.json_depth import JsonDepthLimit

    app.add_middleware(JsonDepthLimit)  # inside UploadLimit: a body within its size limit, then its nesting
    app.add_middleware(UploadLimit, limit=settings.upload_limit, json_limit=settings.json_limit, slots=slots,
                       body_timeout_s=settings.body_timeout_s, request_json_limit=settings.request_json_limit,
                       min_rate=settings.body_min_rate, rate_window_s=settings.body_rate_window_s)
    app.add_middleware(ShortIds)
    from service.api.access import AccessGate
    from service.api.lanes import HealthLane, RequestTurns

    app.add_middleware(RequestTurns)  # requests start a few per loop iteration (health's lane)
    app.add_middleware(AccessGate, settings=settings)  # before any slot, thread, turn or body byte

    from service.api import datasets, exports, jobs, plans, reconstructions, retention, scans

    health_document = _add_health_routes(app, settings)
    # outermost: health answered ahead of the queue, after the gate's own rules
    app.add_middleware(HealthLane, settings=settings, document=health_document)
    app.add_middleware(InternalErrors)  # outermost: no error drops a kept-alive connection
    for module in (plans, scans, datasets, reconstructions, jobs, exports, retention):
        app.include_router(module.router)
    _state_security_in_openapi(app, settings)
    _render_openapi_once(app)
    _mount_web_page(app, settings)
    return app


def _lifespan(settings: Settings, slots: dict[str, Slots], start_workers: bool,
              given_executor: Any = None) -> Callable[[FastAPI], contextlib.AbstractAsyncContextManager[None]]:
    """``create_app``'s lifespan: the job store and context, then (``start_workers``) the
    queue, its executor and the scan manager; the route warm-up; on shutdown all stopped."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        from service.jobs.store import JobStore

        Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
        settings.token_value()  # an unreadable or empty token_file stops the start here
        store = JobStore(settings.database, reserve_bytes=settings.db_reserve_bytes)
        context = Context(settings=settings, store=store, slots=slots)
        from service.api.jobs import EventWakeups

        context.wakeups = EventWakeups(asyncio.get_running_loop())
        store.add_listener(context.wakeups.notify)
        app.state.ctx = context
        executor = _start_workers(context, store, settings, given_executor) if start_workers else None
        usage = await _count_disk_usage(settings)
        await warm_routes(app, settings)
        freeze_startup_objects()
        try:
            yield
        finally:
            usage.stop()
            _stop_workers(context, executor, store)

    return lifespan


async def _count_disk_usage(settings: Settings) -> DiskUsage:
    """The data folder's disk-use counters (``service.storage.usage``) set by one walk
    before the server answers (in a thread: start-up only), then checked by a walk every
    ``disk_walk_period_s`` in a thread of their own; returns them."""
    from service.jobs.lifecycle import disk_usage
    from service.storage.usage import usage_for

    usage = usage_for(settings.data_dir, settings.database)
    await asyncio.to_thread(usage.reconcile, disk_usage)
    usage.start_walks(disk_usage, settings.disk_walk_period_s)
    return usage


def _start_workers(context: Context, store: JobStore, settings: Settings, executor: Any = None) -> Any:
    """Start the reconstruction queue (after crash recovery, debris removal and the
    retention policy) on ``executor`` (default: made from the settings), the plan worker and
    the scan manager; returns the executor."""
    from service.jobs.executors import make_executor
    from service.jobs.queue import ReconQueue

    if executor is None:
        executor = make_executor(settings)
    if hasattr(executor, "start_workers"):  # the local pool: its workers start (and warm up) now,
        context.extras["worker_starts"] = executor.start_workers()  # in the background
    context.queue = ReconQueue(store, executor, settings)
    recovered = store.recover(context.queue.owner, settings.max_attempts)
    from service.jobs.queue import remove_debris

    debris = remove_debris(settings.data_dir, PROCESS_START)
    if debris:
        log.info("startup removed crash debris: %s", ", ".join(debris[:20]))
    if settings.resume_scans:
        for jid in recovered["paused"]:
            store.set_state(jid, "queued", only_from=("paused",), progress={"stage": "resuming", "reason": None})
    log.info("startup recovered=%s executor=%s resume_scans=%s", recovered, settings.executor,
             settings.resume_scans)
    from service.jobs.lifecycle import apply_retention

    apply_retention(store, settings)  # a policy tightened while the server was down
    context.queue.start()
    from service.api.plans import plan_executor

    plan_executor(context)  # the plan worker starts loading now, not at the first plan request
    try:
        from service.jobs.scans import ScanManager

        context.scans = ScanManager(store, settings)
        context.scans.start()
    except ImportError as exc:  # the driver is not installed
        log.warning("scanning unavailable: %s", exc)
    return executor


def _stop_workers(context: Context, executor: Any, store: JobStore) -> None:
    """Stop scans, the queue, the executor and the plan worker, wait for the queue's
    running jobs (they re-queue themselves) and close the store."""
    if context.scans is not None:
        context.scans.stop()
    if context.queue is not None:
        context.queue.stop()
    if executor is not None:
        executor.close()
    if context.extras.get("plan_executor") is not None:
        context.extras["plan_executor"].close()
    if context.queue is not None:
        context.queue.join()  # running jobs re-queue themselves (SIGTERM re-queues)
    store.close()


def _add_error_handlers(app: FastAPI) -> None:
    """Every error answers ``{"detail": reason}``: 422 for invalid values, the HTTP error's
    own status (405 with the path's ``Allow``), 503 for a full disk, 500 with a reference."""

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": validation_reason(exc)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = capped(exc.detail if isinstance(exc.detail, str) else str(exc.detail))
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # Allow: every method of the path (Starlette names only the first route's)
            allowed = allowed_methods(app, request.scope)
            headers = {**(headers or {}), "Allow": ", ".join(allowed)} if allowed else headers
            detail = f"method {request.method} not allowed here; allowed: {', '.join(allowed)}" if allowed else detail
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=headers)

    @app.exception_handler(OSError)
    @app.exception_handler(sqlite3.Error)
    async def _storage(request: Request, exc: Exception) -> JSONResponse:
        # handled here, not by the catch-all below (Starlette re-raises from that one and
        # the server then drops the client's kept-alive connection)
        if is_disk_full(exc):  # the server's condition, not a bug: say so, and how to fix it
            log.warning("disk full %s %s: %s", request.method, shown(request.url.path), exc)
            return JSONResponse({"detail": "the data folder's disk is full; free space, then retry "
                                           "(/api/health shows the free bytes)"},
                                status_code=503, headers={"Retry-After": "10"})
        return await _internal(request, exc)

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        return internal_error(request.scope, exc)


def internal_error(scope: Scope, exc: BaseException) -> JSONResponse:
    """The 500 of an unexpected error: logged with a reference, the client told only the reference.

    Parameters
    ----------
    scope : dict
        The request's ASGI scope (its method and path, capped, are logged).
    exc : BaseException
        The error (logged with its traceback).

    Returns
    -------
    JSONResponse
        Status 500, ``{"detail": "internal error (reference <8 hex>)"}``.
    """
    ref = uuid.uuid4().hex[:8]
    log.error("internal error ref=%s %s %s", ref, scope.get("method"), shown(scope.get("path", "")), exc_info=exc)
    return JSONResponse({"detail": f"internal error (reference {ref})"}, status_code=500)


class InternalErrors:
    """ASGI middleware, the outermost of the app's own: an error no handler took becomes a
    500 answer (:func:`internal_error`) and goes no further. Starlette's own last handler
    re-raises after answering, and uvicorn then closes the client's kept-alive connection
    and logs the traceback a second time; here the connection stays open for the client's
    next request. An error after the answer started is logged and the connection closed
    (there is no way to tell the client).

    A client gone (its disconnect received, its connection reset, a send to a closed
    connection: :func:`client_gone`) is no internal error: it is logged at most one line per
    client address per interval (``service.api.logcaps.RefusalLog``), and nothing is answered.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.

    Attributes
    ----------
    app : ASGI application
        As given.
    gone : RefusalLog
        The rate-limited log of clients gone mid-request.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.gone = RefusalLog(log)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False
        disconnected = False

        async def tracked_receive() -> Message:
            nonlocal disconnected
            message = await receive()
            if message["type"] == "http.disconnect":
                disconnected = True
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, tracked_receive, tracked_send)
        except Exception as exc:
            if disconnected or client_gone(exc):
                client = (scope.get("client") or ("?", 0))[0]
                self.gone.refused(client, "client gone client=%s method=%s path=%s: %s", client,
                                  shown(scope.get("method"), 16), shown(scope.get("path", "")),
                                  shown(type(exc).__name__, 60))
                return
            if started:
                raise
            await internal_error(scope, exc)(scope, receive, send)


def client_gone(exc: BaseException) -> bool:
    """Whether ``exc`` says the client went away: a connection reset or broken pipe, a stream
    whose other end closed (anyio), Starlette's ``ClientDisconnect``, or a group of only those.

    Parameters
    ----------
    exc : BaseException
        The error a request's handling raised.

    Returns
    -------
    bool
        True for a client gone; False for anything else (an internal error).
    """
    import anyio
    from starlette.requests import ClientDisconnect

    if isinstance(exc, BaseExceptionGroup):
        return all(client_gone(e) for e in exc.exceptions)
    return isinstance(exc, (ConnectionError, anyio.ClosedResourceError, anyio.BrokenResourceError,
                            ClientDisconnect))


def _add_health_routes(app: FastAPI, settings: Settings) -> Callable[[Context], Awaitable[Health]]:
    """``GET /api/health`` and ``GET /api/auth``; returns health's document (an awaitable
    of :class:`Health`, given the app's context), which ``service.api.lanes.HealthLane``
    answers with ahead of the other requests."""
    from service.storage.usage import usage_for

    usage = usage_for(settings.data_dir, settings.database)

    async def health_document(c: Context) -> Health:
        return Health(version=VERSION, executor=settings.executor,
                      jobs_running=c.queue.running() if c.queue is not None else 0,
                      disk=usage.snapshot(), problems=health_problems(c))

    @app.get("/api/health", response_model=Health, tags=["health"], dependencies=[Depends(read_access)])
    async def health(c: Context = Depends(ctx)) -> Health:
        """Liveness: ``{"status": "ok", "version", "executor", "jobs_running", "disk",
        "problems"}``; ``disk``: bytes the data folder uses by part (scans, results, datasets,
        exports, other) and the free bytes of its file system; ``problems``: what keeps jobs
        from running now, one line each (a full disk, a lost device). Answered on the event
        loop without a server thread, ahead of the other requests waiting for their turn
        (``service.api.lanes``), in time independent of the data folder: the bytes are
        counters kept as files are written and removed (``service.storage.usage``, checked
        by a walk in a thread of its own), a stored change shows in the next answer, a scan
        file's growth within a second."""
        return await health_document(c)

    @app.get("/api/auth", response_model=AuthInfo, tags=["health"])
    def auth(request: Request) -> AuthInfo:
        """Whether this server needs a bearer token, and whether the request carried the
        right one (needs no token itself: the web page asks it first, to show its login view
        before any other request)."""
        from service.api.access import token_matches

        expected = settings.token_value()
        return AuthInfo(token_required=expected is not None,
                        authenticated=expected is None
                        or token_matches(request.headers.get("authorization"), expected) is None)

    return health_document


def health_problems(c: Context) -> list[str]:
    """What keeps jobs from running now, one line each, for ``/api/health``.

    Parameters
    ----------
    c : Context
        The app's context (settings, store, queue, scans).

    Returns
    -------
    list of str
        The data folder's disk below the reserve (``disk_reserve_bytes``), the job database's
        reserve in use, reconstructions waiting for disk space (``service.jobs.queue``) and
        interrupted scans (``service.jobs.scans``); empty when nothing is wrong.
    """
    from service.storage.usage import usage_for

    out: list[str] = []
    settings = c.settings
    free = usage_for(settings.data_dir).snapshot().get("free_bytes")
    if free is not None and c.store.reserve_spent is not None:  # those bytes are the job database's
        free = max(0, free - c.store.reserve_bytes)
    if free is not None and free < settings.disk_reserve_bytes:
        out.append(f"the data folder's disk is full: {free} bytes free, below the reserve of "
                   f"{settings.disk_reserve_bytes} (disk_reserve_bytes); reconstructions that do not fit fail or wait, "
                   "scans pause: free space")
    out += c.store.problems()
    if c.queue is not None:
        out += c.queue.problems()
    if c.scans is not None:
        out += c.scans.problems()
    return out


def _state_security_in_openapi(app: FastAPI, settings: Settings) -> None:
    """Make the app's OpenAPI schema say whether routes need the token."""
    base_openapi = app.openapi

    def openapi() -> dict:
        """The schema states what the server enforces: with a token configured every API
        route needs it; without one (a loopback-only server) none does (``security``
        lists the empty requirement first)."""
        done = app.openapi_schema is not None
        schema = base_openapi()
        if not done and settings.token is None and settings.token_file is None:
            for item in schema.get("paths", {}).values():
                for op in item.values():
                    if isinstance(op, dict) and op.get("security") and {} not in op["security"]:
                        op["security"] = [{}, *op["security"]]
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _render_openapi_once(app: FastAPI) -> None:
    """Serve ``/openapi.json`` as bytes rendered once: the schema (some 100 kB of JSON) does
    not change while the server runs, and FastAPI's own route serialises it on the event loop
    at every request (a few ms each: strangers pipelining it held the loop for seconds)."""
    from starlette.responses import Response
    from starlette.routing import Route

    rendered: list[bytes] = []

    async def openapi(request: Request) -> Response:
        if not rendered:
            rendered.append(bytes(JSONResponse(app.openapi()).body))
        return Response(rendered[0], media_type="application/json")

    for i, route in enumerate(app.router.routes):
        if isinstance(route, Route) and route.path == app.openapi_url:
            app.router.routes[i] = Route(route.path, openapi, include_in_schema=False)


def _mount_web_page(app: FastAPI, settings: Settings) -> None:
    """Serve ``settings.web_root`` (the web page) at ``/`` when it is a folder."""
    if settings.web_root is not None:
        root = Path(settings.web_root)
        if root.is_dir():
            app.mount("/", StaticFiles(directory=str(root), html=True), name="web")
        else:
            log.warning("web_root %s is not a folder; no web page", root)
