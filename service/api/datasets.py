"""Dataset upload: ``POST /api/datasets`` (multipart ``file`` + ``format`` + spacings).

Formats: those of the registry marked ``upload`` (``fpscan.service.formats``; listed by
``GET /api/datasets/formats``, each module documenting its layout): ``npy`` (a NumPy array,
time first unless the field ``axes`` gives its order — ``y,x,t``, ``x,t``, ...; an undeclared
array whose shape does not show its time axis is refused with 422 naming the readings it could
have, ``fpscan.service.formats.npy.time_axes`` — with form fields ``dt`` (s), ``dx`` (m), optional ``dy``
(m, default dx) and ``sound_speed`` (m/s, default 1500; outside ``fpscan.constants.C_PLAUSIBLE``
only with ``force``, the registry's ``SpeedOptions``:
``fpscan.driver.units.check_plausible``, as everywhere)), ``kwave-hdf5`` (such an array in HDF5
at ``key``; spacings from the form or the file's attributes), ``fpscan`` (our scan file,
reconstructed from its completed points) and ``ipasc``.

The upload is stored under a server-chosen id (``<data_dir>/datasets/<id>/``); the client's
file name is never used as a path (it is kept, cleaned, as the dataset's display name). Every
upload is read with ``fpscan.service.storage.loader.load_dataset`` and kept as the canonical
dataset file (``fpscan.service.storage.loader.write_dataset``), which the job worker reads.

Datasets never pile up:

- Deduplicated: the upload's SHA-256 together with the options that change the stored
  dataset (format, ``dt``, ``dx``, ``dy``, ``c``, ``key``, ``axes``, the wavelength index) is its
  key; the same file with the same options uploaded again answers (201, as any upload)
  with the stored dataset's id and ``deduplicated: true``, storing nothing.
- Acknowledged means on disk: a new dataset's file, then its folder, then the folder
  ``datasets/`` that names it are flushed (``fpscan.service.disk.fsync_tree``) before the job
  store's commit that records it (``synchronous=FULL``), and the 201 comes after that commit:
  a power cut after the 201 loses nothing it named.
- Acknowledged means stored: the dataset a 201 names (found or new) is found
  or stored under ``fpscan.service.jobs.lifecycle.guard``, the lock deletions take, and held
  (``lifecycle.hold_dataset``) until the 201 has been sent (a background task of the
  response releases it): a ``DELETE`` of it meanwhile waits, and retention passes it by.
- Listed (``GET /api/datasets``: size on disk, content hash, the jobs that read it) and
  deletable (``DELETE /api/datasets/{id}``, 409 while a queued/running/paused job reads it).
- Covered by retention (``fpscan.service.jobs.lifecycle.apply_dataset_retention``, applied after
  each new upload too).
- Admitted against the disk: the body's length before it is spooled (inside the data folder,
  ``fpscan.service.api.spool``), then the decoded dataset's bytes, must fit the free space
  less ``disk_reserve_bytes`` less what uploads and imports in flight reserved
  (``fpscan.service.formats.untrusted.DiskAdmission``), else 507 before it is written.
- Imported within its budget: in a child process capped at the memory limit
  (``fpscan.service.formats.untrusted.import_memory_limit``), decoding at most the decode
  budget (``fpscan.service.formats.untrusted.hdf5_limit``), each array sized before it is
  decoded.
"""
from __future__ import annotations

import hashlib
import inspect
import json
import logging
import shutil
import uuid
from pathlib import Path
from typing import Any

from fastapi import APIRouter, BackgroundTasks, Depends, File, Form, HTTPException, UploadFile
from fastapi import Path as PathParam

from fpscan.constants import C_DEFAULT
from fpscan.driver.units import parse_quantity
from fpscan.service.api.context import Context, ctx, read_access, reason, require_token
from fpscan.service.api.models import (
    ID_PATTERN,
    Dataset,
    DatasetFormat,
    DatasetFormatInfo,
    DatasetInfo,
    Deleted,
)
from fpscan.service.api.spool import SpooledUploads, disk_admission
from fpscan.service.disk import durable_mkdir, fsync_folder, fsync_tree
from fpscan.service.formats import upload_formats
from fpscan.service.formats.load_options import check_load_options, load_option_schemas
from fpscan.service.formats.untrusted import NotAdmitted, hdf5_limit, import_memory_limit, run_bounded
from fpscan.service.jobs import lifecycle
from fpscan.service.jobs.queue import INCOMING
from fpscan.service.recon.methods.options import SpeedOptions, plausible_speeds
from fpscan.service.storage.loader import import_dataset
from fpscan.service.storage.usage import usage_for

