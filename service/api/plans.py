"""Plan routes: create (mask parameters or a point list), preview, list, get, preview PNG.

A plan is the JSON of docs/architecture.md (``fpscan-plan/1``); its id is the content hash
of ``driver.plan``. Every plan, a user point list (lattice indices) included, is built by
``service.plans.make_plan``.
"""
from __future__ import annotations

import base64
import contextlib
import json
from collections.abc import Iterator

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Path, Response

from service.api.context import Context, ctx, read_access, reason, require_token
from service.api.models import ID_PATTERN, Deleted, MaskKindInfo, Plan, PlanCreate, PlanDocument, PlanPreview
from service.jobs import lifecycle

router = APIRouter(prefix="/api/plans", tags=["plans"])

#: Most points a plan made over HTTP may have: building, hashing and drawing a plan costs
#: time linear in its points; beyond this a request is refused (422) before that work.
MAX_POINTS = 1 << 18
#: Plans with more points are previewed as a plain lattice image (one pixel per point).
PREVIEW_DETAIL_POINTS = 1 << 14


def build_plan(req) -> dict:
    """The plan JSON for a request (a ``PlanCreate`` variant): a plan JSON is checked
    (``driver.plan`` via ``service.plans.Plan``) and kept as it is, so it keeps its id;
    anything else is built by ``service.plans.make_plan``, the one plan builder (a user
    point list is the mask kind ``points``). Raises ``ValueError`` with the reason."""
    from service.plans import check_plausible_request, make_mask, make_plan

    if isinstance(req, PlanDocument):
        from driver.units import check_plausible

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
    """Seconds: points × averages × wavelengths / PRF (None when the PRF is 0 =
    unthrottled: the scanner's own rate decides)."""
    acq = plan["acquisition"]
    n = len(plan["points"]["indices"])
    prf = float(acq.get("prf", 0) or 0)
    return n * int(acq.get("averages", 1)) * len(acq.get("wavelengths", [1])) / prf if prf > 0 else None


def summary(plan: dict) -> Plan:
    """The API summary of a stored plan dict."""
    mask = plan.get("mask", {})
    pid = plan["id"]
    from service.plans.mask import shortfall

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
    """The mask preview PNG, drawn by the one renderer (``service.storage.render``: x
    right, y up, axes in mm at equal aspect, colour bar, ``fpscan:axes`` chunk): points
    as coloured markers (``service.plans.preview_png``) up to ``PREVIEW_DETAIL_POINTS``
    points; beyond that (markers cost time linear in the points) and for a plan the plan
    model cannot read, the mask as an image on its lattice (``render_lattice``: one cell
    per lattice point, coloured by weight)."""
    if len(plan["points"]["indices"]) <= PREVIEW_DETAIL_POINTS:
        try:
            from service.plans import Plan as PlanModel
            from service.plans import preview_png as plans_preview

            return plans_preview(PlanModel.model_validate(plan))
        except (ImportError, ValueError):
            pass
    from service.storage.render import render_lattice

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


def _build_or_422(body) -> dict:
    try:
        return build_plan(body)
    except (ValueError, OverflowError) as exc:
        raise HTTPException(422, reason(exc)) from None


@contextlib.contextmanager
def _plan_turn(c: Context) -> Iterator[None]:
    """Plan work within the service's bounds: a turn of ``c.slots["plans"]`` (the request
    was counted in, or refused with 429, before its body was read: ``UploadLimit``)."""
    with c.slots["plans"].turn():
        yield


@router.post("", status_code=201, response_model=Plan, dependencies=[Depends(require_token)])
def create_plan(
    body: PlanCreate,  # a union built from service.plans.kinds.KINDS
    response: Response, c: Context = Depends(ctx),
) -> Plan:
    """Create (or find, same content → same id) a plan from a mask kind and its params, a
    point list, or a plan JSON made by ``fpscan plan`` (kept with its id); ``Location``
    names it."""
    with _plan_turn(c):
        plan = _build_or_422(body)
    s = summary(plan)
    c.store.put_plan(plan["id"], plan, s.model_dump())
    response.headers["Location"] = f"/api/plans/{plan['id']}"
    return s


