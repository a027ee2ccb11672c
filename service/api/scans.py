"""Scanner and scan routes: list scanners, start a scan (202 + ``Location``), pause,
resume, abort, download the scan file (HTTP Range) and its IPASC export, live preview."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, Depends, Header, HTTPException, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse

from fpscan.service.api.context import Context, ctx, read_access, require_token
from fpscan.service.api.files import HeldFileResponse
from fpscan.service.api.jobs import get_job_or_404, job_view
from fpscan.service.api.models import ID_PATTERN, Job, Plane, PreviewInfo, Scanner, ScanRequest
from fpscan.service.jobs import lifecycle
from fpscan.service.jobs.store import TERMINAL, IdempotencyConflict

if TYPE_CHECKING:
    from fpscan.service.jobs.scan_manager import ScanManager

__all__ = [
    "router", "JobId", "list_scanners", "start_scan", "pause_scan", "resume_scan", "abort_scan", "scan_file_path",
    "scan_file",
    "scan_preview", "scan_preview_png",
]

router = APIRouter(tags=["scans"])

JobId = PathParam(pattern=ID_PATTERN, description="scan job id")


def _scans(context: Context) -> ScanManager:
    if context.scans is None:
        raise HTTPException(409, "scanning is not available on this server (no driver)")
    return context.scans


@router.get("/api/scanners", response_model=list[Scanner], dependencies=[Depends(read_access)], tags=["scanners"])
def list_scanners(context: Context = Depends(ctx)) -> list[Scanner]:
    """The configured serial devices and their status (idle, busy with a job)."""
    if context.scans is None:
        return [Scanner(id=k, port=v, status="unknown") for k, v in context.settings.devices.items()]
    return [Scanner(**s) for s in context.scans.scanners()]


@router.post("/api/scans", status_code=202, response_model=Job, dependencies=[Depends(require_token)],
             responses={404: {"description": "unknown plan or scanner"},
                        409: {"description": "Idempotency-Key reused with other parameters"}})
def start_scan(body: ScanRequest, response: Response, context: Context = Depends(ctx),
               idempotency_key: str | None = Header(None, alias="Idempotency-Key", min_length=1,
                                                    max_length=200)) -> Job:
    """Queue a scan of a plan on a scanner → 202, ``Location: /api/jobs/{id}``. The scan
    starts when the scanner is free; it owns the serial port while it runs. A repeat of a
    request already answered (its ``Idempotency-Key``, the same plan, scanner and preview
    wavelength) is answered with its job, even where the plan has been deleted since."""
    mgr = _scans(context)
    params: dict[str, Any] = {"plan_id": body.plan_id, "scanner_id": body.scanner_id}
    if body.preview_wavelength:
        params["preview_wavelength"] = body.preview_wavelength
    if idempotency_key is not None:  # (a job's params hold no preview_wavelength 0: None is its absence)
        earlier = context.store.find_repeat(idempotency_key, "scan",
                                            {**params, "preview_wavelength": body.preview_wavelength or None})
        if earlier is not None:
            response.headers["Location"] = f"/api/jobs/{earlier['id']}"
            return job_view(earlier)
    found = context.store.get_plan(body.plan_id)
    if found is None:
        raise HTTPException(404, f"no plan {body.plan_id}")
    if body.scanner_id not in context.settings.devices:
        raise HTTPException(404, f"no scanner {body.scanner_id}")
    n_w = len(found[0]["acquisition"]["wavelengths"])
    if body.preview_wavelength >= n_w:
        raise HTTPException(422, f"preview_wavelength {body.preview_wavelength} is not one of the plan's "
                                 f"{n_w} wavelengths (0..{n_w - 1})")
    try:  # the plan looked up again with the job's creation, no deletion between (lifecycle.guard)
        job, created = lifecycle.create_job(context.store, "scan", params, idempotency_key=idempotency_key)
    except IdempotencyConflict as exc:
        raise HTTPException(409, str(exc)) from None
    except lifecycle.NotFound as exc:
        raise HTTPException(404, f"{exc} (deleted meanwhile)") from None
    if created:
        scan_path = Path(context.settings.data_dir) / "scans" / f"{job['id']}.h5"
        context.store.update_params(job["id"], {"scan_path": str(scan_path)})
        mgr.wake()
    response.headers["Location"] = f"/api/jobs/{job['id']}"
    return job_view(get_job_or_404(context, job["id"]))


def _control(context: Context, job_id: str, action: str) -> Job:
    mgr = _scans(context)
    job = get_job_or_404(context, job_id, "scan")
    if job["state"] in TERMINAL:
        raise HTTPException(409, f"scan {job_id} already {job['state']}")
    try:
        getattr(mgr, action)(job_id)
    except ValueError as exc:
        raise HTTPException(409, str(exc)) from None
    return job_view(get_job_or_404(context, job_id))


@router.post("/api/scans/{job_id}/pause", response_model=Job, dependencies=[Depends(require_token)])
def pause_scan(job_id: str = JobId, context: Context = Depends(ctx)) -> Job:
    """Pause a running scan after the current A-line (state ``paused``)."""
    return _control(context, job_id, "pause")


@router.post("/api/scans/{job_id}/resume", response_model=Job, dependencies=[Depends(require_token)])
def resume_scan(job_id: str = JobId, context: Context = Depends(ctx)) -> Job:
    """Resume a paused scan, also one interrupted by a server restart: it continues from
    its scan file's record of completed points."""
    return _control(context, job_id, "resume")


