"""What an endpoint is: one HTTP request and how its answer becomes the result (no I/O here).

Every endpoint of the client is a *request builder*, a plain function of the endpoint's
arguments that returns a :class:`Call` (a :class:`Request` and ``read(response) -> result``)
or a :class:`Download` (a request whose body is saved to a file, then ``finish(path) ->
result``). The builders live with their endpoint group in :mod:`fpscan.clients.http.endpoints`,
beside the two thin methods that run them: ``Client``'s (``self._call(call)``, blocking) and
``AsyncClient``'s (``await self._call(call)``), which run :func:`fpscan.clients.http.core.call_flow`.
Only :mod:`fpscan.clients.http.client` and :mod:`fpscan.clients.http.async_client` send anything.

The response helpers here (:func:`as_model`, :func:`field_of`, :func:`to_dict`,
:func:`read_job_id`) are shared by every group.
"""
from __future__ import annotations

import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import httpx

from fpscan.clients.http.models import MODELS

__all__ = ["Request", "Call", "Download", "MIP_PLANES", "as_model", "field_of", "to_dict", "read_job_id",
           "idempotency", "jsonable", "check_plane", "read_json", "read_model", "read_models", "SyncCaller",
           "AsyncCaller"]

T = TypeVar("T")

#: the planes of a maximum-intensity projection (MIP) or a live preview picture
MIP_PLANES = ("xy", "xz", "yz")


@dataclass(frozen=True)
class Request:
    """One HTTP request, relative to the client's base URL.

    Parameters
    ----------
    method, path, json, params, headers, form, upload
        As the attributes below.

    Attributes
    ----------
    method : str
        ``GET``, ``POST``, ``PUT`` or ``DELETE``.
    path : str
        The route, e.g. ``/api/plans``.
    json : any
        A JSON body, or None.
    params : Mapping or None
        The query string's fields.
    headers : Mapping
        Extra headers (the client adds ``Authorization`` and ``Accept``).
    form : Mapping or None
        Multipart form fields sent with ``upload``.
    upload : pathlib.Path or None
        A file streamed (not read into memory) as the multipart field ``file``.

    Examples
    --------
    >>> from fpscan.clients.http.calls import Request
    >>> Request("GET", "/api/jobs", params={"state": "running"}).params
    {'state': 'running'}
    """

    method: str
    path: str
    json: Any = None
    params: Mapping[str, Any] | None = None
    headers: Mapping[str, str] = field(default_factory=dict)
    form: Mapping[str, str] | None = None
    upload: Path | None = None


@dataclass(frozen=True)
class Call(Generic[T]):
    """An endpoint's request and how its answer becomes the result.

    Parameters
    ----------
    request, read
        As the attributes below.

    Attributes
    ----------
    request : Request
    read : callable
        ``read(response: httpx.Response) -> result``, called with a 2xx answer only (a 4xx/5xx
        is raised as :class:`~fpscan.clients.http.errors.ApiError` before).

    Examples
    --------
    >>> from fpscan.clients.http.calls import Call, Request, read_json
    >>> call = Call(Request("GET", "/api/health"), read_json)
    >>> call.request.path
    '/api/health'
    """

    request: Request
    read: Callable[[httpx.Response], T]


def _same(path: Path, content_type: str) -> Path:
    return path


@dataclass(frozen=True)
class Download(Generic[T]):
    """A ``GET`` whose body is saved to a file (resumable), then turned into the result.

    Parameters
    ----------
    request, dest, finish
        As the attributes below.

    Attributes
    ----------
    request : Request
    dest : pathlib.Path
        The file to write (its folder is made; ``dest.part`` while downloading).
    finish : callable
        ``finish(dest, content_type) -> result`` once the file is complete, with the answer's
        ``Content-Type`` (default: ``dest`` itself).

    Examples
    --------
    >>> from pathlib import Path
    >>> from fpscan.clients.http.calls import Download, Request
    >>> d = Download(Request("GET", "/api/scans/j1/file"), Path("scan.h5"))
    >>> d.finish(d.dest, "application/x-hdf5")
    PosixPath('scan.h5')
    """

    request: Request
    dest: Path
    finish: Callable[[Path, str], T] = _same  # type: ignore[assignment]


class SyncCaller:
    """What an endpoint group's blocking methods call: ``self._call(call) -> result``
    (implemented by :class:`fpscan.clients.http.client.Client`).

    Attributes
    ----------
    None
        A mixin: it declares ``_call`` only.

    Examples
    --------
    >>> from fpscan.clients.http.calls import SyncCaller
    >>> hasattr(SyncCaller, "_call")
    True
    """

    def _call(self, call: Call[T] | Download[T]) -> T:
        raise NotImplementedError


class AsyncCaller:
    """What an endpoint group's coroutine methods await: ``await self._call(call) -> result``
    (implemented by :class:`fpscan.clients.http.async_client.AsyncClient`).

    Attributes
    ----------
    None
        A mixin: it declares ``_call`` only.

    Examples
    --------
    >>> from fpscan.clients.http.calls import AsyncCaller
    >>> hasattr(AsyncCaller, "_call")
    True
    """

    async def _call(self, call: Call[T] | Download[T]) -> T:
        raise NotImplementedError


