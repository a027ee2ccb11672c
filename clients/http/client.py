"""The blocking client of the fpscan HTTP API (``docs/api.md``): :class:`Client`.

:class:`Client` is the blocking mixins of every endpoint group (:mod:`clients.http.endpoints`:
each endpoint a request builder and a thin method) over one ``httpx.Client``: :meth:`Client._call`
sends a :class:`~clients.http.calls.Call` or saves a :class:`~clients.http.calls.Download`.
Waiting on jobs (:meth:`Client.events`, :meth:`Client.wait`) listens to the Server-Sent Events
stream ``/api/jobs/{id}/events`` (reconnecting with ``Last-Event-ID``; falling back to polling
when the stream is unavailable) and reports progress through a callback
(:mod:`clients.http.waiting`). :class:`clients.http.async_client.AsyncClient` is the same over
``asyncio``.

Responses are parsed into the client's lenient pydantic models (``clients.http.models``) when
they fit, else returned as plain ``dict``.

Errors: :class:`~clients.http.errors.ServerUnavailable` when the server cannot be reached,
:class:`~clients.http.errors.ApiError` (and its subclasses ``AuthError``, ``NotFound``,
``Conflict``) carrying the server's ``detail`` for every 4xx/5xx,
:class:`~clients.http.errors.JobFailed` / ``JobCancelled`` / ``WaitTimeout`` from
:meth:`Client.wait`.

Example::

    from clients.http import Client
    with Client("http://127.0.0.1:8000", token="s3cret") as api:
        plan = api.create_plan({...})
        job = api.start_scan(plan_id, "sim")
        api.wait(job_id, on_progress=print)
        api.download_scan(job_id, "scan.h5")
"""
from __future__ import annotations

import time
from collections.abc import Generator
from pathlib import Path
from typing import Any, TypeVar

import httpx

from .calls import Call, Download, Request, field_of, to_dict
from .endpoints.datasets import Datasets
from .endpoints.jobs import Jobs
from .endpoints.plans import Plans
from .endpoints.reconstructions import Reconstructions
from .endpoints.scans import Scans
from .endpoints.server import Server
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

__all__ = ["Client"]

T = TypeVar("T")


