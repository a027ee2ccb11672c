"""The rules of waiting on a job, shared by both clients' ``events`` and ``wait``.

A wait listens to the job's Server-Sent Events stream ``/api/jobs/{id}/events``
(reconnecting with ``Last-Event-ID``), falls back to polling ``GET /api/jobs/{id}`` where the
stream is unavailable, and reports each progress update once, in the order the job made it.
"""
from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any, TypeVar

from fpscan.clients.http.calls import field_of
from fpscan.clients.http.errors import ApiError, JobCancelled, JobFailed
from fpscan.clients.http.transport import reads_until

__all__ = ["TERMINAL_STATES", "ProgressCallback", "MAX_EVENT_BYTES", "DEADLINE_PASSED", "StreamGuard", "read_timeout", "past",
           "report_snapshot", "keep_sse", "parse_event", "progress_of", "finish"]

J = TypeVar("J")

#: the states a job never leaves
TERMINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})

#: ``on_progress(progress: dict)``: keys ``fraction, stage, points_done, points_total, rate_per_s, eta_s``
ProgressCallback = Callable[[dict], Any]


#: the most bytes an event stream may send between two events (a job's events are under 1 kB): past
#: it the stream is malformed (a line or an event that never ends) and the wait polls instead
MAX_EVENT_BYTES = 1 << 20

#: why a wait's event stream was dropped at its deadline
DEADLINE_PASSED = "the wait's deadline passed while the event stream was open"


class StreamGuard:
    """What an event stream may spend: the wait's deadline and :data:`MAX_EVENT_BYTES`
    between two events. It stands in for the stream's ``httpx.Response`` before
    ``httpx_sse.EventSource`` (which reads only the response's ``headers`` and its text),
    checking both on every chunk the server sends, keep-alive comments included: a comment
    yields no event, so without it a wait's deadline went unchecked while a job was quiet
    (the server comments every 15 s), and a line that never ended grew without bound. Each
    read of the stream ends by the deadline too
    (:func:`~fpscan.clients.http.transport.reads_until`): a read waiting for the next comment
    outran it by up to the comments' interval. And a line begun must end within ``line_s`` s,
    as a read must bring a byte within its timeout: a server sending a byte of one line now and
    then held a wait without a deadline for ever.

    Parameters
    ----------
    response : httpx.Response
        The event stream's response.
    deadline : float or None
        ``time.monotonic()`` s past which the stream is dropped (None: none).
    line_s : float or None, optional
        s within which a line begun must end (the stream's read timeout; None: no bound).

    Attributes
    ----------
    response : httpx.Response
        The response it stands in for.
    headers : httpx.Headers
        The response's headers (``EventSource`` checks the content type there).
    deadline : float or None
        As given.
    pending : int
        Characters received since the last event.
    line_s : float or None
        As given.
    line_open : float or None
        When the line not yet ended began (``time.monotonic()`` s; None: every line so far ended).

    Raises
    ------
    TimeoutError
        From the text iterators, once the deadline has passed.
    httpx.ReadTimeout
        From the text iterators, a read still waiting at the deadline (its message
        :data:`DEADLINE_PASSED`).
    ValueError
        From the text iterators, when more than :data:`MAX_EVENT_BYTES` arrive without an event,
        or a line begun does not end within ``line_s``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.waiting import StreamGuard
    >>> response = httpx.Response(200, text=": keep-alive", headers={"Content-Type": "text/event-stream"})
    >>> guard = StreamGuard(response, deadline=0.0)  # a deadline long past
    >>> next(guard.iter_text())
    Traceback (most recent call last):
    ...
    TimeoutError: the wait's deadline passed while the event stream was open
    """

    def __init__(self, response: Any, deadline: float | None = None, line_s: float | None = None) -> None:
        self.response = response
        self.headers = response.headers
        self.deadline, self.line_s = deadline, line_s
        self.pending = 0
        self.line_open: float | None = None  # when the line still open began (None: none is)

    def event(self) -> None:
        """An event was decoded: the byte count starts again."""
        self.pending = 0

    def _check(self, text: str) -> None:
        if past(self.deadline):
            raise TimeoutError(DEADLINE_PASSED)
        now = time.monotonic()
        if text.endswith(("\n", "\r")):
            self.line_open = None  # every line so far ended
        elif "\n" in text or "\r" in text or self.line_open is None:
            self.line_open = now  # a line begun with this text
        elif self.line_s is not None and now - self.line_open > self.line_s:
            raise ValueError(f"the event stream sent a line that did not end in {now - self.line_open:.1f} s "
                             f"(its read timeout: {self.line_s:g} s)")
        self.pending += len(text)
        if self.pending > MAX_EVENT_BYTES:
            raise ValueError(f"the event stream sent more than {MAX_EVENT_BYTES} bytes without an event")

    def iter_text(self) -> Any:
        """The response's text, checked chunk by chunk, each read back by the deadline."""
        texts = self.response.iter_text()
        while True:
            with reads_until(self.deadline, DEADLINE_PASSED):  # set and reset inside one step of this generator
                text = next(texts, None)
            if text is None:
                return
            self._check(text)
            yield text

    async def aiter_text(self) -> Any:
        """The response's text (async), checked chunk by chunk, each read back by the deadline."""
        texts = self.response.aiter_text()
        while True:
            with reads_until(self.deadline, DEADLINE_PASSED):
                text = await anext(texts, None)
            if text is None:
                return
            self._check(text)
            yield text


