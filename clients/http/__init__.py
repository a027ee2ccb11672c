"""The fpscan HTTP client: :class:`Client` (blocking) and :class:`AsyncClient`
(asyncio), both over httpx, and the exceptions they raise. See ``docs/api.md``."""
from fpscan.clients.http.async_client import AsyncClient
from fpscan.clients.http.calls import field_of, to_dict
from fpscan.clients.http.client import Client
from fpscan.clients.http.errors import (
    ApiError,
    AuthError,
    BadAnswer,
    Conflict,
    FpscanClientError,
    JobCancelled,
    JobError,
    JobFailed,
    NotFound,
    ServerUnavailable,
    WaitTimeout,
)
from fpscan.clients.http.waiting import TERMINAL_STATES

__all__ = [
    "AsyncClient", "Client", "TERMINAL_STATES", "field_of", "to_dict",
    "ApiError", "AuthError", "BadAnswer", "Conflict", "FpscanClientError", "JobCancelled", "JobError",
    "JobFailed", "NotFound", "ServerUnavailable", "WaitTimeout",
]
