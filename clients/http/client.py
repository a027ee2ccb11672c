"""Typed Python client for the fpscan HTTP API (``docs/api.md``), sync and async.

Both :class:`Client` and :class:`AsyncClient` offer the same methods; every endpoint is
written once as a *sans-I/O* generator (it yields request descriptions and receives the
responses), and each client drives those generators with ``httpx`` (blocking or
``asyncio``). Downloads go to ``<dest>.part`` and are renamed into place when complete;
one cut off by a network failure resumes where it stopped on the next call (HTTP
``Range`` with ``If-Range``, so a changed file is fetched whole). Waiting on jobs listens to the Server-Sent Events stream
``/api/jobs/{id}/events`` (reconnecting with ``Last-Event-ID``; falling back to polling
when the stream is unavailable) and reports progress through a callback.

Responses are parsed into the service's own pydantic models (``service.api.models``)
when the service package is installed alongside, so client and server share one
definition; otherwise (a client-only install) they are returned as plain ``dict``.

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

import asyncio
import functools
import json
import os
import time
import uuid
from collections.abc import Callable, Coroutine, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Concatenate, Generic, ParamSpec, TypeVar, overload

import httpx

from .errors import (
    ApiError,
    JobCancelled,
    JobFailed,
    ServerUnavailable,
    WaitTimeout,
    error_for_status,
)
from .models import MODELS

__all__ = [
    "TERMINAL_STATES", "MIP_PLANES", "ProgressCallback", "as_model", "field_of", "to_dict",
    "Client", "AsyncClient",
]

TERMINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})
MIP_PLANES = ("xy", "xz", "yz")

ProgressCallback = Callable[[dict], Any]


# --------------------------------------------------------------------------- helpers
def as_model(name: str, data: Any) -> Any:
    """A response parsed into ``clients.http.models.<name>`` when it fits, else returned as is.

    Parameters
    ----------
    name : str
        A model name of ``clients.http.models.MODELS`` (``"Job"``, ``"Plan"``, ...).
    data : any
        The decoded JSON response.

    Returns
    -------
    pydantic.BaseModel or any
        The model; ``data`` unchanged for an unknown name, a non-dict or a response that does
        not fit (a server newer or older than this client).

    Examples
    --------
    >>> from clients.http.client import as_model
    >>> job = as_model("Job", {"id": "j1", "kind": "scan", "state": "running", "new_field": 1})
    >>> type(job).__name__, job.state, job.new_field  # unknown fields are kept
    ('Job', 'running', 1)
    >>> as_model("Job", {"id": "j1"})  # does not fit: the raw JSON
    {'id': 'j1'}
    """
    cls = MODELS.get(name)
    if cls is None or not isinstance(data, dict):
        return data
    try:
        return cls.model_validate(data)
    except ValueError:  # the server is newer/older than this client: keep the raw data
        return data


def _read_timeout(deadline: float | None) -> float:
    """Read timeout of one event stream: 20 s (longer than the server's 15 s pings), less
    when the deadline is nearer (at least 0.5 s)."""
    if deadline is None:
        return 20.0
    return min(20.0, max(0.5, deadline - time.monotonic()))


def _past(deadline: float | None) -> bool:
    return deadline is not None and time.monotonic() > deadline


def _report_snapshot(job: Any, use_sse: bool) -> bool:
    """Whether ``wait`` reports the progress of a ``GET /api/jobs/{id}`` snapshot: when the
    job has ended (its final progress), still waits in the queue (nothing came before it)
    or progress is polled. While the event stream is followed it alone reports a running
    job's progress, in order: the stream replays the job's events from its start, so a
    snapshot reported first would show a later stage before the earlier ones
    (``writing 90%`` before ``starting 0%``)."""
    progress = field_of(job, "progress")
    if progress is None:
        return False
    waiting = field_of(job, "state") == "queued" and field_of(progress, "stage") in (None, "queued")
    return not use_sse or waiting or field_of(job, "state") in TERMINAL_STATES


def _keep_sse(exc: ApiError) -> bool:
    """Whether to keep reading events after ``exc``: no for a missing (404) or unsupported
    (405, 501) stream, where the caller polls instead; any other error is raised."""
    if exc.status_code in (404, 405, 501):
        return False
    raise exc


def field_of(obj: Any, name: str, default: Any = None) -> Any:
    """Read a field from a response model or a dict (responses are either).

    Parameters
    ----------
    obj : pydantic.BaseModel, Mapping or None
        The response.
    name : str
        The field.
    default : any, optional
        Returned when the field is missing or ``obj`` is None.

    Returns
    -------
    any

    Examples
    --------
    >>> from clients.http import field_of
    >>> from clients.http.models import Job
    >>> field_of(Job(id="j1", kind="scan", state="queued"), "state"), field_of({"state": "running"}, "state")
    ('queued', 'running')
    >>> field_of(None, "state", "unknown")
    'unknown'
    """
    if obj is None:
        return default
    if isinstance(obj, Mapping):
        return obj.get(name, default)
    return getattr(obj, name, default)


def to_dict(obj: Any) -> Any:
    """A JSON-able dict from a response model or a dict.

    Parameters
    ----------
    obj : pydantic.BaseModel or any
        A model is dumped in JSON mode; anything else is returned unchanged.

    Returns
    -------
    dict or any

    Examples
    --------
    >>> from clients.http import to_dict
    >>> from clients.http.models import Job
    >>> d = to_dict(Job(id="j1", kind="scan", state="queued"))
    >>> type(d).__name__, d["state"], d["progress"]["fraction"]
    ('dict', 'queued', 0.0)
    >>> to_dict({"a": 1})
    {'a': 1}
    """
    if hasattr(obj, "model_dump"):
        return obj.model_dump(mode="json")
    return obj


def _jsonable(body: Any) -> Any:
    return to_dict(body) if hasattr(body, "model_dump") else body


@dataclass
class _Req:
    method: str
    path: str
    json: Any = None
    params: dict | None = None
    headers: dict = field(default_factory=dict)
    files: Any = None
    data: Any = None


@dataclass
class _Download:
    req: _Req
    dest: Path


def _unzip_folder(zipped: Path, dest: Path) -> Path:
    """Unpack a zip holding one top folder (an OME-Zarr export) into the folder ``dest``
    (the top folder's name dropped), via a temporary sibling renamed into place. Raises
    ValueError for a zip that is not one folder or names a path outside it."""
    import shutil
    import uuid
    import zipfile

    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        with zipfile.ZipFile(zipped) as z:
            names = [n for n in z.namelist() if not n.endswith("/")]
            tops = {n.split("/", 1)[0] for n in names}
            if len(tops) != 1 or any("/" not in n for n in names):
                raise ValueError(f"{zipped.name}: expected one folder in the zip, found {sorted(tops)[:5]}")
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


def _detail(response: httpx.Response) -> Any:
    try:
        body = response.json()
    except ValueError:
        text = response.text.strip()
        return text[:500] or response.reason_phrase
    if isinstance(body, dict) and "detail" in body:
        return body["detail"]
    return body


def _raise_for(response: httpx.Response) -> None:
    if response.status_code >= 400:
        raise error_for_status(
            response.status_code,
            _detail(response),
            method=response.request.method,
            url=str(response.request.url),
        )


def _job_id_from(response: httpx.Response) -> str | None:
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict):
        for key in ("id", "job_id"):
            if body.get(key):
                return str(body[key])
    loc = response.headers.get("location", "")
    if "/api/jobs/" in loc:
        return loc.rstrip("/").rsplit("/", 1)[-1]
    return None


def _idem(headers: dict, key: str | None) -> dict:
    headers = dict(headers)
    headers["Idempotency-Key"] = key or uuid.uuid4().hex
    return headers


def _part_path(dest: Path) -> Path:
    return dest.with_name(dest.name + ".part")


class _Resume:
    """Resumable download state of ``dest``: ``dest.part`` (bytes so far) and
    ``dest.part.etag`` (the validator they came with). A later download of the same
    file asks for the rest only (``Range`` + ``If-Range``, RFC 9110 §14.2/§13.1.5); the
    server answers 206 with the remainder if the file is unchanged, else 200 with all of
    it."""

    def __init__(self, dest: Path):
        self.dest = dest
        self.part = _part_path(dest)
        self.meta = self.part.with_name(self.part.name + ".etag")

    def headers(self) -> dict:
        if self.part.exists() and self.meta.exists() and self.part.stat().st_size > 0:
            return {"Range": f"bytes={self.part.stat().st_size}-", "If-Range": self.meta.read_text()}
        return {}

    def open(self, response: httpx.Response):
        """The file to write the body into: appended on 206, rewritten otherwise."""
        validator = response.headers.get("etag") or response.headers.get("last-modified")
        if validator:
            self.meta.write_text(validator)
        else:
            self.meta.unlink(missing_ok=True)
        return open(self.part, "ab" if response.status_code == 206 else "wb")

    def done(self) -> Path:
        os.replace(self.part, self.dest)
        self.meta.unlink(missing_ok=True)
        return self.dest

    def discard(self) -> None:
        self.part.unlink(missing_ok=True)
        self.meta.unlink(missing_ok=True)


# --------------------------------------------------------------------------- endpoints
_P = ParamSpec("_P")
_R = TypeVar("_R")


def _sync_method(gen_fn):
    @functools.wraps(gen_fn)
    def method(self, *args, **kwargs):
        return self._drive(gen_fn(self, *args, **kwargs))
    return method


def _async_method(gen_fn):
    @functools.wraps(gen_fn)
    async def method(self, *args, **kwargs):
        return await self._drive(gen_fn(self, *args, **kwargs))
    return method


class _endpoint(Generic[_P, _R]):
    """An endpoint written once as a generator (``response = yield _Req(...)``), served as
    a blocking method on :class:`Client` and a coroutine method on :class:`AsyncClient`
    (which one is read from the class's ``_asynchronous``). The overloads of ``__get__``
    give the type checker both signatures from the one generator."""

    def __init__(self, gen_fn: Callable[Concatenate[Any, _P], Generator[Any, Any, _R]]):
        self._sync = _sync_method(gen_fn)
        self._async = _async_method(gen_fn)

    @overload
    def __get__(self, obj: None, owner: type) -> Callable[..., Any]: ...
    @overload
    def __get__(self, obj: AsyncClient, owner: type | None = None) -> Callable[_P, Coroutine[Any, Any, _R]]: ...
    @overload
    def __get__(self, obj: Client, owner: type | None = None) -> Callable[_P, _R]: ...

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        cls = owner if owner is not None else type(obj)
        fn = self._async if getattr(cls, "_asynchronous", False) else self._sync
        return fn if obj is None else fn.__get__(obj, cls)


class _Endpoints:
    """Every endpoint once, as a generator: ``response = yield _Req(...)``."""

    # -- health
    @_endpoint
    def health(self):
        """``GET /api/health``: whether the server is up.

        Returns
        -------
        dict
            ``{"status": "ok", "version": ...}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (e.g. 503 while the server starts).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/health")
        return r.json()

    @_endpoint
    def auth(self):
        """``GET /api/auth`` (needs no token): whether the server needs a token, and whether
        this client's is right.

        Returns
        -------
        dict
            ``{"token_required": bool, "authenticated": bool}``.

        Raises
        ------
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/auth")
        return r.json()

    # -- plans
    @_endpoint
    def create_plan(self, body: Mapping | Any):
        """``POST /api/plans``: create a plan from mask parameters or a point list.

        Parameters
        ----------
        body : Mapping or pydantic model
            The body of ``service.api.models`` ``PlanCreate``: ``lattice`` (``n_x``, ``n_y``,
            ``pitch`` in m), ``mask`` (``kind``, ``params`` in SI units), optional ``order`` and
            ``acquisition``; or a whole plan JSON (``fpscan-plan/1``).

        Returns
        -------
        Plan or dict
            The stored plan (201; the same request gives the same plan).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", "/api/plans", json=_jsonable(body))
        return as_model("Plan", r.json())

    @_endpoint
    def preview_plan(self, body: Mapping | Any):
        """``POST /api/plans/preview``: the mask a plan body gives, nothing saved.

        Parameters
        ----------
        body : Mapping or pydantic model
            As :meth:`create_plan`.

        Returns
        -------
        PlanPreview or dict
            ``points``, ``weight_ratio``, ``expected_scan_time_s`` (s), ``preview_png_base64``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", "/api/plans/preview", json=_jsonable(body))
        return as_model("PlanPreview", r.json())

    @_endpoint
    def mask_kinds(self):
        """``GET /api/plans/kinds``: the mask kinds and their parameters (SI units).

        Returns
        -------
        list of dict
            ``{kind, label, description, aliases, fields, params_schema}`` per kind.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/plans/kinds")
        return r.json()

    @_endpoint
    def list_plans(self):
        """``GET /api/plans``: the stored plans.

        Returns
        -------
        list of Plan or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/plans")
        body = r.json()
        items = body.get("items", body) if isinstance(body, dict) else body
        return [as_model("Plan", p) for p in items]

    @_endpoint
    def get_plan(self, plan_id: str):
        """``GET /api/plans/{plan_id}``: one plan's summary.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        Plan or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", f"/api/plans/{plan_id}")
        return as_model("Plan", r.json())

    @_endpoint
    def get_plan_json(self, plan_id: str):
        """``GET /api/plans/{plan_id}/plan.json``: the full plan, as ``fpscan scan`` reads it.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        dict
            The ``fpscan-plan/1`` JSON: lattice, mask, points in scan order, acquisition (SI units).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", f"/api/plans/{plan_id}/plan.json")
        return r.json()

    @_endpoint
    def download_plan_preview(self, plan_id: str, dest: str | os.PathLike):
        """``GET /api/plans/{plan_id}/preview.png`` (the mask picture, PNG) saved to ``dest``.

        Parameters
        ----------
        plan_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/plans/{plan_id}/preview.png"), Path(dest)))

    # -- scanners and scans
    @_endpoint
    def scanners(self):
        """``GET /api/scanners``: the configured serial devices and their status.

        Returns
        -------
        list of Scanner or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/scanners")
        body = r.json()
        items = body.get("items", body) if isinstance(body, dict) and "items" in body else body
        return [as_model("Scanner", s) for s in items] if isinstance(items, list) else items

    @_endpoint
    def start_scan(self, plan_id: str, scanner_id: str, *, idempotency_key: str | None = None,
                   **extra: Any):
        """``POST /api/scans`` ``{plan_id, scanner_id}``: start a scan job.

        Parameters
        ----------
        plan_id : str
        scanner_id : str
            A scanner of :meth:`scanners`.
        idempotency_key : str, optional
            Same key -> same job (default: a fresh random key).
        **extra
            Further body fields, e.g. ``preview_wavelength=1`` (the wavelength the live preview
            shows).

        Returns
        -------
        str
            The new scan job's id (202).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown plan or scanner).
        ServerUnavailable
            The server cannot be reached.
        """
        body = {"plan_id": plan_id, "scanner_id": scanner_id, **extra}
        r = yield _Req("POST", "/api/scans", json=body, headers=_idem({}, idempotency_key))
        return _job_id_from(r)

    @_endpoint
    def pause_scan(self, job_id: str):
        """``POST /api/scans/{job_id}/pause``: pause a running scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not running, NotFound for an unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", f"/api/scans/{job_id}/pause")
        return as_model("Job", r.json()) if r.content else None

    @_endpoint
    def resume_scan(self, job_id: str):
        """``POST /api/scans/{job_id}/resume``: resume a paused (or interrupted) scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not paused, NotFound for an unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", f"/api/scans/{job_id}/resume")
        return as_model("Job", r.json()) if r.content else None

    @_endpoint
    def abort_scan(self, job_id: str):
        """``POST /api/scans/{job_id}/abort``: stop a scan; it ends ``cancelled``.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict for a finished job, NotFound for an unknown one).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", f"/api/scans/{job_id}/abort")
        return as_model("Job", r.json()) if r.content else None

    @_endpoint
    def download_scan(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/scans/{job_id}/file`` (the scan file, HDF5) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/scans/{job_id}/file"), Path(dest)))

    @_endpoint
    def download_ipasc(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/scans/{job_id}/ipasc`` (IPASC HDF5 export) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/scans/{job_id}/ipasc"), Path(dest)))

    @_endpoint
    def scan_preview(self, job_id: str):
        """``GET /api/scans/{job_id}/preview``: the live preview's state.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        PreviewInfo or dict
            ``version``, ``points_used``, ``updated`` (UNIX s), ...

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", f"/api/scans/{job_id}/preview")
        return as_model("PreviewInfo", r.json())

    @_endpoint
    def download_scan_preview(self, job_id: str, plane: str, dest: str | os.PathLike):
        """``GET /api/scans/{job_id}/preview/{plane}.png`` (live MIP, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        plane : {"xy", "xz", "yz"}
            The MIP's plane.
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ValueError
            An unknown plane (before any request).
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        _check_plane(plane)
        return (yield _Download(_Req("GET", f"/api/scans/{job_id}/preview/{plane}.png"), Path(dest)))

    # -- datasets and reconstructions
    @_endpoint
    def upload_dataset(self, path: str | os.PathLike, format: str = "fpscan", **fields: Any):
        """``POST /api/datasets``: upload a data file for reconstruction.

        The file is streamed (multipart), not read into memory.

        Parameters
        ----------
        path : str or os.PathLike
            The file.
        format : str, optional
            One of the server's (:meth:`dataset_formats`; another is answered 422 naming them);
            default ``"fpscan"``.
        **fields
            Spacings and settings the format needs, SI units: ``dx``, ``dy`` (m), ``dt`` (s),
            ``sound_speed`` (m/s; ``c`` is its deprecated name), ...

        Returns
        -------
        str
            The dataset id (201).

        Raises
        ------
        ValueError
            A missing file (before any request).
        ApiError
            The server's reason (422 for a bad file or field).
        ServerUnavailable
            The server cannot be reached.
        """
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"no such file: {p}")
        data = {"format": format, **{k: str(v) for k, v in fields.items() if v is not None}}
        with open(p, "rb") as fh:  # streamed from the file, not read into memory
            r = yield _Req("POST", "/api/datasets", data=data,
                           files={"file": (p.name, fh, "application/octet-stream")})
        body = r.json()
        return str(body.get("dataset_id") or body.get("id"))

    @_endpoint
    def start_reconstruction(self, *, scan_job_id: str | None = None, dataset_id: str | None = None,
                             method: str | None = None, params: Mapping | None = None,
                             wavelength: int | str | None = None, idempotency_key: str | None = None):
        """``POST /api/reconstructions``: start a reconstruction job.

        Parameters
        ----------
        scan_job_id : str, optional
            A scan job whose file to reconstruct; exactly one of it and ``dataset_id``.
        dataset_id : str, optional
            An uploaded dataset.
        method : str, optional
            One of the ``service.recon`` methods (``ner``, ``nedner``, ``linear``, ...,
            :meth:`methods`); None: the server's default for the data (ner for grid data, nedner
            for sensor points).
        params : Mapping, optional
            The reconstruction options: ``sound_speed`` (m/s or ``"auto"``; ``c`` is its
            deprecated name), ``sound_speed_range``, ``force`` and the method's own (``eps``,
            ``dtype``, ``upsample``, ``positivity``, ``dz`` in m, ...; ``tv``: ``lam`` (λ,
            default automatic) and ``iterations``; the job's progress stage names the
            iteration). Each option's type, range, unit and default: :meth:`methods`.
        wavelength : int or "all", optional
            Of a multi-wavelength scan: an index into its wavelengths, or ``"all"`` (one volume
            each: ``download_volume(..., wavelength=k)``); None: the first, recorded in the
            volume's params.
        idempotency_key : str, optional
            Same key -> same job (default: a fresh random key).

        Returns
        -------
        str
            The reconstruction job's id (202).

        Raises
        ------
        ValueError
            Both or neither input given (before any request).
        ApiError
            The server's reason (422 naming an invalid option, NotFound for an unknown input).
        ServerUnavailable
            The server cannot be reached.
        """
        if (scan_job_id is None) == (dataset_id is None):
            raise ValueError("give exactly one of scan_job_id or dataset_id")
        body: dict[str, Any] = {"params": dict(params or {})}
        if method is not None:
            body["method"] = method
        if wavelength is not None:
            body["wavelength"] = wavelength
        if scan_job_id is not None:
            body["scan_job_id"] = scan_job_id
        else:
            body["dataset_id"] = dataset_id
        r = yield _Req("POST", "/api/reconstructions", json=body,
                       headers=_idem({}, idempotency_key))
        return _job_id_from(r)

    @_endpoint
    def dataset_formats(self):
        """``GET /api/datasets/formats``: the formats :meth:`upload_dataset` takes.

        Returns
        -------
        list of dict
            ``{name, title, wavelengths}`` per format (the server's registry of formats).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/datasets/formats")
        return r.json()

    @_endpoint
    def methods(self):
        """``GET /api/reconstructions/methods``: the reconstruction methods.

        Returns
        -------
        list of dict
            ``{name, title, needs_grid, options: [{name, description, default, value_schema}],
            source}`` per method; ``value_schema`` is an option's JSON schema (``type``,
            ``minimum``/``maximum`` or ``enum``, ``unit``, ``quantity``): a value outside it is
            refused (422).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/reconstructions/methods")
        return r.json()

    @_endpoint
    def start_unmix(self, *, scan_job_id: str | None = None, dataset_ids: Sequence[str] | None = None,
                    wavelengths: Sequence[float] | None = None, method: str | None = None,
                    params: Mapping | None = None, threshold: float | None = None,
                    fluence: Sequence[float] | None = None, idempotency_key: str | None = None):
        """``POST /api/reconstructions`` with ``unmix``: reconstruct every wavelength and unmix.

        Every wavelength is reconstructed (same ``method`` and ``params``;
        ``params["sound_speed"]`` may be ``"auto"``) and unmixed into HbO2/Hb, THb and sO2 (``service.recon.unmix``).

        Parameters
        ----------
        scan_job_id : str, optional
            A multi-wavelength scan job; exactly one of it and ``dataset_ids``.
        dataset_ids : sequence of str, optional
            One uploaded dataset per wavelength.
        wavelengths : sequence of float, optional
            The datasets' wavelengths, m.
        method : str, optional
            As :meth:`start_reconstruction`.
        params : Mapping, optional
            As :meth:`start_reconstruction`.
        threshold : float, optional
            THb fraction in [0, 1) below which voxels are masked.
        fluence : sequence of float, optional
            J/m² per wavelength (default: assumed equal).
        idempotency_key : str, optional
            Same key -> same job.

        Returns
        -------
        str
            The job's id (202).

        Raises
        ------
        ValueError
            Both or neither input given (before any request).
        ApiError
            The server's reason (422 for fewer than two wavelengths, ...).
        ServerUnavailable
            The server cannot be reached.
        """
        if (scan_job_id is None) == (not dataset_ids):
            raise ValueError("give exactly one of scan_job_id or dataset_ids")
        unmix: dict[str, Any] = {}
        if threshold is not None:
            unmix["threshold"] = float(threshold)
        if fluence is not None:
            unmix["fluence"] = [float(f) for f in fluence]
        body: dict[str, Any] = {"params": dict(params or {}), "unmix": unmix}
        if method is not None:
            body["method"] = method
        if scan_job_id is not None:
            body["scan_job_id"] = scan_job_id
        else:
            body["dataset_ids"] = list(dataset_ids or [])
            if wavelengths is not None:
                body["wavelengths"] = [float(w) for w in wavelengths]
        r = yield _Req("POST", "/api/reconstructions", json=body, headers=_idem({}, idempotency_key))
        return _job_id_from(r)

    @_endpoint
    def download_unmix(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/reconstructions/{job_id}/unmix.h5`` (HbO2, Hb, THb, sO2, mask; HDF5) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/unmix.h5"), Path(dest)))

    @_endpoint
    def download_so2(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/reconstructions/{job_id}/so2.png`` (masked sO2 map with colour bar, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/so2.png"), Path(dest)))

    @_endpoint
    def download_volume(self, job_id: str, dest: str | os.PathLike, *, wavelength: int | None = None):
        """``GET /api/reconstructions/{job_id}/volume.h5`` (p0 with its axes in m, HDF5) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).
        wavelength : int, optional
            Wavelength k's volume of a job over every wavelength.

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        params = None if wavelength is None else {"wavelength": int(wavelength)}
        return (yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/volume.h5", params=params), Path(dest)))

    @_endpoint
    def download_ome_tiff(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/reconstructions/{job_id}/volume.ome.tif`` (OME-TIFF, voxel sizes in µm) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return (yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/volume.ome.tif"), Path(dest)))

    @_endpoint
    def download_ome_zarr(self, job_id: str, dest: str | os.PathLike):
        """``GET /api/reconstructions/{job_id}/volume.ome.zarr.zip`` unpacked into a folder.

        OME-Zarr, voxel sizes in µm.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The folder (conventionally ``*.ome.zarr``; an existing one there is replaced).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ValueError
            A zip that is not one folder or names a path outside it.
        ApiError
            The server's reason (NotFound for an unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        dest = Path(dest)
        zipped = dest.with_name(f".{dest.name}.zip")
        got = yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/volume.ome.zarr.zip"), zipped)
        try:
            return _unzip_folder(Path(got), dest)
        finally:
            Path(got).unlink(missing_ok=True)

    @_endpoint
    def download_mip(self, job_id: str, plane: str, dest: str | os.PathLike, *, wavelength: int | None = None):
        """``GET /api/reconstructions/{job_id}/mip/{plane}.png`` (maximum-intensity projection, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        plane : {"xy", "xz", "yz"}
            The projection's plane.
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).
        wavelength : int, optional
            As :meth:`download_volume`.

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ValueError
            An unknown plane (before any request).
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        _check_plane(plane)
        params = None if wavelength is None else {"wavelength": int(wavelength)}
        return (yield _Download(_Req("GET", f"/api/reconstructions/{job_id}/mip/{plane}.png", params=params),
                                Path(dest)))

    @_endpoint
    def download_slice(self, job_id: str, index: int, dest: str | os.PathLike):
        """``GET /api/reconstructions/{job_id}/slice.png?index=k`` (one depth slice, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        index : int
            The slice's depth index k.
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        req = _Req("GET", f"/api/reconstructions/{job_id}/slice.png", params={"index": int(index)})
        return (yield _Download(req, Path(dest)))

    # -- jobs
    @_endpoint
    def list_jobs(self, *, state: str | None = None, kind: str | None = None):
        """``GET /api/jobs?state=&kind=``: the jobs, newest first.

        Parameters
        ----------
        state : str, optional
            Only jobs in this state (``queued``, ``running``, ``paused``, ``succeeded``,
            ``failed``, ``cancelled``).
        kind : str, optional
            Only jobs of this kind.

        Returns
        -------
        list of Job or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        params = {k: v for k, v in (("state", state), ("kind", kind)) if v}
        r = yield _Req("GET", "/api/jobs", params=params or None)
        body = r.json()
        items = body.get("items", body) if isinstance(body, dict) else body
        return [as_model("Job", j) for j in items]

    @_endpoint
    def get_job(self, job_id: str):
        """``GET /api/jobs/{job_id}``: one job.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict
            ``id, kind, state, progress, timings, params, links, error``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", f"/api/jobs/{job_id}")
        return as_model("Job", r.json())

    @_endpoint
    def cancel_job(self, job_id: str):
        """``POST /api/jobs/{job_id}/cancel``: cancel a job (cooperative).

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict for a finished job, NotFound for an unknown one).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("POST", f"/api/jobs/{job_id}/cancel")
        return as_model("Job", r.json()) if r.content else None

    @_endpoint
    def delete_job(self, job_id: str):
        """``DELETE /api/jobs/{job_id}``: a finished job and its files.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while the job or a job reading it is active, NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("DELETE", f"/api/jobs/{job_id}")
        return r.json()

    @_endpoint
    def delete_plan(self, plan_id: str):
        """``DELETE /api/plans/{plan_id}``: a stored plan.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active scan uses it, NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("DELETE", f"/api/plans/{plan_id}")
        return r.json()

    @_endpoint
    def list_datasets(self):
        """``GET /api/datasets``: the stored datasets, oldest first.

        Returns
        -------
        list of dict
            ``dataset_id``, ``name``, ``format``, ``layout``, ``shape``, ``size_bytes`` (on disk),
            ``created`` (UNIX s), ``content_sha256``, ``jobs`` (ids of the jobs that read it),
            ``in_use`` (an active job does: it cannot be deleted).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("GET", "/api/datasets")
        return r.json()

    @_endpoint
    def delete_dataset(self, dataset_id: str):
        """``DELETE /api/datasets/{dataset_id}``: a stored dataset.

        Parameters
        ----------
        dataset_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active reconstruction reads it, NotFound (404) for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        r = yield _Req("DELETE", f"/api/datasets/{dataset_id}")
        return r.json()

    @_endpoint
    def retention(self, **policy: Any):
        """``GET /api/retention``, or ``PUT`` it with a new policy: what the server keeps.

        Parameters
        ----------
        **policy
            ``keep_results``, ``keep_bytes``, ``include_scans``, ``datasets_keep_bytes``,
            ``datasets_max_age_s`` (s); none: read the policy.

        Returns
        -------
        dict
            The policy.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 for an invalid value).
        ServerUnavailable
            The server cannot be reached.
        """
        if policy:
            r = yield _Req("PUT", "/api/retention", json=policy)
        else:
            r = yield _Req("GET", "/api/retention")
        return r.json()


def _check_plane(plane: str) -> None:
    if plane not in MIP_PLANES:
        raise ValueError(f"plane must be one of {', '.join(MIP_PLANES)}, not {plane!r}")


def _parse_event(sse) -> tuple[str, dict]:
    try:
        data = json.loads(sse.data) if sse.data else {}
    except ValueError:
        data = {"message": sse.data}
    if not isinstance(data, dict):
        data = {"value": data}
    return sse.event or "message", data


def _progress_of(data: dict) -> dict:
    prog = data.get("progress")
    return prog if isinstance(prog, dict) else data


def _finish(job: Any) -> Any:
    state = field_of(job, "state")
    if state == "failed":
        err = field_of(job, "error") or "no reason given"
        raise JobFailed(job, f"job {field_of(job, 'id')} failed: {err}")
    if state == "cancelled":
        raise JobCancelled(job, f"job {field_of(job, 'id')} was cancelled")
    return job


# --------------------------------------------------------------------------- sync
class _BaseClient(_Endpoints):
    _asynchronous: ClassVar[bool] = False

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0):
        base_url = base_url or os.environ.get("FPSCAN_SERVER") or "http://127.0.0.1:8000"
        if not base_url.startswith(("http://", "https://")):
            raise ValueError(f"server URL must start with http:// or https://, not {base_url!r}")
        self.base_url = base_url.rstrip("/")
        self.token = token if token is not None else os.environ.get("FPSCAN_TOKEN") or None
        self.timeout = timeout

    def _headers(self) -> dict:
        h = {"Accept": "application/json"}
        if self.token:
            h["Authorization"] = f"Bearer {self.token}"
        return h

    def _unavailable(self, exc: Exception) -> ServerUnavailable:
        reason = str(exc) or type(exc).__name__
        return ServerUnavailable(self.base_url, reason)


class Client(_BaseClient):
    """Blocking client of the fpscan HTTP API (``docs/api.md``).

    Every endpoint is a method (the same on :class:`AsyncClient`, there as coroutines):
    health and auth (``health``, ``auth``); plans (``create_plan``, ``preview_plan``,
    ``mask_kinds``, ``list_plans``, ``get_plan``, ``get_plan_json``,
    ``download_plan_preview``, ``delete_plan``); scanners and scans (``scanners``,
    ``start_scan``, ``pause_scan``, ``resume_scan``, ``abort_scan``, ``download_scan``,
    ``download_ipasc``, ``scan_preview``, ``download_scan_preview``); datasets and
    reconstructions (``upload_dataset``, ``dataset_formats``, ``methods``,
    ``start_reconstruction``, ``start_unmix``, ``download_volume``, ``download_ome_tiff``,
    ``download_ome_zarr``, ``download_mip``, ``download_slice``, ``download_unmix``,
    ``download_so2``, ``list_datasets``, ``delete_dataset``); jobs (``list_jobs``,
    ``get_job``, ``cancel_job``, ``delete_job``, ``events``, ``wait``); ``retention``.
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
                 timeout: float = 30.0):
        super().__init__(base_url, token=token, timeout=timeout)
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, headers=self._headers())

    def close(self) -> None:
        """Close the client's connections (leaving a ``with`` block does it)."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- transport
    def _send(self, req: _Req) -> httpx.Response:
        try:
            r = self._http.request(req.method, req.path, json=req.json, params=req.params,
                                   headers=req.headers, files=req.files, data=req.data)
        except httpx.TransportError as exc:
            raise self._unavailable(exc) from None
        _raise_for(r)
        return r

    def _download(self, op: _Download) -> Path:
        op.dest.parent.mkdir(parents=True, exist_ok=True)
        state = _Resume(op.dest)
        for _attempt in range(2):
            try:
                with self._http.stream(op.req.method, op.req.path, params=op.req.params,
                                       headers=state.headers()) as r:
                    if r.status_code == 416:  # what we hold no longer fits: start over
                        state.discard()
                        continue
                    if r.status_code >= 400:
                        r.read()
                        _raise_for(r)
                    with state.open(r) as fh:
                        for chunk in r.iter_bytes(1 << 20):
                            fh.write(chunk)
                return state.done()
            except httpx.TransportError as exc:  # keep the part: the next call resumes it
                raise self._unavailable(exc) from None
            except BaseException:
                state.discard()
                raise
        raise ApiError(416, "the server refused every byte range of the download")

    def _drive(self, gen):
        try:
            op = next(gen)
            while True:
                result = self._download(op) if isinstance(op, _Download) else self._send(op)
                op = gen.send(result)
        except StopIteration as stop:
            return stop.value

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
            s without a byte before the stream counts as dropped (the server pings every 15 s).

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
                    _raise_for(source.response)
                for sse in source.iter_sse():
                    event, data = _parse_event(sse)
                    yield event, data, sse.id or None
        except httpx.TransportError as exc:
            raise self._unavailable(exc) from None

    def _follow_events(self, job_id: str, last_id: str | None, deadline: float | None,
                       on_progress: ProgressCallback | None) -> tuple[int, str | None, bool]:
        """Read the job's event stream until it ends, drops, the job ends or the deadline
        passes; returns ``(events read, last event id, whether to keep using SSE)``."""
        n_events = 0
        stream = self.events(job_id, last_event_id=last_id, read_timeout=_read_timeout(deadline))
        try:
            for event, data, eid in stream:
                n_events += 1
                last_id = eid or last_id
                if event == "progress" and on_progress is not None:
                    on_progress(_progress_of(data))
                if data.get("state") in TERMINAL_STATES or _past(deadline):
                    break
        except ServerUnavailable:
            pass  # dropped or idle stream: the caller's get_job tells which
        except ApiError as exc:
            if exc.status_code == 404:
                self.get_job(job_id)  # NotFound propagates for an unknown job
            return n_events, last_id, _keep_sse(exc)
        except Exception:  # a malformed stream: poll instead
            return n_events, last_id, False
        finally:
            stream.close()
        return n_events, last_id, True

    def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
             timeout: float | None = None, poll_interval: float = 0.5, raise_on_failure: bool = True):
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
            if on_progress is not None and _report_snapshot(job, use_sse):
                on_progress(to_dict(field_of(job, "progress")))
            if field_of(job, "state") in TERMINAL_STATES:
                return _finish(job) if raise_on_failure else job
            if deadline is not None and time.monotonic() > deadline:
                raise WaitTimeout(f"job {job_id} still {field_of(job, 'state')} after {timeout} s")
            if use_sse:
                n_events, last_id, use_sse = self._follow_events(job_id, last_id, deadline, on_progress)
                if n_events == 0:
                    time.sleep(poll_interval)
            else:
                time.sleep(poll_interval)
            job = self.get_job(job_id)


# --------------------------------------------------------------------------- async
class AsyncClient(_BaseClient):
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

    _asynchronous: ClassVar[bool] = True

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0):
        super().__init__(base_url, token=token, timeout=timeout)
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout,
                                       headers=self._headers())

    async def aclose(self) -> None:
        """Close the client's connections (leaving an ``async with`` block does it)."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc) -> None:
        await self.aclose()

    async def _send(self, req: _Req) -> httpx.Response:
        try:
            r = await self._http.request(req.method, req.path, json=req.json, params=req.params,
                                         headers=req.headers, files=req.files, data=req.data)
        except httpx.TransportError as exc:
            raise self._unavailable(exc) from None
        _raise_for(r)
        return r

    async def _download(self, op: _Download) -> Path:
        op.dest.parent.mkdir(parents=True, exist_ok=True)
        state = _Resume(op.dest)
        for _attempt in range(2):
            try:
                async with self._http.stream(op.req.method, op.req.path, params=op.req.params,
                                             headers=state.headers()) as r:
                    if r.status_code == 416:
                        state.discard()
                        continue
                    if r.status_code >= 400:
                        await r.aread()
                        _raise_for(r)
                    with state.open(r) as fh:
                        async for chunk in r.aiter_bytes(1 << 20):
                            fh.write(chunk)
                return state.done()
            except httpx.TransportError as exc:
                raise self._unavailable(exc) from None
            except BaseException:
                state.discard()
                raise
        raise ApiError(416, "the server refused every byte range of the download")

    async def _drive(self, gen):
        try:
            op = next(gen)
            while True:
                result: Path | httpx.Response
                if isinstance(op, _Download):
                    result = await self._download(op)
                else:
                    result = await self._send(op)
                op = gen.send(result)
        except StopIteration as stop:
            return stop.value

    async def events(self, job_id: str, *, last_event_id: str | None = None,
                     read_timeout: float = 30.0):
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
                    _raise_for(source.response)
                async for sse in source.aiter_sse():
                    event, data = _parse_event(sse)
                    yield event, data, sse.id or None
        except httpx.TransportError as exc:
            raise self._unavailable(exc) from None

    async def _follow_events(self, job_id: str, last_id: str | None, deadline: float | None,
                             report: Callable[[dict], Any]) -> tuple[int, str | None, bool]:
        """See :meth:`Client._follow_events` (``report`` is awaited)."""
        n_events = 0
        stream = self.events(job_id, last_event_id=last_id, read_timeout=_read_timeout(deadline))
        try:
            async for event, data, eid in stream:
                n_events += 1
                last_id = eid or last_id
                if event == "progress":
                    await report(_progress_of(data))
                if data.get("state") in TERMINAL_STATES or _past(deadline):
                    break
        except ServerUnavailable:
            pass
        except ApiError as exc:
            if exc.status_code == 404:
                await self.get_job(job_id)  # NotFound propagates for an unknown job
            return n_events, last_id, _keep_sse(exc)
        except Exception:
            return n_events, last_id, False
        finally:
            await stream.aclose()
        return n_events, last_id, True

    async def wait(self, job_id: str, *, on_progress: ProgressCallback | None = None,
                   timeout: float | None = None, poll_interval: float = 0.5,
                   raise_on_failure: bool = True):
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
            if _report_snapshot(job, use_sse):
                await report(to_dict(field_of(job, "progress")))
            if field_of(job, "state") in TERMINAL_STATES:
                return _finish(job) if raise_on_failure else job
            if deadline is not None and time.monotonic() > deadline:
                raise WaitTimeout(f"job {job_id} still {field_of(job, 'state')} after {timeout} s")
            if use_sse:
                n_events, last_id, use_sse = await self._follow_events(job_id, last_id, deadline, report)
                if n_events == 0:
                    await asyncio.sleep(poll_interval)
            else:
                await asyncio.sleep(poll_interval)
            job = await self.get_job(job_id)

