"""Error handling: every error answers ``{"detail": "<reason>"}`` (internals stay in the
log), and the error answers every route may give, as the OpenAPI schema documents them."""
from __future__ import annotations

import logging
import sqlite3
from collections.abc import Iterable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import BaseRoute
from starlette.types import Scope

from fpscan.service.api.context import capped, validation_reason
from fpscan.service.api.internal_errors import internal_error
from fpscan.service.api.logcaps import shown
from fpscan.service.api.models import Error
from fpscan.service.disk import is_disk_full

__all__ = ["ERROR_RESPONSES", "allowed_methods", "add_error_handlers"]

log = logging.getLogger("fpscan.api")

#: The error answers every route may give (``{"detail": reason}``, :class:`~fpscan.service.api.models.Error`),
#: by status, as the OpenAPI schema documents them.
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": Error, "description": "bad request"},
    401: {"model": Error, "description": "missing or invalid bearer token"},
    403: {"model": Error, "description": "refused: a Host name the server does not answer to, or (no token "
                                         "configured) a state-changing request from another origin"},
    404: {"model": Error, "description": "not found"},
    409: {"model": Error, "description": "conflict with the resource's state"},
    408: {"model": Error, "description": "an upload or plan request body stalled (FPSCAN_BODY_TIMEOUT_S)"},
    413: {"model": Error, "description": "upload too large"},
    422: {"model": Error, "description": "invalid input (the reason is in detail)"},
    429: {"model": Error, "description": "too many expensive requests (uploads, plans) in progress; "
                                         "retry after Retry-After seconds"},
    503: {"model": Error, "description": "the data folder's disk is full; free space, then retry"},
}


def allowed_methods(app: FastAPI, scope: Scope) -> list[str]:
    """The HTTP methods the routes matching ``scope``'s path take, for a 405's ``Allow`` header.

    RFC 9110 §15.5.6; included routers are walked too.

    Parameters
    ----------
    app : FastAPI
        The application.
    scope : dict
        The request's ASGI scope (its path is matched; its method is not).

    Returns
    -------
    list of str
        The methods, sorted (with HEAD where GET is, as the routes declare them).
    """
    from starlette.routing import Match

    methods: set[str] = set()
    probe = {**scope, "method": "GET"}

    def walk(routes: Iterable[BaseRoute]) -> None:
        for route in routes:
            inner = getattr(route, "original_router", None)  # an included router (FastAPI wraps them)
            if inner is not None:
                walk(inner.routes)
                continue
            route_methods = getattr(route, "methods", None)
            if not route_methods:
                continue
            try:
                match, _ = route.matches(probe)
            except Exception:  # a route type that cannot judge this scope: not ours
                continue
            if match != Match.NONE:
                methods.update(route_methods)

    walk(app.router.routes)
    return sorted(methods)


def add_error_handlers(app: FastAPI) -> None:
    """Make every error answer ``{"detail": reason}``.

    422 for invalid values (:func:`~fpscan.service.api.context.validation_reason`), the HTTP
    error's own status (405 with the path's ``Allow``: :func:`allowed_methods`), 503 with
    ``Retry-After`` for a full disk (an ``OSError`` or ``sqlite3.Error`` that says so), 500
    with a reference for anything else (:func:`~fpscan.service.api.internal_errors.internal_error`).

    Parameters
    ----------
    app : FastAPI
        The application the handlers are added to.
    """

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": validation_reason(exc)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = capped(exc.detail if isinstance(exc.detail, str) else str(exc.detail))
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # Allow: every method of the path (Starlette names only the first route's)
            allowed = allowed_methods(app, request.scope)
            headers = {**(headers or {}), "Allow": ", ".join(allowed)} if allowed else headers
            detail = f"method {request.method} not allowed here; allowed: {', '.join(allowed)}" if allowed else detail
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=headers)

    @app.exception_handler(OSError)
    @app.exception_handler(sqlite3.Error)
    async def _storage(request: Request, exc: Exception) -> JSONResponse:
        # handled here, not by the catch-all below (Starlette re-raises from that one and
        # the server then drops the client's kept-alive connection)
        if is_disk_full(exc):  # the server's condition, not a bug: say so, and how to fix it
            log.warning("disk full %s %s: %s", request.method, shown(request.url.path), exc)
            return JSONResponse({"detail": "the data folder's disk is full; free space, then retry "
                                           "(/api/health shows the free bytes)"},
                                status_code=503, headers={"Retry-After": "10"})
        return await _internal(request, exc)

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        return internal_error(request.scope, exc)