log = logging.getLogger("fpscan.api")
__all__ = ["router", "list_datasets", "list_formats", "upload_dataset", "delete_dataset"]

# the upload's body spooled inside the data folder, admitted by the disk admission first
router = APIRouter(prefix="/api/datasets", tags=["datasets"], route_class=SpooledUploads)

@router.get("", response_model=list[DatasetInfo], dependencies=[Depends(read_access)])
def list_datasets(context: Context = Depends(ctx)) -> list[DatasetInfo]:
    """The stored datasets, oldest first: name, format, size on disk, upload time,
    content hash and the jobs that read them (``in_use``: an active one does)."""
    return [DatasetInfo(**d) for d in lifecycle.list_datasets(context.store, context.settings.data_dir)]


@router.get("/formats", response_model=list[DatasetFormatInfo], dependencies=[Depends(read_access)])
def list_formats() -> list[DatasetFormatInfo]:
    """The formats an upload may have (the registry ``fpscan.service.formats``, in its order):
    name (the ``format`` field), title and whether it may hold several wavelengths. The
    web page builds its format choices from this."""
    return [DatasetFormatInfo(**f) for f in upload_formats()]


#: the upload's speed fields, in the words of the registry's one speed option
#: (``fpscan.service.recon.methods.options.SpeedOptions``: unit, bounds, default)
_SPEED = (f"speed of sound, m/s (or 1.5 km/s; {plausible_speeds()} unless force; default: the file's, else "
          f"{C_DEFAULT:g})")
_FORCE = SpeedOptions.model_fields["force"].description


def upload_dataset(file: UploadFile = File(..., description="the data file"),
                   format: DatasetFormat = Form(...),
                   sound_speed: str | None = Form(None, max_length=40, description=_SPEED),
                   c: str | None = Form(None, max_length=40, description="deprecated name of sound_speed"),
                   force: bool = Form(False, description=_FORCE),
                   context: Context = Depends(ctx), sent: BackgroundTasks = None,  # type: ignore[assignment]
                   **options: Any) -> Dataset:
    """Upload a dataset for reconstruction → 201 ``{dataset_id, ...}``; the same file with
    the same options again → 201 with the stored one (``deduplicated: true``, nothing new
    stored: 201 as for any upload, so clients need not tell the cases apart). At most
    ``FPSCAN_IMPORT_WORKERS`` uploads are imported at once (4x as many wait; beyond, 429).
    The form's other fields are the formats' load options (``dt``, ``dx``, ``dy``, ``key``,
    ``axes``, ``wavelength``: each format's own, ``GET /api/formats``; one the chosen format does not
    take is refused with 422). A dataset holds one wavelength's data (``wavelength``; the
    response's ``wavelength_nm`` says which). 507 when the body (before it is read) or the
    decoded dataset does not fit the disk, or the body's spool fails."""
    if sound_speed is not None and c is not None and sound_speed.strip() != c.strip():
        raise HTTPException(422, "give the speed of sound once: sound_speed (c is its deprecated name)")
    speed = c if sound_speed is None else sound_speed
    quantities = _LOAD_QUANTITIES
    try:  # numbers typed with units, as everywhere (fpscan.driver.units.parse_quantity)
        q = {name: None if text is None or not str(text).strip() else parse_quantity(text, kind, name=name)
             for name, text, kind in [*((n, options.get(n), k) for n, k in quantities.items()),
                                      ("sound_speed", speed, "speed")]}
        given = {**options, **{n: q[n] for n in quantities}}
        given.update(check_load_options(format, {k: v for k, v in given.items() if k != "wavelength"}))
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    with context.slots["uploads"].turn():
        out = _store_upload(file, format, dt=given.get("dt"), dx=given.get("dx"), dy=given.get("dy"),
                            sound_speed=q["sound_speed"],
                            key=given.get("key"), axes=given.get("axes"), force=force, wavelength=given.get("wavelength"), context=context)
    # held since it was found or stored: released once the 201 naming it has been sent
    sent.add_task(lifecycle.release_dataset, context.store, out.dataset_id)
    return out


