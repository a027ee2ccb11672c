"""What both clients share on the wire: the connection settings, the error of a 4xx/5xx
answer, resumable downloads and the OME-Zarr zip's unpacking.

:class:`fpscan.clients.http.client.Client` and :class:`fpscan.clients.http.async_client.AsyncClient` send with
``httpx`` (blocking or ``asyncio``) what :mod:`fpscan.clients.http.core`'s flows ask for; everything
here is the same for both. Downloads go to
``<dest>.part`` and are renamed into place when complete; one cut off by a network failure
resumes where it stopped on the next call (HTTP ``Range`` with ``If-Range``, RFC 9110
§14.2 / §13.1.5, so a changed file is fetched whole).

An answer's head (status line and headers) must arrive whole within the client's timeout of its
first wait for it (:func:`head_within`, :func:`bound_reads`): httpx's timeout bounds each read, so
a server that sent a byte of its head now and then held a call for ever (httpx has no timeout
of a whole request: encode/httpx#1450). The body's bounds are
:class:`fpscan.clients.http.core.BodyCheck`'s; a wait's event stream ends its reads by the
wait's deadline (:func:`reads_until`).
"""
from __future__ import annotations

import math
import os
import shutil
import ssl
import time
import uuid
import warnings
import zipfile
from collections.abc import AsyncIterator, Iterable, Iterator
from contextlib import (
    AbstractAsyncContextManager,
    AbstractContextManager,
    AsyncExitStack,
    ExitStack,
    asynccontextmanager,
    contextmanager,
)
from contextvars import ContextVar
from pathlib import Path
from typing import IO, Any, TypeVar

import httpcore
import httpx

from fpscan.clients.http.errors import ServerUnavailable, error_for_status

__all__ = ["Connection", "raise_for", "head_within", "reads_until", "bounded_head", "async_bounded_head", "bound_reads",
           "Resume", "RangeMismatch", "MAX_ZIP_RATIO", "unzip_folder"]

R = TypeVar("R")


class Connection:
    """The settings of a client: server URL, bearer token, timeout.

    Parameters
    ----------
    base_url : str, optional
        ``http://`` or ``https://`` URL of the server; default ``$FPSCAN_SERVER`` or
        ``http://127.0.0.1:8000``.
    token : str, optional
        Bearer token; default ``$FPSCAN_TOKEN`` (``""``: send none).
    timeout : float, optional
        Seconds per request (default 30): each read waits at most this long, and an answer's
        head (status line and headers) arrives whole within it of the request's sending
        (:func:`head_within`); past it a body must average
        :data:`fpscan.clients.http.core.MIN_BODY_RATE` bytes/s.

    Attributes
    ----------
    base_url : str
        Without a trailing slash.
    token : str or None
    timeout : float
        s.

    Raises
    ------
    ValueError
        A URL that is not http(s); a timeout that is not a finite number > 0.

    Examples
    --------
    >>> from fpscan.clients.http.transport import Connection
    >>> c = Connection("http://127.0.0.1:8000/", token="s3cret")
    >>> c.base_url, c.headers()["Authorization"]
    ('http://127.0.0.1:8000', 'Bearer s3cret')
    >>> Connection("http://127.0.0.1:8000", timeout=None)
    Traceback (most recent call last):
    ...
    ValueError: a client's timeout is a finite number of seconds > 0, not None
    """

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0) -> None:
        base_url = base_url or os.environ.get("FPSCAN_SERVER") or "http://127.0.0.1:8000"
        if not base_url.startswith(("http://", "https://")):
            raise ValueError(f"server URL must start with http:// or https://, not {base_url!r}")
        try:  # a number (numpy's too), not a flag or a text
            seconds = math.nan if isinstance(timeout, (bool, str, bytes)) else float(timeout)
        except (TypeError, ValueError):
            seconds = math.nan
        if not 0 < seconds < math.inf:
            raise ValueError(f"a client's timeout is a finite number of seconds > 0, not {timeout!r}")
        self.base_url = base_url.rstrip("/")
        self.token = token if token is not None else os.environ.get("FPSCAN_TOKEN") or None
        self.timeout = seconds

    def headers(self) -> dict[str, str]:
        """The headers of every request: ``Accept`` and, with a token, ``Authorization``.

        Returns
        -------
        dict
        """
        h = {"Accept": "application/json"}
        if self.token:
            h["Authorization"] = f"Bearer {self.token}"
        return h

    def unavailable(self, exc: Exception) -> ServerUnavailable:
        """The :class:`ServerUnavailable` of a transport failure ``exc``.

        Parameters
        ----------
        exc : Exception

        Returns
        -------
        ServerUnavailable
        """
        return ServerUnavailable(self.base_url, str(exc) or type(exc).__name__)


