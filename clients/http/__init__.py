"""The fpscan HTTP client: :class:`Client` (blocking) and :class:`AsyncClient`
(asyncio), both over httpx, and the exceptions they raise. See ``docs/api.md``."""
from .client import TERMINAL_STATES, AsyncClient, Client, field_of, to_dict
from .errors import (
    ApiError,
    AuthError,
    Conflict,
    FpscanClientError,
    JobCancelled,
    JobError,
    JobFailed,
    NotFound,
    ServerUnavailable,
    WaitTimeout,
)

__all__ = [
    "AsyncClient", "Client", "TERMINAL_STATES", "field_of", "to_dict",
    "ApiError", "AuthError", "Conflict", "FpscanClientError", "JobCancelled", "JobError",
    "JobFailed", "NotFound", "ServerUnavailable", "WaitTimeout",
]