@router.post("/api/scans/{job_id}/abort", response_model=Job, dependencies=[Depends(require_token)])
def abort_scan(job_id: str = JobId, context: Context = Depends(ctx)) -> Job:
    """Abort a scan (state ``cancelled``); the scan file keeps the points acquired."""
    return _control(context, job_id, "abort")


def scan_file_path(context: Context, job_id: str) -> Path:
    """The scan file of the scan job ``job_id``.

    Parameters
    ----------
    context : Context
        The app's context.
    job_id : str
        The scan job.

    Returns
    -------
    pathlib.Path
        The scan file.

    Raises
    ------
    fastapi.HTTPException
        404 for no such scan job, 409 while it has no scan file.
    """
    job = get_job_or_404(context, job_id, "scan")
    path = job["params"].get("scan_path")
    if not path or not Path(path).exists():
        raise HTTPException(409, f"scan {job_id} has no scan file yet")
    return Path(path)


@router.head("/api/scans/{job_id}/file", dependencies=[Depends(read_access)], include_in_schema=False)  # its headers alone
@router.get("/api/scans/{job_id}/file", dependencies=[Depends(read_access)], response_class=FileResponse,
            responses={200: {"content": {"application/x-hdf5": {}}, "description": "the scan file (HDF5)"},
                       206: {"description": "partial content (HTTP Range)"}})
def scan_file(job_id: str = JobId, context: Context = Depends(ctx)) -> HeldFileResponse:
    """The scan file (HDF5, ``fpscan.driver.scanfile`` layout); supports ``Range``."""
    # the file as it is now (a running scan's grows): its size when opened, those bytes
    return HeldFileResponse(scan_file_path(context, job_id), gone=f"scan {job_id} was deleted meanwhile",
                            root=context.settings.data_dir, media_type="application/x-hdf5", filename=f"{job_id}.h5")


@router.get("/api/scans/{job_id}/preview", response_model=PreviewInfo, dependencies=[Depends(read_access)])
def scan_preview(job_id: str = JobId, context: Context = Depends(ctx)) -> PreviewInfo:
    """The live preview's state: ``version`` grows with every refresh (0 = none yet)."""
    get_job_or_404(context, job_id, "scan")
    state = _scans(context).preview(job_id)
    if state is None:
        return PreviewInfo(version=0, points_used=0, updated=None)
    return PreviewInfo(version=state.version, points_used=state.points_used, updated=state.updated,
                       refresh_s=state.refresh_s, wavelength_index=state.wavelength_index)


@router.get("/api/scans/{job_id}/preview/{plane}.png", dependencies=[Depends(read_access)], response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "live preview MIP"}})
def scan_preview_png(plane: Plane, job_id: str = JobId, context: Context = Depends(ctx)) -> Response:
    """The live preview's MIP on ``plane`` (``X-Preview-Version`` header)."""
    get_job_or_404(context, job_id, "scan")
    state = _scans(context).preview(job_id)
    if state is None or plane not in state.planes:
        raise HTTPException(404, f"no live preview of scan {job_id} yet")
    return Response(state.png(plane), media_type="image/png", headers={"X-Preview-Version": str(state.version)})