class _ReadBound:
    """The time the reads inside a block may take: until ``deadline`` (``time.monotonic()`` s), or
    ``seconds`` from the first read; ``reason`` is the ReadTimeout's past it."""

    def __init__(self, reason: str, *, seconds: float = math.inf, deadline: float | None = None) -> None:
        self.reason, self.seconds, self.deadline = reason, float(seconds), deadline

    def left(self) -> float:
        """Seconds left (a relative bound's clock starts at the first call); ReadTimeout once none are."""
        now = time.monotonic()
        if self.deadline is None:
            self.deadline = now + self.seconds
        if now >= self.deadline:
            raise httpcore.ReadTimeout(self.reason)
        return self.deadline - now


#: the read bound of the current thread or asyncio task (None: each read's timeout alone)
_BOUND: ContextVar[_ReadBound | None] = ContextVar("fpscan_http_read_bound", default=None)


@contextmanager
def _bound(bound: _ReadBound) -> Iterator[None]:
    token = _BOUND.set(bound)
    try:
        yield
    finally:
        _BOUND.reset(token)


@contextmanager
def head_within(seconds: float) -> Iterator[None]:
    """Inside, every read of a :func:`bound_reads` client's connection made by
    this thread (or asyncio task) ends by ``seconds`` after the first: the time an answer's head
    may take from the moment the request is sent (an upload's time does not count). Past it the
    read raises ``httpcore.ReadTimeout`` (``httpx.ReadTimeout`` to the caller).

    Parameters
    ----------
    seconds : float
        s (> 0).

    Returns
    -------
    context manager
        The bound, set on entering and taken off on leaving.

    Raises
    ------
    ValueError
        ``seconds`` not > 0.

    Examples
    --------
    >>> from fpscan.clients.http.transport import head_within
    >>> with head_within(30.0):
    ...     pass  # client.stream(...).__enter__() here: the head within 30 s
    """
    if not seconds > 0:
        raise ValueError(f"an answer's head needs a time > 0 s, got {seconds!r}")
    with _bound(_ReadBound(f"its answer's head (status line and headers) did not arrive whole within {seconds:g} s",
                           seconds=seconds)):
        yield


@contextmanager
def reads_until(deadline: float | None, reason: str) -> Iterator[None]:
    """Inside, every read of a :func:`bound_reads` client's connection made by
    this thread (or asyncio task) ends by ``deadline``, whatever its own timeout: a wait's
    deadline on its event stream, which a keep-alive comment would otherwise outrun by up to its
    interval. Past it the read raises ``httpcore.ReadTimeout`` with ``reason``.

    Parameters
    ----------
    deadline : float or None
        ``time.monotonic()`` s (None: no bound).
    reason : str
        The ReadTimeout's message.

    Returns
    -------
    context manager
        The bound, set on entering and taken off on leaving.

    Examples
    --------
    >>> import time
    >>> from fpscan.clients.http.transport import reads_until
    >>> with reads_until(time.monotonic() + 5.0, "the wait's deadline passed"):
    ...     pass  # next(response.iter_text()) here: back by the deadline
    """
    if deadline is None:
        yield
        return
    with _bound(_ReadBound(reason, deadline=deadline)):
        yield


