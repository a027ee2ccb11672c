"""Plan routes: create (mask parameters or a point list), preview, list, get, preview PNG.

A plan is the JSON of docs/architecture.md (``fpscan-plan/1``); its id is the content hash
of ``fpscan.driver.plan``. Every plan, a user point list (lattice indices) included, is built by
``fpscan.service.plans.make_plan``.
"""
from __future__ import annotations

import base64
import collections
import contextlib
import functools
import gzip
import json
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, TypeVar

import anyio
import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Path, Request, Response
from pydantic import TypeAdapter, ValidationError

from fpscan.service.api.context import Context, ctx, read_access, reason, require_token, validation_reason
from fpscan.service.api.models import (
    ID_PATTERN,
    Deleted,
    MaskKindInfo,
    Plan,
    PlanCreate,
    PlanDocument,
    PlanPreview,
)
from fpscan.service.jobs import lifecycle

if TYPE_CHECKING:
    from fpscan.service.jobs.executors import LocalExecutor

__all__ = [
    "router", "MAX_POINTS", "PREVIEW_DETAIL_POINTS", "build_plan", "expected_scan_time", "summary",
    "preview_png", "parse_plan_request", "plan_work", "gzip_text", "SERVED", "warm_up", "preview_png_of_text",
    "PLAN_WORKER_NICE", "plan_executor", "create_plan_raw", "preview_plan_raw", "create_plan", "preview_plan",
    "list_mask_kinds", "list_plans", "plan_or_404", "get_plan", "delete_plan", "accepts_encoding",
    "get_plan_json", "plan_preview_png",
]

router = APIRouter(prefix="/api/plans", tags=["plans"])

_T = TypeVar("_T")

#: Most points a plan made over HTTP may have: building, hashing and drawing a plan costs
#: time linear in its points; beyond this a request is refused (422) before that work.
MAX_POINTS = 1 << 18
#: Plans with more points are previewed as a plain lattice image (one pixel per point).
PREVIEW_DETAIL_POINTS = 1 << 14


def build_plan(req: Any) -> dict:  # a PlanCreate variant (models built at import)
    """The plan JSON for a plan request.

    A plan JSON is checked (``fpscan.driver.plan`` via ``fpscan.service.plans.Plan``) and kept as it is, so
    it keeps its id; anything else is built by ``fpscan.service.plans.make_plan``, the one plan
    builder (a user point list is the mask kind ``points``).

    Parameters
    ----------
    req : PlanCreate
        A variant of the request model: a plan document, mask parameters, or a point list.

    Returns
    -------
    dict
        The plan JSON (``fpscan-plan/1``).

    Raises
    ------
    ValueError
        With the reason: implausible units (a pitch of 60 m, dt 8 s), a point list given both
        as points and params or as neither, bad mask parameters, or more than
        :data:`MAX_POINTS` points.
    """
    from fpscan.service.plans import check_plausible_request, make_mask, make_plan

    if isinstance(req, PlanDocument):
        from fpscan.driver.units import check_plausible

        # the unit rules of a plan request (a pitch of 60 m, dt 8 s); a document states no
        # force, so its sound speed (which make_plan may have forced) is not judged here
        check_plausible(pitch=req.lattice.pitch, dt=req.acquisition.dt)
        out = req.to_dict()
    else:
        params = req.params.mask_kwargs() if req.params is not None else {}
        if getattr(req, "points", None) is not None:
            if params:
                raise ValueError("give the point list either as points or as params, not both")
            params = {"indices": [list(p) for p in req.points]}
        elif req.params is None:
            raise ValueError("a point list needs points (lattice indices) or params (points in m or indices)")
        # a unit mistake (a pitch of 60 m, a depth of 3.6 m) is named before any mask is made
        check_plausible_request(None, req.kind, req.lattice.model_dump(), params, req.acquisition.model_dump(),
                                force=req.force)
        try:
            mask = make_mask(req.kind, req.lattice.model_dump(), **params)
            if mask.obtained_points > MAX_POINTS:  # refused before the plan's linear-time work
                raise ValueError(f"the mask has {mask.obtained_points} points; a plan made here may have at most "
                                 f"{MAX_POINTS} points")
            plan = make_plan(mask, order=req.order or "auto", acquisition=req.acquisition.model_dump(),
                             force=req.force)
        except (TypeError, OverflowError, IndexError, KeyError, ZeroDivisionError) as exc:
            raise ValueError(f"bad mask parameters ({type(exc).__name__}: {exc})") from None
        out = plan.model_dump(mode="json")
    if len(out["points"]["indices"]) > MAX_POINTS:
        raise ValueError(f"a plan made here may have at most {MAX_POINTS} points")
    return out