#: the formats' load options (``fpscan.service.formats.load_options``): the upload's generated fields
_LOAD_OPTIONS = load_option_schemas()
#: those whose values may be text with a unit: name -> kind of ``fpscan.driver.units.parse_quantity``
_LOAD_QUANTITIES = {o["name"]: o["schema"]["quantity"] for o in _LOAD_OPTIONS if o["schema"].get("quantity")}


def _form_field(option: dict[str, Any]) -> inspect.Parameter:
    """The upload's form field of one load option: text with a unit for a quantity (parsed by
    ``fpscan.driver.units.parse_quantity``), an integer within its bounds, or bounded text."""
    schema, who = option["schema"], ", ".join(option["formats"])
    said = f"{option['description']} ({who})"
    default: Any
    if schema.get("quantity"):
        annotation: Any = str | None
        default = Form(None, max_length=40, description=f"{said}; {schema.get('unit', '')}, or with a unit")
    elif schema.get("type") == "integer":
        annotation = int | None
        default = Form(None, ge=schema.get("minimum"), le=schema.get("maximum"), description=said)
    else:
        annotation = str | None
        default = Form(None, max_length=int(schema.get("maxLength", 200)), description=said)
    return inspect.Parameter(option["name"], inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)


_fixed = [p for p in inspect.signature(upload_dataset).parameters.values() if p.kind != p.VAR_KEYWORD]
upload_dataset.__signature__ = inspect.Signature(  # type: ignore[attr-defined]
    [*(p.replace(kind=p.KEYWORD_ONLY) for p in _fixed), *(_form_field(o) for o in _LOAD_OPTIONS)])
upload_dataset = router.post(
    "", status_code=201, response_model=Dataset, dependencies=[Depends(require_token)],
    responses={413: {"description": "upload larger than the configured limit"},
               507: {"description": "the body (before it is read) or the decoded dataset does not fit the free "
                                    "disk (counting the uploads and imports in progress), or spooling the body "
                                    "into the data folder failed"}})(upload_dataset)


def _display_name(name: str | None) -> str | None:
    """The client's file name for display: its last path part, printable, at most 200 characters."""
    if not name:
        return None
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    clean = "".join(ch for ch in base if ch.isprintable())[:200].strip()
    return clean or None


def _dedup_key(sha256: str, format: str, **options: object) -> str:
    """The key of a stored dataset: the upload's bytes and the options that change what is stored."""
    options["wavelength"] = options.get("wavelength") or 0  # None reads the first wavelength
    return hashlib.sha256(json.dumps({"sha256": sha256, "format": format, **options}, sort_keys=True)
                          .encode()).hexdigest()


def _stored(context: Context, dedup_key: str, sha256: str) -> Dataset | None:
    """The oldest stored dataset of ``dedup_key`` whose file is there, as a deduplicated
    answer, held (``lifecycle.hold_dataset``); None when there is none. Called under
    ``lifecycle.guard``: no deletion falls between the look and the hold."""
    for dataset_id in context.store.find_datasets(dedup_key):
        meta = context.store.get_dataset(dataset_id)
        if meta is not None and (Path(context.settings.data_dir) / "datasets" / dataset_id / meta["path"]).is_file():
            lifecycle.hold_dataset(context.store, dataset_id)
            return Dataset(dataset_id=dataset_id, format=meta["format"], layout=meta["layout"], shape=meta["shape"],
                           dt=meta["dt"], wavelength_nm=meta.get("wavelength_nm"), deduplicated=True,
                           content_sha256=sha256)
    return None


