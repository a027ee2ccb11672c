"""The one client core: what sending, downloading (with its retry) and waiting on a job do,
written once, with no I/O (the model is httpx's one request model with only the
I/O differing between ``Client`` and ``AsyncClient``).

Each operation is a *flow*: a generator that yields the I/O it needs as a :data:`Step`
(:class:`Send` a request, :class:`Stream` a body into a file, :class:`Follow` a job's event
stream, :class:`Sleep`, :class:`Report` a progress update) and receives the step's answer,
or has the step's exception thrown into it; its return value is the operation's result.
:class:`Driver` steps a flow (answers in, exceptions thrown back, the result out);
:class:`fpscan.clients.http.client.Client` does each step's I/O with blocking httpx calls,
:class:`fpscan.clients.http.async_client.AsyncClient` with ``await`` s: that is all they differ in.
What the I/O decides is here too: the :class:`Stream` step's 416 and file, the
:class:`Follow` step's stop and progress :class:`Report` per event, :func:`sse_event`.

- :func:`call_flow`: an endpoint's :class:`~fpscan.clients.http.calls.Call` (one request; a
  transport failure is ``ServerUnavailable``, a 4xx/5xx its ``ApiError``) or
  :class:`~fpscan.clients.http.calls.Download` (:func:`download_flow`).
- :func:`download_flow`: a resumable download to ``<dest>.part`` (``Range`` + ``If-Range``,
  RFC 9110 §14.2 / §13.1.5: :class:`~fpscan.clients.http.transport.Resume`), renamed into place when
  complete; a 416 starts over once; a cut connection keeps the part for the next call.
- :func:`wait_flow`: a job's end, following its Server-Sent Events (reconnecting with
  ``Last-Event-ID``), polling where the stream is unavailable (:mod:`fpscan.clients.http.waiting`).
"""
from __future__ import annotations

import time
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Generic, TypeVar, cast

import httpx