@contextmanager
def bounded_head(answer: AbstractContextManager[R], seconds: float) -> Iterator[R]:
    """``with answer as r`` with the head of ``answer`` (an ``httpx.Client.stream(...)`` or
    ``httpx_sse.connect_sse(...)``) within ``seconds`` (:func:`head_within`); the body is read
    outside that bound.

    Parameters
    ----------
    answer : context manager
        Entering it sends the request and reads the answer's head.
    seconds : float
        s (> 0).

    Returns
    -------
    context manager
        Entered, what entering ``answer`` gives (an ``httpx.Response``, an ``httpx_sse.EventSource``).

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.transport import bounded_head
    >>> http = httpx.Client(transport=httpx.MockTransport(lambda request: httpx.Response(200, json=[])))
    >>> with bounded_head(http.stream("GET", "http://h/api/jobs"), 30.0) as r:
    ...     r.status_code, r.read()
    (200, b'[]')
    >>> http.close()
    """
    with ExitStack() as stack:
        with head_within(seconds):
            r = stack.enter_context(answer)
        yield r


@asynccontextmanager
async def async_bounded_head(answer: AbstractAsyncContextManager[R], seconds: float) -> AsyncIterator[R]:
    """:func:`bounded_head` for an ``httpx.AsyncClient``'s answer (``async with``).

    Parameters
    ----------
    answer : async context manager
        Entering it sends the request and reads the answer's head.
    seconds : float
        s (> 0).

    Returns
    -------
    async context manager
        Entered, what entering ``answer`` gives.

    Examples
    --------
    >>> import asyncio, httpx
    >>> from fpscan.clients.http.transport import async_bounded_head
    >>> async def jobs():
    ...     async with httpx.AsyncClient(transport=httpx.MockTransport(lambda request: httpx.Response(200))) as http:
    ...         async with async_bounded_head(http.stream("GET", "http://h/api/jobs"), 30.0) as r:
    ...             return r.status_code
    >>> asyncio.run(jobs())
    200
    """
    async with AsyncExitStack() as stack:
        with head_within(seconds):
            r = await stack.enter_async_context(answer)
        yield r


def _read_timeout(timeout: float | None) -> tuple[float | None, _ReadBound | None]:
    """A read's timeout under the read bound, and the bound where it is the shorter."""
    bound = _BOUND.get()
    if bound is None:
        return timeout, None
    left = bound.left()
    return (timeout, None) if timeout is not None and timeout <= left else (left, bound)


class _BoundedStream(httpcore.NetworkStream):
    """A connection whose reads keep to the read bound (:func:`head_within`, :func:`reads_until`)."""

    def __init__(self, inner: httpcore.NetworkStream) -> None:
        self._inner = inner

    def read(self, max_bytes: int, timeout: float | None = None) -> bytes:
        timeout, bound = _read_timeout(timeout)
        try:
            return self._inner.read(max_bytes, timeout)
        except httpcore.ReadTimeout:
            if bound is None:
                raise
            raise httpcore.ReadTimeout(bound.reason) from None

    def write(self, buffer: bytes, timeout: float | None = None) -> None:
        self._inner.write(buffer, timeout)

    def close(self) -> None:
        self._inner.close()

    def start_tls(self, ssl_context: ssl.SSLContext, server_hostname: str | None = None,
                  timeout: float | None = None) -> httpcore.NetworkStream:
        return _BoundedStream(self._inner.start_tls(ssl_context, server_hostname, timeout))

    def get_extra_info(self, info: str) -> Any:
        return self._inner.get_extra_info(info)


class _AsyncBoundedStream(httpcore.AsyncNetworkStream):
    """:class:`_BoundedStream` for asyncio."""

    def __init__(self, inner: httpcore.AsyncNetworkStream) -> None:
        self._inner = inner

    async def read(self, max_bytes: int, timeout: float | None = None) -> bytes:
        timeout, bound = _read_timeout(timeout)
        try:
            return await self._inner.read(max_bytes, timeout)
        except httpcore.ReadTimeout:
            if bound is None:
                raise
            raise httpcore.ReadTimeout(bound.reason) from None

    async def write(self, buffer: bytes, timeout: float | None = None) -> None:
        await self._inner.write(buffer, timeout)

    async def aclose(self) -> None:
        await self._inner.aclose()

    async def start_tls(self, ssl_context: ssl.SSLContext, server_hostname: str | None = None,
                        timeout: float | None = None) -> httpcore.AsyncNetworkStream:
        return _AsyncBoundedStream(await self._inner.start_tls(ssl_context, server_hostname, timeout))

    def get_extra_info(self, info: str) -> Any:
        return self._inner.get_extra_info(info)


