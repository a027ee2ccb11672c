"""Files in and out: the registry of formats (``GET /api/formats``) and a job's file exported in
any of them (``GET /api/jobs/{job_id}/export/{format}``): one route for every export format,
found in the registry (:func:`fpscan.service.formats.export_formats`), so that a format added as one
module appears here, in the job's links, the HTTP client and the web page with no other edit.

A scan job exports its scan file (format ``fpscan``), a reconstruction its result volume
(``result``; ``?wavelength=k``: wavelength k's of a job over every wavelength). The file itself
is served as it is; another format is written by its exporter (``fpscan.service.formats.export_file``)
beside the job's files once and then served from there (a result never changes; a scan's export
is written anew on every request, since the scan may have grown). A folder export (OME-Zarr) is
served zipped. Exports run in FastAPI's thread pool, off the event loop.

Admission: a request for an export not built yet is counted in first (``context.slots["exports"]``):
``export_workers`` build at once and four times as many may wait, for a turn or for another
request's build of the same file; a further request is refused at once with 429 and
``Retry-After``, so requests for exports never hold more server threads than that (40
concurrent requests of one export held all of AnyIO's 40 and stalled every other route). Only a
request that builds takes one of the ``export_workers`` turns. A result's export already built
is served without either. The exporters of a result volume read it in slabs
(``fpscan.service.formats.result.read_slabs``), so their memory is bounded by the turns, not by
the volumes' size or the requests' number; the IPASC export of a scan reads the whole scan
(``fpscan.driver.scanfile.read_scan``: every A-line as float64, four times the scan file's
int16 samples), so its memory grows with the scan (a scan is as large as its plan).

Disk: before it writes, a build reserves the most its export may take (:func:`export_bytes`)
with the disk admission of uploads and imports (``fpscan.service.api.spool.disk_admission``):
an export that would eat into ``disk_reserve_bytes`` (kept for scans and the job store) is
refused up front with 507 and the reason. A full disk met while writing anyway (another writer
filled it) is answered 507 with the free bytes (never 500), logged with the exception's name;
the writers remove their temporary files and folders, however deep
(``fpscan.service.disk``), and a crash's leftovers go at the next start-up
(``fpscan.service.jobs.queue.remove_debris``). Only the server's own files are read and
served: a source or export that is a symbolic link, or reached through one, is refused (404,
logged once: ``fpscan.service.api.files.open_own``).

Single flight: one export file is built by one request at a time
(``fpscan.service.api.single_flight.SingleFlight``, a lock per output path). Requests that
come while it is built (and are counted in) wait for that build and serve its file: 20
concurrent first requests of a volume's OME-TIFF (``export_workers`` 4: 20 counted in) build it once, and every response carries the same bytes (one OME UUID), so a download
resumed with ``Range`` never mixes two builds. A scan's export, written anew per request,
is written once for the requests that came while it was being written.

Acknowledged means stored: a build ends under ``fpscan.service.jobs.lifecycle.guard``
with a look at the job; one deleted meanwhile has what the build wrote removed (404), so an
export never leaves a file behind a deleted job.
"""
from __future__ import annotations

import logging
import os
import shutil
import uuid
from pathlib import Path

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi import Path as PathParam
from fastapi.responses import FileResponse

from fpscan.service.api.context import Context, ctx, read_access
from fpscan.service.api.files import HeldFileResponse, NotOwnFile, check_own
from fpscan.service.api.jobs import get_job_or_404
from fpscan.service.api.logcaps import shown
from fpscan.service.api.models import ID_PATTERN, FormatInfo
from fpscan.service.api.single_flight import SingleFlight
from fpscan.service.api.spool import disk_admission
from fpscan.service.disk import free_bytes, is_disk_full, remove_tree, temp_sibling
from fpscan.service.formats import FORMATS, Format, export_file, export_formats
from fpscan.service.formats.result import VOLUME_FILE
from fpscan.service.jobs import lifecycle

__all__ = ["router", "list_formats", "export", "job_export_source", "export_bytes", "EXPORTS_DIR"]

router = APIRouter(tags=["formats"])

log = logging.getLogger("fpscan.api")

#: the folder of the data folder where scans' exports are written (a scan's file may grow)
EXPORTS_DIR = "exports"


@router.get("/api/formats", response_model=list[FormatInfo], dependencies=[Depends(read_access)])
def list_formats() -> list[FormatInfo]:
    """Every file format of the server's registry, in its order: what it reads (``input``,
    ``upload``) and what it exports (``export_from``: the format of the files it is made
    from; ``suffix``, ``folder``), with its load options. The web page's upload choices and
    download links, and the HTTP client's default file names, come from this."""
    return [FormatInfo.of(f) for f in FORMATS.values()]


