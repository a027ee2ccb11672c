"""A file served as it was when the answer was made: :class:`HeldFileResponse`.

Starlette's ``FileResponse`` names a path and opens it only when the answer is sent, after
the route has returned: a job deleted in between (its folder removed) made the answer a 500
("File at path ... does not exist"), and a file replaced in between (a scan's export
written anew) or growing (a scan file while it scans) could be served with another file's
bytes or more bytes than its ``Content-Length`` said. A :class:`HeldFileResponse` opens the
file in the route (a file gone by then is a 404, the reason said), takes its size from the
open file, and serves that open file, never past that size: what the route saw is what the
client gets, however the path changes after (a deletion frees the file's blocks only once
the answer is sent, as POSIX keeps an unlinked open file).
"""
from __future__ import annotations

import os
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
from fastapi import HTTPException
from starlette.responses import FileResponse
from starlette.types import Receive, Scope, Send

__all__ = ["HeldFileResponse"]


class _Bounded:
    """A binary file read no further than ``size`` bytes (the size it had when opened)."""

    def __init__(self, file: Any, size: int) -> None:
        self._file, self._size = file, size

    def read(self, n: int = -1) -> bytes:
        left = max(0, self._size - self._file.tell())
        return self._file.read(left if n is None or n < 0 else min(n, left))

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def close(self) -> None:  # the response closes the file once it is sent
        pass


class HeldFileResponse(FileResponse):
    """A ``FileResponse`` (``Range`` included) of the file at ``path`` as it is now.

    Parameters
    ----------
    path : str or os.PathLike
        The file; opened here.
    gone : str
        The 404's reason when there is no file at ``path`` any more (deleted meanwhile).
    **kwargs
        ``FileResponse``'s (``media_type``, ``filename``, ``headers``, ...).

    Raises
    ------
    fastapi.HTTPException
        404 with ``gone`` when the file is not there (or is not a regular file).
    """

    #: bytes read and sent at a time: each read runs in a worker thread of the event loop, so
    #: Starlette's 64 KiB made a 72 MiB result 1150 thread round trips (0.41-0.92 s to a client
    #: on the same machine; docs/performance.md, "One reconstruction through every door")
    chunk_size = 1 << 20

    def __init__(self, path: str | os.PathLike, *, gone: str, **kwargs: Any) -> None:
        try:
            self._held = open(path, "rb")  # closed once the answer is sent
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            raise HTTPException(404, gone) from None
        stat_result = os.fstat(self._held.fileno())
        super().__init__(Path(path), stat_result=stat_result, **kwargs)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        extensions = {k: v for k, v in (scope.get("extensions") or {}).items() if k != "http.response.pathsend"}
        try:  # never a send of the path: the bytes are those of the file held
            await super().__call__({**scope, "extensions": extensions}, receive, send)
        finally:
            self._held.close()

    @asynccontextmanager
    async def _open_file(self) -> AsyncIterator[anyio.AsyncFile[bytes]]:
        assert self.stat_result is not None
        yield anyio.wrap_file(_Bounded(self._held, self.stat_result.st_size))  # type: ignore[arg-type]
