"""Upload bodies spooled inside the data folder, counted by the disk admission.

The multipart body of ``POST /api/datasets`` is parsed (Starlette's ``MultiPartParser``, the
parser FastAPI uses) before the route runs, each file part into a
``tempfile.SpooledTemporaryFile``: in memory up to 1 MiB, then a file. Starlette puts that
file in the system's temporary folder (``TMPDIR``), outside what the server watches: 10 uploads
waiting their turn could spool 20 GiB there, and a spool that failed (a full ``/tmp``)
answered 400 "There was an error parsing the body" with nothing logged. Here instead
(:class:`SpooledUploads`, the route class of the datasets router):

- the spool files are made in ``<data_dir>/incoming`` (unnamed: ``O_TMPFILE`` where the
  file system has it, so nothing is left behind by a crash; ``tempfile.TemporaryFile``);
- before a byte of the body is read, its length (``Content-Length``; without one, the
  upload limit plus its multipart allowance, as the 507's reason then says) is admitted by
  the disk admission of the imports (:func:`disk_admission`, ``fpscan.service.formats.untrusted.DiskAdmission``: the free
  space less ``disk_reserve_bytes`` less what uploads and imports in flight were admitted
  for), else 507 with the reason, the body unread; the reservation lasts while the body
  is spooled (then the disk's free space counts it);
- a spool that fails while it is written (the disk full after all, a file-size limit, an
  I/O error) is answered 507 with the reason, and logged.

Source: Starlette's ``starlette/formparsers.py`` and ``starlette/requests.py`` (1.x): the
parser's ``on_headers_finished`` makes the part's ``UploadFile`` and its spool file; this
module's parser replaces that spool file with one in the data folder before any data is
written to it.
"""
from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Coroutine
from contextlib import aclosing
from pathlib import Path
from tempfile import SpooledTemporaryFile
from typing import Any

from fastapi import HTTPException
from fastapi.routing import APIRoute
from starlette.datastructures import FormData
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.requests import Request
from starlette.responses import Response

from fpscan.service.api.context import Context
from fpscan.service.api.upload_limit import MULTIPART_ALLOWANCE
from fpscan.service.disk import free_bytes
from fpscan.service.formats.untrusted import DiskAdmission
from fpscan.service.jobs.queue import INCOMING

__all__ = ["disk_admission", "SpoolParser", "SpooledUploads"]

log = logging.getLogger("fpscan.api")

def disk_admission(context: Context) -> DiskAdmission:
    """The service's one disk admission of uploads and imports (made at first use).

    Parameters
    ----------
    context : Context
        The service's shared state.

    Returns
    -------
    fpscan.service.formats.untrusted.DiskAdmission
        Free space of the data folder's disk less ``disk_reserve_bytes`` less what is reserved.
    """
    adm = context.extras.get("disk_admission")
    if adm is None:
        adm = context.extras.setdefault("disk_admission", DiskAdmission(context.settings.data_dir,
                                                                       context.settings.disk_reserve_bytes))
    return adm


class SpoolParser(MultiPartParser):
    """Starlette's multipart parser with its file parts spooled into ``spool_dir``.

    Parameters
    ----------
    *args, **kwargs
        Those of ``starlette.formparsers.MultiPartParser``.
    spool_dir : pathlib.Path
        Where a file part larger than the parser's ``spool_max_size`` (1 MiB) is written.
    """

    def __init__(self, *args: Any, spool_dir: Path, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.spool_dir = spool_dir

    def on_headers_finished(self) -> None:
        super().on_headers_finished()
        upload = self._current_part.file
        if upload is None:  # a plain field
            return
        spooled = SpooledTemporaryFile(max_size=self.spool_max_size, dir=str(self.spool_dir))
        upload.file.close()  # Starlette's, in the system's folder, still empty
        upload.file = spooled  # type: ignore[assignment]  # as Starlette does
        opened = getattr(self, "_files_to_close_on_error", None)
        if opened:
            opened[-1] = spooled


class _SpoolingRequest(Request):
    """A request whose multipart form is parsed by :class:`SpoolParser` after its length was
    admitted (module docstring)."""

    async def _get_form(self, *, max_files: int | float = 1000, max_fields: int | float = 1000,
                        max_part_size: int = 1024 * 1024) -> FormData:
        if self._form is not None or not self.headers.get("content-type", "").lower().startswith("multipart/form-data"):
            return await super()._get_form(max_files=max_files, max_fields=max_fields, max_part_size=max_part_size)
        context: Context = self.app.state.ctx
        spool_dir = Path(context.settings.data_dir) / INCOMING
        admission = disk_admission(context)
        chunked = False
        try:
            length = int(self.headers.get("content-length", ""))
            what = f"the upload's body holds {length} bytes"
        except ValueError:  # chunked: as much as the upload limit lets through
            chunked, length = True, context.settings.upload_limit + MULTIPART_ALLOWANCE
            what = (f"an upload without Content-Length is admitted for up to {length} bytes (the upload limit and "
                    "its multipart allowance)")
        key = f"spool-{uuid.uuid4().hex}"
        reason = admission.reserve(key, length, what=what)
        if reason:
            if chunked:
                reason += "; send its Content-Length to be admitted for its own bytes"
            log.warning("upload refused (507) before its body was spooled: %s", reason)
            raise HTTPException(507, reason)
        try:  # reserved while it is written; once written, the disk's free space counts it
            spool_dir.mkdir(parents=True, exist_ok=True)
            async with aclosing(self.stream()) as stream:
                parser = SpoolParser(self.headers, stream, spool_dir=spool_dir, max_files=max_files,
                                     max_fields=max_fields, max_part_size=max_part_size)
                self._form = await parser.parse()
        except MultiPartException as exc:
            raise HTTPException(400, exc.message) from None
        except OSError as exc:  # the server's disk, not the client's body
            free = free_bytes(spool_dir)
            reason = (f"the upload could not be spooled into the data folder ({exc.strerror or type(exc).__name__}; "
                      f"{'an unknown number of' if free is None else free} bytes free there): free space or retry "
                      "later")
            log.warning("upload refused (507), its spool failed: %s", reason)
            raise HTTPException(507, reason) from None
        finally:
            admission.release(key)
        return self._form


class SpooledUploads(APIRoute):
    """The route class of the upload routes: their multipart body spooled inside the data folder,
    admitted by the disk admission first (module docstring)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def spooling(request: Request) -> Response:
            return await handler(_SpoolingRequest(request.scope, request.receive))

        return spooling

