"""Dataset upload: ``POST /api/datasets`` (multipart ``file`` + ``format`` + spacings).

Formats:
- ``npy``: a NumPy array in k-Wave layout, ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` (time
  first, as k-Wave's ``'ty'``/``'tyz'``), with form fields ``dt`` (s), ``dx`` (m),
  optional ``dy`` (m, default dx) and ``c`` (m/s, default 1500; outside 1000-2000 m/s
  only with ``force``: ``driver.units.check_plausible``, as everywhere). Loaded with
  ``allow_pickle=False``.
- ``kwave-hdf5``: an HDF5 file holding such an array at ``key`` (default
  ``sensor_data/clean``, then ``sensor_data``); spacings from the form or from the file's
  ``dt_s``, ``dx_m``, ``dy_m``, ``c_m_per_s`` attributes (shared/data/README.md layout).
- ``fpscan``: our scan file (``driver.scanfile``), reconstructed from its completed points.
- ``ipasc``: an IPASC HDF5 file (``service.ipasc.read_ipasc``).

The upload is stored under a server-chosen id (``<data_dir>/datasets/<id>/``); the client's
file name is never used as a path. Every upload is read with
``service.storage.datasets.load_dataset`` and kept as the canonical dataset file
(``service.storage.datasets.write_dataset``), which the job worker reads.
"""
from __future__ import annotations

import shutil
import uuid
from pathlib import Path

from fastapi import APIRouter, Depends, File, Form, HTTPException, UploadFile
from fastapi import Path as PathParam

from service.api.context import Context, ctx, reason, require_token
from service.api.models import ID_PATTERN, Dataset, DatasetFormat, Deleted
from service.jobs import lifecycle
from service.storage.datasets import import_dataset
from service.storage.untrusted import hdf5_limit, run_bounded

router = APIRouter(prefix="/api/datasets", tags=["datasets"])

@router.post("", status_code=201, response_model=Dataset, dependencies=[Depends(require_token)],
             responses={413: {"description": "upload larger than the configured limit"}})
def upload_dataset(file: UploadFile = File(..., description="the data file"),
                   format: DatasetFormat = Form(...),
                   dt: float | None = Form(None, description="sample interval, s"),
                   dx: float | None = Form(None, description="lateral spacing along x, m"),
                   dy: float | None = Form(None, description="lateral spacing along y, m"),
                   c: float | None = Form(None, description="speed of sound, m/s (1000-2000 unless force)"),
                   force: bool = Form(False, description="accept a c outside 1000-2000 m/s (a medium other "
                                                         "than tissue or water)"),
                   key: str | None = Form(None, max_length=200, description="HDF5 dataset path (kwave-hdf5)"),
                   wavelength: int | None = Form(None, ge=0, le=1023,
                                                 description="of a multi-wavelength scan or IPASC file: the index of "
                                                             "the excitation wavelength to store (default: the "
                                                             "first); out of range: 422 naming the file's"),
                   cx: Context = Depends(ctx)) -> Dataset:
    """Upload a dataset for reconstruction → 201 ``{dataset_id, ...}``. At most
    ``FPSCAN_IMPORT_WORKERS`` uploads are imported at once (4x as many wait; beyond, 429).
    A dataset holds one wavelength's data (``wavelength``; the response's
    ``wavelength_nm`` says which)."""
    with cx.slots["uploads"].turn():
        return _store_upload(file, format, dt=dt, dx=dx, dy=dy, c=c, key=key, force=force, wavelength=wavelength,
                             cx=cx)


def _store_upload(file: UploadFile, format: str, *, dt, dx, dy, c, key, force: bool, wavelength: int | None,
                  cx: Context) -> Dataset:
    dataset_id = uuid.uuid4().hex
    dest = Path(cx.settings.data_dir) / "datasets" / dataset_id
    dest.mkdir(parents=True)
    src = dest / "upload.bin"
    limit = cx.settings.upload_limit
    size = 0
    try:
        with open(src, "wb") as out:
            while chunk := file.file.read(1 << 20):
                size += len(chunk)
                if size > limit:
                    raise HTTPException(413, f"upload larger than the limit of {limit} bytes")
                out.write(chunk)
        try:
            # in a child process with a time and memory bound: the HDF5 library can block
            # (holding the GIL) or expand a small file into gigabytes (import_dataset lives
            # in service.storage, so the child does not import the web stack)
            meta = run_bounded(import_dataset, src, dest, format, dt=dt, dx=dx, dy=dy, c=c, key=key, force=force,
                               wavelength=wavelength,
                               max_bytes=hdf5_limit(limit, cx.settings.memory_limit),
                               timeout=cx.settings.import_timeout_s, what="the upload",
                               memory_bytes=cx.settings.memory_limit + 2 * 2**30)
        except ValueError as exc:
            msg = reason(exc).replace(str(src.resolve()), "the upload").replace(str(src), "the upload")
            raise HTTPException(422, cx.settings.redact(msg)) from None
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    src.unlink(missing_ok=True)
    meta["format"] = format
    cx.store.put_dataset(dataset_id, meta)
    return Dataset(dataset_id=dataset_id, format=format, layout=meta["layout"], shape=meta["shape"], dt=meta["dt"],
                   wavelength_nm=meta.get("wavelength_nm"))


@router.delete("/{dataset_id}", response_model=Deleted, dependencies=[Depends(require_token)],
               responses={409: {"description": "an active reconstruction reads the dataset"}})
def delete_dataset(dataset_id: str = PathParam(pattern=ID_PATTERN), cx: Context = Depends(ctx)) -> Deleted:
    """Delete an uploaded dataset and its files; 409 while a queued or running
    reconstruction reads it."""
    try:
        return Deleted(kind="dataset", **lifecycle.delete_dataset(cx.store, cx.settings.data_dir, dataset_id))
    except lifecycle.NotFound as exc:
        raise HTTPException(404, str(exc)) from None
    except lifecycle.InUse as exc:
        raise HTTPException(409, str(exc)) from None