class _BoundedBackend(httpcore.NetworkBackend):
    """httpcore's network backend, its connections :class:`_BoundedStream`."""

    def __init__(self, inner: httpcore.NetworkBackend) -> None:
        self._inner = inner

    def connect_tcp(self, host: str, port: int, timeout: float | None = None, local_address: str | None = None,
                    socket_options: Iterable[Any] | None = None) -> httpcore.NetworkStream:
        return _BoundedStream(self._inner.connect_tcp(host, port, timeout, local_address, socket_options))

    def connect_unix_socket(self, path: str, timeout: float | None = None,
                            socket_options: Iterable[Any] | None = None) -> httpcore.NetworkStream:
        return _BoundedStream(self._inner.connect_unix_socket(path, timeout, socket_options))

    def sleep(self, seconds: float) -> None:
        self._inner.sleep(seconds)


class _AsyncBoundedBackend(httpcore.AsyncNetworkBackend):
    """:class:`_BoundedBackend` for asyncio."""

    def __init__(self, inner: httpcore.AsyncNetworkBackend) -> None:
        self._inner = inner

    async def connect_tcp(self, host: str, port: int, timeout: float | None = None,
                          local_address: str | None = None,
                          socket_options: Iterable[Any] | None = None) -> httpcore.AsyncNetworkStream:
        return _AsyncBoundedStream(await self._inner.connect_tcp(host, port, timeout, local_address, socket_options))

    async def connect_unix_socket(self, path: str, timeout: float | None = None,
                                  socket_options: Iterable[Any] | None = None) -> httpcore.AsyncNetworkStream:
        return _AsyncBoundedStream(await self._inner.connect_unix_socket(path, timeout, socket_options))

    async def sleep(self, seconds: float) -> None:
        await self._inner.sleep(seconds)


def _wrap_backend(made: object, wrapper: type) -> None:
    """Put ``made``'s connection pool on ``wrapper`` around its network backend. httpx takes no
    backend of its own (encode/httpx#1450: a whole-request timeout belongs in httpcore), so this
    reaches the pool httpx made (httpx 0.27-0.28, httpcore 1.x); where another version names
    them otherwise it warns and leaves the transport as it is (each read then bound by its timeout only)."""
    pool = getattr(made, "_pool", None)
    backend = getattr(pool, "_network_backend", None)
    if backend is None:
        warnings.warn(f"httpx {httpx.__version__} / httpcore {httpcore.__version__}: no connection pool to bound "
                      "an answer's head or a wait's deadline on; each read is still bounded by the timeout", RuntimeWarning, stacklevel=3)
        return
    if not isinstance(backend, wrapper):
        pool._network_backend = wrapper(backend)  # type: ignore[union-attr]


Http = TypeVar("Http", httpx.Client, httpx.AsyncClient)


def bound_reads(http: Http) -> Http:
    """Keep the reads of every connection ``http`` makes to the bound of :func:`head_within`
    (:func:`bounded_head`) or :func:`reads_until` where one is set.

    That is every transport httpx made for the client: its own, and one per proxy it took from the
    environment (``HTTP_PROXY``, ``HTTPS_PROXY``, ``ALL_PROXY``, less the hosts of ``NO_PROXY``).
    httpx reads those only for a client made without a ``transport=``, so the client is made as
    usual and its transports are bound afterwards. Binding a client twice changes nothing.

    Parameters
    ----------
    http : httpx.Client or httpx.AsyncClient
        A client made without ``transport=`` or ``mounts=`` of one's own (a transport that is not
        httpx's ``HTTPTransport`` / ``AsyncHTTPTransport`` is left as it is, with a
        ``RuntimeWarning``).

    Returns
    -------
    httpx.Client or httpx.AsyncClient
        ``http`` itself.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.transport import bound_reads, bounded_head
    >>> with bound_reads(httpx.Client(base_url="http://127.0.0.1:8000", timeout=30.0)) as http:
    ...     pass  # with bounded_head(http.stream("GET", "/api/health"), 30.0) as r: ...
    """
    wrapper = _AsyncBoundedBackend if isinstance(http, httpx.AsyncClient) else _BoundedBackend
    made = [getattr(http, "_transport", None), *getattr(http, "_mounts", {}).values()]
    for transport in made:
        if transport is not None:  # None: a NO_PROXY host, sent by the client's own transport
            _wrap_backend(transport, wrapper)
    return http


