"""The blocking client of the fpscan HTTP API (``docs/api.md``): :class:`Client`.

:class:`Client` is every endpoint group's class (:mod:`fpscan.clients.http.endpoints`: each endpoint
declared once, made a blocking method here by :class:`~fpscan.clients.http.calls.SyncCaller`) over
one ``httpx.Client``: :meth:`Client._call` sends a :class:`~fpscan.clients.http.calls.Call` or saves
a :class:`~fpscan.clients.http.calls.Download`.
Waiting on jobs (:meth:`Client.events`, :meth:`Client.wait`) listens to the Server-Sent Events
stream ``/api/jobs/{id}/events`` (reconnecting with ``Last-Event-ID``; falling back to polling
when the stream is unavailable) and reports progress through a callback
(:mod:`fpscan.clients.http.waiting`). :class:`fpscan.clients.http.async_client.AsyncClient` is the same over
``asyncio``.

Every method's return type is precise: responses are parsed into the client's lenient pydantic
models (``fpscan.clients.http.models``: ``Job``, ``Plan``, ``Health``, ``MethodInfo``, ...; an
answer that does not fit is kept unvalidated as the same model; their fields read like a
dict's too), a few into plain ``dict`` s typed as ``TypedDict`` s (``AuthInfo``, ``Deleted``,
...), downloads return their ``pathlib.Path``.

Errors: :class:`~fpscan.clients.http.errors.ServerUnavailable` when the server cannot be reached,
:class:`~fpscan.clients.http.errors.ApiError` (and its subclasses ``AuthError``, ``NotFound``,
``Conflict``) carrying the server's ``detail`` for every 4xx/5xx,
:class:`~fpscan.clients.http.errors.JobFailed` / ``JobCancelled`` / ``WaitTimeout`` from
:meth:`Client.wait`.

Example::

    from fpscan.clients.http import Client
    with Client("http://127.0.0.1:8000", token="s3cret") as api:
        plan = api.create_plan({...})
        job = api.start_scan(plan_id, "sim")
        api.wait(job_id, on_progress=print)
        api.download_scan(job_id, "scan.h5")
"""
from __future__ import annotations

import math
import time
from collections.abc import Generator
from typing import TypeVar

import httpx

from fpscan.clients.http.calls import Call, Download, Request, SyncCaller
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
from fpscan.clients.http.transport import Connection, bound_reads, bounded_head, raise_for
from fpscan.clients.http.waiting import ProgressCallback, StreamGuard

__all__ = ["Client"]

T = TypeVar("T")


