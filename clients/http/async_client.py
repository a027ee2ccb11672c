"""The asyncio client of the fpscan HTTP API (``docs/api.md``): :class:`AsyncClient`.

:class:`AsyncClient` is the asyncio mixins of every endpoint group (:mod:`clients.http.endpoints`)
over one ``httpx.AsyncClient``: the same endpoints, requests and answers as the blocking
:class:`clients.http.client.Client`, as coroutines; waiting on a job follows the same rules
(:mod:`clients.http.waiting`).
"""
from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncGenerator, Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

import httpx

from .calls import Call, Download, Request, field_of, to_dict
from .endpoints.datasets import AsyncDatasets
from .endpoints.jobs import AsyncJobs
from .endpoints.plans import AsyncPlans
from .endpoints.reconstructions import AsyncReconstructions
from .endpoints.scans import AsyncScans
from .endpoints.server import AsyncServer
from .errors import ApiError, ServerUnavailable, WaitTimeout
from .transport import Connection, Resume, raise_for
from .waiting import (
    TERMINAL_STATES,
    ProgressCallback,
    finish,
    keep_sse,
    parse_event,
    past,
    progress_of,
    read_timeout,
    report_snapshot,
)

__all__ = ["AsyncClient"]

T = TypeVar("T")


class AsyncClient(Connection, AsyncServer, AsyncPlans, AsyncScans, AsyncDatasets, AsyncReconstructions,
                  AsyncJobs):
    """``asyncio`` client with the same methods as :class:`Client`.

    All endpoint methods are coroutines; :meth:`events` is an async iterator; ``wait``'s
    ``on_progress`` may be a plain function or a coroutine function. Use ``async with`` or
    ``await aclose()``.

    Parameters
    ----------
    base_url, token, timeout
        As :class:`Client`.

    Attributes
    ----------
    base_url : str
    token : str or None
    timeout : float
        s.

    Raises
    ------
    ValueError
        A URL that is not http(s).

    Examples
    --------
    >>> import asyncio
    >>> from clients.http import AsyncClient, ServerUnavailable
    >>> async def health(url):
    ...     async with AsyncClient(url, token="", timeout=2) as api:
    ...         try:
    ...             return await api.health()
    ...         except ServerUnavailable as exc:
    ...             return exc.base_url
    >>> asyncio.run(health("http://127.0.0.1:9"))  # nothing listens on port 9
    'http://127.0.0.1:9'
    >>> AsyncClient("ftp://host").base_url
    Traceback (most recent call last):
    ...
    ValueError: server URL must start with http:// or https://, not 'ftp://host'
    """

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0) -> None:
        super().__init__(base_url, token=token, timeout=timeout)
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, headers=self.headers())

    async def aclose(self) -> None:
        """Close the client's connections (leaving an ``async with`` block does it)."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    # -- transport: every endpoint method ends here
    async def _call(self, call: Call[T] | Download[T]) -> T:
        if isinstance(call, Download):
            return call.finish(*(await self._download(call.request, call.dest)))
        return call.read(await self._send(call.request))

    async def _send(self, req: Request) -> httpx.Response:
        try:
            if req.upload is None:
                r = await self._http.request(req.method, req.path, json=req.json, params=req.params,
                                             headers=req.headers, data=req.form)
            else:
                with open(req.upload, "rb") as fh:  # streamed from the file, not read into memory
                    r = await self._http.request(req.method, req.path, params=req.params, headers=req.headers,
                                                 data=req.form,
                                                 files={"file": (req.upload.name, fh, "application/octet-stream")})
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None
        raise_for(r)
        return r

    async def _download(self, req: Request, dest: Path) -> tuple[Path, str]:
        dest.parent.mkdir(parents=True, exist_ok=True)
        state = Resume(dest)
        for _attempt in range(2):
            try:
                async with self._http.stream(req.method, req.path, params=req.params,
                                             headers=state.headers()) as r:
                    if r.status_code == 416:  # what we hold no longer fits: start over
                        state.discard()
                        continue
                    if r.status_code >= 400:
                        await r.aread()
                        raise_for(r)
                    content_type = r.headers.get("content-type", "")
                    with state.open(r) as fh:
                        async for chunk in r.aiter_bytes(1 << 20):
                            fh.write(chunk)
                return state.done(), content_type
            except httpx.TransportError as exc:  # keep the part: the next call resumes it
                raise self.unavailable(exc) from None
            except BaseException:
                state.discard()
                raise
        raise ApiError(416, "the server refused every byte range of the download")

    # -- events and waiting
    async def events(self, job_id: str, *, last_event_id: str | None = None,
                     read_timeout: float = 30.0) -> AsyncGenerator[tuple[str, dict, str | None], None]:
        """Async iterator of ``(event, data, id)``; see :meth:`Client.events`.

        Parameters
        ----------
        job_id, last_event_id, read_timeout
            As :meth:`Client.events`.

        Yields
        ------
        tuple of (str, dict, str or None)

        Raises
        ------
        ApiError, ServerUnavailable
            As :meth:`Client.events`.
        """
        from httpx_sse import aconnect_sse

        headers = {"Last-Event-ID": last_event_id} if last_event_id else {}
        timeout = httpx.Timeout(self.timeout, read=read_timeout)
        try:
            async with aconnect_sse(self._http, "GET", f"/api/jobs/{job_id}/events",
                                    headers=headers, timeout=timeout) as source:
                if source.response.status_code >= 400:
                    await source.response.aread()
                    raise_for(source.response)
                async for sse in source.aiter_sse():
                    if not sse.data:  # a keep-alive comment: no event (SSE spec; httpx_sse hands it on)
                        continue
                    event, data = parse_event(sse.event, sse.data)
                    yield event, data, sse.id or None
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None

    async def _follow_events(self, job_id: str, last_id: str | None, deadline: float | None,
                             report: Callable[[dict], Awaitable[None]]) -> tuple[int, str | None, bool]:
        """See :meth:`Client._follow_events` (``report`` is awaited)."""
        n_events = 0
        stream = self.events(job_id, last_event_id=last_id, read_timeout=read_timeout(deadline))
        try:
            async for event, data, eid in stream:
                n_events += 1
                last_id = eid or last_id
                if event == "progress":
                    await report(progress_of(data))
                if data.get("state") in TERMINAL_STATES or past(deadline):
                    break
        except ServerUnavailable:
            pass  # dropped or idle stream: the caller's get_job tells which
        except ApiError as exc:
            if exc.status_code == 404:
                await self.get_job(job_id)  # NotFound propagates for an unknown job
            return n_events, last_id, keep_sse(exc)
        except Exception:  # a malformed stream: poll instead
            return n_events, last_id, False
        finally:
            await stream.aclose()
        return n_events, last_id, True

    async def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
                   timeout: float | None = None, poll_interval: float = 0.5,
                   raise_on_failure: bool = True) -> Any:
        """Await the end of a job; see :meth:`Client.wait` (same behaviour and errors).

        Parameters
        ----------
        job_id, timeout, poll_interval, raise_on_failure
            As :meth:`Client.wait`.
        on_progress : callable, optional
            A plain function or a coroutine function, called with each progress dict.

        Returns
        -------
        Job or dict

        Raises
        ------
        JobFailed, JobCancelled, WaitTimeout, ApiError, ServerUnavailable
            As :meth:`Client.wait`.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        last_id: str | None = None
        use_sse = True

        async def report(progress: dict) -> None:
            if on_progress is not None:
                res = on_progress(progress)
                if asyncio.iscoroutine(res):
                    await res

        job = await self.get_job(job_id)
        while True:
            if report_snapshot(job, use_sse):
                await report(to_dict(field_of(job, "progress")))
            if field_of(job, "state") in TERMINAL_STATES:
                return finish(job) if raise_on_failure else job
            if deadline is not None and time.monotonic() > deadline:
                raise WaitTimeout(f"job {job_id} still {field_of(job, 'state')} after {timeout} s")
            if use_sse:
                n_events, last_id, use_sse = await self._follow_events(job_id, last_id, deadline, report)
                if n_events == 0:
                    await asyncio.sleep(poll_interval)
            else:
                await asyncio.sleep(poll_interval)
            job = await self.get_job(job_id)
