"""What an endpoint is: one declaration, one HTTP request and how its answer becomes the result
(no I/O here).

Every endpoint of the API is declared once, as an :class:`Endpoint`: a *request builder* (a
plain function of the endpoint's arguments, with the endpoint's docstring, that checks them
and returns a :class:`Call`, a :class:`Request` and ``read(response) -> result``, or a
:class:`Download`, a request whose body is saved to a file, then ``finish(path) -> result``)
put in its group's class with :func:`endpoint` (:mod:`fpscan.clients.http.endpoints`). Both
clients are made of the same group classes: :class:`SyncCaller` (the base of
:class:`fpscan.clients.http.Client`) turns each declaration into a blocking method
(``self._call(build(...))``), :class:`AsyncCaller` (the base of
:class:`fpscan.clients.http.AsyncClient`) into a coroutine method (``await
self._call(build(...))``), with the builder's parameters, docstring and the result type of its
``Call[T]`` / ``Download[T]`` as the method's return annotation. Their ``_call`` runs
:func:`fpscan.clients.http.core.call_flow`; only :mod:`fpscan.clients.http.client` and
:mod:`fpscan.clients.http.async_client` send anything.

The response helpers here (:func:`as_model`, :func:`field_of`, :func:`to_dict`,
:func:`read_job_id`, ...) are shared by every group.
"""
from __future__ import annotations

import inspect
import typing
import uuid
from collections.abc import Callable, Coroutine, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, ParamSpec, TypeVar, overload

import httpx
from pydantic import BaseModel, ValidationError

__all__ = ["Request", "Call", "Download", "Endpoint", "endpoint", "endpoints_of", "SyncCaller", "AsyncCaller",
           "MIP_PLANES", "as_model", "field_of", "to_dict", "read_job_id", "idempotency", "jsonable", "check_plane",
           "read_json", "read_model", "read_optional_model", "read_models"]

T = TypeVar("T")
P = ParamSpec("P")
M = TypeVar("M", bound=BaseModel)

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


class Endpoint(Generic[P, T]):
    """One endpoint of the API, declared once: its request builder ``build`` (see the module
    docstring). In a group class of :mod:`fpscan.clients.http.endpoints` it becomes a method of
    both clients (:class:`SyncCaller`, :class:`AsyncCaller`), typed for each: on a
    :class:`fpscan.clients.http.Client` it is ``(*args) -> T``, on an
    :class:`fpscan.clients.http.AsyncClient` a coroutine function ``async (*args) -> T``.

    Parameters
    ----------
    build : callable
        ``build(*args, **kwargs) -> Call[T] | Download[T]``: the endpoint's arguments checked (a
        ``ValueError`` before any request) and turned into its request; its docstring is the
        methods'.

    Attributes
    ----------
    build : callable
        As given.
    name : str
        The methods' name (the attribute it is declared as).

    Examples
    --------
    >>> from fpscan.clients.http.calls import Call, Endpoint, Request, read_json
    >>> def health() -> Call[dict]:
    ...     "``GET /api/health``."  # its docstring
    ...     return Call(Request("GET", "/api/health"), read_json)
    >>> ep = Endpoint(health)
    >>> ep.name, ep.build().request.path, ep.result_type()
    ('health', '/api/health', <class 'dict'>)
    >>> ep.__doc__
    '``GET /api/health``.'
    """

    def __init__(self, build: Callable[P, Call[T] | Download[T]]) -> None:
        self.build = build
        self.name: str = build.__name__
        self.__doc__ = build.__doc__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> Endpoint[P, T]: ...

    @overload
    def __get__(self, obj: AsyncCaller, owner: type | None = None) -> Callable[P, Coroutine[Any, Any, T]]: ...

    @overload
    def __get__(self, obj: SyncCaller, owner: type | None = None) -> Callable[P, T]: ...

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        # The clients' methods are installed on their classes (SyncCaller, AsyncCaller); this
        # typed view is what a type checker sees, and what a group class itself holds.
        if obj is None:
            return self
        return self.method(isinstance(obj, AsyncCaller), type(obj)).__get__(obj, type(obj))

    def result_type(self) -> Any:
        """The type of the endpoint's result: ``T`` of its builder's ``Call[T]`` / ``Download[T]``
        return annotation.

        Returns
        -------
        type
            E.g. ``Health``, ``list[Job]``, ``pathlib.Path``, ``str | None``.

        Examples
        --------
        >>> from pathlib import Path
        >>> from fpscan.clients.http.calls import Download, Endpoint, Request
        >>> def scan_file(job_id: str) -> Download[Path]:
        ...     return Download(Request("GET", f"/api/scans/{job_id}/file"), Path("scan.h5"))
        >>> Endpoint(scan_file).result_type()
        <class 'pathlib.Path'>
        """
        returned = typing.get_type_hints(self.build)["return"]
        if typing.get_origin(returned) not in (Call, Download):  # Call[T] | Download[T]
            returned = typing.get_args(returned)[0]
        return typing.get_args(returned)[0]

    def method(self, awaited: bool, owner: type) -> Callable[..., Any]:
        """The method of a client class: blocking (``client._call(build(...))``) or a coroutine
        function (``await client._call(build(...))``), with the builder's parameters after
        ``self``, its docstring, and :meth:`result_type` as its return annotation.

        Parameters
        ----------
        awaited : bool
            A coroutine function (the asyncio client's).
        owner : type
            The client class (its module and qualified name are the method's).

        Returns
        -------
        function

        Examples
        --------
        >>> import inspect
        >>> from fpscan.clients.http import AsyncClient
        >>> from fpscan.clients.http.endpoints.jobs import Jobs
        >>> get_job = Jobs.get_job.method(True, AsyncClient)
        >>> inspect.iscoroutinefunction(get_job), str(inspect.signature(get_job))
        (True, '(self, job_id: str) -> fpscan.clients.http.models.Job')
        """
        build = self.build
        if awaited:
            async def run_awaited(client: Any, /, *args: Any, **kwargs: Any) -> Any:
                return await client._call(build(*args, **kwargs))
            run: Callable[..., Any] = run_awaited
        else:
            def run_blocking(client: Any, /, *args: Any, **kwargs: Any) -> Any:
                return client._call(build(*args, **kwargs))
            run = run_blocking
        sig = inspect.signature(build, eval_str=True)
        result = self.result_type()
        params = [inspect.Parameter("self", inspect.Parameter.POSITIONAL_OR_KEYWORD), *sig.parameters.values()]
        run.__signature__ = sig.replace(parameters=params, return_annotation=result)  # type: ignore[attr-defined]
        run.__annotations__ = {**{p.name: p.annotation for p in sig.parameters.values()
                                  if p.annotation is not inspect.Parameter.empty}, "return": result}
        run.__name__ = self.name
        run.__qualname__ = f"{owner.__qualname__}.{self.name}"
        run.__module__ = owner.__module__
        run.__doc__ = build.__doc__
        run.__endpoint__ = self  # type: ignore[attr-defined]
        return run


