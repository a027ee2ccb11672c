"""Reconstruction routes: start a job from a scan or a dataset (202 + ``Location``),
download its volume (HDF5, HTTP Range), MIPs and depth slices (PNG)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from fastapi import APIRouter, Depends, Header, HTTPException, Query, Request, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse
from pydantic import ValidationError

from fpscan.service.api.context import Context, ctx, read_access, reason, require_token
from fpscan.service.api.files import HeldFileResponse, NotOwnFile, check_own, read_own
from fpscan.service.api.jobs import get_job_or_404, job_view
from fpscan.service.api.models import (
    ID_PATTERN,
    REQUEST_MODELS,
    Error,
    Job,
    MethodInfo,
    MethodOption,
    Plane,
    ReconRequest,
    ReconRequestBase,
)
from fpscan.service.formats.result import VOLUME_FILE, mip_file
from fpscan.service.jobs import lifecycle
from fpscan.service.jobs.admission import (
    admit,
    admit_device,
    admit_work,
    estimate_memory,
    estimate_result_bytes,
    estimate_work,
    input_shape,
)
from fpscan.service.jobs.store import IdempotencyConflict, QueueFull
from fpscan.service.pipeline import METHODS, default_method
from fpscan.service.recon.methods import get as method_named

__all__ = [
    "router", "JobId", "IdemKey", "mask_facts", "list_methods", "start_reconstruction", "queue_wait", "WavelengthQuery", "result_dir",
    "volume_dir", "volume", "unmix_h5", "so2_png", "mip_png", "slice_png",
]

router = APIRouter(prefix="/api/reconstructions", tags=["reconstructions"])

JobId = PathParam(pattern=ID_PATTERN, description="reconstruction job id")
IdemKey = Header(None, alias="Idempotency-Key", min_length=1, max_length=200,
                 description="same key → same job (1-200 characters; an empty key is refused)")


#: the keys of a reconstruction job's params that the client's request decides, which an
#: Idempotency-Key's repeat must match: not the paths, estimates and shapes the server works out
#: (a restart with its data folder spelled otherwise, or another time limit, changes those)
REQUEST_KEYS = ("method", "params", "input_id", "scan_job_id", "dataset_id", "wavelength", "unmix")


def _full_scan_job_id(context: Context, body: ReconRequestBase) -> ReconRequestBase:
    """``body`` with a short ``scan_job_id`` (a unique prefix) replaced by the full id;
    409 when the prefix is ambiguous."""
    sid = body.scan_job_id
    if sid is None or len(sid) >= 32:
        return body
    found = context.store.resolve(sid)
    if len(found) > 1:
        raise HTTPException(409, f"scan_job_id {sid!r} matches several jobs: give more characters")
    return body.model_copy(update={"scan_job_id": found[0]}) if found else body


def _with_method(context: Context, body: ReconRequestBase) -> ReconRequestBase:
    """``body`` as its method's variant (``fpscan.service.api.models.REQUEST_MODELS``): as given, or,
    for a request that names no method, the default for the input
    (``fpscan.service.pipeline.default_method`` of a stored dataset's layout; a scan file loads as
    sensor points), whose model then validates ``params`` (422 naming the refusal). An unknown
    dataset is left to the input checks (404)."""
    if body.method is not None and type(body) is REQUEST_MODELS.get(body.method):
        return body
    kind = "points"
    ds_id = body.dataset_id if body.dataset_id is not None else next(iter(body.dataset_ids or ()), None)
    if body.plan_id is None and ds_id is not None:  # a plan's sensor mask: points
        meta = context.store.get_dataset(ds_id)
        kind = meta["layout"] if meta is not None else "points"
    method = body.method or default_method(kind)
    fields = {name: getattr(body, name) for name in ReconRequestBase.model_fields if name not in ("method", "params")}
    try:
        return REQUEST_MODELS[method].model_validate({**fields, "method": method, "params": body.params or {}})
    except ValidationError as exc:
        raise HTTPException(422, reason(exc)) from None


def _check_unmix_wavelengths(wavelengths: list) -> None:
    """422 unless HbO2 and Hb can be unmixed at ``wavelengths`` (m): at least two,
    distinct, excitation wavelengths (400-2000 nm) within the extinction table
    (:func:`fpscan.service.recon.unmix.endmember_matrix`)."""
    from fpscan.service.recon.unmix import endmember_matrix

    try:
        endmember_matrix(wavelengths)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None


def _unmix_inputs(context: Context, body: ReconRequestBase) -> tuple[dict, dict, str]:
    """Job parameters (``inputs``/``wavelengths``), memory-estimate shape and input id of
    an unmixing request; raises HTTPException."""
    if body.dataset_ids is not None:
        if body.scan_job_id is not None or body.dataset_id is not None:
            raise HTTPException(422, "give either scan_job_id or dataset_ids, not both")
        if body.wavelengths is None or len(body.wavelengths) != len(body.dataset_ids):
            raise HTTPException(422, f"{len(body.dataset_ids)} datasets need as many wavelengths (m), got "
                                     f"{0 if body.wavelengths is None else len(body.wavelengths)}")
        _check_unmix_wavelengths(body.wavelengths)
        inputs: list[dict] = []
        shape: dict = {}
        for ds_id in body.dataset_ids:
            one = body.model_copy(update={"dataset_id": ds_id, "dataset_ids": None, "unmix": None})
            spec, shape, _ = _input_for(context, one)
            inputs.append(spec)
        return {"inputs": inputs, "wavelengths": list(body.wavelengths)}, shape, \
            "datasets:" + ",".join(body.dataset_ids)
    if body.scan_job_id is None:
        raise HTTPException(422, "unmixing needs scan_job_id (a multi-wavelength scan) or dataset_ids")
    spec, shape, input_id = _input_for(context, body.model_copy(update={"unmix": None}))
    job = context.store.get(body.scan_job_id)
    found = context.store.get_plan(job["params"]["plan_id"]) if job is not None else None
    if found is None:  # _input_for has checked both; the store may have changed since
        raise HTTPException(404, f"the plan of scan job {body.scan_job_id} is gone")
    plan = found[0]
    _check_unmix_wavelengths(list(plan["acquisition"].get("wavelengths") or []))
    return {"input": spec, "wavelengths": None}, shape, input_id  # shape: input_shape of the plan, its wavelengths


def _input_for(context: Context, body: ReconRequestBase) -> tuple[dict, dict, str]:
    """``(input spec, shape for the memory estimate, input id)``; raises HTTPException."""
    if body.dataset_ids is not None and body.unmix is None:
        raise HTTPException(422, "dataset_ids (one dataset per wavelength) need unmix")
    if (body.scan_job_id is None) == (body.dataset_id is None):
        raise HTTPException(422, "give exactly one of scan_job_id or dataset_id")
    method = body.method
    assert method is not None  # resolved by _with_method, its options validated by its model
    if getattr(body.params, "device", None) == "cuda":  # refused at the door where no GPU is visible
        from fpscan.service.recon.device import choose

        try:
            choose("cuda", 0)
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from None
    needs_grid = METHODS[method].needs_grid
    if body.scan_job_id is not None:
        job = context.store.get(body.scan_job_id)
        if job is None or job["kind"] != "scan":
            raise HTTPException(404, f"no scan job {body.scan_job_id}")
        scan_path = job["params"].get("scan_path")
        if not scan_path or not Path(scan_path).exists():
            raise HTTPException(409, f"scan job {body.scan_job_id} has no scan file yet")
        found = context.store.get_plan(job["params"]["plan_id"])
        if found is None:
            raise HTTPException(404, f"the plan of scan job {body.scan_job_id} is gone")
        plan = found[0]
        lat, acq = plan["lattice"], plan["acquisition"]
        shape = input_shape(plan)
        if needs_grid and len(plan["points"]["indices"]) != lat["n_x"] * lat.get("n_y", 1):
            raise HTTPException(422, f"method {body.method!r} needs every lattice point; this scan's plan "
                                     f"is a sensor mask: use {default_method('points')!r}")
        wavelengths = list(acq.get("wavelengths") or [])
        spec = _with_wavelength({"kind": "scan", "path": scan_path}, body.wavelength, wavelengths,
                                f"scan job {body.scan_job_id}")
        return spec, shape, f"scan:{body.scan_job_id}"
    dataset_id = body.dataset_id
    assert dataset_id is not None  # exactly one of the two, checked above
    meta = context.store.get_dataset(dataset_id)
    if meta is None:
        raise HTTPException(404, f"no dataset {dataset_id}")
    path = str(Path(context.settings.data_dir) / "datasets" / dataset_id / meta["path"])
    # a stored dataset holds one wavelength's data (of a multi-wavelength file: the one chosen at upload)
    ds_spec = _with_wavelength({"kind": "dataset", "path": path}, body.wavelength, [None], f"dataset {dataset_id}")
    if body.plan_id is not None:
        return _sampled(context, body, meta, ds_spec, needs_grid)
    if meta["layout"] != "grid" and needs_grid and not meta.get("full_lattice"):
        raise HTTPException(422, f"method {body.method!r} needs a full regular grid; this dataset needs "
                                 f"{default_method('points')!r}")
    return ds_spec, input_shape(meta), f"dataset:{body.dataset_id}"


def _sampled(context: Context, body: ReconRequestBase, meta: dict, spec: dict,
             needs_grid: bool) -> tuple[dict, dict, str]:
    """The input of a dataset sampled by a stored plan (``fpscan.service.subsample``): 404 for an
    unknown plan, 422 where the plan cannot sample the dataset (its record: dense, the pitch,
    dt and lattice that fit) or the method needs a full grid the mask does not give."""
    from pydantic import ValidationError

    from fpscan.service.plans import Plan
    from fpscan.service.subsample import check_fit

    found = context.store.get_plan(str(body.plan_id))
    if found is None:
        raise HTTPException(404, f"no plan {body.plan_id}")
    doc = found[0]
    lat = doc["lattice"]
    if needs_grid and len(doc["points"]["indices"]) != lat["n_x"] * lat.get("n_y", 1):
        raise HTTPException(422, f"method {body.method!r} needs every lattice point; plan {body.plan_id} is a sensor "
                                 f"mask: use {default_method('points')!r}")
    shape = list(meta["shape"])
    if meta["layout"] != "grid":
        if not meta.get("full_lattice"):
            raise HTTPException(422, f"plan_id samples dense data (every point of a grid); dataset "
                                     f"{body.dataset_id} is a sensor mask's points")
        n_y, n_x = int(meta.get("n_y") or 1), int(meta["n_x"])
        shape = [shape[1], n_x] if n_y == 1 else [shape[1], n_y, n_x]
    try:
        check_fit(shape, (meta.get("dx"),), float(meta["dt"]), Plan.from_dict(doc))
    except (ValueError, ValidationError) as exc:
        raise HTTPException(422, f"plan {body.plan_id} cannot sample dataset {body.dataset_id}: {reason(exc)}") \
            from None
    return {**spec, "plan_id": str(body.plan_id)}, input_shape(doc), f"dataset:{body.dataset_id}+plan:{body.plan_id}"


def _with_wavelength(spec: dict, wavelength: int | str | None, wavelengths: list, what: str) -> dict:
    """The job input ``spec`` with the request's ``wavelength`` (``fpscan.service.jobs.work``:
    an index, or ``"all"``); 422 for an index outside the input's ``wavelengths`` (m;
    ``[None]``: one wavelength, unknown), naming them."""
    if wavelength is None:
        return spec
    n = max(len(wavelengths), 1)
    if wavelength != "all" and not 0 <= int(wavelength) < n:
        known = [w for w in wavelengths if w is not None]
        listed = f" ({', '.join(f'{float(w) * 1e9:g} nm' for w in known)})" if known else ""
        raise HTTPException(422, f"wavelength index {wavelength} is out of range: {what} has {n} wavelength"
                                 f"{'s' if n != 1 else ''}{listed}, indices 0..{n - 1}")
    return {**spec, "wavelength": wavelength}


@router.get("/methods", response_model=list[MethodInfo], dependencies=[Depends(read_access)])
def list_methods() -> list[MethodInfo]:
    """The reconstruction methods (the registry ``fpscan.service.recon.methods``, in its order):
    name, title, whether they need a full regular grid, whether iterative, time-limited and
    cancellable, the inputs each is the default for, the options each takes (the speed
    of sound ``sound_speed`` first, then its options model's fields, each with this
    method's default and its JSON schema: type, range, unit) and the algorithm's source.
    The web page builds its method choices and option fields from this."""
    from fpscan.service.recon.methods import option_schemas
    from fpscan.service.recon.methods.options import SpeedOptions, speed_schema

    speed = MethodOption(name="sound_speed", description=SpeedOptions.model_fields["sound_speed"].description or "",
                         default=None, value_schema=speed_schema())
    return [MethodInfo(name=m.name, title=m.title, needs_grid=m.needs_grid, source=m.source, iterative=m.iterative,
                       time_limited=m.time_limited, cancellable=m.cancellable, default_for=list(m.default_for),
                       summary=[f.as_dict() for f in m.summary], options=[speed, *(MethodOption(name=o["name"], description=o["description"],
                                                      default=o["default"], value_schema=o["schema"])
                                         for o in option_schemas(m))])
            for m in METHODS.values()]


def mask_facts(source: dict, plan_id: str | None = None) -> dict:
    """What a reconstruction's input samples of its lattice, for the job's record (its label):
    ``kind`` (a plan's mask kind, ``"equisteradian"``, ...; ``"full"`` for a dataset holding every
    point of its grid; ``"points"`` for a dataset of other sensor points), ``n_points`` (A-lines),
    ``lattice`` (``[n_x, n_y]``) and, for a plan, ``plan_id``. ``source``: a plan document or a
    stored dataset's record."""
    if "lattice" in source and "acquisition" in source:  # a plan document
        lat = source["lattice"]
        return {"kind": str((source.get("mask") or {}).get("kind") or "points"),
                "n_points": len(source["points"]["indices"]), "lattice": [int(lat["n_x"]), int(lat.get("n_y", 1))],
                "plan_id": plan_id or source.get("id")}
    shape = input_shape(source)
    n_x, n_y = int(shape["n_x"]), int(shape.get("n_y") or 1)
    if source.get("layout") == "grid":
        return {"kind": "full", "n_points": n_x * n_y, "lattice": [n_x, n_y]}
    return {"kind": "full" if source.get("full_lattice") else "points", "n_points": int(shape["n_points"]),
            "lattice": [n_x, n_y]}


def _mask_of(context: Context, body: ReconRequestBase) -> dict | None:
    """:func:`mask_facts` of the request's input (its scan's plan, the sampling plan or the
    dataset: the first of ``dataset_ids``); None where the store no longer has it."""
    if body.scan_job_id is not None:
        job = context.store.get(body.scan_job_id)
        plan_id = job["params"].get("plan_id") if job is not None else None
        found = context.store.get_plan(plan_id) if plan_id else None
        return mask_facts(found[0], plan_id) if found is not None else None
    if body.plan_id is not None:
        found = context.store.get_plan(str(body.plan_id))
        return mask_facts(found[0], str(body.plan_id)) if found is not None else None
    ds_id = body.dataset_id if body.dataset_id is not None else next(iter(body.dataset_ids or ()), None)
    meta = context.store.get_dataset(ds_id) if ds_id is not None else None
    return mask_facts(meta) if meta is not None else None


@router.post("", status_code=202, response_model=Job, dependencies=[Depends(require_token)],
             responses={409: {"description": "Idempotency-Key reused with other parameters, or no scan file"},
                        404: {"description": "unknown scan job or dataset"},
                        429: {"description": "the client has queued_per_client reconstructions queued (the reason "
                                            "says the cap, the queue's length and its estimated wait)"},
                        507: {"model": Error, "description": "the result does not fit the free disk"}})
def start_reconstruction(body: ReconRequest, response: Response, request: Request, context: Context = Depends(ctx),
                         idempotency_key: str | None = IdemKey) -> Job:
    """Queue a reconstruction → 202, ``Location: /api/jobs/{id}``. Refused with 422 when
    it can never fit in the memory limit, when its work estimate is over the server's work
    limit (the reason says both), when its method refuses the input's options (tv: an
    image deeper than the record can hear), or when it asks for ``device: "cuda"`` where the
    server has no GPU or the job's GPU path needs more than the GPU's memory; 507 when its result does not fit the free disk;
    429 (``Retry-After``) while the client's address has ``queued_per_client`` reconstructions
    queued, saying the cap, the queue's length and its estimated wait. A repeat of a request
    already answered, with its ``Idempotency-Key`` and the same body, is answered with its job
    before anything else is looked up (an input deleted since, a full disk or queue)."""
    asked = _request_digest(body)
    if idempotency_key is not None:
        earlier = context.store.find_repeat(idempotency_key, "recon", {"request_digest": asked})
        if earlier is not None:
            response.headers["Location"] = f"/api/jobs/{earlier['id']}"
            return job_view(earlier)
    body = _with_method(context, _full_scan_job_id(context, body))
    extra: dict = {}
    if body.unmix is not None and body.wavelength is not None:
        raise HTTPException(422, "unmix reconstructs every wavelength: leave wavelength out")
    if body.unmix is not None:
        extra, shape, input_id = _unmix_inputs(context, body)
        spec = extra.pop("input", None) or extra["inputs"][0]
        extra["unmix"] = body.unmix.model_dump()
    else:
        spec, shape, input_id = _input_for(context, body)
    # the method's own options, as its model dumps them: what the job's record holds and its worker runs
    params = body.params.model_dump(mode="json")
    try:
        mem = estimate_memory(shape, {**params, "method": body.method})
        work = _work(context, shape, params, body, extra)
        if body.unmix is not None:  # every wavelength's volume is held for the unmixing (float32, x3 temporaries)
            n_w = len(extra.get("inputs") or []) or int(shape.get("n_wavelengths", 2))
            mem += 3 * n_w * 4 * int(shape["n_t"]) * int(shape["n_x"]) * int(shape.get("n_y", 1))
        elif body.wavelength == "all":  # every wavelength's volume is held until written (up to float64)
            mem += int(shape.get("n_wavelengths", 1)) * 8 * int(shape["n_t"]) * int(shape["n_x"]) * \
                int(shape.get("n_y", 1))
        admit(mem, context.settings.memory_limit)
        admit_work(work, context.settings.work_limit_s)
        devices = getattr(request.app.state, "devices", None)
        if devices is not None and params.get("device") == "cuda":
            devices.listed.wait(timeout=120)  # the server's first seconds: its GPUs are being listed
        admit_device(shape, {**params, "method": body.method}, devices.gpus if devices is not None else [])
    except ValueError as exc:  # AdmissionError, or the method's refusal of options the input cannot carry
        raise HTTPException(422, reason(exc)) from None
    needed = _result_bytes(shape, params, body, extra)
    free = _free_bytes(context)
    if free is not None and free < needed:
        raise HTTPException(507, f"no room for the result on the data folder's disk: {free} bytes free (beyond "
                                 f"the reserve), {needed} needed; free space, then retry")
    job_params = {"method": body.method, "params": params, "input": spec, "input_id": input_id, "shape": shape,
                  "scan_job_id": body.scan_job_id, "dataset_id": body.dataset_id, "memory_estimate": mem,
                  "work_estimate_s": float(f"{work:.4g}"), "result_bytes": needed,
                  "wavelength": body.wavelength, "mask": _mask_of(context, body), **extra, "request_digest": asked,
                  "client": (request.scope.get("client") or ("?", 0))[0]}  # whose queue it counts in
    try:  # its inputs looked up again with the job's creation, no deletion between (lifecycle.guard)
        job, _created = lifecycle.create_job(context.store, "recon", job_params, idempotency_key=idempotency_key,
                                             memory_bytes=mem, max_queued=context.settings.queued_per_client,
                                             request_keys=REQUEST_KEYS)
    except QueueFull as exc:
        wait, first = queue_wait(context, exc.client)
        raise HTTPException(
            429, f"this client has {exc.queued} reconstructions queued, the most one client may have (queued_per_client "
                 f"= {exc.limit}); the queue holds {wait['queued']} queued and {wait['running']} running, an estimated "
                 f"{wait['wait_s']:.0f} s of work before a new one would start; retry when one of yours has started "
                 f"(in about {first:.0f} s)",
            headers={"Retry-After": str(max(1, min(int(first + 0.999), 86400)))}) from None
    except IdempotencyConflict as exc:
        raise HTTPException(409, str(exc)) from None
    except lifecycle.NotFound as exc:
        raise HTTPException(404, f"{exc} (deleted meanwhile)") from None
    if context.queue is not None:
        context.queue.wake()
    response.headers["Location"] = f"/api/jobs/{job['id']}"
    return job_view(job)


def _request_digest(body: ReconRequestBase) -> str:
    """The SHA-256 (hex) of the request body as parsed (canonical JSON of its model, keys
    sorted): two sends of one request give the same digest, however the JSON was spaced."""
    return hashlib.sha256(json.dumps(body.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


def queue_wait(context: Context, client: str | None = None) -> tuple[dict, float]:
    """The reconstruction queue's length and estimated wait, from the jobs' work estimates
    (``params["work_estimate_s"]``, s on 2 cores: ``fpscan.service.jobs.admission.estimate_work``).

    The work ahead of a new job is the queued jobs' estimates plus what is left of the
    running ones' (estimate less time run, at least 0), shared by the local workers
    (``workers``; the estimate assumes one job per worker at a time).

    Parameters
    ----------
    context : Context
        The app's context.
    client : str or None, optional
        A client's address: also say when its oldest queued job is estimated to start.

    Returns
    -------
    tuple of (dict, float)
        ``{"queued", "running", "wait_s"}`` (counts; s until a job queued now would start)
        and the s until ``client``'s oldest queued job starts (``wait_s`` when it has none).
    """
    now = context.store.monotonic()  # the running jobs' started_mono are on the store's time
    queued = context.store.queued("recon")
    running = context.store.list(state="running", kind="recon", limit=1_000_000)
    workers = max(1, int(context.settings.workers))

    def work(job: dict) -> float:
        return max(0.0, float(job["params"].get("work_estimate_s") or 0.0))

    ahead = sum(max(0.0, work(j) - (now - float(j["started_mono"] or now))) for j in running)
    first = None
    for job in queued:  # oldest first
        if first is None and client is not None and job["params"].get("client") == client:
            first = ahead / workers
        ahead += work(job)
    wait = ahead / workers
    return {"queued": len(queued), "running": len(running), "wait_s": wait}, (wait if first is None else first)


def _work(context: Context, shape: dict, params: dict, body: ReconRequestBase, extra: dict) -> float:
    """The job's work in seconds on 2 cores (``fpscan.service.jobs.admission.estimate_work``) with
    a time-limited method's time limit as the worker will cap it (the server's ``time_limit_s``), times the
    wavelengths it reconstructs (``wavelength: "all"``, unmixing)."""
    asked = {**params, "method": body.method}
    if body.method is not None and method_named(body.method).time_limited:
        cap = float(context.settings.time_limit_s)
        asked["time_limit"] = min(float(params.get("time_limit") or cap), cap)
    seconds = estimate_work(shape, asked)
    if body.unmix is not None:
        seconds *= len(extra.get("inputs") or []) or int(shape.get("n_wavelengths", 2))
    elif body.wavelength == "all":
        seconds *= int(shape.get("n_wavelengths", 1))
    return seconds


def _free_bytes(context: Context) -> int | None:
    """Free bytes of the data folder's disk for a result (None when unknown): less the
    reserve an upload must leave (``disk_reserve_bytes``) and the job database's reserve
    while it is spent."""
    from fpscan.service.disk import free_bytes

    free = free_bytes(context.settings.data_dir)
    if free is None:
        return None
    spent = context.store.reserve_bytes if context.store.reserve_spent is not None else 0
    return max(0, free - int(context.settings.disk_reserve_bytes) - spent)


def _result_bytes(shape: dict, params: dict, body: ReconRequestBase, extra: dict) -> int:
    """Bytes the job's result needs on disk (``fpscan.service.jobs.admission.estimate_result_bytes``):
    a volume per wavelength it reconstructs, and the unmixing's maps."""
    volumes = 1
    if body.unmix is not None:
        volumes = (len(extra.get("inputs") or []) or int(shape.get("n_wavelengths", 2))) + 5
    elif body.wavelength == "all":
        volumes = int(shape.get("n_wavelengths", 1))
    return estimate_result_bytes(shape, {**params, "method": body.method}, volumes)


def result_dir(context: Context, job_id: str) -> Path:
    """The result folder of the succeeded reconstruction ``job_id``.

    Parameters
    ----------
    context : Context
        The app's context.
    job_id : str
        The reconstruction job.

    Returns
    -------
    pathlib.Path
        The job's result folder (its ``result_path``).

    Raises
    ------
    fastapi.HTTPException
        404 for no such reconstruction job; 409 while it has no result (not ``succeeded``).
    """
    job = get_job_or_404(context, job_id, "recon")
    if job["state"] != "succeeded" or not job["result_path"]:
        raise HTTPException(409, f"reconstruction {job_id} is {job['state']}, no result yet")
    return Path(job["result_path"])


WavelengthQuery = Query(None, ge=0, le=15, description="the volume of wavelength k of a job with wavelength "
                                                       "'all' or unmix (default: the first)")


def volume_dir(context: Context, job_id: str, wavelength: int | None) -> Path:
    """The folder of the job's volume at ``wavelength``.

    Parameters
    ----------
    context : Context
        The app's context.
    job_id : str
        The reconstruction job.
    wavelength : int or None
        The wavelength index k; None: the job's own folder.

    Returns
    -------
    pathlib.Path
        ``wavelength_<k>/`` of a job over every wavelength; the job's own folder when
        ``wavelength`` is None, or when it is the one wavelength the job reconstructed.

    Raises
    ------
    fastapi.HTTPException
        404 naming the wavelengths the job has when it has no volume at ``wavelength``;
        404 / 409 from :func:`result_dir`.
    """
    folder = result_dir(context, job_id)
    if wavelength is None:
        return folder
    if (folder / f"wavelength_{wavelength}").is_dir():
        return folder / f"wavelength_{wavelength}"
    job = get_job_or_404(context, job_id, "recon")
    have = sorted(int(p.name.split("_", 1)[1]) for p in folder.glob("wavelength_*") if p.name[11:].isdigit())
    if not have and wavelength == int(job["params"].get("wavelength") or 0):  # a job of one wavelength
        return folder
    raise HTTPException(404, f"reconstruction {job_id} has no volume at wavelength index {wavelength} "
                             f"(it has: {', '.join(map(str, have)) if have else job['params'].get('wavelength') or 0})")


@router.head("/{job_id}/volume.h5", dependencies=[Depends(read_access)], include_in_schema=False)  # its headers alone
@router.get("/{job_id}/volume.h5", dependencies=[Depends(read_access)], response_class=FileResponse,
            responses={200: {"content": {"application/x-hdf5": {}}, "description": "p0 volume (HDF5)"},
                       206: {"description": "partial content (HTTP Range)"},
                       404: {"description": "no volume at that wavelength"}})
def volume(job_id: str = JobId, wavelength: int | None = WavelengthQuery,
           context: Context = Depends(ctx)) -> HeldFileResponse:
    """The result volume: ``/p0`` ``(n_z, n_y, n_x)``, ``/z``, ``/x``, ``/y`` (m), attributes
    ``method``, ``params`` (with ``wavelength_index``/``wavelength_nm`` for a
    multi-wavelength input). ``?wavelength=k``: wavelength ``k``'s volume of a job over
    every wavelength (``wavelength='all'`` or unmix). Supports ``Range``."""
    path = volume_dir(context, job_id, wavelength) / VOLUME_FILE
    return HeldFileResponse(path, gone=f"reconstruction {job_id} was deleted meanwhile", root=context.settings.data_dir,
                            media_type="application/x-hdf5",
                            filename=f"{job_id}.h5" if wavelength is None else f"{job_id}-wavelength_{wavelength}.h5")


@router.head("/{job_id}/unmix.h5", dependencies=[Depends(read_access)], include_in_schema=False)  # its headers alone
@router.get("/{job_id}/unmix.h5", dependencies=[Depends(read_access)], response_class=FileResponse,
            responses={200: {"content": {"application/x-hdf5": {}},
                             "description": "HbO2, Hb, THb, sO2 and mask volumes (HDF5, fpscan-unmix/1)"},
                       404: {"description": "the job did not unmix"}})
def unmix_h5(job_id: str = JobId, context: Context = Depends(ctx)) -> HeldFileResponse:
    """The unmixing of a multi-wavelength job: ``/hbo2``, ``/hb``, ``/thb``, ``/so2`` (NaN
    where masked), ``/mask``, ``/z``, ``/x``, ``/y`` (m), ``/wavelengths_m``
    (``fpscan.service.spectral``). Supports ``Range``."""
    path = result_dir(context, job_id) / "unmix.h5"
    if not path.exists():
        raise HTTPException(404, f"reconstruction {job_id} was not unmixed (ask with 'unmix')")
    return HeldFileResponse(path, gone=f"reconstruction {job_id} was deleted meanwhile", root=context.settings.data_dir,
                            media_type="application/x-hdf5", filename=f"{job_id}-unmix.h5")


@router.get("/{job_id}/so2.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "sO2 map (colour), THb (brightness), background black"},
                       404: {"description": "the job did not unmix"}})
def so2_png(job_id: str = JobId, context: Context = Depends(ctx)) -> Response:
    """The sO2 picture: at each (x, y) the sO2 of the voxel of largest THb along depth,
    colour bar 0..100 %, brightness from THb, background black (``fpscan.service.spectral.render_so2_png``)."""
    try:
        png = read_own(result_dir(context, job_id) / "so2.png", context.settings.data_dir)
    except NotOwnFile:
        raise HTTPException(404, "no such file") from None
    except FileNotFoundError:
        raise HTTPException(404, f"reconstruction {job_id} was not unmixed (ask with 'unmix')") from None
    return Response(png, media_type="image/png")


@router.get("/{job_id}/mip/{plane}.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "MIP"}})
def mip_png(plane: Plane, job_id: str = JobId, wavelength: int | None = WavelengthQuery,
            context: Context = Depends(ctx)) -> Response:
    """Maximum-intensity projection: ``xy`` (over z), ``xz`` (over y), ``yz`` (over x);
    ``?wavelength=k`` as for the volume."""
    try:
        png = read_own(volume_dir(context, job_id, wavelength) / mip_file(plane), context.settings.data_dir)
    except NotOwnFile:
        raise HTTPException(404, "no such file") from None
    except FileNotFoundError:
        raise HTTPException(404, f"a 2-D image has no {plane} MIP") from None
    return Response(png, media_type="image/png")


@router.get("/{job_id}/slice.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "depth slice z = index·dz"}})
def slice_png(job_id: str = JobId, index: int = Query(0, ge=0, le=1_000_000, description="depth index"),
              context: Context = Depends(ctx)) -> Response:
    """The lateral slice at depth index ``index`` of a 3-D result (2-D: the image row),
    drawn like every picture (``fpscan.service.pictures.render``): axes in mm, y down, the depth
    in mm in the title, a colour bar in p0 units."""
    from fpscan.service.pictures.render import render_result_slice

    try:
        png = render_result_slice(check_own(result_dir(context, job_id) / VOLUME_FILE, context.settings.data_dir), index)
    except NotOwnFile:
        raise HTTPException(404, "no such file") from None
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    return Response(png, media_type="image/png")