class Client(SyncCaller, Connection, Server, Plans, Scans, Datasets, Reconstructions, Jobs):
    """Blocking client of the fpscan HTTP API (``docs/api.md``).

    Every endpoint is a method (the same on :class:`AsyncClient`, there as coroutines):
    health and auth (``health``, ``auth``); plans (``create_plan``, ``preview_plan``,
    ``mask_kinds``, ``list_plans``, ``get_plan``, ``get_plan_json``,
    ``download_plan_preview``, ``delete_plan``); scanners and scans (``scanners``,
    ``start_scan``, ``pause_scan``, ``resume_scan``, ``abort_scan``, ``download_scan``,
    ``scan_preview``, ``download_scan_preview``); datasets and
    reconstructions (``upload_dataset``, ``dataset_formats``, ``formats``, ``methods``,
    ``start_reconstruction``, ``start_unmix``, ``download_volume``, ``download_mip``,
    ``download_slice``, ``download_unmix``, ``download_so2``, ``list_datasets``,
    ``delete_dataset``); jobs (``list_jobs``, ``get_job``, ``cancel_job``, ``delete_job``,
    ``events``, ``wait``, ``export``: a job's file in any export format of ``formats``, e.g.
    ``"ipasc"``, ``"ome-tiff"``, ``"ome-zarr"``); ``retention``.
    Downloads go to ``<dest>.part`` and are renamed into place when complete; one cut off
    by a network failure resumes on the next call.

    Parameters
    ----------
    base_url : str, optional
        ``http://`` or ``https://`` URL of the server; default ``$FPSCAN_SERVER`` or
        ``http://127.0.0.1:8000``.
    token : str, optional
        Bearer token; default ``$FPSCAN_TOKEN`` (``""``: send none).
    timeout : float, optional
        Seconds per request (default 30).

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
        A URL that is not http(s).

    Examples
    --------
    Creating a client opens no connection:

    >>> from fpscan.clients.http import Client, ServerUnavailable
    >>> api = Client("http://127.0.0.1:8000/", token="s3cret")
    >>> api.base_url, api.token
    ('http://127.0.0.1:8000', 's3cret')
    >>> api.close()
    >>> Client("127.0.0.1:8000")
    Traceback (most recent call last):
    ...
    ValueError: server URL must start with http:// or https://, not '127.0.0.1:8000'

    A server that cannot be reached is a ``ServerUnavailable`` (port 9 on loopback: nothing
    listens there):

    >>> with Client("http://127.0.0.1:9", token="", timeout=2) as api:
    ...     api.health()
    Traceback (most recent call last):
    ...
    fpscan.clients.http.errors.ServerUnavailable: cannot reach fpscan server at http://127.0.0.1:9: ...

    A session against a running server (``fpscan serve``; needs one, so not run here):

    >>> with Client("http://127.0.0.1:8000", token="s3cret") as api:  # doctest: +SKIP
    ...     plan = api.create_plan({"lattice": {"n_x": 41, "n_y": 41, "pitch": 1e-4},
    ...                             "mask": {"kind": "equisteradian", "params": {"depth": 2e-3, "n_points": 50}}})
    ...     scan = api.start_scan(plan.id, "sim")
    ...     api.wait(scan, on_progress=print)
    ...     recon = api.start_reconstruction(scan_job_id=scan, method="nedner")
    ...     api.wait(recon)
    ...     api.download_volume(recon, "p0.h5")
    """

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0) -> None:
        super().__init__(base_url, token=token, timeout=timeout)
        self._http = bound_reads(httpx.Client(base_url=self.base_url, timeout=self.timeout, headers=self.headers()))

    def close(self) -> None:
        """Close the client's connections (leaving a ``with`` block does it)."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the I/O of the flows (fpscan.clients.http.core): every endpoint method ends here
    def _call(self, call: Call[T] | Download[T]) -> T:
        return self._run(call_flow(call, self.base_url))

    def _run(self, flow: Flow[T]) -> T:
        """Run ``flow``'s steps (:mod:`fpscan.clients.http.core`) with blocking I/O; its result."""
        run = Driver(flow)
        for step in run:
            try:
                run.answer = self._do(step)
            except BaseException as exc:  # the flow decides (ServerUnavailable, resume, poll)
                run.error = exc
        return run.result

    def _do(self, step: Step) -> httpx.Response | None:
        if isinstance(step, Send):
            with request_args(step.request) as args, bounded_head(self._http.stream(**args), self.timeout) as r:
                return self._bounded(r, step.request)
        if isinstance(step, Stream):
            req = step.request
            with bounded_head(self._http.stream(req.method, req.path, params=req.params, headers=step.headers),
                              self.timeout) as r:
                if not step.saves(r):  # a 4xx/5xx: its detail for the flow
                    return self._bounded(r, req)
                check = BodyCheck(self.base_url, req, self.timeout, cap=math.inf, keep=False)
                with step.open(r) as fh:
                    for chunk in r.iter_bytes():
                        check.add(chunk)  # a trickle is dropped (the part kept: resumable)
                        fh.write(chunk)
                return r
        if isinstance(step, Follow):
            stream = self._stream(step.job_id, step.last_id, step.read_timeout, step.deadline)
            try:
                for event in stream:
                    report, stop = step.seen(*event)
                    if report is not None:
                        self._do(report)
                    if stop:
                        break
            finally:
                stream.close()
            return None
        if isinstance(step, Sleep):
            time.sleep(step.seconds)
            return None
        step.call()
        return None

    def _bounded(self, r: httpx.Response, req: Request) -> httpx.Response:
        """``r``'s body read within :meth:`~fpscan.clients.http.core.BodyCheck.answer`'s bounds."""
        check = BodyCheck.answer(self.base_url, req, self.timeout, r.status_code)
        for chunk in r.iter_bytes():
            if check.add(chunk):
                break
        return check.response(r)

    # -- events and waiting
    def events(self, job_id: str, *, last_event_id: str | None = None,
               read_timeout: float = 30.0) -> Generator[tuple[str, dict, str | None], None, None]:
        """Iterate over the events of a job's Server-Sent Events stream.

        ``GET /api/jobs/{job_id}/events`` until the server closes the stream (after the job's
        final state).

        Parameters
        ----------
        job_id : str
        last_event_id : str, optional
            Resume after this event (``Last-Event-ID``).
        read_timeout : float, optional
            s without a byte before the stream counts as dropped (the server sends a keep-alive
            comment after 15 s without an event, ``FPSCAN_EVENTS_KEEPALIVE_S``; comments are not
            yielded).

        Yields
        ------
        tuple of (str, dict, str or None)
            ``(event, data, id)``: the event name (``progress``, ``state``), its decoded JSON
            payload and its id.

        Raises
        ------
        ApiError
            E.g. :class:`NotFound` for an unknown job.
        ServerUnavailable
            The server cannot be reached.
        ValueError
            The stream sent more than ``fpscan.clients.http.waiting.MAX_EVENT_BYTES`` without an
            event, or a line begun that does not end within ``read_timeout`` (a line that never
            ends: no fpscan server's).
        """
        yield from self._stream(job_id, last_event_id, read_timeout)

    def _stream(self, job_id: str, last_event_id: str | None, read_timeout: float,
                deadline: float | None = None) -> Generator[tuple[str, dict, str | None], None, None]:
        """:meth:`events`, dropped (TimeoutError) once ``deadline`` (``time.monotonic()`` s) has
        passed, keep-alive comments counting (:class:`~fpscan.clients.http.waiting.StreamGuard`)."""
        from httpx_sse import EventSource, connect_sse

        try:
            with bounded_head(connect_sse(self._http, **events_request(job_id, last_event_id, self.timeout,
                                                                       read_timeout)), self.timeout) as source:
                if source.response.status_code >= 400:
                    source.response.read()
                    raise_for(source.response)
                guard = StreamGuard(source.response, deadline, read_timeout)
                for sse in EventSource(guard).iter_sse():  # type: ignore[arg-type]
                    guard.event()
                    if (event := sse_event(sse)) is not None:
                        yield event
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None

    def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
             timeout: float | None = None, poll_interval: float = 0.5, raise_on_failure: bool = True,
             quiet: bool = False) -> Job:
        """Block until a job ends; return its final Job.

        Listens to the SSE stream (reconnecting with ``Last-Event-ID`` when it drops), calling
        ``on_progress(progress: dict)`` for every progress update in the order the job made them
        (keys ``fraction, stage, points_done, points_total, rate_per_s, eta_s``), the last one
        with the job's final progress; falls back to polling ``GET /api/jobs/{id}`` every
        ``poll_interval`` s when the stream is not available.

        In a Jupyter notebook, without ``on_progress`` and unless ``quiet``, the cell's output
        shows one progress bar, updated in place and ending on the job's final state
        (``succeeded``, ``failed: why``, ``cancelled``; :mod:`fpscan.clients.http.notebook`).
        Elsewhere nothing is shown.

        Parameters
        ----------
        job_id : str
        on_progress : callable, optional
            ``on_progress(progress: dict)``; given, no notebook bar.
        timeout : float, optional
            s; None: no limit.
        poll_interval : float, optional
            s between polls (default 0.5).
        raise_on_failure : bool, optional
            Raise for a job that failed or was cancelled (default True); False returns it.
        quiet : bool, optional
            True: no notebook bar (default False).

        Returns
        -------
        Job
            The job's final record.

        Raises
        ------
        JobFailed, JobCancelled
            The job ended so (unless ``raise_on_failure`` is False).
        WaitTimeout
            ``timeout`` passed first.
        ApiError, ServerUnavailable
            As every endpoint.
        """
        return self._run(wait_flow(job_id, self.base_url, on_progress=on_progress, timeout=timeout,
                                   poll_interval=poll_interval, raise_on_failure=raise_on_failure, quiet=quiet))