def expected_scan_time(plan: dict) -> float | None:
    """The expected duration of a plan's scan: points × averages × wavelengths / PRF.

    Parameters
    ----------
    plan : dict
        The plan JSON (its ``points`` and ``acquisition``: ``prf`` in Hz, ``averages``,
        ``wavelengths``).

    Returns
    -------
    float or None
        Seconds; None when the PRF is 0 (unthrottled: the scanner's own rate decides).
    """
    acq = plan["acquisition"]
    n = len(plan["points"]["indices"])
    prf = float(acq.get("prf", 0) or 0)
    return n * int(acq.get("averages", 1)) * len(acq.get("wavelengths", [1])) / prf if prf > 0 else None


def summary(plan: dict) -> Plan:
    """The API summary of a stored plan dict.

    Parameters
    ----------
    plan : dict
        The plan JSON.

    Returns
    -------
    Plan
        Its id, mask kind, point counts and shortfall, weight ratio, expected scan time,
        lattice, acquisition and links.
    """
    mask = plan.get("mask", {})
    pid = plan["id"]
    from fpscan.service.plans.mask import shortfall

    n = len(plan["points"]["indices"])
    return Plan(id=pid, kind=mask.get("kind", "points"), n_points=n,
                requested_points=mask.get("requested_points"),
                shortfall=shortfall(mask.get("kind", "points"), mask.get("requested_points"), n,
                                    (plan.get("lattice") or {}).get("pitch")),
                weight_ratio=mask.get("weight_ratio"),
                expected_scan_time_s=expected_scan_time(plan), lattice=plan["lattice"],
                acquisition=plan["acquisition"],
                links={"self": f"/api/plans/{pid}", "preview": f"/api/plans/{pid}/preview.png"})


def preview_png(plan: dict) -> bytes:
    """The mask preview PNG, drawn by the one renderer (``fpscan.service.pictures.render``: x
    right, y down, axes in mm at equal aspect, colour bar, ``fpscan:axes`` chunk): points
    as coloured markers (``fpscan.service.plans.preview_png``) up to ``PREVIEW_DETAIL_POINTS``
    points; beyond that (markers cost time linear in the points) and for a plan the plan
    model cannot read, the mask as an image on its lattice (``render_lattice``: one cell
    per lattice point, coloured by weight).

    Parameters
    ----------
    plan : dict
        The plan JSON.

    Returns
    -------
    bytes
        The PNG file's bytes.
    """
    if len(plan["points"]["indices"]) <= PREVIEW_DETAIL_POINTS:
        try:
            from fpscan.service.plans import Plan as PlanModel
            from fpscan.service.plans import preview_png as plans_preview

            return plans_preview(PlanModel.model_validate(plan))
        except (ImportError, ValueError):
            pass
    from fpscan.service.pictures.render import render_lattice

    lat, mask = plan["lattice"], plan.get("mask", {})
    n_x, n_y, pitch = int(lat["n_x"]), int(lat.get("n_y", 1)), float(lat["pitch"])
    idx = np.asarray(plan["points"]["indices"], dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(plan["points"].get("weights") or [], dtype=np.float64)
    line = n_y == 1
    if weights.shape == (len(idx),):
        values, label = weights * (1e6 if line else 1e12), "weight (µm)" if line else "weight (µm²)"
    else:
        values, label = np.ones(len(idx)), "sensor point"
    ratio = mask.get("weight_ratio")
    title = (f"{mask.get('kind', 'points')}: {len(idx)} of {mask.get('requested_points') or len(idx)} "
             f"requested points on {n_x}×{n_y}" + (f"\nouter/inner weight ratio {ratio:.3g}" if ratio else ""))
    p = (mask.get("params") or {}).get("poi")
    poi = None if p is None else (float(np.ravel(p)[0]), float(np.ravel(p)[1]) if np.size(p) > 1 else 0.0)
    return render_lattice(idx, values, n_x, n_y, pitch, title=title, colorbar_label=label, poi=poi)


@functools.cache
def _plan_request_adapter() -> TypeAdapter:
    return TypeAdapter(PlanCreate)


def parse_plan_request(raw: bytes, content_type: str | None) -> Any:  # a PlanCreate variant
    """The ``PlanCreate`` variant of a request body, read as FastAPI reads a JSON body.

    Parameters
    ----------
    raw : bytes
        The request body.
    content_type : str or None
        Its ``Content-Type``: JSON when absent, ``application/json`` or ``…+json``; else the
        raw bytes are validated, which no variant takes.

    Returns
    -------
    PlanCreate
        The validated request.

    Raises
    ------
    ValueError
        With the reason in the words of the API's 422 answers (an empty body, malformed
        JSON, a validation error).
    """
    from fastapi.exceptions import RequestValidationError

    if not raw:
        raise ValueError("body: Field required")
    value: Any = raw
    maintype, _, subtype = (content_type or "application/json").split(";")[0].strip().lower().partition("/")
    if maintype == "application" and (subtype == "json" or subtype.endswith("+json")):
        try:
            value = json.loads(raw)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"malformed JSON: {getattr(exc, 'msg', None) or exc}") from None
        except RecursionError:  # the door (fpscan.service.api.json_depth) refuses such a body before it comes here
            raise ValueError("JSON nested too deep") from None
    try:
        return _plan_request_adapter().validate_python(value)
    except ValidationError as exc:
        raise ValueError(validation_reason(RequestValidationError(exc.errors()))) from None