def _detail(response: httpx.Response) -> Any:
    try:
        body = response.json()
    except ValueError:
        text = response.text.strip()
        return text[:500] or response.reason_phrase
    if isinstance(body, dict) and "detail" in body:
        return body["detail"]
    return body


def raise_for(response: httpx.Response) -> None:
    """Raise the :class:`~fpscan.clients.http.errors.ApiError` of a 4xx/5xx answer (its subclass by
    status), carrying the server's ``detail`` verbatim; nothing for a 1xx-3xx.

    Parameters
    ----------
    response : httpx.Response
        Read (its body available).

    Raises
    ------
    ApiError
        ``AuthError`` (401/403), ``NotFound`` (404), ``Conflict`` (409) or ``ApiError``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.transport import raise_for
    >>> r = httpx.Response(404, json={"detail": "no job j1"}, request=httpx.Request("GET", "http://h/api/jobs/j1"))
    >>> raise_for(r)
    Traceback (most recent call last):
    ...
    fpscan.clients.http.errors.NotFound: HTTP 404: no job j1
    """
    if response.status_code >= 400:
        raise error_for_status(response.status_code, _detail(response), method=response.request.method,
                               url=str(response.request.url))


class RangeMismatch(ValueError):
    """A 206 whose ``Content-Range`` does not continue the partial file (another start, or no
    range): its bytes must not be appended (RFC 9110 §14.4); the download starts over.

    A ``ValueError`` raised by :meth:`Resume.open`.

    Attributes
    ----------
    args : tuple
        The message: the range the server stated and the bytes held.

    Examples
    --------
    >>> from fpscan.clients.http.transport import RangeMismatch
    >>> issubclass(RangeMismatch, ValueError)
    True
    """


class Resume:
    """Resumable download state of ``dest``: ``dest.part`` (bytes so far) and
    ``dest.part.etag`` (the validator they came with). A later download of the same
    file asks for the rest only (``Range`` + ``If-Range``, RFC 9110 §14.2/§13.1.5); the
    server answers 206 with the remainder if the file is unchanged, else 200 with all of it.

    Parameters
    ----------
    dest : pathlib.Path
        The file the download ends in.

    Attributes
    ----------
    dest, part, meta : pathlib.Path
        The file, its partial file and the partial file's validator.

    Examples
    --------
    >>> from pathlib import Path
    >>> from fpscan.clients.http.transport import Resume
    >>> r = Resume(Path("/tmp/none/scan.h5"))
    >>> r.part.name, r.headers()  # nothing held yet: ask for everything
    ('scan.h5.part', {})
    """

    def __init__(self, dest: Path) -> None:
        self.dest = dest
        self.part = dest.with_name(dest.name + ".part")
        self.meta = self.part.with_name(self.part.name + ".etag")

    def headers(self) -> dict[str, str]:
        """``Range`` and ``If-Range`` for the bytes not yet held (none when nothing is).

        Returns
        -------
        dict
        """
        if self.part.exists() and self.meta.exists() and self.part.stat().st_size > 0:
            return {"Range": f"bytes={self.part.stat().st_size}-", "If-Range": self.meta.read_text()}
        return {}

    def open(self, response: httpx.Response) -> IO[bytes]:
        """The file to write the body into: appended on 206, rewritten otherwise.

        Parameters
        ----------
        response : httpx.Response
            The answer whose body follows (its validator, ``ETag`` or ``Last-Modified``, is kept).

        Returns
        -------
        file
            Opened for binary writing.
        """
        if response.status_code == 206:
            held = self.part.stat().st_size if self.part.exists() else 0
            stated = response.headers.get("content-range", "")
            unit, _, span = stated.partition(" ")
            if unit.strip().lower() != "bytes" or span.split("-", 1)[0].strip() != str(held):
                raise RangeMismatch(f"the server's partial answer ({stated or 'no Content-Range'}) does not "
                                    f"continue the {held} bytes held")
        validator = response.headers.get("etag") or response.headers.get("last-modified")
        if validator:
            self.meta.write_text(validator)
        else:
            self.meta.unlink(missing_ok=True)
        return open(self.part, "ab" if response.status_code == 206 else "wb")

    def done(self) -> Path:
        """The complete file moved into place.

        Returns
        -------
        pathlib.Path
            ``dest``.
        """
        os.replace(self.part, self.dest)
        self.meta.unlink(missing_ok=True)
        return self.dest

    def discard(self) -> None:
        """Forget the partial file (the next download starts over)."""
        self.part.unlink(missing_ok=True)
        self.meta.unlink(missing_ok=True)


