"""Exceptions raised by the fpscan HTTP client.

Every error the server reports (a 4xx/5xx with ``{"detail": "<reason>"}``, see
``docs/api.md``) becomes an :class:`ApiError` carrying the HTTP status and the server's
``detail`` verbatim; transport failures become :class:`ServerUnavailable`; jobs that end
in ``failed``/``cancelled`` while being waited on raise :class:`JobFailed` /
:class:`JobCancelled` with the job's record attached.
"""
from __future__ import annotations

import unicodedata
from typing import Any

__all__ = [
    "FpscanClientError", "ServerUnavailable", "BadAnswer", "MAX_DETAIL_CHARS", "format_detail", "ApiError", "AuthError", "NotFound",
    "TOKEN_HINT", "Conflict", "JobError", "JobFailed", "JobCancelled", "WaitTimeout", "error_for_status",
]


class FpscanClientError(Exception):
    """Base class of everything the client raises on purpose.

    Attributes
    ----------
    args : tuple
        The message.

    Examples
    --------
    >>> from fpscan.clients.http import FpscanClientError, NotFound, ServerUnavailable, WaitTimeout
    >>> all(issubclass(e, FpscanClientError) for e in (NotFound, ServerUnavailable, WaitTimeout))
    True
    >>> issubclass(FpscanClientError, Exception)
    True
    """


class ServerUnavailable(FpscanClientError):
    """The server could not be reached (connection refused, DNS, TLS or timeout).

    Parameters
    ----------
    base_url : str
        The server's URL.
    reason : str
        What the transport reported.

    Attributes
    ----------
    base_url : str
    reason : str

    Examples
    --------
    >>> from fpscan.clients.http import ServerUnavailable
    >>> exc = ServerUnavailable("http://127.0.0.1:8000", "connection refused")
    >>> print(exc)
    cannot reach fpscan server at http://127.0.0.1:8000: connection refused
    >>> exc.reason
    'connection refused'
    """

    def __init__(self, base_url: str, reason: str):
        self.base_url = base_url
        self.reason = reason
        super().__init__(f"cannot reach fpscan server at {base_url}: {reason}")


#: the most characters of a server's reason shown (the rest named by its length): fpscan's own
#: reasons are under 1000; a server's 5 MB "reason" was one line of 5 MB on the terminal
MAX_DETAIL_CHARS = 2000


def _one_line(text: str) -> str:
    """``text`` safe for a terminal line: line breaks and tabs as spaces, every other control
    character (an escape sequence's ESC, which can recolour or retitle the terminal) shown as
    a backslash, ``x`` and its two hex digits, cut at :data:`MAX_DETAIL_CHARS`."""
    out = "".join(" " if c in "\r\n\t" else (f"\\x{ord(c):02x}" if unicodedata.category(c) == "Cc" else c)
                  for c in text[: MAX_DETAIL_CHARS + 1])
    if len(text) > MAX_DETAIL_CHARS:
        out = f"{out[:MAX_DETAIL_CHARS]}... ({len(text) - MAX_DETAIL_CHARS} characters more)"
    return out


class BadAnswer(FpscanClientError, RuntimeError):
    """The server answered, but not with what the call reads: a body that is not JSON, JSON of
    another shape than the answer's (a list where a record belongs), or a redirect (never
    followed) where an answer belongs. An older or newer server, or not an fpscan server.

    A ``RuntimeError``: the command line exits 1 with its message.

    Parameters
    ----------
    base_url : str
        The server.
    what : str
        The request, ``"GET /api/jobs"``.
    reason : str
        What did not fit.

    Attributes
    ----------
    base_url, what, reason : str
        As given.

    Examples
    --------
    >>> from fpscan.clients.http.errors import BadAnswer
    >>> print(BadAnswer("http://h:8000", "GET /api/jobs", "not JSON"))
    the server at http://h:8000 answered GET /api/jobs with what this client cannot read: not JSON
    """

    def __init__(self, base_url: str, what: str, reason: str):
        self.base_url = base_url
        self.what = what
        self.reason = reason
        super().__init__(f"the server at {base_url} answered {what} with what this client cannot read: "
                         f"{_one_line(reason)}")