def plan_work(raw: bytes, content_type: str | None, preview: bool) -> dict:
    """A plan request's whole CPU work, run in the plan worker process (so the server's
    event loop and its other threads never wait for it): parse and check the body
    (:func:`parse_plan_request`), build the plan (:func:`build_plan`), its summary and,
    for a preview, its PNG, else its JSON text as stored and served.

    Parameters
    ----------
    raw : bytes
        The request body.
    content_type : str or None
        Its ``Content-Type``.
    preview : bool
        Draw the preview PNG (``POST /api/plans/preview``) rather than make the plan's text.

    Returns
    -------
    dict
        ``{"status": 422, "detail": reason}`` for a refused request, else
        ``{"status": 200, "summary": {...}, "png": bytes}`` (``preview``) or
        ``{"status": 201, "summary": {...}, "text": str, "gzip": bytes}`` (the JSON text and
        :func:`gzip_text` of it).
    """
    try:
        plan = build_plan(parse_plan_request(raw, content_type))
    except (ValueError, OverflowError) as exc:
        return {"status": 422, "detail": reason(exc)}
    s = summary(plan)
    if preview:
        return {"status": 200, "summary": s.model_dump(mode="json"), "png": preview_png(plan)}
    text = json.dumps(plan)
    return {"status": 201, "summary": s.model_dump(mode="json"), "text": text, "gzip": gzip_text(text)}


def gzip_text(text: str) -> bytes:
    """``text`` (a plan's JSON) UTF-8 encoded and gzip-compressed, as served to clients that accept it.

    A plan of 262 144 points: 16 MB of JSON, about 1.5 MB compressed.

    Parameters
    ----------
    text : str
        The text.

    Returns
    -------
    bytes
        The gzip data (level 5, no time stamp: the same text gives the same bytes).
    """
    return gzip.compress(text.encode(), compresslevel=5, mtime=0)


class _ServedPlans:
    """The compressed JSON of recently made or read plans, ready to serve (a plan's id is
    the hash of its content, so an entry never goes stale; at most ``size`` are kept)."""

    def __init__(self, size: int = 16):
        self.size = size
        self._lock = threading.Lock()
        self._items: collections.OrderedDict[str, bytes] = collections.OrderedDict()

    def get(self, plan_id: str) -> bytes | None:
        with self._lock:
            if plan_id in self._items:
                self._items.move_to_end(plan_id)
            return self._items.get(plan_id)

    def put(self, plan_id: str, data: bytes) -> None:
        with self._lock:
            self._items[plan_id] = data
            self._items.move_to_end(plan_id)
            while len(self._items) > self.size:
                self._items.popitem(last=False)


