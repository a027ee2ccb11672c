"""The fpscan HTTP client: :class:`Client` (blocking) and :class:`AsyncClient`
(asyncio), both over httpx, and the exceptions they raise. See ``docs/api.md``."""
from .async_client import AsyncClient
from .calls import field_of, to_dict
from .client import Client
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
from .waiting import TERMINAL_STATES

__all__ = [
    "AsyncClient", "Client", "TERMINAL_STATES", "field_of", "to_dict",
    "ApiError", "AuthError", "Conflict", "FpscanClientError", "JobCancelled", "JobError",
    "JobFailed", "NotFound", "ServerUnavailable", "WaitTimeout",
]