def endpoint(build: Callable[P, Call[T] | Download[T]]) -> Endpoint[P, T]:
    """Declare an endpoint in a group class: ``@endpoint`` over its request builder (a function
    without ``self``; see :class:`Endpoint`).

    Parameters
    ----------
    build : callable
        The request builder.

    Returns
    -------
    Endpoint

    Examples
    --------
    >>> from fpscan.clients.http.calls import Call, Request, endpoint, read_json
    >>> class Server:
    ...     @endpoint
    ...     def auth() -> Call[dict]:
    ...         "``GET /api/auth``."  # its docstring
    ...         return Call(Request("GET", "/api/auth"), read_json)
    >>> Server.auth.name, Server.auth.build().request.path
    ('auth', '/api/auth')
    """
    return Endpoint(build)


def endpoints_of(cls: type) -> dict[str, Endpoint[Any, Any]]:
    """The endpoints a class offers: its declarations (:class:`Endpoint`) and the methods made
    from them, by name (a method a subclass writes itself instead is not one).

    Parameters
    ----------
    cls : type
        A client class or a group class.

    Returns
    -------
    dict of str to Endpoint

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient, Client
    >>> from fpscan.clients.http.calls import endpoints_of
    >>> endpoints_of(Client) == endpoints_of(AsyncClient)
    True
    >>> endpoints_of(Client)["get_job"].build("j1").request.path
    '/api/jobs/j1'
    """
    found: dict[str, Endpoint[Any, Any]] = {}
    for name in dir(cls):
        attr = inspect.getattr_static(cls, name)
        declared = attr if isinstance(attr, Endpoint) else getattr(attr, "__endpoint__", None)
        if isinstance(declared, Endpoint):
            found[name] = declared
    return found


def _install(cls: type, awaited: bool) -> None:
    """Put the method of each endpoint ``cls`` inherits from its group classes on ``cls``."""
    for name, declared in endpoints_of(cls).items():
        if isinstance(inspect.getattr_static(cls, name), Endpoint):
            setattr(cls, name, declared.method(awaited, cls))


class SyncCaller:
    """The base of the blocking client: each endpoint its class inherits from a group class
    (:func:`endpoint`) becomes a method ``(*args) -> result`` that runs ``self._call(call)``
    (implemented by :class:`fpscan.clients.http.client.Client`).

    Attributes
    ----------
    None
        A base class: it declares ``_call`` only.

    Examples
    --------
    >>> import inspect
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.calls import SyncCaller
    >>> issubclass(Client, SyncCaller), inspect.iscoroutinefunction(Client.get_job)
    (True, False)
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _install(cls, awaited=False)

    def _call(self, call: Call[T] | Download[T]) -> T:
        raise NotImplementedError


class AsyncCaller:
    """The base of the asyncio client: each endpoint its class inherits from a group class
    (:func:`endpoint`) becomes a coroutine method ``async (*args) -> result`` that awaits
    ``self._call(call)`` (implemented by :class:`fpscan.clients.http.async_client.AsyncClient`).

    Attributes
    ----------
    None
        A base class: it declares ``_call`` only.

    Examples
    --------
    >>> import inspect
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.calls import AsyncCaller
    >>> issubclass(AsyncClient, AsyncCaller), inspect.iscoroutinefunction(AsyncClient.get_job)
    (True, True)
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _install(cls, awaited=True)

    async def _call(self, call: Call[T] | Download[T]) -> T:
        raise NotImplementedError