SERVED = _ServedPlans()


def warm_up() -> None:
    """Load what plan work needs (the plan models, the mask builders, matplotlib) in the
    plan worker, by previewing a 4-point plan: the first request then waits for none of it."""
    plan_work(b'{"lattice": {"n_x": 2, "n_y": 2, "pitch": 1e-4}, "points": [[0, 0], [1, 1]]}', None, True)


def preview_png_of_text(text: str) -> bytes:
    """:func:`preview_png` of a stored plan's JSON text (run in the plan worker process).

    Parameters
    ----------
    text : str
        The plan's JSON text.

    Returns
    -------
    bytes
        The PNG file's bytes.
    """
    return preview_png(json.loads(text))


_EXECUTOR_LOCK = threading.Lock()


#: CPU priority (``nice`` increment) of the plan worker: below the server's threads, beside
#: the live-preview worker (``fpscan.service.jobs.preview.PREVIEW_WORKER_NICE``, +5); the reconstruction
#: workers run at ``Settings.worker_nice`` (default 0, the server's own priority).
PLAN_WORKER_NICE = 8


def plan_executor(context: Context) -> LocalExecutor:
    """The service's plan worker: one spawned process at a lower CPU priority.

    Made on first use and kept in ``context.extras["plan_executor"]``; closed with the app. With
    ``Settings.warm_up`` the app makes it at start-up and warms it up in the background
    (:func:`warm_up`); without, its process starts at the first plan request.

    Parameters
    ----------
    context : Context
        The app's context.

    Returns
    -------
    LocalExecutor
        A one-worker ``fpscan.service.jobs.executors.LocalExecutor`` at priority increment
        :data:`PLAN_WORKER_NICE`, which replaces a worker that died.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    from fpscan.service.jobs.executors import LocalExecutor, lower_priority

    class PlanWorker(LocalExecutor):
        def _new_pool(self) -> ProcessPoolExecutor:
            return ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=lower_priority,
                                       initargs=(PLAN_WORKER_NICE, os.getpid()))

    with _EXECUTOR_LOCK:
        ex = context.extras.get("plan_executor")
        if ex is None:
            ex = context.extras["plan_executor"] = PlanWorker(1)
        return ex


def _in_plan_worker(context: Context, fn: Callable[..., _T], *args: Any, admit: bool = False) -> _T:
    """``fn(*args)`` in the plan worker (blocking: call it from a worker thread), within a
    turn of ``context.slots["plans"]``. ``admit``: count the request in first, 429 when the plan
    slots are full (reads such as ``preview.png``, which ``UploadLimit`` does not count: a
    burst of them must not queue without bound, each holding a server thread). A worker that
    died is answered 503."""
    slots = context.slots["plans"]
    if admit:
        if not slots.enter():
            raise HTTPException(429, slots.busy_reason(), headers={"Retry-After": str(slots.retry_after_s)})
        try:
            return _in_plan_worker(context, fn, *args)
        finally:
            slots.leave()
    from fpscan.service.jobs.executors import WorkerDied

    with _plan_turn(context):
        try:
            return plan_executor(context).run(fn, *args)
        except WorkerDied:
            raise HTTPException(503, "the plan worker process died (out of memory?); retry",
                                headers={"Retry-After": "5"}) from None


@contextlib.contextmanager
def _plan_turn(context: Context) -> Iterator[None]:
    """Plan work within the service's bounds: a turn of ``context.slots["plans"]`` (the request
    was counted in, or refused with 429, before its body was read: ``UploadLimit``)."""
    with context.slots["plans"].turn():
        yield


async def _plan_request(request: Request, context: Context, preview: bool) -> dict:
    raw = await request.body()  # I/O only: parsing and checking happen in the plan worker
    out = await anyio.to_thread.run_sync(_in_plan_worker, context, plan_work, raw, request.headers.get("content-type"),
                                         preview)
    if out["status"] >= 400:
        raise HTTPException(out["status"], out["detail"])
    return out


# The plan-request routes read their body raw and leave parsing and checking (a point list
# or a plan JSON of 262 144 points: megabytes of JSON) to the plan worker, so no request
# holds the event loop. Starlette dispatches to the first route that matches, so these two
# (left out of the schema) answer; the typed routes after them document the body
# (PlanCreate) in the OpenAPI schema and, if ever reached, answer the same way.
@router.post("", status_code=201, include_in_schema=False, dependencies=[Depends(require_token)])
async def create_plan_raw(request: Request, context: Context = Depends(ctx)) -> Response:
    """``POST /api/plans`` (documented by :func:`create_plan`): build in the plan worker, store, 201."""
    out = await _plan_request(request, context, preview=False)
    s = out["summary"]
    await anyio.to_thread.run_sync(context.store.put_plan_text, s["id"], out["text"], s)
    SERVED.put(s["id"], out["gzip"])
    # pydantic's JSON: a non-finite number (an unbounded scan time) is null, as in every answer
    return Response(Plan(**s).model_dump_json(), 201, media_type="application/json",
                    headers={"Location": f"/api/plans/{s['id']}"})


@router.post("/preview", include_in_schema=False, dependencies=[Depends(require_token)])
async def preview_plan_raw(request: Request, context: Context = Depends(ctx)) -> Response:
    """``POST /api/plans/preview`` (documented by :func:`preview_plan`): build and draw in the plan worker."""
    out = await _plan_request(request, context, preview=True)
    s = out["summary"]
    return Response(PlanPreview(points=s["n_points"], weight_ratio=s["weight_ratio"],
                                expected_scan_time_s=s["expected_scan_time_s"],
                                preview_png_base64=base64.b64encode(out["png"]).decode()).model_dump_json(),
                    media_type="application/json")


@router.post("", status_code=201, response_model=Plan, dependencies=[Depends(require_token)])
async def create_plan(
    request: Request,
    body: PlanCreate,  # a union built from fpscan.service.plans.kinds.KINDS
    context: Context = Depends(ctx),
) -> Response:
    """Create (or find, same content → same id) a plan from a mask kind and its params, a
    point list, or a plan JSON made by ``fpscan plan`` (kept with its id); ``Location``
    names it. The work runs in the plan worker process."""
    return await create_plan_raw(request, context)


@router.post("/preview", response_model=PlanPreview, dependencies=[Depends(require_token)])
async def preview_plan(
    request: Request,
    body: PlanCreate,  # a union built from fpscan.service.plans.kinds.KINDS
    context: Context = Depends(ctx),
) -> Response:
    """The plan a request would give, without saving it. Does the work of a plan, so it
    needs the token like the mutating routes (and, like them, 429 when too many plan
    requests are in progress)."""
    return await preview_plan_raw(request, context)


@router.get("/kinds", response_model=list[MaskKindInfo], dependencies=[Depends(read_access)])
def list_mask_kinds() -> list[MaskKindInfo]:
    """The mask kinds and their parameters (``fpscan.service.plans.kinds``): name, label, aliases,
    one descriptor per parameter (SI unit, default, bounds) and the parameter model's JSON
    schema. The web page builds its plan form from this."""
    from fpscan.service.plans.kinds import KINDS, kind_fields

    return [MaskKindInfo(kind=k.name, label=k.label, description=k.description, aliases=list(k.aliases),
                         fields=kind_fields(k.name), params_schema=k.params.model_json_schema())
            for k in KINDS.values()]


@router.get("", response_model=list[Plan], dependencies=[Depends(read_access)])
def list_plans(context: Context = Depends(ctx)) -> list[Plan]:
    """All stored plans, as summaries."""
    return [Plan(**s) for s in context.store.list_plans()]


def plan_or_404(context: Context, plan_id: str) -> dict:
    """The stored plan dict ``plan_id``.

    Parameters
    ----------
    context : Context
        The app's context.
    plan_id : str
        The plan's id.

    Returns
    -------
    dict
        The plan JSON.

    Raises
    ------
    fastapi.HTTPException
        404 when there is no such plan.
    """
    found = context.store.get_plan(plan_id)
    if found is None:
        raise HTTPException(404, f"no plan {plan_id}")
    return found[0]


@router.get("/{plan_id}", response_model=Plan, dependencies=[Depends(read_access)])
def get_plan(plan_id: str = Path(pattern=ID_PATTERN), context: Context = Depends(ctx)) -> Plan:
    """One plan's summary (stored with the plan: its points are not read)."""
    found = context.store.get_plan_summary(plan_id)
    if found is None:
        raise HTTPException(404, f"no plan {plan_id}")
    return Plan(**found)