@router.post("/preview", response_model=PlanPreview, dependencies=[Depends(require_token)])
def preview_plan(
    body: PlanCreate,  # a union built from service.plans.kinds.KINDS
    c: Context = Depends(ctx),
) -> PlanPreview:
    """The plan a request would give, without saving it. Does the work of a plan, so it
    needs the token like the mutating routes (and, like them, 429 when too many plan
    requests are in progress)."""
    with _plan_turn(c):
        plan = _build_or_422(body)
        s = summary(plan)
        png = preview_png(plan)
    return PlanPreview(points=s.n_points, weight_ratio=s.weight_ratio, expected_scan_time_s=s.expected_scan_time_s,
                       preview_png_base64=base64.b64encode(png).decode())


@router.get("/kinds", response_model=list[MaskKindInfo], dependencies=[Depends(read_access)])
def list_mask_kinds() -> list[MaskKindInfo]:
    """The mask kinds and their parameters (``service.plans.kinds``): name, label, aliases,
    one descriptor per parameter (SI unit, default, bounds) and the parameter model's JSON
    schema. The web page builds its plan form from this."""
    from service.plans.kinds import KINDS, kind_fields

    return [MaskKindInfo(kind=k.name, label=k.label, description=k.description, aliases=list(k.aliases),
                         fields=kind_fields(k.name), params_schema=k.params.model_json_schema())
            for k in KINDS.values()]


@router.get("", response_model=list[Plan], dependencies=[Depends(read_access)])
def list_plans(c: Context = Depends(ctx)) -> list[Plan]:
    """All stored plans, as summaries."""
    return [Plan(**s) for s in c.store.list_plans()]


def plan_or_404(c: Context, plan_id: str) -> dict:
    """The stored plan dict ``plan_id``; HTTP 404 when there is none."""
    found = c.store.get_plan(plan_id)
    if found is None:
        raise HTTPException(404, f"no plan {plan_id}")
    return found[0]


@router.get("/{plan_id}", response_model=Plan, dependencies=[Depends(read_access)])
def get_plan(plan_id: str = Path(pattern=ID_PATTERN), c: Context = Depends(ctx)) -> Plan:
    """One plan's summary."""
    return summary(plan_or_404(c, plan_id))


@router.delete("/{plan_id}", response_model=Deleted, dependencies=[Depends(require_token)],
               responses={409: {"description": "an active scan job uses the plan"}})
def delete_plan(plan_id: str = Path(pattern=ID_PATTERN), c: Context = Depends(ctx)) -> Deleted:
    """Delete a stored plan; 409 while a queued, running or paused scan uses it."""
    try:
        return Deleted(kind="plan", **lifecycle.delete_plan(c.store, plan_id))
    except lifecycle.NotFound as exc:
        raise HTTPException(404, str(exc)) from None
    except lifecycle.InUse as exc:
        raise HTTPException(409, str(exc)) from None


@router.get("/{plan_id}/plan.json", dependencies=[Depends(read_access)],
            responses={200: {"content": {"application/json": {}}, "description": "the full plan JSON"}})
def get_plan_json(plan_id: str = Path(pattern=ID_PATTERN), c: Context = Depends(ctx)) -> Response:
    """The full plan (docs/architecture.md, ``fpscan-plan/1``)."""
    return Response(json.dumps(plan_or_404(c, plan_id)), media_type="application/json")


@router.get("/{plan_id}/preview.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "mask preview"}})
def plan_preview_png(plan_id: str = Path(pattern=ID_PATTERN), c: Context = Depends(ctx)) -> Response:
    """The plan's sensor-mask preview (PNG)."""
    return Response(preview_png(plan_or_404(c, plan_id)), media_type="image/png")