class Client(Connection, Server, Plans, Scans, Datasets, Reconstructions, Jobs):
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

    >>> from clients.http import Client, ServerUnavailable
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
    clients.http.errors.ServerUnavailable: cannot reach fpscan server at http://127.0.0.1:9: ...

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
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, headers=self.headers())

    def close(self) -> None:
        """Close the client's connections (leaving a ``with`` block does it)."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- transport: every endpoint method ends here
    def _call(self, call: Call[T] | Download[T]) -> T:
        if isinstance(call, Download):
            return call.finish(*(self._download(call.request, call.dest)))
        return call.read(self._send(call.request))

    def _send(self, req: Request) -> httpx.Response:
        try:
            if req.upload is None:
                r = self._http.request(req.method, req.path, json=req.json, params=req.params,
                                       headers=req.headers, data=req.form)
            else:
                with open(req.upload, "rb") as fh:  # streamed from the file, not read into memory
                    r = self._http.request(req.method, req.path, params=req.params, headers=req.headers,
                                           data=req.form,
                                           files={"file": (req.upload.name, fh, "application/octet-stream")})
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None
        raise_for(r)
        return r

    def _download(self, req: Request, dest: Path) -> tuple[Path, str]:
        dest.parent.mkdir(parents=True, exist_ok=True)
        state = Resume(dest)
        for _attempt in range(2):
            try:
                with self._http.stream(req.method, req.path, params=req.params, headers=state.headers()) as r:
                    if r.status_code == 416:  # what we hold no longer fits: start over
                        state.discard()
                        continue
                    if r.status_code >= 400:
                        r.read()
                        raise_for(r)
                    content_type = r.headers.get("content-type", "")
                    with state.open(r) as fh:
                        for chunk in r.iter_bytes(1 << 20):
                            fh.write(chunk)
                return state.done(), content_type
            except httpx.TransportError as exc:  # keep the part: the next call resumes it
                raise self.unavailable(exc) from None
            except BaseException:
                state.discard()
                raise
        raise ApiError(416, "the server refused every byte range of the download")

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
        """
        from httpx_sse import connect_sse

        headers = {"Last-Event-ID": last_event_id} if last_event_id else {}
        timeout = httpx.Timeout(self.timeout, read=read_timeout)
        try:
            with connect_sse(self._http, "GET", f"/api/jobs/{job_id}/events",
                             headers=headers, timeout=timeout) as source:
                if source.response.status_code >= 400:
                    source.response.read()
                    raise_for(source.response)
                for sse in source.iter_sse():
                    if not sse.data:  # a keep-alive comment: no event (SSE spec; httpx_sse hands it on)
                        continue
                    event, data = parse_event(sse.event, sse.data)
                    yield event, data, sse.id or None
        except httpx.TransportError as exc:
            raise self.unavailable(exc) from None

    def _follow_events(self, job_id: str, last_id: str | None, deadline: float | None,
                       on_progress: ProgressCallback | None) -> tuple[int, str | None, bool]:
        """Read the job's event stream until it ends, drops, the job ends or the deadline
        passes; returns ``(events read, last event id, whether to keep using SSE)``."""
        n_events = 0
        stream = self.events(job_id, last_event_id=last_id, read_timeout=read_timeout(deadline))
        try:
            for event, data, eid in stream:
                n_events += 1
                last_id = eid or last_id
                if event == "progress" and on_progress is not None:
                    on_progress(progress_of(data))
                if data.get("state") in TERMINAL_STATES or past(deadline):
                    break
        except ServerUnavailable:
            pass  # dropped or idle stream: the caller's get_job tells which
        except ApiError as exc:
            if exc.status_code == 404:
                self.get_job(job_id)  # NotFound propagates for an unknown job
            return n_events, last_id, keep_sse(exc)
        except Exception:  # a malformed stream: poll instead
            return n_events, last_id, False
        finally:
            stream.close()
        return n_events, last_id, True

    def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
             timeout: float | None = None, poll_interval: float = 0.5, raise_on_failure: bool = True) -> Any:
        """Block until a job ends; return its final Job.

        Listens to the SSE stream (reconnecting with ``Last-Event-ID`` when it drops), calling
        ``on_progress(progress: dict)`` for every progress update in the order the job made them
        (keys ``fraction, stage, points_done, points_total, rate_per_s, eta_s``), the last one
        with the job's final progress; falls back to polling ``GET /api/jobs/{id}`` every
        ``poll_interval`` s when the stream is not available.

        Parameters
        ----------
        job_id : str
        on_progress : callable, optional
            ``on_progress(progress: dict)``.
        timeout : float, optional
            s; None: no limit.
        poll_interval : float, optional
            s between polls (default 0.5).
        raise_on_failure : bool, optional
            Raise for a job that failed or was cancelled (default True); False returns it.

        Returns
        -------
        Job or dict
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
        deadline = None if timeout is None else time.monotonic() + timeout
        last_id: str | None = None
        use_sse = True
        job = self.get_job(job_id)
        while True:
            if on_progress is not None and report_snapshot(job, use_sse):
                on_progress(to_dict(field_of(job, "progress")))
            if field_of(job, "state") in TERMINAL_STATES:
                return finish(job) if raise_on_failure else job
            if deadline is not None and time.monotonic() > deadline:
                raise WaitTimeout(f"job {job_id} still {field_of(job, 'state')} after {timeout} s")
            if use_sse:
                n_events, last_id, use_sse = self._follow_events(job_id, last_id, deadline, on_progress)
                if n_events == 0:
                    time.sleep(poll_interval)
            else:
                time.sleep(poll_interval)
            job = self.get_job(job_id)