@router.delete("/{plan_id}", response_model=Deleted, dependencies=[Depends(require_token)],
               responses={409: {"description": "an active scan job uses the plan"}})
def delete_plan(plan_id: str = Path(pattern=ID_PATTERN), context: Context = Depends(ctx)) -> Deleted:
    """Delete a stored plan; 409 while a queued, running or paused scan uses it."""
    try:
        return Deleted(kind="plan", **lifecycle.delete_plan(context.store, plan_id))
    except lifecycle.NotFound as exc:
        raise HTTPException(404, str(exc)) from None
    except lifecycle.InUse as exc:
        raise HTTPException(409, str(exc)) from None


def accepts_encoding(header: str, coding: str) -> bool:
    """Whether an ``Accept-Encoding`` header accepts ``coding``.

    RFC 9110 §12.5.3: a listed coding, or ``*``, with a quality above 0; ``gzip;q=0``
    refuses it.

    Parameters
    ----------
    header : str
        The ``Accept-Encoding`` header's value.
    coding : str
        A content coding in lower case (``"gzip"``).

    Returns
    -------
    bool
        True when accepted.
    """
    quality: dict[str, float] = {}
    for item in header.lower().split(","):
        name, _, params = item.strip().partition(";")
        q = 1.0
        for p in params.split(";"):
            key, _, value = p.strip().partition("=")
            if key == "q":
                try:
                    q = float(value)
                except ValueError:
                    q = 0.0
        if name:
            quality[name.strip()] = q
    return quality.get(coding, quality.get("*", 0.0)) > 0