def read_timeout(deadline: float | None) -> float:
    """Read timeout of one event stream, s: 20 (longer than the server's 15 s pings), less when
    the deadline (``time.monotonic()`` s) is nearer, at least 0.5.

    Parameters
    ----------
    deadline : float or None

    Returns
    -------
    float

    Examples
    --------
    >>> from fpscan.clients.http.waiting import read_timeout
    >>> read_timeout(None)
    20.0
    """
    if deadline is None:
        return 20.0
    return min(20.0, max(0.5, deadline - time.monotonic()))


def past(deadline: float | None) -> bool:
    """Whether the deadline (``time.monotonic()`` s, or None: none) has passed.

    Parameters
    ----------
    deadline : float or None

    Returns
    -------
    bool

    Examples
    --------
    >>> from fpscan.clients.http.waiting import past
    >>> past(None), past(0.0)
    (False, True)
    """
    return deadline is not None and time.monotonic() > deadline


def report_snapshot(job: Any, use_sse: bool) -> bool:
    """Whether ``wait`` reports the progress of a ``GET /api/jobs/{id}`` snapshot: when the
    job has ended (its final progress), still waits in the queue (nothing came before it)
    or progress is polled. While the event stream is followed it alone reports a running
    job's progress, in order: the stream replays the job's events from its start, so a
    snapshot reported first would show a later stage before the earlier ones
    (``writing 90%`` before ``starting 0%``).

    Parameters
    ----------
    job : Job or dict
        The snapshot.
    use_sse : bool
        Whether the event stream is followed.

    Returns
    -------
    bool

    Examples
    --------
    >>> from fpscan.clients.http.waiting import report_snapshot
    >>> running = {"state": "running", "progress": {"fraction": 0.5, "stage": "iteration 3/100"}}
    >>> report_snapshot(running, use_sse=True), report_snapshot(running, use_sse=False)
    (False, True)
    """
    progress = field_of(job, "progress")
    if progress is None:
        return False
    waiting = field_of(job, "state") == "queued" and field_of(progress, "stage") in (None, "queued")
    return not use_sse or waiting or field_of(job, "state") in TERMINAL_STATES


def keep_sse(exc: ApiError) -> bool:
    """Whether to keep reading events after ``exc``: no for a missing (404) or unsupported
    (405, 501) stream, where the caller polls instead; any other error is raised.

    Parameters
    ----------
    exc : ApiError

    Returns
    -------
    bool
        False (poll instead).

    Raises
    ------
    ApiError
        ``exc`` itself, for any other status.

    Examples
    --------
    >>> from fpscan.clients.http import ApiError
    >>> from fpscan.clients.http.waiting import keep_sse
    >>> keep_sse(ApiError(501, "no events here"))
    False
    """
    if exc.status_code in (404, 405, 501):
        return False
    raise exc


def parse_event(name: str | None, payload: str) -> tuple[str, dict]:
    """An SSE event's name (default ``message``) and its JSON payload as a dict (a payload that
    is not JSON becomes ``{"message": text}``, a JSON non-dict ``{"value": ...}``).

    Parameters
    ----------
    name : str or None
        The ``event:`` field.
    payload : str
        The ``data:`` field.

    Returns
    -------
    tuple of (str, dict)

    Examples
    --------
    >>> from fpscan.clients.http.waiting import parse_event
    >>> parse_event("progress", '{"fraction": 0.5}'), parse_event(None, "hello")
    (('progress', {'fraction': 0.5}), ('message', {'message': 'hello'}))
    """
    try:
        data = json.loads(payload) if payload else {}
    except ValueError:
        data = {"message": payload}
    if not isinstance(data, dict):
        data = {"value": data}
    return name or "message", data


def progress_of(data: dict) -> dict:
    """The progress of a ``progress`` event's payload (its ``progress`` field, or the payload).

    Parameters
    ----------
    data : dict

    Returns
    -------
    dict

    Examples
    --------
    >>> from fpscan.clients.http.waiting import progress_of
    >>> progress_of({"progress": {"fraction": 1.0}}), progress_of({"fraction": 0.2})
    ({'fraction': 1.0}, {'fraction': 0.2})
    """
    prog = data.get("progress")
    return prog if isinstance(prog, dict) else data


def finish(job: J) -> J:
    """The job of an ended wait, raised for a failed or cancelled one.

    Parameters
    ----------
    job : Job or dict
        The final record.

    Returns
    -------
    Job or dict
        ``job`` itself (succeeded).

    Raises
    ------
    JobFailed, JobCancelled
        With the job attached.

    Examples
    --------
    >>> from fpscan.clients.http.waiting import finish
    >>> finish({"id": "j1", "state": "succeeded"})["state"]
    'succeeded'
    >>> finish({"id": "j1", "state": "failed", "error": "disk full"})
    Traceback (most recent call last):
    ...
    fpscan.clients.http.errors.JobFailed: job j1 failed: disk full
    """
    state = field_of(job, "state")
    if state == "failed":
        err = field_of(job, "error") or "no reason given"
        raise JobFailed(job, f"job {field_of(job, 'id')} failed: {err}")
    if state == "cancelled":
        raise JobCancelled(job, f"job {field_of(job, 'id')} was cancelled")
    return job
