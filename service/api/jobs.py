"""Job routes: list, get, Server-Sent Events progress (``Last-Event-ID``), cancel."""
from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Iterator
from urllib.parse import urlencode

import anyio
from fastapi import APIRouter, Depends, Header, HTTPException, Path, Query, Response
from sse_starlette.sse import EventSourceResponse, ServerSentEvent

from fpscan.service.api.context import Context, ctx, read_access, require_token
from fpscan.service.api.models import ID_PATTERN, Deleted, Job, JobKind, JobState
from fpscan.service.jobs import lifecycle
from fpscan.service.jobs.store import TERMINAL, JobStore

__all__ = [
    "router", "JobId", "job_links", "job_view", "get_job_or_404", "list_jobs", "get_job", "cancel_job",
    "delete_job", "job_events", "last_event_seq", "EventWakeups", "POLL_S", "STREAM_READERS", "EVENTS_PAGE", "LAST_EVENT_MAX",
]

router = APIRouter(prefix="/api/jobs", tags=["jobs"])

JobId = Path(pattern=ID_PATTERN, description="job id")

#: how often an events stream looks at the store when no listener wakes it (an app run
#: without its lifespan, as in some tests), s
POLL_S = 0.2
#: threads the events streams' store reads may take at once
STREAM_READERS = 2