def job_export_source(context: Context, job: dict, wavelength: int | None = None) -> tuple[str, Path]:
    """The file a job exports, and its format.

    Parameters
    ----------
    context : Context
        The app's context.
    job : dict
        The stored job (``id``, ``kind``, ...).
    wavelength : int or None, optional
        A reconstruction's volume at this wavelength (a job over every wavelength); default
        None: its volume.

    Returns
    -------
    tuple of (str, pathlib.Path)
        ``("fpscan", scan file)`` for a scan job, ``("result", volume file)`` for a succeeded
        reconstruction.

    Raises
    ------
    fastapi.HTTPException
        409 while the file is not there (a reconstruction not yet done, a scan not started),
        404 for a wavelength the job has not, 422 for ``wavelength`` on a scan.
    """
    if job["kind"] == "scan":
        if wavelength is not None:
            raise HTTPException(422, "wavelength applies to a reconstruction's volume; a scan exports every "
                                     "wavelength it holds")
        from fpscan.service.api.scans import scan_file_path

        return "fpscan", scan_file_path(context, job["id"])
    from fpscan.service.api.reconstructions import volume_dir

    return "result", volume_dir(context, job["id"], wavelength) / VOLUME_FILE


WavelengthQuery = Query(None, ge=0, le=15, description="a reconstruction's volume at wavelength k (a job over "
                                                       "every wavelength); default: its volume")


@router.head("/api/jobs/{job_id}/export/{format}", dependencies=[Depends(read_access)],
             include_in_schema=False)  # its headers alone (the export is made, as for GET)
@router.get("/api/jobs/{job_id}/export/{format}", dependencies=[Depends(read_access)], response_class=FileResponse,
            responses={200: {"description": "the job's file in that format (a folder export zipped)"},
                       206: {"description": "partial content (HTTP Range)"},
                       404: {"description": "no such job, or a format the job does not export (the reason "
                                            "names those it does)"},
                       409: {"description": "the job has no file yet, or its file cannot be exported so"},
                       429: {"description": "too many exports being built or waiting (export_workers); retry "
                                            "after Retry-After seconds"},
                       507: {"description": "the export does not fit the free disk less disk_reserve_bytes (the "
                                            "reason says the bytes); free space, then retry"}})
def export(job_id: str = PathParam(pattern=ID_PATTERN, description="a scan or reconstruction job's id"),
           format: str = PathParam(pattern=r"^[a-z0-9][a-z0-9-]{0,39}$", description="an export format's name "
                                   "(GET /api/formats: those with export_from)"),
           wavelength: int | None = WavelengthQuery, context: Context = Depends(ctx)) -> HeldFileResponse:
    """The job's file (a scan file, or a reconstruction's p0 volume) in the export ``format``
    (``fpscan.service.formats``: the job's ``export_<format>`` links name them; e.g. ``ipasc`` of a
    scan, ``ome-tiff`` and ``ome-zarr`` of a volume, the file itself as ``fpscan`` / ``result``);
    a folder export (OME-Zarr) as a zip of one folder ``<job_id><suffix>``. Supports ``Range``.
    An export not built yet is built within ``export_workers`` turns (429 when that many build
    and four times as many wait already); 507 when it does not fit the free disk less
    ``disk_reserve_bytes``."""
    job = get_job_or_404(context, job_id)
    source, src = job_export_source(context, job, wavelength)
    offered = export_formats(source)
    if format not in offered:
        raise HTTPException(404, f"a {job['kind']} job exports {', '.join(offered)}; no export format {format!r}")
    fmt = FORMATS[format]
    name = f"{job_id}{'' if wavelength is None else f'-wavelength_{wavelength}'}{fmt.suffix}"
    gone = f"job {job_id} was deleted meanwhile"
    root = context.settings.data_dir
    if format == source:  # the file itself
        return HeldFileResponse(src, gone=gone, root=root, media_type=fmt.media_type, filename=name)
    if source == "result":  # a result never changes: its exports are kept beside it
        out = src.with_name(f"volume{fmt.suffix}" + (".zip" if fmt.folder else ""))
    else:  # a scan may grow: written anew
        out = Path(root) / EXPORTS_DIR / (f"{job_id}{fmt.suffix}" + (".zip" if fmt.folder else ""))

    def served() -> HeldFileResponse:  # opened before another build may replace it: each answer serves its build's
        return HeldFileResponse(out, gone=gone, root=root, media_type="application/zip" if fmt.folder else fmt.media_type,
                                filename=name + (".zip" if fmt.folder else ""))

    if source == "result" and os.path.lexists(out):  # built before, and never rebuilt
        return served()
    slots = context.slots["exports"]
    if not slots.enter():  # counted in before waiting for anything (module docstring)
        raise HTTPException(429, slots.busy_reason(), headers={"Retry-After": str(slots.retry_after_s)})
    try:
        with _BUILDS.turn(out) as turn:
            if not (os.path.lexists(out) if source == "result" else turn.built_meanwhile):
                with slots.turn():  # this request builds
                    _build(context, job, src, out, format, source, gone)
                turn.built()
            return served()
    finally:
        slots.leave()


