"""The asyncio client of the fpscan HTTP API (``docs/api.md``): :class:`AsyncClient`.

:class:`AsyncClient` is every endpoint group's class (:mod:`fpscan.clients.http.endpoints`: each endpoint
declared once, made a coroutine method here by :class:`~fpscan.clients.http.calls.AsyncCaller`) over
one ``httpx.AsyncClient``: the same endpoints, requests, answers and return types as the blocking
:class:`fpscan.clients.http.client.Client`, as coroutines; waiting on a job follows the same rules
(:mod:`fpscan.clients.http.waiting`).
"""
from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncGenerator
from typing import TypeVar

import httpx

from fpscan.clients.http.calls import AsyncCaller, Call, Download, Request
from fpscan.clients.http.core import (
    BodyCheck,
    Driver,
    Flow,
    Follow,
    Send,
    Sleep,
    Step,
    Stream,
    call_flow,
    events_request,
    request_args,
    sse_event,
    wait_flow,
)
from fpscan.clients.http.endpoints.datasets import Datasets
from fpscan.clients.http.endpoints.jobs import Jobs
from fpscan.clients.http.endpoints.plans import Plans
from fpscan.clients.http.endpoints.reconstructions import Reconstructions
from fpscan.clients.http.endpoints.scans import Scans
from fpscan.clients.http.endpoints.server import Server
from fpscan.clients.http.models import Job
from fpscan.clients.http.transport import Connection, async_bounded_head, bound_reads, raise_for
from fpscan.clients.http.waiting import ProgressCallback, StreamGuard

__all__ = ["AsyncClient"]

T = TypeVar("T")


class AsyncClient(AsyncCaller, Connection, Server, Plans, Scans, Datasets, Reconstructions, Jobs):
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
    >>> from fpscan.clients.http import AsyncClient, ServerUnavailable
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
        self._http = bound_reads(httpx.AsyncClient(base_url=self.base_url, timeout=self.timeout,
                                                   headers=self.headers()))

    async def aclose(self) -> None:
        """Close the client's connections (leaving an ``async with`` block does it)."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    # -- the I/O of the flows (fpscan.clients.http.core): every endpoint method ends here
    async def _call(self, call: Call[T] | Download[T]) -> T:
        return await self._run(call_flow(call, self.base_url))

    async def _run(self, flow: Flow[T]) -> T:
        """Run ``flow``'s steps (:mod:`fpscan.clients.http.core`) with ``asyncio`` I/O; its result."""
        run = Driver(flow)
        for step in run:
            try:
                run.answer = await self._do(step)
            except BaseException as exc:  # the flow decides (ServerUnavailable, resume, poll)
                run.error = exc
        return run.result

    async def _do(self, step: Step) -> httpx.Response | None:
        if isinstance(step, Send):
            with request_args(step.request) as args:
                async with async_bounded_head(self._http.stream(**args), self.timeout) as r:
                    return await self._bounded(r, step.request)
        if isinstance(step, Stream):
            req = step.request
            async with async_bounded_head(self._http.stream(req.method, req.path, params=req.params,
                                                            headers=step.headers), self.timeout) as r:
                if not step.saves(r):  # a 4xx/5xx: its detail for the flow
                    return await self._bounded(r, req)
                check = BodyCheck(self.base_url, req, self.timeout, cap=math.inf, keep=False)
                with step.open(r) as fh:
                    async for chunk in r.aiter_bytes():
                        check.add(chunk)  # a trickle is dropped (the part kept: resumable)
                        fh.write(chunk)
                return r
        if isinstance(step, Follow):
            stream = self._stream(step.job_id, step.last_id, step.read_timeout, step.deadline)
            try:
                async for event in stream:
                    report, stop = step.seen(*event)
                    if report is not None:
                        await self._do(report)
                    if stop:
                        break
            finally:
                await stream.aclose()
            return None
        if isinstance(step, Sleep):
            await asyncio.sleep(step.seconds)
            return None
        res = step.call()
        if asyncio.iscoroutine(res):  # a coroutine function's on_progress
            await res
        return None

    async def _bounded(self, r: httpx.Response, req: Request) -> httpx.Response:
        """``r``'s body read within :meth:`~fpscan.clients.http.core.BodyCheck.answer`'s bounds."""
        check = BodyCheck.answer(self.base_url, req, self.timeout, r.status_code)
        async for chunk in r.aiter_bytes():
            if check.add(chunk):
                break
        return check.response(r)

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
        ApiError, ServerUnavailable, ValueError
            As :meth:`Client.events`.
        """
        async for event in self._stream(job_id, last_event_id, read_timeout):
            yield event

    async def _stream(self, job_id: str, last_event_id: str | None, read_timeout: float,
                      deadline: float | None = None) -> AsyncGenerator[tuple[str, dict, str | None], None]:
        """:meth:`events`, dropped once ``deadline`` has passed (:meth:`Client._stream`)."""
        from httpx_sse import EventSource, aconnect_sse

        try:
            async with async_bounded_head(aconnect_sse(self._http, **events_request(job_id, last_event_id, self.timeout,
                                                                                    read_timeout)),
                                          self.timeout) as source:
                if source.response.status_code >= 400:
                    await source.response.aread()
                    raise_for(source.response)
                guard = StreamGuard(source.response, deadline, read_timeout)
                async for sse in EventSource(guard).aiter_sse():  # type: ignore[arg-type]
                    guard.event()
                    if (event := sse_event(sse)) is not None:
                        yield event
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None

    async def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
                   timeout: float | None = None, poll_interval: float = 0.5,
                   raise_on_failure: bool = True, quiet: bool = False) -> Job:
        """Await the end of a job; see :meth:`Client.wait` (same behaviour and errors; in a
        Jupyter notebook, without ``on_progress`` and unless ``quiet``, one progress bar in the
        cell's output, ending on the job's final state).

        Parameters
        ----------
        job_id, timeout, poll_interval, raise_on_failure, quiet
            As :meth:`Client.wait`.
        on_progress : callable, optional
            A plain function or a coroutine function, called with each progress dict; given,
            no notebook bar.

        Returns
        -------
        Job

        Raises
        ------
        JobFailed, JobCancelled, WaitTimeout, ApiError, ServerUnavailable
            As :meth:`Client.wait`.
        """
        return await self._run(wait_flow(job_id, self.base_url, on_progress=on_progress, timeout=timeout,
                                         poll_interval=poll_interval, raise_on_failure=raise_on_failure, quiet=quiet))