def format_detail(detail: Any) -> str:
    """Render a FastAPI ``detail`` on one line: control characters escaped, at most
    :data:`MAX_DETAIL_CHARS` characters (the rest counted).

    Parameters
    ----------
    detail : str, list of dict, None or any
        The server's reason: a string, or FastAPI's list of validation errors (``loc``,
        ``msg``).

    Returns
    -------
    str
        The reason; validation errors as ``"loc: msg"`` joined by ``"; "`` (``body`` left out
        of the location); ``""`` for None.

    Examples
    --------
    >>> from fpscan.clients.http.errors import format_detail
    >>> format_detail([{"loc": ["body", "params", "eps"], "msg": "Input should be greater than or equal to 1e-14"}])
    'params.eps: Input should be greater than or equal to 1e-14'
    >>> format_detail(None)
    ''
    """
    return _one_line(_joined(detail))


def _joined(detail: Any) -> str:
    """:func:`format_detail` before it is made one safe line."""
    if detail is None:
        return ""
    if isinstance(detail, str):
        return detail
    if isinstance(detail, list):
        parts = []
        for item in detail:
            if isinstance(item, dict):
                loc = ".".join(str(p) for p in item.get("loc", ()) if p != "body")
                msg = item.get("msg", "")
                parts.append(f"{loc}: {msg}" if loc else str(msg))
            else:
                parts.append(str(item))
        return "; ".join(parts)
    return str(detail)


class ApiError(FpscanClientError):
    """The server answered with an error status (4xx/5xx).

    Parameters
    ----------
    status_code : int
        The HTTP status.
    detail : any
        The server's ``detail`` (its reason), as sent.
    method, url : str, optional
        Of the request.

    Attributes
    ----------
    status_code : int
    detail : any
        The server's reason, verbatim (the message renders it with :func:`format_detail`).
    method : str
    url : str

    Examples
    --------
    >>> from fpscan.clients.http import ApiError
    >>> exc = ApiError(422, [{"loc": ["body", "eps"], "msg": "must be in [1e-14, 1e-1]"}], method="POST")
    >>> print(exc)
    HTTP 422: eps: must be in [1e-14, 1e-1]
    >>> exc.status_code, exc.method
    (422, 'POST')
    """

    def __init__(self, status_code: int, detail: Any, *, method: str = "", url: str = ""):
        self.status_code = status_code
        self.detail = detail
        self.method = method
        self.url = url
        reason = format_detail(detail) or "no reason given"
        super().__init__(f"HTTP {status_code}: {reason}")


class AuthError(ApiError):
    """401/403: the bearer token is missing or wrong (401), or the server refuses the request's
    host or origin (403).

    A 401's message adds how to give the token (:data:`TOKEN_HINT`) after the server's reason;
    ``detail`` stays the server's reason verbatim.

    Parameters
    ----------
    status_code, detail, method, url
        As :class:`ApiError`.
    hint : str, optional
        How to give the token, appended to a 401's message (default :data:`TOKEN_HINT`, in the
        Python client's words; the command line names ``--token``).

    Attributes
    ----------
    status_code, detail, method, url
        As :class:`ApiError`.
    hint : str
        The hint of the message ("" for a 403).

    Examples
    --------
    >>> from fpscan.clients.http import ApiError, AuthError
    >>> from fpscan.clients.http.errors import error_for_status
    >>> exc = error_for_status(401, "missing bearer token")
    >>> type(exc).__name__, isinstance(exc, ApiError)
    ('AuthError', True)
    >>> print(exc)
    HTTP 401: missing bearer token; give the server's token: Client(url, token=...) or the FPSCAN_TOKEN environment variable
    """

    def __init__(self, status_code: int, detail: Any, *, method: str = "", url: str = "",
                 hint: str | None = None):
        super().__init__(status_code, detail, method=method, url=url)
        self.hint = (TOKEN_HINT if hint is None else hint) if status_code == 401 else ""
        if self.hint:
            self.args = (f"{self.args[0]}; {self.hint}",)