def _store_upload(file: UploadFile, format: str, *, dt: float | None, dx: float | None, dy: float | None,
                  sound_speed: float | None, key: str | None, axes: str | None, force: bool, wavelength: int | None,
                  context: Context) -> Dataset:
    dataset_id = uuid.uuid4().hex
    # staged outside datasets/ until stored (one rename): datasets/ changes only when a
    # dataset is added, and /api/health's disk usage is re-walked only then
    dest = Path(context.settings.data_dir) / INCOMING / dataset_id
    dest.mkdir(parents=True)
    src = dest / "upload.bin"
    limit = context.settings.upload_limit
    size = 0
    digest = hashlib.sha256()
    admission = disk_admission(context)
    try:
        # the body's copy is admitted too (its size is known: the form parser has spooled it)
        held = int(file.size or 0)
        refused = admission.reserve(dataset_id, held, what=f"the upload holds {held} bytes")
        if refused:
            raise HTTPException(507, refused)
        with open(src, "wb") as out:
            while chunk := file.file.read(1 << 20):
                size += len(chunk)
                if size > limit:
                    raise HTTPException(413, f"upload larger than the limit of {limit} bytes")
                digest.update(chunk)
                out.write(chunk)
        sha256 = digest.hexdigest()
        dedup_key = _dedup_key(sha256, format, dt=dt, dx=dx, dy=dy, sound_speed=sound_speed, key=key, wavelength=wavelength,
                               force=bool(force), **({"axes": axes} if axes is not None else {}))
        with lifecycle.guard(context.store):  # found and held with no deletion between
            found = _stored(context, dedup_key, sha256)
        if found is not None:
            try:
                shutil.rmtree(dest, ignore_errors=True)
                context.store.touch_dataset(found.dataset_id)  # asked for again: retention by age counts from now
            except BaseException:
                lifecycle.release_dataset(context.store, found.dataset_id)
                raise
            log.info("upload deduplicated: dataset=%s bytes=%d", found.dataset_id, size)
            return found
        try:
            # in a child process with a time and memory bound: the HDF5 library can block
            # (holding the GIL) or expand a small file into gigabytes (import_dataset lives
            # in fpscan.service.storage, so the child does not import the web stack)
            meta = run_bounded(import_dataset, src, dest, format, dt=dt, dx=dx, dy=dy, sound_speed=sound_speed, key=key,
                               axes=axes, force=force,
                               wavelength=wavelength,
                               max_bytes=hdf5_limit(limit, context.settings.memory_limit),
                               timeout=context.settings.import_timeout_s, what="the upload",
                               memory_bytes=import_memory_limit(context.settings.memory_limit),
                               admit=lambda nbytes: admission.reserve(dataset_id, nbytes))
        except ValueError as exc:
            msg = reason(exc).replace(str(src.resolve()), "the upload").replace(str(src), "the upload")
            raise HTTPException(422, context.settings.redact(msg)) from None
        except NotAdmitted as exc:
            raise HTTPException(507, str(exc)) from None
        src.unlink(missing_ok=True)
        meta.update({"format": format, "name": _display_name(file.filename), "content_sha256": sha256,
                     "dedup_key": dedup_key})
        fsync_tree(dest, parent=False)  # the dataset's file, then its folder: on disk before it is recorded
        with lifecycle.guard(context.store):  # an identical upload may have been stored meanwhile: keep that one
            found = _stored(context, dedup_key, sha256)
            if found is None:
                stored = durable_mkdir(Path(context.settings.data_dir) / "datasets") / dataset_id
                dest.rename(stored)
                dest = stored
                fsync_folder(stored.parent)  # the entry naming it, then the commit (synchronous=FULL)
                context.store.put_dataset(dataset_id, meta)
                lifecycle.hold_dataset(context.store, dataset_id)  # until its 201 is sent (retention passes it by)
                usage_for(context.settings.data_dir).add_path(stored)  # /api/health's counters
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    finally:
        admission.release(dataset_id)
    if found is not None:
        shutil.rmtree(dest, ignore_errors=True)
        return found
    try:
        lifecycle.apply_dataset_retention(context.store, context.settings)
    except Exception:  # retention must not fail the upload that was stored
        log.exception("dataset retention failed after upload=%s", dataset_id)
    return Dataset(dataset_id=dataset_id, format=format, layout=meta["layout"], shape=meta["shape"], dt=meta["dt"],
                   wavelength_nm=meta.get("wavelength_nm"), content_sha256=sha256)


@router.delete("/{dataset_id}", response_model=Deleted, dependencies=[Depends(require_token)],
               responses={409: {"description": "an active reconstruction reads the dataset"}})
def delete_dataset(dataset_id: str = PathParam(pattern=ID_PATTERN), context: Context = Depends(ctx)) -> Deleted:
    """Delete an uploaded dataset and its files; 409 while a queued or running
    reconstruction reads it."""
    try:
        return Deleted(kind="dataset", **lifecycle.delete_dataset(context.store, context.settings.data_dir, dataset_id))
    except lifecycle.NotFound as exc:
        raise HTTPException(404, str(exc)) from None
    except lifecycle.InUse as exc:
        raise HTTPException(409, str(exc)) from None
