"""The server itself: health (``/api/health``), whether a token is needed (``/api/auth``) and
what it keeps (``/api/retention``)."""
from __future__ import annotations

from typing import Any

from fpscan.clients.http.calls import Call, Request, endpoint, read_json, read_model
from fpscan.clients.http.models import AuthInfo, Health, Retention

__all__ = ["Server"]


class Server:
    """The server's own endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`):
    methods of :class:`fpscan.clients.http.Client` and, as coroutines, of
    :class:`fpscan.clients.http.AsyncClient`.

    Attributes
    ----------
    health, auth, retention : Endpoint
        The declarations (each a request builder with the method's docstring).

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient, Client
    >>> from fpscan.clients.http.endpoints.server import Server
    >>> issubclass(Client, Server), issubclass(AsyncClient, Server)
    (True, True)
    >>> Server.health.build().request.path, Server.health.result_type().__name__
    ('/api/health', 'Health')
    >>> Server.retention.build(keep_results=3).request.method, Server.retention.build().request.method
    ('PUT', 'GET')
    """

    @endpoint
    def health() -> Call[Health]:
        """``GET /api/health``: whether the server is up, its version and what keeps jobs from running.

        Returns
        -------
        Health
            ``status`` (``"ok"``), ``version``, ``executor``, ``jobs_running``, ``disk``,
            ``problems``, ``devices`` (its fields read like a dict's too: ``health["version"]``).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (e.g. 503 while the server starts).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/health"), read_model(Health))

    @endpoint
    def auth() -> Call[AuthInfo]:
        """``GET /api/auth`` (needs no token): whether the server needs a token, and whether
        this client's is right.

        Returns
        -------
        dict
            ``{"token_required": bool, "authenticated": bool}`` (:class:`~fpscan.clients.http.models.AuthInfo`).

        Raises
        ------
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/auth"), read_json)

    @endpoint
    def retention(**policy: Any) -> Call[Retention]:
        """``GET /api/retention``, or ``PUT`` it with a new policy: what the server keeps.

        Parameters
        ----------
        **policy
            ``keep_results``, ``keep_bytes``, ``include_scans``, ``datasets_keep_bytes``,
            ``datasets_max_age_s`` (s); none: read the policy.

        Returns
        -------
        dict
            The policy (:class:`~fpscan.clients.http.models.Retention`).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 for an invalid value).
        ServerUnavailable
            The server cannot be reached.
        """
        if policy:
            return Call(Request("PUT", "/api/retention", json=policy), read_json)
        return Call(Request("GET", "/api/retention"), read_json)