#: how to give the server's token, in a 401's message from the Python client
TOKEN_HINT = "give the server's token: Client(url, token=...) or the FPSCAN_TOKEN environment variable"


class NotFound(ApiError):
    """404: no such plan, job, dataset or file.

    Attributes
    ----------
    status_code, detail, method, url
        As :class:`ApiError`.

    Examples
    --------
    >>> from fpscan.clients.http.errors import error_for_status
    >>> exc = error_for_status(404, "no such job abc", method="GET", url="http://127.0.0.1:8000/api/jobs/abc")
    >>> type(exc).__name__, str(exc)
    ('NotFound', 'HTTP 404: no such job abc')
    """


class Conflict(ApiError):
    """409: the resource is in a state that does not allow the request.

    Attributes
    ----------
    status_code, detail, method, url
        As :class:`ApiError`.

    Examples
    --------
    >>> from fpscan.clients.http.errors import error_for_status
    >>> exc = error_for_status(409, "the scan is not running")
    >>> type(exc).__name__, exc.detail
    ('Conflict', 'the scan is not running')
    """


class JobError(FpscanClientError):
    """Base for jobs that ended without success.

    Parameters
    ----------
    job : Job or dict
        The job's record.
    message : str

    Attributes
    ----------
    job : Job or dict
        The job's record (``state``, ``error``, ``progress``, ...).

    Examples
    --------
    >>> from fpscan.clients.http import JobCancelled, JobError, JobFailed
    >>> issubclass(JobFailed, JobError), issubclass(JobCancelled, JobError)
    (True, True)
    >>> JobError({"id": "j1", "state": "cancelled"}, "job j1 was cancelled").job["state"]
    'cancelled'
    """

    def __init__(self, job: Any, message: str):
        self.job = job
        super().__init__(message)


class JobFailed(JobError):
    """The job ended in state ``failed``; the message is the server's ``error``.

    Attributes
    ----------
    job : Job or dict
        The job's record.

    Examples
    --------
    >>> from fpscan.clients.http import JobFailed
    >>> exc = JobFailed({"id": "j1", "state": "failed", "error": "out of memory"}, "job j1 failed: out of memory")
    >>> print(exc)
    job j1 failed: out of memory
    >>> exc.job["error"]
    'out of memory'
    """


class JobCancelled(JobError):
    """The job ended in state ``cancelled``.

    Attributes
    ----------
    job : Job or dict
        The job's record.

    Examples
    --------
    >>> from fpscan.clients.http import JobCancelled
    >>> exc = JobCancelled({"id": "j1", "state": "cancelled"}, "job j1 was cancelled")
    >>> print(exc)
    job j1 was cancelled
    >>> exc.job["state"]
    'cancelled'
    """


class WaitTimeout(FpscanClientError, TimeoutError):
    """Waiting on a job took longer than the caller's timeout.

    Attributes
    ----------
    args : tuple of str
        The message: the job and the state it was still in.

    Examples
    --------
    >>> from fpscan.clients.http import FpscanClientError, WaitTimeout
    >>> issubclass(WaitTimeout, TimeoutError), issubclass(WaitTimeout, FpscanClientError)
    (True, True)
    >>> print(WaitTimeout("job j1 still running after 5 s"))
    job j1 still running after 5 s
    """


def error_for_status(status_code: int, detail: Any, *, method: str = "", url: str = "") -> ApiError:
    """The :class:`ApiError` subclass matching an HTTP status.

    Parameters
    ----------
    status_code : int
        The HTTP status.
    detail : any
        The server's reason, as sent.
    method, url : str, optional
        Of the request.

    Returns
    -------
    ApiError
        :class:`AuthError` for 401/403, :class:`NotFound` for 404, :class:`Conflict` for 409,
        else :class:`ApiError`.

    Examples
    --------
    >>> from fpscan.clients.http.errors import error_for_status
    >>> type(error_for_status(403, "wrong token")).__name__
    'AuthError'
    >>> print(error_for_status(500, None))
    HTTP 500: no reason given
    """
    cls = {401: AuthError, 403: AuthError, 404: NotFound, 409: Conflict}.get(status_code, ApiError)
    return cls(status_code, detail, method=method, url=url)