from fpscan.clients.http.calls import Call, Download, Request, field_of, to_dict
from fpscan.clients.http.endpoints.jobs import Jobs
from fpscan.clients.http.errors import ApiError, BadAnswer, ServerUnavailable, WaitTimeout, error_for_status
from fpscan.clients.http.models import Job
from fpscan.clients.http.notebook import job_bar
from fpscan.clients.http.transport import RangeMismatch, Resume, raise_for
from fpscan.clients.http.waiting import (
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

if TYPE_CHECKING:
    from httpx_sse import ServerSentEvent

__all__ = ["Send", "Stream", "Follow", "Sleep", "Report", "Step", "Flow", "Driver", "call_flow", "download_flow",
           "wait_flow", "request_args", "events_request", "sse_event", "MAX_ANSWER_BYTES",
           "MAX_ERROR_BYTES", "MIN_BODY_RATE", "BodyCheck"]

T = TypeVar("T")

#: the most bytes of an answer the client reads into memory (a list of 1000 jobs is about 1 MB, a
#: plan of 100 000 points about 5 MB); a bigger one is no fpscan answer (:class:`BodyCheck`)
MAX_ANSWER_BYTES = 64 << 20
#: the most bytes of an error's answer read for its reason
MAX_ERROR_BYTES = 1 << 20
#: bytes/s an answer's body must average once the request's timeout has passed since its head
#: arrived: httpx's timeout bounds each read, so a server sending a byte now and then held a call
#: for ever (a minimum rate, as Apache's ``mod_reqtimeout`` ``MinRate``)
MIN_BODY_RATE = 1000


class BodyCheck:
    """The bounds of one answer's body as a client reads it chunk by chunk: at most ``cap``
    bytes (decoded: a gzip bomb counts what it unpacks to), and, once ``timeout`` s have passed
    since the answer's head arrived, an average of :data:`MIN_BODY_RATE` bytes/s.

    Parameters
    ----------
    base_url : str
        The server, for the errors.
    request : Request
        What was asked (its method and path name it in the errors).
    timeout : float
        The client's seconds per request.
    cap : float, optional
        Bytes (default :data:`MAX_ANSWER_BYTES`; ``math.inf`` for a download, which goes to a file).
    cut : bool, optional
        Past ``cap``, keep the first ``cap`` bytes and stop (an error's reason: its start will do)
        rather than refuse the answer (default False).
    keep : bool, optional
        Keep the chunks for :meth:`response` (default True; False for a download).

    Attributes
    ----------
    chunks : list of bytes
        What was kept.
    size : int
        Bytes read.

    Raises
    ------
    BadAnswer
        (From :meth:`add`) past ``cap``, unless ``cut``.
    ServerUnavailable
        (From :meth:`add`) under the minimum rate.

    Examples
    --------
    >>> from fpscan.clients.http.calls import Request
    >>> from fpscan.clients.http.core import BodyCheck
    >>> check = BodyCheck("http://h", Request("GET", "/api/jobs"), 30.0, cap=4)
    >>> check.add(b"[1]")
    False
    >>> check.add(b"[2]")
    Traceback (most recent call last):
    ...
    fpscan.clients.http.errors.BadAnswer: the server at http://h answered GET /api/jobs with what this client cannot read: more than 4 bytes (an answer of fpscan's is far smaller)
    """

    def __init__(self, base_url: str, request: Request, timeout: float, *, cap: float = MAX_ANSWER_BYTES,
                 cut: bool = False, keep: bool = True) -> None:
        self.base_url, self.what = base_url, f"{request.method} {request.path}"
        self.timeout, self.cap, self.cut, self.keep = timeout, cap, cut, keep
        self.chunks: list[bytes] = []
        self.size = 0
        self.start = time.monotonic()

    def add(self, chunk: bytes) -> bool:
        """Take ``chunk``, or raise past the bounds; True once ``cut`` has kept ``cap`` bytes (stop
        reading)."""
        full = self.size + len(chunk) > self.cap
        if full and self.cut:
            chunk = chunk[: int(self.cap) - self.size]
        self.size += len(chunk)
        if full and not self.cut:
            raise BadAnswer(self.base_url, self.what, f"more than {self.cap} bytes (an answer of fpscan's is far smaller)")
        late = time.monotonic() - self.start - self.timeout
        if late > 0 and self.size < MIN_BODY_RATE * late:
            raise ServerUnavailable(self.base_url, f"its answer to {self.what} came at under {MIN_BODY_RATE} bytes/s "
                                                   f"({self.size} bytes in {late + self.timeout:.0f} s)")
        if self.keep:
            self.chunks.append(chunk)
        return full

    def response(self, streamed: httpx.Response) -> httpx.Response:
        """The answer with the body read (decoded: its ``Content-Encoding`` dropped)."""
        headers = [(k, v) for k, v in streamed.headers.multi_items()
                   if k.lower() not in ("content-encoding", "content-length", "transfer-encoding")]
        return httpx.Response(streamed.status_code, headers=headers, content=b"".join(self.chunks),
                              request=streamed.request)

    @classmethod
    def answer(cls, base_url: str, request: Request, timeout: float, status_code: int) -> BodyCheck:
        """The check of an answer read into memory: an error's (``status_code`` ≥ 400) cut at
        :data:`MAX_ERROR_BYTES`, any other refused past :data:`MAX_ANSWER_BYTES`."""
        if status_code >= 400:
            return cls(base_url, request, timeout, cap=MAX_ERROR_BYTES, cut=True)
        return cls(base_url, request, timeout)


@dataclass(frozen=True)
class Send:
    """Send ``request`` (the client's ``httpx`` ``request(**args)``, :func:`request_args`);
    answer: the ``httpx.Response``, read.

    Attributes
    ----------
    request : Request
    """

    request: Request


@dataclass
class Stream:
    """Send ``request`` with ``headers`` and stream the answer: a body to save
    (:meth:`saves`) is written as it arrives into ``open(response)`` (:class:`BodyCheck`: at a minimum rate), a
    4xx/5xx (a 416 too) is read whole; answer: the ``httpx.Response`` (the flow decides:
    a 416 starts over, another 4xx/5xx is raised, :func:`download_flow`).

    Attributes
    ----------
    request : Request
    headers : dict
        ``Range`` / ``If-Range`` for what is already held.
    resume : Resume
        The partial file (``resume.open(response)`` gives the file to write).
    """

    request: Request
    headers: dict[str, str]
    resume: Resume

    def saves(self, response: httpx.Response) -> bool:
        """True for a body to save (200, or 206 for the range asked), False for any other
        answer (a redirect's or an error's body is not the file)."""
        return response.status_code in (200, 206)

    def open(self, response: httpx.Response) -> IO[bytes]:
        """The file the body goes into (appended on 206)."""
        return self.resume.open(response)


@dataclass
class Follow:
    """Read the job's event stream (the client's ``events``) from ``last_id``, counting the
    events (:meth:`seen`) and reporting each progress event, until it ends, drops, the job
    ends or the deadline passes (:meth:`seen` says stop); answer: None. Exceptions of the
    stream are thrown into the flow, which decides (:func:`wait_flow`).

    Attributes
    ----------
    job_id : str
    last_id : str or None
        The last event id seen (``Last-Event-ID`` of the next stream).
    deadline : float or None
        ``time.monotonic()`` s.
    on_progress : callable or None
        The wait's ``on_progress``.
    n_events : int
        Events read from this stream.
    """

    job_id: str
    last_id: str | None
    deadline: float | None
    on_progress: ProgressCallback | None
    n_events: int = 0

    @property
    def read_timeout(self) -> float:
        """Seconds without a byte before the stream counts as dropped (:func:`~fpscan.clients.http.waiting.read_timeout`)."""
        return read_timeout(self.deadline)

    def seen(self, event: str, data: dict, event_id: str | None) -> tuple[Report | None, bool]:
        """Count one event; returns ``(the Report step of its progress or None, whether to
        stop reading)``: the client does the report (:meth:`Report.call`) before reading on."""
        self.n_events += 1
        self.last_id = event_id or self.last_id
        report = None
        if event == "progress" and self.on_progress is not None:
            report = Report(self.on_progress, progress_of(data))
        return report, data.get("state") in TERMINAL_STATES or past(self.deadline)


@dataclass(frozen=True)
class Sleep:
    """Wait ``seconds`` (``time.sleep`` / ``asyncio.sleep``); answer: None.

    Attributes
    ----------
    seconds : float
    """

    seconds: float


@dataclass(frozen=True)
class Report:
    """Call ``on_progress(progress)`` (a coroutine function's result awaited by the async
    client); answer: None.

    Attributes
    ----------
    on_progress : callable
    progress : dict
    """

    on_progress: ProgressCallback
    progress: dict

    def call(self) -> object:
        """``on_progress(progress)``: its result (a coroutine, for a coroutine function's, which
        the async client awaits)."""
        return self.on_progress(self.progress)


#: the I/O a flow asks for
Step = Send | Stream | Follow | Sleep | Report
#: an operation: yields steps, receives their answers, returns the result
Flow = Generator[Step, Any, T]


class Driver(Generic[T]):
    """How a client runs a flow, written once: iterating gives the flow's steps; after each,
    the client sets ``answer`` (the step's result) or ``error`` (its exception, thrown into
    the flow, which decides); when the flow returns, ``result`` holds its value. A client's
    ``_run`` is this loop with its own I/O (``self._do(step)``, blocking or awaited).

    Parameters
    ----------
    flow : generator
        A :data:`Flow`.

    Attributes
    ----------
    answer : any
        The last step's answer (None until set).
    error : BaseException or None
        The last step's exception.
    result : any
        The flow's return value, once it has returned.

    Examples
    --------
    >>> from fpscan.clients.http.core import Driver, Sleep
    >>> def flow():
    ...     slept = yield Sleep(0.5)
    ...     return f"slept {slept} s"
    >>> run = Driver(flow())
    >>> for step in run:
    ...     run.answer = step.seconds  # the client's I/O would go here
    >>> run.result
    'slept 0.5 s'
    """

    def __init__(self, flow: Flow[T]) -> None:
        self.flow = flow
        self.answer: Any = None
        self.error: BaseException | None = None
        self.result: T = cast(T, None)

    def __iter__(self) -> Iterator[Step]:
        while True:
            answer, error = self.answer, self.error
            self.answer, self.error = None, None
            try:
                step = self.flow.throw(error) if error is not None else self.flow.send(answer)
            except StopIteration as done:
                self.result = done.value
                return
            yield step


@contextmanager
def request_args(req: Request) -> Iterator[dict[str, Any]]:
    """The keywords of ``httpx`` ``request(...)`` for ``req``, its upload file open (streamed
    from the file, not read into memory) while the ``with`` block runs.

    Parameters
    ----------
    req : Request

    Returns
    -------
    contextlib.AbstractContextManager of dict
        ``method``, ``url``, ``params``, ``headers``, ``data`` and ``json`` or ``files``.

    Examples
    --------
    >>> from fpscan.clients.http.calls import Request
    >>> from fpscan.clients.http.core import request_args
    >>> with request_args(Request("POST", "/api/plans", json={"a": 1})) as args:
    ...     sorted(args), args["json"]
    (['data', 'headers', 'json', 'method', 'params', 'url'], {'a': 1})
    """
    args: dict[str, Any] = {"method": req.method, "url": req.path, "params": req.params, "headers": req.headers,
                            "data": req.form}
    if req.upload is None:
        yield {**args, "json": req.json}
        return
    with open(req.upload, "rb") as fh:
        yield {**args, "files": {"file": (req.upload.name, fh, "application/octet-stream")}}


def events_request(job_id: str, last_event_id: str | None, timeout: float,
                   read_timeout: float) -> dict[str, Any]:
    """The keywords of ``httpx_sse`` ``connect_sse`` / ``aconnect_sse`` for a job's event
    stream (``GET /api/jobs/{job_id}/events``, from ``last_event_id``).

    Parameters
    ----------
    job_id : str
    last_event_id : str or None
    timeout : float
        s, per request.
    read_timeout : float
        s without a byte before the stream counts as dropped.

    Returns
    -------
    dict

    Examples
    --------
    >>> from fpscan.clients.http.core import events_request
    >>> args = events_request("j1", "7", 30.0, 20.0)
    >>> args["url"], args["headers"], args["timeout"].read
    ('/api/jobs/j1/events', {'Last-Event-ID': '7'}, 20.0)
    """
    return {"method": "GET", "url": f"/api/jobs/{job_id}/events",
            "headers": {"Last-Event-ID": last_event_id} if last_event_id else {},
            "timeout": httpx.Timeout(timeout, read=read_timeout)}


def sse_event(sse: ServerSentEvent) -> tuple[str, dict, str | None] | None:
    """What ``events`` yields for one received Server-Sent Event: ``(event, data, id)``
    (:func:`~fpscan.clients.http.waiting.parse_event`), or None for a keep-alive comment (no event,
    SSE spec; ``httpx_sse`` hands it on with an empty ``data``).

    Parameters
    ----------
    sse : httpx_sse.ServerSentEvent

    Returns
    -------
    tuple of (str, dict, str or None) or None

    Examples
    --------
    >>> from httpx_sse import ServerSentEvent
    >>> from fpscan.clients.http.core import sse_event
    >>> sse_event(ServerSentEvent("progress", '{"fraction": 0.5}', "3")), sse_event(ServerSentEvent(data=""))
    (('progress', {'fraction': 0.5}, '3'), None)
    """
    if not sse.data:
        return None
    event, data = parse_event(sse.event, sse.data)
    return event, data, sse.id or None


def call_flow(call: Call[T] | Download[T], base_url: str) -> Flow[T]:
    """An endpoint's call: one request read by ``call.read``, or a download finished by
    ``call.finish``.

    Parameters
    ----------
    call : Call or Download
    base_url : str
        The server, named by ``ServerUnavailable``.

    Returns
    -------
    generator
        The flow (module docstring); its result is the endpoint's.

    Raises
    ------
    ServerUnavailable
        The server cannot be reached.
    ApiError
        A 4xx/5xx answer (its subclass by status).
    BadAnswer
        A redirect, or a body ``call.read`` cannot read (not JSON, another shape).

    Examples
    --------
    Run with a stand-in for the network (a client sends instead):

    >>> import httpx
    >>> from fpscan.clients.http.calls import Call, Request, read_json
    >>> from fpscan.clients.http.core import call_flow
    >>> flow = call_flow(Call(Request("GET", "/api/health"), read_json), "http://h")
    >>> step = next(flow)
    >>> step.request.path
    '/api/health'
    >>> try:
    ...     flow.send(httpx.Response(200, json={"status": "ok"}, request=httpx.Request("GET", "http://h/api/health")))
    ... except StopIteration as done:
    ...     print(done.value)
    {'status': 'ok'}
    """
    if isinstance(call, Download):
        got, content_type = yield from download_flow(call.request, call.dest, base_url)
        return call.finish(got, content_type)
    response = yield from _send(call.request, base_url)
    what = f"{call.request.method} {call.request.path}"
    if response.status_code >= 300:  # a redirect, never followed: its body is no answer
        where = response.headers.get("location")
        raise BadAnswer(base_url, what, f"HTTP {response.status_code}{f' to {where}' if where else ''}")
    try:
        return call.read(response)
    except ValueError as exc:  # not JSON, or JSON of another shape than the answer's
        raise BadAnswer(base_url, what, f"{type(exc).__name__}: {exc}") from None


def _send(req: Request, base_url: str) -> Flow[httpx.Response]:
    try:
        response = yield Send(req)
    except httpx.TransportError as exc:
        raise _unavailable(base_url, exc) from None
    raise_for(response)
    return response


def _unavailable(base_url: str, exc: Exception) -> ServerUnavailable:
    return ServerUnavailable(base_url, str(exc) or type(exc).__name__)


#: the first bytes of the files the API serves, by how their route ends: an HDF5 volume, unmixing
#: or scan file, a PNG picture
_SIGNATURES = {".h5": (b"\x89HDF\r\n\x1a\n", "an HDF5 file"), "/file": (b"\x89HDF\r\n\x1a\n", "an HDF5 file"),
               ".png": (b"\x89PNG\r\n\x1a\n", "a PNG picture")}


def _check_signature(part: Path, req: Request, base_url: str, state: Resume) -> None:
    """A BadAnswer (the part discarded) when a downloaded volume, scan file or picture does not
    begin as one does: a 200 from a proxy's or a stranger's page was kept as the volume."""
    for ending, (signature, kind) in _SIGNATURES.items():
        if req.path.endswith(ending):
            with open(part, "rb") as fh:
                head = fh.read(len(signature))
            if head != signature:
                state.discard()
                raise BadAnswer(base_url, f"{req.method} {req.path}",
                                f"the download does not begin as {kind} does (it begins {head[:16]!r})")


def download_flow(req: Request, dest: Path, base_url: str) -> Flow[tuple[Path, str]]:
    """Save the body of ``req`` at ``dest`` (module docstring: resumable, renamed into place).

    Parameters
    ----------
    req : Request
    dest : pathlib.Path
        The file (its folder is made).
    base_url : str
        The server, named by ``ServerUnavailable``.

    Returns
    -------
    generator
        The flow; its result ``(dest, Content-Type)``.

    Raises
    ------
    ServerUnavailable
        The connection failed (the part is kept: the next call resumes it).
    ApiError
        A 4xx/5xx answer, or any other than 200 or 206 (a redirect: its ``Location`` named; the
        part is discarded), or 416 twice, or twice a 206 that did not continue the part.
    BadAnswer
        A volume, scan file or picture that does not begin with its HDF5 or PNG signature (the
        part is discarded).
    """
    dest.parent.mkdir(parents=True, exist_ok=True)
    state = Resume(dest)
    for _attempt in range(2):
        try:
            response = yield Stream(req, state.headers(), state)
        except httpx.TransportError as exc:  # keep the part: the next call resumes it
            raise _unavailable(base_url, exc) from None
        except ServerUnavailable:  # a body under the minimum rate (BodyCheck): keep the part too
            raise
        except RangeMismatch:  # a 206 that does not continue the part: start over
            state.discard()
            continue
        except BaseException:
            state.discard()
            raise
        if response.status_code not in (200, 206):  # a 416: what we hold no longer fits: start over
            state.discard()
            if response.status_code == 416:
                continue
            raise_for(response)
            where = response.headers.get("location")
            raise error_for_status(response.status_code, f"the server answered {response.status_code}"
                                   f"{f' (to {where})' if where else ''} instead of the file",
                                   method=response.request.method, url=str(response.request.url))
        _check_signature(state.part, req, base_url, state)
        return state.done(), response.headers.get("content-type", "")
    raise ApiError(416, "the server refused every byte range of the download, or answered another range twice")


def wait_flow(job_id: str, base_url: str, *, on_progress: ProgressCallback | None = None,
              timeout: float | None = None, poll_interval: float = 0.5,
              raise_on_failure: bool = True, quiet: bool = False) -> Flow[Job]:
    """Wait for the end of job ``job_id``: ``Client.wait`` / ``AsyncClient.wait`` (their
    docstrings say what it does; the rules are :mod:`fpscan.clients.http.waiting`'s). In a Jupyter
    kernel, without ``on_progress`` and not ``quiet``, the job's progress is one notebook bar
    (:mod:`fpscan.clients.http.notebook`) that ends on the job's final state.

    Parameters
    ----------
    job_id : str
    base_url : str
        The server, named by ``ServerUnavailable``.
    on_progress, timeout, poll_interval, raise_on_failure, quiet
        As ``Client.wait``.

    Returns
    -------
    generator
        The flow; its result the job's final record (a :class:`~fpscan.clients.http.models.Job`).

    Raises
    ------
    JobFailed, JobCancelled, WaitTimeout, ApiError, ServerUnavailable
        As ``Client.wait``.
    """
    deadline = None if timeout is None else time.monotonic() + timeout
    job = yield from call_flow(Jobs.get_job.build(job_id), base_url)
    bar = job_bar(job, on_progress=on_progress, quiet=quiet)
    if bar is None:
        return (yield from _wait(job, job_id, base_url, on_progress, deadline, timeout, poll_interval,
                                 raise_on_failure))
    final: Job | None = None
    try:
        final = yield from _wait(job, job_id, base_url, bar, deadline, timeout, poll_interval, False)
    finally:
        bar.close(final)
    return finish(final) if raise_on_failure else final


def _wait(job: Job, job_id: str, base_url: str, on_progress: ProgressCallback | None, deadline: float | None,
          timeout: float | None, poll_interval: float, raise_on_failure: bool) -> Flow[Job]:
    """:func:`wait_flow` from the job's first record ``job``."""
    last_id: str | None = None
    use_sse = True
    while True:
        if on_progress is not None and report_snapshot(job, use_sse):
            yield Report(on_progress, to_dict(field_of(job, "progress")))
        if field_of(job, "state") in TERMINAL_STATES:
            return finish(job) if raise_on_failure else job
        if deadline is not None and time.monotonic() > deadline:
            raise WaitTimeout(f"job {job_id} still {field_of(job, 'state')} after {timeout} s")
        if use_sse:
            follow = Follow(job_id, last_id, deadline, on_progress)
            use_sse = yield from _follow(follow, base_url)
            last_id = follow.last_id
            if follow.n_events == 0:
                yield Sleep(poll_interval)
        else:
            yield Sleep(poll_interval)
        job = yield from call_flow(Jobs.get_job.build(job_id), base_url)


def _follow(follow: Follow, base_url: str) -> Flow[bool]:
    """Read one event stream (:class:`Follow`); returns whether to keep using SSE."""
    try:
        yield follow
    except ServerUnavailable:
        pass  # dropped or idle stream: the caller's get_job tells which
    except ApiError as exc:
        if exc.status_code == 404:
            yield from call_flow(Jobs.get_job.build(follow.job_id), base_url)  # NotFound propagates for an unknown job
        return keep_sse(exc)
    except Exception:  # a malformed stream: poll instead
        return False
    return True
