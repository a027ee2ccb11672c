"""Exceptions raised by the fpscan HTTP client.

Every error the server reports (a 4xx/5xx with ``{"detail": "<reason>"}``, see
``docs/api.md``) becomes an :class:`ApiError` carrying the HTTP status and the server's
``detail`` verbatim; transport failures become :class:`ServerUnavailable`; jobs that end
in ``failed``/``cancelled`` while being waited on raise :class:`JobFailed` /
:class:`JobCancelled` with the job's record attached.
"""
from __future__ import annotations

from typing import Any

__all__ = [
    "FpscanClientError", "ServerUnavailable", "format_detail", "ApiError", "AuthError", "NotFound",
    "Conflict", "JobError", "JobFailed", "JobCancelled", "WaitTimeout", "error_for_status",
]


class FpscanClientError(Exception):
    """Base class of everything the client raises on purpose."""


class ServerUnavailable(FpscanClientError):
    """The server could not be reached (connection refused, DNS, TLS or timeout)."""

    def __init__(self, base_url: str, reason: str):
        self.base_url = base_url
        self.reason = reason
        super().__init__(f"cannot reach fpscan server at {base_url}: {reason}")


def format_detail(detail: Any) -> str:
    """Render a FastAPI ``detail`` (string, or list of validation errors) on one line."""
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
    """The server answered with an error status.

    Attributes: ``status_code`` (int), ``detail`` (the server's reason, as sent),
    ``method`` and ``url`` of the request.
    """

    def __init__(self, status_code: int, detail: Any, *, method: str = "", url: str = ""):
        self.status_code = status_code
        self.detail = detail
        self.method = method
        self.url = url
        reason = format_detail(detail) or "no reason given"
        super().__init__(f"HTTP {status_code}: {reason}")


class AuthError(ApiError):
    """401/403: the bearer token is missing or wrong."""


class NotFound(ApiError):
    """404: no such plan, job, dataset or file."""


class Conflict(ApiError):
    """409: the resource is in a state that does not allow the request."""


class JobError(FpscanClientError):
    """Base for jobs that ended without success; ``job`` holds the job's record."""

    def __init__(self, job: Any, message: str):
        self.job = job
        super().__init__(message)


class JobFailed(JobError):
    """The job ended in state ``failed``; the message is the server's ``error``."""


class JobCancelled(JobError):
    """The job ended in state ``cancelled``."""


class WaitTimeout(FpscanClientError, TimeoutError):
    """Waiting on a job took longer than the caller's timeout."""


def error_for_status(status_code: int, detail: Any, *, method: str = "", url: str = "") -> ApiError:
    """The :class:`ApiError` subclass matching ``status_code``."""
    cls = {401: AuthError, 403: AuthError, 404: NotFound, 409: Conflict}.get(status_code, ApiError)
    return cls(status_code, detail, method=method, url=url)