def as_model(name: str, data: Any) -> Any:
    """A response parsed into ``fpscan.clients.http.models.<name>`` when it fits, else returned as is.

    Parameters
    ----------
    name : str
        A model name of ``fpscan.clients.http.models.MODELS`` (``"Job"``, ``"Plan"``, ...).
    data : any
        The decoded JSON response.

    Returns
    -------
    pydantic.BaseModel or any
        The model; ``data`` unchanged for an unknown name, a non-dict or a response that does
        not fit (a server newer or older than this client).

    Examples
    --------
    >>> from fpscan.clients.http.calls import as_model
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
    >>> from fpscan.clients.http import field_of
    >>> from fpscan.clients.http.models import Job
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
    >>> from fpscan.clients.http import to_dict
    >>> from fpscan.clients.http.models import Job
    >>> d = to_dict(Job(id="j1", kind="scan", state="queued"))
    >>> type(d).__name__, d["state"], d["progress"]["fraction"]
    ('dict', 'queued', 0.0)
    >>> to_dict({"a": 1})
    {'a': 1}
    """
    if hasattr(obj, "model_dump"):
        return obj.model_dump(mode="json")
    return obj


def jsonable(body: Any) -> Any:
    """A request body as JSON-able data: a pydantic model dumped (JSON mode), else unchanged.

    Parameters
    ----------
    body : pydantic.BaseModel or any

    Returns
    -------
    any

    Examples
    --------
    >>> from fpscan.clients.http.calls import jsonable
    >>> jsonable({"a": 1})
    {'a': 1}
    """
    return to_dict(body) if hasattr(body, "model_dump") else body


def read_json(response: httpx.Response) -> Any:
    """The decoded JSON body (a :class:`Call`'s ``read`` for endpoints that answer plain JSON).

    Parameters
    ----------
    response : httpx.Response

    Returns
    -------
    any

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_json
    >>> read_json(httpx.Response(200, json={"status": "ok"}))
    {'status': 'ok'}
    """
    return response.json()


def read_model(name: str, *, empty_ok: bool = False) -> Callable[[httpx.Response], Any]:
    """A ``read`` that parses the body into the model ``name`` (:func:`as_model`).

    Parameters
    ----------
    name : str
        A model of ``fpscan.clients.http.models.MODELS``.
    empty_ok : bool, optional
        An empty body reads as None (the answers of pause, resume, abort and cancel).

    Returns
    -------
    callable
        ``read(response) -> model or dict or None``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_model
    >>> read_model("Job")(httpx.Response(200, json={"id": "j1", "kind": "scan", "state": "queued"})).state
    'queued'
    >>> read_model("Job", empty_ok=True)(httpx.Response(200)) is None
    True
    """
    def read(response: httpx.Response) -> Any:
        if empty_ok and not response.content:
            return None
        return as_model(name, response.json())

    return read


def read_models(name: str) -> Callable[[httpx.Response], Any]:
    """A ``read`` for a list answer (``[...]`` or ``{"items": [...]}``): each item as the model ``name``.

    Parameters
    ----------
    name : str
        A model of ``fpscan.clients.http.models.MODELS``.

    Returns
    -------
    callable
        ``read(response) -> list``; an answer that is not a list is returned as decoded.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_models
    >>> jobs = read_models("Job")(httpx.Response(200, json={"items": [{"id": "a", "kind": "scan",
    ...                                                                 "state": "queued"}]}))
    >>> [j.id for j in jobs]
    ['a']
    """
    def read(response: httpx.Response) -> Any:
        body = response.json()
        items = body.get("items", body) if isinstance(body, dict) and "items" in body else body
        return [as_model(name, item) for item in items] if isinstance(items, list) else items

    return read


def read_job_id(response: httpx.Response) -> str | None:
    """The id of the job a ``202`` created: the body's ``id`` / ``job_id``, else the last part
    of a ``Location: /api/jobs/<id>`` header.

    Parameters
    ----------
    response : httpx.Response

    Returns
    -------
    str or None

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_job_id
    >>> read_job_id(httpx.Response(202, json={"id": "j1"}))
    'j1'
    >>> read_job_id(httpx.Response(202, headers={"location": "/api/jobs/j2"}))
    'j2'
    """
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


def idempotency(key: str | None) -> dict[str, str]:
    """The ``Idempotency-Key`` header of a request that starts a job: ``key``, or a fresh random one.

    Parameters
    ----------
    key : str or None

    Returns
    -------
    dict

    Examples
    --------
    >>> from fpscan.clients.http.calls import idempotency
    >>> idempotency("k1")
    {'Idempotency-Key': 'k1'}
    >>> len(idempotency(None)["Idempotency-Key"])
    32
    """
    return {"Idempotency-Key": key or uuid.uuid4().hex}


def check_plane(plane: str) -> None:
    """Refuse a MIP plane that is not one of :data:`MIP_PLANES` (before any request).

    Parameters
    ----------
    plane : str

    Raises
    ------
    ValueError
        Naming the planes.

    Examples
    --------
    >>> from fpscan.clients.http.calls import check_plane
    >>> check_plane("xy")
    >>> check_plane("zz")
    Traceback (most recent call last):
    ...
    ValueError: plane must be one of xy, xz, yz, not 'zz'
    """
    if plane not in MIP_PLANES:
        raise ValueError(f"plane must be one of {', '.join(MIP_PLANES)}, not {plane!r}")
