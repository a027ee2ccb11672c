"""The FastAPI application factory: ``create_app(settings) -> FastAPI``, and its lifespan.

Wires the job store (SQLite, WAL), restart recovery, the executor (local process pool or
dask.distributed), the reconstruction queue, the scan manager, the routes (docs/api.md;
health in :mod:`fpscan.service.api.health`), error handling (every error is
``{"detail": "<reason>"}``; internals stay in the log: :mod:`fpscan.service.api.errors`), the
middlewares (each in its module: :mod:`fpscan.service.api.upload_limit`,
:mod:`fpscan.service.api.json_depth`, :mod:`fpscan.service.api.short_ids`, :mod:`fpscan.service.api.access`,
:mod:`fpscan.service.api.lanes`, :mod:`fpscan.service.api.internal_errors`,
:mod:`fpscan.service.api.browser_headers`), the OpenAPI schema (:mod:`fpscan.service.api.openapi`), its
reference page (``/docs``: :mod:`fpscan.service.api.reference_pages`) and the static web page
(``settings.web_root``).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Callable, MutableMapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI
from starlette.staticfiles import StaticFiles

from fpscan.driver.acquire import software_version
from fpscan.service.api.context import Context, Slots, default_slots
from fpscan.service.api.errors import ERROR_RESPONSES, add_error_handlers
from fpscan.service.api.health import add_health_routes
from fpscan.service.api.internal_errors import InternalErrors
from fpscan.service.api.openapi import render_openapi_once, state_security_in_openapi
from fpscan.service.api.short_ids import ShortIds
from fpscan.service.api.upload_limit import UploadLimit
from fpscan.service.settings import Settings

if TYPE_CHECKING:
    from fpscan.service.jobs.store import JobStore
    from fpscan.service.storage.usage import DiskUsage

__all__ = ["VERSION", "PROCESS_START", "warm_routes", "freeze_startup_objects", "create_app"]

log = logging.getLogger("fpscan.api")

VERSION = software_version()
#: When this server process started (UNIX time): files older than it are a previous run's.
PROCESS_START = time.time()


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
        (:func:`fpscan.service.jobs.executors.make_executor`).

    Returns
    -------
    FastAPI
        The application.
    """
    settings = settings or Settings.load()
    slots = default_slots(settings)
    app = FastAPI(title="fpscan", version=VERSION, lifespan=_lifespan(settings, slots, start_workers, executor),
                  responses=ERROR_RESPONSES, docs_url=None, redoc_url=None,  # served from files: reference_pages
                  description="Planar Fabry-Perot photoacoustic scanning: plans, scans, reconstructions as jobs.")
    add_error_handlers(app)
    from fpscan.service.api.json_depth import JsonDepthLimit

    app.add_middleware(JsonDepthLimit)  # inside UploadLimit: a body within its size limit, then its nesting
    app.add_middleware(UploadLimit, limit=settings.upload_limit, json_limit=settings.json_limit, slots=slots,
                       body_timeout_s=settings.body_timeout_s, request_json_limit=settings.request_json_limit,
                       min_rate=settings.body_min_rate, rate_window_s=settings.body_rate_window_s)
    app.add_middleware(ShortIds)
    from fpscan.service.api.access import AccessGate, TokenFailures
    from fpscan.service.api.lanes import HealthLane, RequestTurns

    failures = TokenFailures()  # wrong tokens per client address: the gate's and health's lane's
    app.add_middleware(RequestTurns)  # requests start a few per loop iteration (health's lane)
    app.add_middleware(AccessGate, settings=settings, failures=failures)  # before any slot, thread, turn or body byte

    from fpscan.service.api import datasets, exports, jobs, plans, reconstructions, retention, scans

    health_document = add_health_routes(app, settings)
    # outermost: health answered ahead of the queue, after the gate's own rules
    app.add_middleware(HealthLane, settings=settings, document=health_document, failures=failures)
    app.add_middleware(InternalErrors)  # no error drops a kept-alive connection
    from fpscan.service.api.browser_headers import BrowserHeaders

    app.add_middleware(BrowserHeaders)  # outermost: every answer, refusals included, carries them
    for module in (plans, scans, datasets, reconstructions, jobs, exports, retention):
        app.include_router(module.router)
    state_security_in_openapi(app, settings)
    render_openapi_once(app)
    from fpscan.service.api.reference_pages import add_reference_pages

    add_reference_pages(app)  # /docs from installed files, before the web page's catch-all mount
    _mount_web_page(app, settings)
    return app