class EventWakeups:
    """The one store watcher every events stream waits on: it wakes a job's streams as soon
    as the job store commits an event of that job, or deletes the job
    (:meth:`fpscan.service.jobs.store.JobStore.add_listener`); streams never poll, so a thousand
    open ones cost nothing between events, and a client waiting on a job hears that it
    finished when it does.

    :meth:`notify` may be called from any thread; :meth:`watch` runs in the loop's thread.

    Parameters
    ----------
    loop : asyncio.AbstractEventLoop
        The server's event loop.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self._loop = loop
        self._waiting: dict[str, set[asyncio.Event]] = {}
        #: the streams' store reads share these few threads: a thousand streams opening at
        #: once queue here, not in front of the routes' threads and the store's lock
        self.reads = anyio.CapacityLimiter(STREAM_READERS)

    def notify(self, job_id: str) -> None:
        """A committed event of ``job_id`` (any thread): wake its streams."""
        if job_id not in self._waiting:  # no stream on it (one starting now reads the store after)
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: the server is stopping
            self._loop.call_soon_threadsafe(self._wake, job_id)

    def _wake(self, job_id: str) -> None:
        for event in self._waiting.get(job_id, ()):
            event.set()

    @contextlib.contextmanager
    def watch(self, job_id: str) -> Iterator[asyncio.Event]:
        """An ``asyncio.Event`` set at every committed event of ``job_id`` while the block
        runs (in the loop's thread); clear it before reading the store, wait on it after."""
        event = asyncio.Event()
        self._waiting.setdefault(job_id, set()).add(event)
        try:
            yield event
        finally:
            waiting = self._waiting.get(job_id)
            if waiting is not None:
                waiting.discard(event)
                if not waiting:
                    del self._waiting[job_id]


def job_links(job: dict) -> dict[str, str]:
    """Links of a job's resources.

    Parameters
    ----------
    job : dict
        The stored job (``id``, ``kind``, ``state``, ``params``).

    Returns
    -------
    dict of str to str
        Name -> API path: ``self``, ``events``, ``cancel``, ``delete``; a scan's ``file``,
        ``preview``, ``pause``, ``resume``, ``abort``; a succeeded reconstruction's
        ``volume``, ``slice`` and ``mip_<plane>``; and for both the job's file in every export
        format as ``export_<format>`` (``GET /api/jobs/{id}/export/{format}``).
    """
    jid = job["id"]
    links = {"self": f"/api/jobs/{jid}", "events": f"/api/jobs/{jid}/events", "cancel": f"/api/jobs/{jid}/cancel",
             "delete": f"/api/jobs/{jid}"}
    source = None
    if job["kind"] == "scan":
        links.update({"file": f"/api/scans/{jid}/file", "preview": f"/api/scans/{jid}/preview",
                      "pause": f"/api/scans/{jid}/pause", "resume": f"/api/scans/{jid}/resume",
                      "abort": f"/api/scans/{jid}/abort"})
        source = "fpscan"
    elif job["state"] == "succeeded":
        planes = job["params"].get("result", {}).get("planes", ["xy", "xz", "yz"])
        links["volume"] = f"/api/reconstructions/{jid}/volume.h5"
        links["slice"] = f"/api/reconstructions/{jid}/slice.png"
        for plane in planes:
            links[f"mip_{plane}"] = f"/api/reconstructions/{jid}/mip/{plane}.png"
        source = "result"
    if source is not None:  # every export format of the job's file (fpscan.service.formats: GET /api/formats)
        from fpscan.service.formats import export_formats

        for name in export_formats(source):
            links[f"export_{name}"] = f"/api/jobs/{jid}/export/{name}"
    return links


def job_view(job: dict) -> Job:
    """The public view of a stored job.

    No file system paths; parameters as stored (a reconstruction's ``params`` are its method's
    own options; a job an earlier release stored with ``c`` reads as ``sound_speed``:
    :func:`fpscan.service.names.current_names`).

    Parameters
    ----------
    job : dict
        The stored job.

    Returns
    -------
    Job
        The API's model, with its timings (``queued_s``, ``run_s``: differences of the store's
        monotonic time, ``fpscan.service.jobs.store.clock``, never of wall times) and links
        (:func:`job_links`).
    """
    # no file system path, nor the submitting client's address (it caps the client's queue), nor the
    # request's digest (how a repeat with its Idempotency-Key is known)
    params = {k: v for k, v in job["params"].items() if k not in ("input", "scan_path", "client", "request_digest")}
    created, started, finished = job["created"], job["started"], job["finished"]
    # durations from the store's monotonic time (immune to the wall clock's steps); an attempt
    # cut off by an earlier release has its wall times alone, clamped at 0
    earlier = [{**a, "run_s": a["run_s"] if a.get("run_s") is not None else
                (max(0.0, a["ended"] - a["started"]) if a.get("started") else None)}
               for a in job.get("earlier_attempts") or []]
    c_mono, s_mono, f_mono = job.get("created_mono"), job.get("started_mono"), job.get("finished_mono")
    timings = {"created": created, "started": started, "finished": finished,
               "queued_s": max(0.0, s_mono - c_mono) if (s_mono is not None and c_mono is not None) else None,
               "run_s": max(0.0, f_mono - s_mono) if (f_mono is not None and s_mono is not None) else None,
               "earlier_attempts": earlier}
    return Job(id=job["id"], kind=job["kind"], state=job["state"], progress=job["progress"], timings=timings,
               params=params, links=job_links(job), attempts=job["attempts"], error=job["error"])


def get_job_or_404(context: Context, job_id: str, kind: str | None = None) -> dict:
    """The stored job ``job_id`` (of ``kind`` if given).

    Parameters
    ----------
    context : Context
        The app's context.
    job_id : str
        The job.
    kind : str or None, optional
        ``"scan"`` or ``"recon"``; default None: any.

    Returns
    -------
    dict
        The stored job.

    Raises
    ------
    fastapi.HTTPException
        404 when there is no such job (of that kind).
    """
    job = context.store.get(job_id)
    if job is None or (kind is not None and job["kind"] != kind):
        raise HTTPException(404, f"no {kind or ''} job {job_id}".replace("  ", " "))
    return job


@router.get("", response_model=list[Job], dependencies=[Depends(read_access)],
            responses={404: {"description": "``before`` names no job (deleted since the page that ended at it)"}})
def list_jobs(response: Response, context: Context = Depends(ctx), state: JobState | None = Query(None),
              kind: JobKind | None = Query(None), limit: int = Query(200, ge=1, le=1000),
              before: str | None = Query(None, pattern=ID_PATTERN, description="a job's id: only the jobs submitted "
                                         "before it (the next page of a listing that ended at it)"),
              scan_job_id: str | None = Query(None, pattern=ID_PATTERN,
                                              description="only the reconstructions of this scan job")) -> list[Job]:
    """Jobs, newest first (in the order they were submitted, whatever the wall clock did),
    optionally filtered by state, kind and the scan a reconstruction reads, at most ``limit``.
    A page that is not the last says where the next begins: a ``Link`` header (RFC 8288) with
    ``rel="next"``, the same query with ``before`` = its last job's id."""
    if before is not None and context.store.get(before) is None:
        raise HTTPException(404, f"no job {before} to list the jobs before (deleted since?): list from the newest")
    jobs = context.store.list(state=state, kind=kind, limit=limit + 1, before=before, scan_job_id=scan_job_id)
    if len(jobs) > limit:
        jobs = jobs[:limit]
        query = {k: v for k, v in (("state", state), ("kind", kind), ("scan_job_id", scan_job_id)) if v}
        response.headers["Link"] = (f'</api/jobs?{urlencode({**query, "limit": limit, "before": jobs[-1]["id"]})}>; '
                                    'rel="next"')
    return [job_view(j) for j in jobs]


@router.get("/{job_id}", response_model=Job, dependencies=[Depends(read_access)])
async def get_job(job_id: str = JobId, context: Context = Depends(ctx)) -> Response:
    """One job: state, progress, timings, parameters, links, error."""
    job = context.store.peek(job_id)  # in-memory fast path; the database in a worker thread
    if job is None:
        job = await anyio.to_thread.run_sync(context.store.get, job_id)
    if job is None:
        raise HTTPException(404, f"no job {job_id}")
    # serialised once here (the model already validates it): the hot polling path
    return Response(job_view(job).model_dump_json(), media_type="application/json")


@router.post("/{job_id}/cancel", response_model=Job, dependencies=[Depends(require_token)])
def cancel_job(job_id: str = JobId, context: Context = Depends(ctx)) -> Job:
    """Cooperative cancel: a queued or paused job ends at once; a running one at its next
    check (a scan after the current A-line, a reconstruction when its step returns)."""
    job = get_job_or_404(context, job_id)
    if job["state"] in TERMINAL:
        raise HTTPException(409, f"job {job_id} already {job['state']}")
    context.store.request_cancel(job_id)
    if job["kind"] == "scan" and context.scans is not None:
        context.scans.cancel(job_id)
    return job_view(get_job_or_404(context, job_id))


@router.delete("/{job_id}", response_model=Deleted, dependencies=[Depends(require_token)],
               responses={409: {"description": "the job is active, or an active job reads its scan"}})
def delete_job(job_id: str = JobId, context: Context = Depends(ctx)) -> Deleted:
    """Delete a finished job with its files (a scan's scan file and IPASC export, a
    reconstruction's volume and pictures) and its events. 409 while the job is queued,
    running or paused (cancel it first) or while an active reconstruction reads this
    scan."""
    try:
        return Deleted(**lifecycle.delete_job(context.store, context.settings.data_dir, job_id))
    except lifecycle.NotFound as exc:
        raise HTTPException(404, str(exc)) from None
    except lifecycle.InUse as exc:
        raise HTTPException(409, str(exc)) from None


@router.get("/{job_id}/events", dependencies=[Depends(read_access)],
            responses={200: {"content": {"text/event-stream": {}},
                             "description": "SSE stream: `event: state|progress`, `id:` sequence, JSON data"}})
async def job_events(job_id: str = JobId, context: Context = Depends(ctx),
                     last_event_id: str | None = Header(None, alias="Last-Event-ID")) -> EventSourceResponse:
    """Server-Sent Events of the job's state changes and progress. Every event has an
    increasing ``id``; reconnecting with ``Last-Event-ID: n`` replays the events after n (an
    id that is not one of ours, :func:`last_event_seq`, replays them all). A keep-alive
    comment comes after ``events_keepalive_s`` (15 s) without an event; the stream lasts as
    long as the job and ends after its final state."""
    job = await anyio.to_thread.run_sync(context.store.get, job_id)
    if job is None:
        raise HTTPException(404, f"no job {job_id}")
    after = last_event_seq(last_event_id)

    async def stream() -> AsyncIterator[ServerSentEvent]:
        # woken by the store's one listener (EventWakeups) at each committed event of this
        # job, never by a clock; a client gone cancels it (the response's disconnect watch)
        nonlocal after
        wakeups = context.wakeups
        with wakeups.watch(job_id) if wakeups is not None else contextlib.nullcontext(asyncio.Event()) as woken:
            while True:
                woken.clear()  # an event committed from here on wakes the wait below
                events, state = await anyio.to_thread.run_sync(_events_and_state, context.store, job_id, after,
                                                               limiter=getattr(wakeups, "reads", None))
                for ev in events:
                    after = ev["seq"]
                    yield ServerSentEvent(data=ev["data"], event=ev["event"], id=str(ev["seq"]))
                if state is None or state in TERMINAL:
                    if len(events) < EVENTS_PAGE:  # every event up to the final state is sent
                        return
                    continue
                if len(events) < EVENTS_PAGE:
                    if wakeups is None:  # no listener (an app without its lifespan): look again soon
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(woken.wait(), POLL_S)
                    else:
                        await woken.wait()

    return EventSourceResponse(stream(), ping=context.settings.events_keepalive_s)


#: events read from the store at once for a stream
EVENTS_PAGE = 500


def _events_and_state(store: JobStore, job_id: str, after: int) -> tuple[list[dict], str | None]:
    """The job's state, then its events after ``after`` (so a final state read here has its
    event among them); state None: the job is gone."""
    job = store.get(job_id)
    return store.events_after(job_id, after, EVENTS_PAGE), (None if job is None else job["state"])


#: the largest event id a stream resumes after (SQLite's INTEGER range)
LAST_EVENT_MAX = 2**63 - 1


def last_event_seq(header: str | None) -> int:
    """The event sequence number a ``Last-Event-ID`` header resumes after.

    The SSE specification makes the id an opaque string; ours are decimal integers from 1. An
    id that is not one (absent, empty, letters, a sign, beyond SQLite's 64-bit range) resumes
    from the beginning: the client gets every event, never an error.

    Parameters
    ----------
    header : str or None
        The header's value.

    Returns
    -------
    int
        The sequence number, in ``[0, 2**63 - 1]``; 0 (from the beginning) for any other text.

    Examples
    --------
    >>> last_event_seq("12"), last_event_seq("99999999999999999999999999"), last_event_seq("abc")
    (12, 0, 0)
    """
    text = (header or "").strip()
    if not text or len(text) > 19 or not (text.isascii() and text.isdigit()):
        return 0
    value = int(text)
    return value if value <= LAST_EVENT_MAX else 0