def as_model(model: type[M], data: Any) -> M:
    """A response parsed into the client's model ``model`` (:mod:`fpscan.clients.http.models`);
    one that does not fit (a server newer or older than this client) is kept unvalidated as
    the same model, every field it has readable (``model_construct``).

    Parameters
    ----------
    model : type
        A model of ``fpscan.clients.http.models`` (``Job``, ``Plan``, ...).
    data : any
        The decoded JSON response.

    Returns
    -------
    pydantic.BaseModel
        An instance of ``model``.

    Raises
    ------
    pydantic.ValidationError
        ``data`` is not a JSON object (a ``ValueError``).

    Examples
    --------
    >>> from fpscan.clients.http.calls import as_model
    >>> from fpscan.clients.http.models import Job
    >>> job = as_model(Job, {"id": "j1", "kind": "scan", "state": "running", "new_field": 1})
    >>> type(job).__name__, job.state, job.new_field  # unknown fields are kept
    ('Job', 'running', 1)
    >>> odd = as_model(Job, {"id": "j1"})  # does not fit: kept as it came
    >>> type(odd).__name__, odd["id"], odd.get("state")
    ('Job', 'j1', None)
    """
    try:
        return model.model_validate(data)
    except ValidationError:
        if not isinstance(data, dict):
            raise
        return model.model_construct(**data)  # the server is newer/older than this client: keep what it sent


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
    """The decoded JSON body (a :class:`Call`'s ``read`` for the answers typed as plain dicts:
    the endpoint's ``Call[...]`` annotation says which, e.g. ``Call[AuthInfo]``).

    Parameters
    ----------
    response : httpx.Response

    Returns
    -------
    any
        The JSON value.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_json
    >>> read_json(httpx.Response(200, json={"status": "ok"}))
    {'status': 'ok'}
    """
    return response.json()


def read_model(model: type[M]) -> Callable[[httpx.Response], M]:
    """A ``read`` that parses the body into ``model`` (:func:`as_model`).

    Parameters
    ----------
    model : type
        A model of ``fpscan.clients.http.models``.

    Returns
    -------
    callable
        ``read(response) -> model``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_model
    >>> from fpscan.clients.http.models import Job
    >>> read_model(Job)(httpx.Response(200, json={"id": "j1", "kind": "scan", "state": "queued"})).state
    'queued'
    """
    def read(response: httpx.Response) -> M:
        return as_model(model, response.json())

    return read


def read_optional_model(model: type[M]) -> Callable[[httpx.Response], M | None]:
    """A ``read`` like :func:`read_model` for which an empty body reads as None (the answers of
    pause, resume, abort and cancel).

    Parameters
    ----------
    model : type
        A model of ``fpscan.clients.http.models``.

    Returns
    -------
    callable
        ``read(response) -> model or None``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_optional_model
    >>> from fpscan.clients.http.models import Job
    >>> read_optional_model(Job)(httpx.Response(200)) is None
    True
    >>> read_optional_model(Job)(httpx.Response(200, json={"id": "j1", "kind": "scan", "state": "paused"})).state
    'paused'
    """
    def read(response: httpx.Response) -> M | None:
        if not response.content:
            return None
        return as_model(model, response.json())

    return read


def read_models(model: type[M]) -> Callable[[httpx.Response], list[M]]:
    """A ``read`` for a list answer (``[...]`` or ``{"items": [...]}``): each item as ``model``.

    Parameters
    ----------
    model : type
        A model of ``fpscan.clients.http.models``.

    Returns
    -------
    callable
        ``read(response) -> list``.

    Raises
    ------
    ValueError
        (From ``read``) an answer that is not a list.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.calls import read_models
    >>> from fpscan.clients.http.models import Job
    >>> jobs = read_models(Job)(httpx.Response(200, json={"items": [{"id": "a", "kind": "scan",
    ...                                                              "state": "queued"}]}))
    >>> [j.id for j in jobs]
    ['a']
    """
    def read(response: httpx.Response) -> list[M]:
        body = response.json()
        items = body["items"] if isinstance(body, dict) and "items" in body else body
        if not isinstance(items, list):
            raise ValueError(f"expected a list of {model.__name__} from the server, got {type(items).__name__}")
        return [as_model(model, item) for item in items]

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
