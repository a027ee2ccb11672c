"""``GET /api/health`` (liveness, disk use, what keeps jobs from running) and ``GET /api/auth``
(whether the server needs a token)."""
from __future__ import annotations

import os
import threading
from collections.abc import Awaitable, Callable

from fastapi import Depends, FastAPI, Request

from fpscan.service.api.context import Context, ctx, read_access
from fpscan.service.api.models import AuthInfo, ComputeDevice, Health
from fpscan.service.settings import Settings

__all__ = ["add_health_routes", "health_problems", "DeviceList"]


class DeviceList:
    """The devices reconstructions can run on: the CPU at once, the CUDA GPUs once a child
    process has listed them (`fpscan.service.recon.device.probe_devices`, started in a thread here, so
    that the server's own process never loads CUDA).

    Attributes
    ----------
    gpus : list of dict
        ``index``, ``name``, ``memory_total`` per GPU ([] until listed, or without one).
    listed : threading.Event
        Set once the child answered.
    """

    def __init__(self) -> None:
        self.gpus: list[dict] = []
        self.listed = threading.Event()
        threading.Thread(target=self._probe, name="fpscan-device-probe", daemon=True).start()

    def _probe(self) -> None:
        from fpscan.service.recon.device import probe_devices

        self.gpus = probe_devices()
        self.listed.set()

    def entries(self) -> list[ComputeDevice]:
        """The CPU, then each GPU listed so far."""
        cpu = ComputeDevice(kind="cpu", name="cpu", cores=os.cpu_count())
        return [cpu, *(ComputeDevice(kind="cuda", name=str(g["name"]), memory_total=int(g["memory_total"]))
                       for g in self.gpus)]


def add_health_routes(app: FastAPI, settings: Settings) -> Callable[[Context], Awaitable[Health]]:
    """Add ``GET /api/health`` and ``GET /api/auth`` to the app.

    Parameters
    ----------
    app : FastAPI
        The application (its ``version`` is health's ``version``).
    settings : Settings
        The service's settings (the executor, the data folder, the token).

    Returns
    -------
    callable
        Health's document: an awaitable of :class:`~fpscan.service.api.models.Health`, given the
        app's context, which ``fpscan.service.api.lanes.HealthLane`` answers with ahead of the other
        requests.
    """
    from fpscan.service.storage.usage import usage_for

    usage = usage_for(settings.data_dir, settings.database)
    version = app.version  # fpscan.service.api.app.VERSION
    devices = DeviceList()
    app.state.devices = devices

    async def health_document(context: Context) -> Health:
        return Health(version=version, executor=settings.executor,
                      jobs_running=context.queue.running() if context.queue is not None else 0,
                      disk=usage.snapshot(), problems=health_problems(context), devices=devices.entries())

    @app.get("/api/health", response_model=Health, tags=["health"], dependencies=[Depends(read_access)])
    async def health(context: Context = Depends(ctx)) -> Health:
        """Liveness: ``{"status": "ok", "version", "executor", "jobs_running", "disk",
        "problems", "devices"}``; ``devices``: the CPU and each CUDA GPU found at the start (what
        ``device`` can ask for); ``disk``: bytes the data folder uses by part (scans, results, datasets,
        exports, other) and the free bytes of its file system; ``problems``: what keeps jobs
        from running now, one line each (a full disk, a lost device). Answered on the event
        loop without a server thread, ahead of the other requests waiting for their turn
        (``fpscan.service.api.lanes``), in time independent of the data folder: the bytes are
        counters kept as files are written and removed (``fpscan.service.storage.usage``, checked
        by a walk in a thread of its own), a stored change shows in the next answer, a scan
        file's growth within a second."""
        return await health_document(context)

    @app.get("/api/auth", response_model=AuthInfo, tags=["health"])
    def auth(request: Request) -> AuthInfo:
        """Whether this server needs a bearer token, and whether the request carried the
        right one (needs no token itself: the web page asks it first, to show its login view
        before any other request)."""
        from fpscan.service.api.access import token_matches

        expected = settings.token_value()
        return AuthInfo(token_required=expected is not None,
                        authenticated=expected is None
                        or token_matches(request.headers.get("authorization"), expected) is None)

    return health_document


def health_problems(context: Context) -> list[str]:
    """What keeps jobs from running now, one line each, for ``/api/health``.

    Parameters
    ----------
    context : Context
        The app's context (settings, store, queue, scans).

    Returns
    -------
    list of str
        The data folder's disk below the reserve (``disk_reserve_bytes``), the job database's
        reserve in use, reconstructions waiting for disk space (``fpscan.service.jobs.queue``) and
        interrupted scans (``fpscan.service.jobs.scan_manager``); empty when nothing is wrong.
    """
    from fpscan.service.storage.usage import usage_for

    out: list[str] = []
    settings = context.settings
    free = usage_for(settings.data_dir).snapshot().get("free_bytes")
    if free is not None and context.store.reserve_spent is not None:  # those bytes are the job database's
        free = max(0, free - context.store.reserve_bytes)
    if free is not None and free < settings.disk_reserve_bytes:
        out.append(f"the data folder's disk is full: {free} bytes free, below the reserve of "
                   f"{settings.disk_reserve_bytes} (disk_reserve_bytes); reconstructions that do not fit fail or wait, "
                   "scans pause: free space")
    out += context.store.problems()
    if context.queue is not None:
        out += context.queue.problems()
    if context.scans is not None:
        out += context.scans.problems()
    return out