def export_bytes(src: str | os.PathLike, fmt: Format) -> int:
    """The most bytes the export ``fmt`` of the HDF5 file ``src`` (a result volume, a scan
    file) may put on the disk while it is built: every array of ``src`` at 8 bytes an element
    (float64, the widest any exporter writes: IPASC's pressure; the others write float32),
    twice for a folder export (the folder and its zip are on the disk at once), + 1 MiB for
    the files' metadata. From what the datasets declare (``h5py``), nothing read.

    Parameters
    ----------
    src : str or os.PathLike
        The file exported.
    fmt : fpscan.service.formats.Format
        The export format.

    Returns
    -------
    int
        Bytes.

    Raises
    ------
    ValueError
        ``src`` is not an HDF5 file that opens (``fpscan.driver.scanfile.open_readonly``).
    """
    import h5py
    import numpy as np

    from fpscan.driver.scanfile import open_readonly

    elements = 0

    def count(_name: str, obj: object) -> None:
        nonlocal elements
        if isinstance(obj, h5py.Dataset) and obj.shape is not None:
            elements += int(np.prod(obj.shape, dtype=np.int64))

    with open_readonly(src) as f:
        f.visititems(count)
    return elements * 8 * (2 if fmt.folder else 1) + (1 << 20)


def _build(context: Context, job: dict, src: Path, out: Path, format: str, source: str, gone: str) -> None:
    """Build the export ``format`` of the server's own file ``src`` at ``out``: 404 for a
    source that is not the server's own (``fpscan.service.api.files.check_own``) or a job
    deleted under the build (what it wrote removed), 409 with the exporter's reason, 507 when
    the disk admission refuses the export's bytes (:func:`export_bytes`) or on a full disk
    (nothing left behind: the writers remove their temporaries)."""
    job_id = job["id"]
    root = context.settings.data_dir
    try:
        check_own(src, root)
    except NotOwnFile:
        raise HTTPException(404, "no such file") from None
    except FileNotFoundError:
        raise HTTPException(404, gone) from None
    try:
        need = export_bytes(src, FORMATS[format])
    except ValueError as exc:
        raise HTTPException(409, str(exc)) from None
    admission, key = disk_admission(context), f"export-{uuid.uuid4().hex}"
    refused = admission.reserve(key, need, what=f"the {format} export of job {job_id} may take up to {need} bytes")
    if refused:
        log.warning("export %s of job %s refused (507) before it was written: %s", format, job_id, refused)
        raise HTTPException(507, refused)
    try:  # reserved while it is written; once written, the disk's free space counts it
        _write_export(context, src, out, format, arcname=f"{job_id}{FORMATS[format].suffix}",
                      replace=source != "result")
    except OSError as exc:
        with lifecycle.guard(context.store):
            if context.store.get(job_id) is None:  # deleted under the build (its folder removed)
                _discard(context, out, job)
                raise HTTPException(404, f"job {job_id} was deleted while its export was made") from None
        if not is_disk_full(exc):
            raise
        free = free_bytes(out.parent)
        log.warning("export %s of job %s: the disk is full: %s", format, job_id,
                    shown(f"{type(exc).__name__}: {exc}"))
        raise HTTPException(507, f"no room for the {format} export of job {job_id} on the data folder's disk "
                                 f"({'an unknown number of' if free is None else free} bytes free); free space, "
                                 "then retry (/api/health shows the free bytes)") from None
    finally:
        admission.release(key)
    with lifecycle.guard(context.store):  # no deletion between the look and the file kept
        if context.store.get(job_id) is None:
            _discard(context, out, job)
            raise HTTPException(404, f"job {job_id} was deleted while its export was made")


#: the exports' builds: one at a time per output path
_BUILDS = SingleFlight()


def _discard(context: Context, out: Path, job: dict) -> None:
    """Remove what a build wrote for a job deleted meanwhile: ``out`` (counted out of
    health's disk-usage counters, which the build counted it in) and the job's files the
    build's folder re-made (``fpscan.service.jobs.lifecycle.job_files``)."""
    from fpscan.service.storage.usage import usage_for

    if out.exists():
        usage_for(context.settings.data_dir).add_path(out, removed=True)
    for path in (out, *lifecycle.job_files(job, context.settings.data_dir)):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _write_export(context: Context, src: Path, out: Path, format: str, *, arcname: str, replace: bool = False) -> None:
    """Write the export ``format`` of ``src`` at ``out`` (a folder export zipped into ``out``),
    counted in health's disk-usage counters; 409 with the exporter's reason."""
    from fpscan.service.storage.results import zip_folder
    from fpscan.service.storage.usage import usage_for

    usage = usage_for(context.settings.data_dir)
    if replace and out.exists():
        usage.add_path(out, removed=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        if FORMATS[format].folder:
            tmp = temp_sibling(out)
            try:
                export_file(src, tmp, format)
                zip_folder(tmp, out, arcname=arcname)
            finally:
                remove_tree(tmp)
        else:
            export_file(src, out, format)
    except ValueError as exc:
        raise HTTPException(409, str(exc)) from None
    usage.add_path(out)