#: the most a zip may unpack to per byte of its own: an OME-Zarr export's chunks are compressed
#: already (about 1:1 in the zip, its JSON some 10:1); a zip of zeros packs 1000:1 and more
MAX_ZIP_RATIO = 100


def unzip_folder(zipped: Path, dest: Path) -> Path:
    """Unpack a zip holding one top folder (an OME-Zarr export) into the folder ``dest``
    (the top folder's name dropped), via a temporary sibling renamed into place.

    Parameters
    ----------
    zipped : pathlib.Path
        The zip file.
    dest : pathlib.Path
        The folder to make (an existing one there is replaced).

    Returns
    -------
    pathlib.Path
        ``dest``.

    Raises
    ------
    ValueError
        A zip that is not one folder, or names a path outside it; one that would unpack to more
        than :data:`MAX_ZIP_RATIO` times its size (a zip bomb), or to more than the free space
        of ``dest``'s disk (the sizes its directory declares, which bound what ``zipfile``
        unpacks).

    Examples
    --------
    >>> import tempfile, zipfile
    >>> from pathlib import Path
    >>> from fpscan.clients.http.transport import unzip_folder
    >>> tmp = Path(tempfile.mkdtemp())
    >>> with zipfile.ZipFile(tmp / "v.zip", "w") as z:
    ...     z.writestr("volume.ome.zarr/zarr.json", "{}")
    >>> sorted(p.name for p in unzip_folder(tmp / "v.zip", tmp / "out.ome.zarr").iterdir())
    ['zarr.json']
    """
    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        with zipfile.ZipFile(zipped) as z:
            names = [n for n in z.namelist() if not n.endswith("/")]
            tops = {n.split("/", 1)[0] for n in names}
            if len(tops) != 1 or any("/" not in n for n in names):
                raise ValueError(f"{zipped.name}: expected one folder in the zip, found {sorted(tops)[:5]}")
            total, packed = sum(i.file_size for i in z.infolist()), max(1, zipped.stat().st_size)
            if total > MAX_ZIP_RATIO * packed:
                raise ValueError(f"{zipped.name}: {packed} bytes that unpack to {total} ({total // packed}:1, over "
                                 f"the {MAX_ZIP_RATIO}:1 an export reaches): refused, not unpacked")
            free = shutil.disk_usage(dest.parent).free
            if total > free:
                raise ValueError(f"{zipped.name} unpacks to {total} bytes; {dest.parent} has {free} free")
            for n in names:
                rel = Path(n.split("/", 1)[1])
                if rel.is_absolute() or ".." in rel.parts:
                    raise ValueError(f"{zipped.name}: unsafe path {n!r} in the zip")
                target = tmp / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                with z.open(n) as src, open(target, "wb") as out:
                    shutil.copyfileobj(src, out)
        if dest.exists():
            shutil.rmtree(dest) if dest.is_dir() else dest.unlink()
        tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
