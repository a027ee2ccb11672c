"""The server's own files, served as they were when the answer was made: :func:`open_own`
and :class:`HeldFileResponse`.

Only the server's own files are served. A file is opened from the data folder down, one
path component at a time, each with ``O_NOFOLLOW`` relative to the folder opened before
(``openat(2)``): a path outside the data folder, a symbolic link anywhere below it (a
result's ``volume.h5`` or its whole folder replaced by a link to ``/etc/passwd``) or
something that is not a regular file is refused (404, :class:`NotOwnFile`), and the
refusal logged once per path (later ones are not: a client repeating the request does not
fill the log). A link swapped in after the open changes nothing: what was opened is served.

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

import errno
import json
import logging
import math
import os
import stat
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
from fastapi import HTTPException
from starlette.responses import FileResponse
from starlette.types import Receive, Scope, Send

from fpscan.service.api.logcaps import Thinning, shown

__all__ = ["HeldFileResponse", "NotOwnFile", "open_own", "read_own", "check_own"]

log = logging.getLogger("fpscan.api")

#: the paths whose refusal was logged (each once; the oldest forgotten beyond this many)
_REFUSALS = Thinning()
_MOST_REFUSALS = 4096


class NotOwnFile(FileNotFoundError):
    """A path the server does not serve: outside its data folder, through a symbolic link,
    or not a regular file (a ``FileNotFoundError``: answered 404, as a file that is not there).

    Parameters
    ----------
    message : str
        The reason (for the log; the client is told only that there is no such file).
    """


def open_own(path: str | os.PathLike, root: str | os.PathLike) -> int:
    """Open the regular file ``path`` below ``root`` (the data folder) for reading through no
    symbolic link (module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The file; a path inside ``root`` (absolute, or relative to the working folder as
        ``root`` is).
    root : str or os.PathLike
        The data folder: opened as it is (it may itself be a link an administrator made);
        every component below it is opened with ``O_NOFOLLOW``.

    Returns
    -------
    int
        The open file descriptor (``O_RDONLY``, close-on-exec); the caller closes it.

    Raises
    ------
    NotOwnFile
        ``path`` outside ``root``, a symbolic link on the way, or not a regular file; the
        refusal is logged, once per path.
    FileNotFoundError
        No such file (or a folder on the way is not there).
    """
    top = os.path.abspath(root)
    rel = os.path.relpath(os.path.abspath(path), top)
    parts = rel.split(os.sep)
    if rel in (".", "") or parts[0] == os.pardir:
        _refused(path, "outside the data folder")
    folder = os.open(top, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    fd = -1
    try:
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | (os.O_NONBLOCK if last else os.O_DIRECTORY)
            try:
                fd = os.open(part, flags, dir_fd=folder)
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR, errno.EMLINK) and _is_link(part, folder):
                    _refused(path, f"{os.sep.join(parts[:i + 1])} is a symbolic link")
                if exc.errno in (errno.ENOTDIR, errno.EISDIR):
                    raise FileNotFoundError(errno.ENOENT, f"no such file: {path}") from None
                raise
            if not last:
                os.close(folder)
                folder, fd = fd, -1
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            os.close(fd)
            fd = -1
            if stat.S_ISDIR(mode):
                raise FileNotFoundError(errno.ENOENT, f"no such file: {path}")
            _refused(path, "not a regular file")
        return fd
    finally:
        os.close(folder)


def _is_link(name: str, folder: int) -> bool:
    try:
        return stat.S_ISLNK(os.stat(name, dir_fd=folder, follow_symlinks=False).st_mode)
    except OSError:
        return False


def _refused(path: str | os.PathLike, why: str) -> None:
    """Log the refusal of ``path`` (the first for it only) and raise :class:`NotOwnFile`."""
    passes, _ = _REFUSALS.let_through(os.path.abspath(path), math.inf, _MOST_REFUSALS)
    if passes:
        log.warning("refused to serve %s: %s (only the server's own files are served; this path's later "
                    "refusals are not logged)", shown(path), why)
    raise NotOwnFile(f"{path}: {why}")


def read_own(path: str | os.PathLike, root: str | os.PathLike) -> bytes:
    """The bytes of the server's own file ``path`` (:func:`open_own`), e.g. a result's picture.

    Parameters
    ----------
    path, root : str or os.PathLike
        As :func:`open_own`.

    Returns
    -------
    bytes

    Raises
    ------
    FileNotFoundError
        As :func:`open_own` (:class:`NotOwnFile` one).
    """
    with os.fdopen(open_own(path, root), "rb") as fh:
        return fh.read()


def check_own(path: str | os.PathLike, root: str | os.PathLike) -> Path:
    """``path``, once :func:`open_own` has opened it (and closed it again): for a reader that
    opens the file by its path itself (h5py). Between this look and that reader's open a link
    could be swapped in only by someone who may write the data folder.

    Parameters
    ----------
    path, root : str or os.PathLike
        As :func:`open_own`.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    FileNotFoundError
        As :func:`open_own` (:class:`NotOwnFile` one).
    """
    os.close(open_own(path, root))
    return Path(path)


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


#: Starlette's own answers to a ``Range`` it cannot serve (plain text: "Malformed range header.",
#: or an empty 416), and the reason the API's ``{"detail"}`` gives instead
_RANGE_REFUSALS = {
    400: "the Range header does not parse as RFC 9110 byte ranges (bytes=FIRST-LAST, bytes=FIRST-, "
         "bytes=-SUFFIX, comma-separated)",
    416: "the Range header asks for no byte inside the file (its size is in Content-Range: bytes */SIZE)",
}


def _range_refusals_as_json(send: Send, scope: Scope) -> Send:
    """``send`` with Starlette's plain-text refusals of a ``Range`` header (the only 400 and 416 a
    ``FileResponse`` makes) answered as every other refusal of the API is: ``{"detail": reason}``
    in JSON, the 416's ``Content-Range: bytes */SIZE`` kept (RFC 9110 §15.5.17)."""
    refused = False

    async def wrapped(message: Any) -> None:
        nonlocal refused
        if message["type"] == "http.response.start" and message["status"] in _RANGE_REFUSALS:
            refused = True  # Starlette's own body follows: not sent
            body = json.dumps({"detail": _RANGE_REFUSALS[message["status"]]}).encode()
            keep = [(k, v) for k, v in message.get("headers", []) if k.lower() == b"content-range"]
            head_only = scope.get("method", "GET").upper() == "HEAD"
            await send({"type": "http.response.start", "status": message["status"],
                        "headers": [(b"content-type", b"application/json"),
                                    (b"content-length", str(len(body)).encode()), *keep]})
            await send({"type": "http.response.body", "body": b"" if head_only else body})
        elif not refused:
            await send(message)

    return wrapped


