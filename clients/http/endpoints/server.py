"""The server itself: health (``/api/health``), whether a token is needed (``/api/auth``) and
what it keeps (``/api/retention``)."""
from __future__ import annotations

from typing import Any

from fpscan.clients.http.calls import AsyncCaller, Call, Request, SyncCaller, read_json

__all__ = ["Server", "AsyncServer"]


def _build_health() -> Call[Any]:
    """``GET /api/health`` (:meth:`Server.health`)."""
    return Call(Request("GET", "/api/health"), read_json)


def _build_auth() -> Call[Any]:
    """``GET /api/auth`` (:meth:`Server.auth`)."""
    return Call(Request("GET", "/api/auth"), read_json)


def _build_retention(policy: dict[str, Any]) -> Call[Any]:
    """``GET /api/retention``, or ``PUT`` with a policy (:meth:`Server.retention`)."""
    if policy:
        return Call(Request("PUT", "/api/retention", json=policy), read_json)
    return Call(Request("GET", "/api/retention"), read_json)


class Server(SyncCaller):
    """The server's own endpoints on :class:`fpscan.clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.server import Server
    >>> issubclass(Client, Server)
    True
    """

    def health(self) -> Any:
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
        return self._call(_build_health())

    def auth(self) -> Any:
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
        return self._call(_build_auth())

    def retention(self, **policy: Any) -> Any:
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
        return self._call(_build_retention(policy))


class AsyncServer(AsyncCaller):
    """The server's own endpoints on :class:`fpscan.clients.http.AsyncClient`: :class:`Server`'s methods
    as coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.endpoints.server import AsyncServer
    >>> issubclass(AsyncClient, AsyncServer)
    True
    """

    async def health(self) -> Any:
        """As :meth:`Server.health`, awaited."""
        return await self._call(_build_health())

    async def auth(self) -> Any:
        """As :meth:`Server.auth`, awaited."""
        return await self._call(_build_auth())

    async def retention(self, **policy: Any) -> Any:
        """As :meth:`Server.retention`, awaited."""
        return await self._call(_build_retention(policy))