def _lifespan(settings: Settings, slots: dict[str, Slots], start_workers: bool,
              given_executor: Any = None) -> Callable[[FastAPI], contextlib.AbstractAsyncContextManager[None]]:
    """``create_app``'s lifespan: the job store and context, then (``start_workers``) the
    queue, its executor and the scan manager; the route warm-up; on shutdown all stopped."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        from fpscan.service.jobs.store import JobStore

        Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
        settings.token_value()  # an unreadable or empty token_file stops the start here
        store = JobStore(settings.database, reserve_bytes=settings.db_reserve_bytes)
        context = Context(settings=settings, store=store, slots=slots)
        from fpscan.service.api.jobs import EventWakeups

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
    """The data folder's disk-use counters (``fpscan.service.storage.usage``) set by one walk
    before the server answers (in a thread: start-up only), then checked by a walk every
    ``disk_walk_period_s`` in a thread of their own; returns them."""
    from fpscan.service.jobs.lifecycle import disk_usage
    from fpscan.service.storage.usage import usage_for

    usage = usage_for(settings.data_dir, settings.database)
    await asyncio.to_thread(usage.reconcile, disk_usage)
    usage.start_walks(disk_usage, settings.disk_walk_period_s)
    return usage


def _start_workers(context: Context, store: JobStore, settings: Settings, executor: Any = None) -> Any:
    """Start the reconstruction queue (after crash recovery, debris removal and the
    retention policy) on ``executor`` (default: made from the settings), the plan worker and
    the scan manager; returns the executor."""
    from fpscan.service.jobs.executors import make_executor
    from fpscan.service.jobs.queue import ReconQueue

    if executor is None:
        executor = make_executor(settings)
    if hasattr(executor, "start_workers"):  # the local pool: its workers start (and warm up) now,
        context.extras["worker_starts"] = executor.start_workers()  # in the background
    context.queue = ReconQueue(store, executor, settings)
    recovered = store.recover(context.queue.owner, settings.max_attempts)
    from fpscan.service.jobs.queue import remove_debris

    debris = remove_debris(settings.data_dir, PROCESS_START, known_datasets={d["id"] for d in store.list_datasets()})
    if debris:
        log.info("startup removed crash debris: %s", ", ".join(debris[:20]))
    if settings.resume_scans:
        for jid in recovered["paused"]:
            store.set_state(jid, "queued", only_from=("paused",), progress={"stage": "resuming", "reason": None})
    log.info("startup recovered=%s executor=%s resume_scans=%s", recovered, settings.executor,
             settings.resume_scans)
    from fpscan.service.jobs.lifecycle import apply_retention

    apply_retention(store, settings)  # a policy tightened while the server was down
    context.queue.start()
    from fpscan.service.api.plans import plan_executor
    from fpscan.service.api.plans import warm_up as warm_plan_worker

    if settings.warm_up:  # the plan worker loads now, in the background, not at the first plan request
        plan_executor(context).submit(warm_plan_worker)  # the first request queues behind it
    try:
        from fpscan.service.jobs.scan_manager import ScanManager

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




def _mount_web_page(app: FastAPI, settings: Settings) -> None:
    """Serve ``settings.web_root`` (the web page) at ``/`` when it is a folder."""
    if settings.web_root is not None:
        root = Path(settings.web_root)
        if root.is_dir():
            app.mount("/", StaticFiles(directory=str(root), html=True), name="web")
        else:
            log.warning("web_root %s is not a folder; no web page", root)