@router.get("/{plan_id}/plan.json", dependencies=[Depends(read_access)],
            responses={200: {"content": {"application/json": {}}, "description": "the full plan JSON"}})
def get_plan_json(request: Request, plan_id: str = Path(pattern=ID_PATTERN),
                  context: Context = Depends(ctx)) -> Response:
    """The full plan (docs/architecture.md, ``fpscan-plan/1``), served as stored at its
    creation (never parsed or serialized again): gzip-compressed (``Content-Encoding:
    gzip``) to clients that accept it, as plain JSON to others."""
    accepts_gzip = accepts_encoding(request.headers.get("accept-encoding", ""), "gzip")
    packed = SERVED.get(plan_id) if accepts_gzip else None
    if packed is not None and context.store.get_plan_summary(plan_id) is not None:
        return Response(packed, media_type="application/json",
                        headers={"Content-Encoding": "gzip", "Vary": "Accept-Encoding"})
    text = context.store.get_plan_text(plan_id)
    if text is None:
        raise HTTPException(404, f"no plan {plan_id}")
    if accepts_gzip:  # compressed once, in the plan worker, then kept
        packed = _in_plan_worker(context, gzip_text, text, admit=True)
        SERVED.put(plan_id, packed)
        return Response(packed, media_type="application/json",
                        headers={"Content-Encoding": "gzip", "Vary": "Accept-Encoding"})
    return Response(text.encode(), media_type="application/json", headers={"Vary": "Accept-Encoding"})


@router.get("/{plan_id}/preview.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "mask preview"}})
async def plan_preview_png(plan_id: str = Path(pattern=ID_PATTERN), context: Context = Depends(ctx)) -> Response:
    """The plan's sensor-mask preview (PNG), drawn in the plan worker process."""
    text = await anyio.to_thread.run_sync(context.store.get_plan_text, plan_id)
    if text is None:
        raise HTTPException(404, f"no plan {plan_id}")
    png = await anyio.to_thread.run_sync(functools.partial(_in_plan_worker, context, preview_png_of_text, text,
                                                           admit=True))
    return Response(png, media_type="image/png")