class HeldFileResponse(FileResponse):
    """A ``FileResponse`` (``Range`` included) of the server's own file at ``path`` as it is now.

    Parameters
    ----------
    path : str or os.PathLike
        The file; opened here (:func:`open_own`: no symbolic link below ``root``).
    gone : str
        The 404's reason when there is no file at ``path`` any more (deleted meanwhile).
    root : str or os.PathLike
        The data folder ``path`` is in.
    **kwargs
        ``FileResponse``'s (``media_type``, ``filename``, ``headers``, ...).

    Raises
    ------
    fastapi.HTTPException
        404 with ``gone`` when the file is not there (or is not a regular file); 404 "no such
        file" for a path the server does not serve (:class:`NotOwnFile`, logged once).
    """

    #: bytes read and sent at a time: each read runs in a worker thread of the event loop, so
    #: Starlette's 64 KiB made a 72 MiB result 1150 thread round trips (0.41-0.92 s to a client
    #: on the same machine; docs/performance.md, "One reconstruction through every door")
    chunk_size = 1 << 20

    def __init__(self, path: str | os.PathLike, *, gone: str, root: str | os.PathLike, **kwargs: Any) -> None:
        try:
            self._held = os.fdopen(open_own(path, root), "rb")  # closed once the answer is sent
        except NotOwnFile:
            raise HTTPException(404, "no such file") from None
        except FileNotFoundError:
            raise HTTPException(404, gone) from None
        stat_result = os.fstat(self._held.fileno())
        super().__init__(Path(path), stat_result=stat_result, **kwargs)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        extensions = {k: v for k, v in (scope.get("extensions") or {}).items() if k != "http.response.pathsend"}
        try:  # never a send of the path: the bytes are those of the file held
            await super().__call__({**scope, "extensions": extensions}, receive, _range_refusals_as_json(send, scope))
        finally:
            self._held.close()

    @asynccontextmanager
    async def _open_file(self) -> AsyncIterator[anyio.AsyncFile[bytes]]:
        assert self.stat_result is not None
        yield anyio.wrap_file(_Bounded(self._held, self.stat_result.st_size))  # type: ignore[arg-type]
