"""The 500 of an unexpected error (:func:`internal_error`) and the ``InternalErrors`` ASGI
middleware, the outermost of the app's own but for the browser headers
(``fpscan.service.api.browser_headers``, which only add headers): no error drops a kept-alive connection, and a
client gone mid-request (:func:`client_gone`) is no internal error."""
from __future__ import annotations

import logging
import uuid

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from fpscan.service.api.logcaps import RefusalLog, shown

__all__ = ["internal_error", "InternalErrors", "client_gone"]

log = logging.getLogger("fpscan.api")


def internal_error(scope: Scope, exc: BaseException) -> JSONResponse:
    """The 500 of an unexpected error: logged with a reference, the exception's name and message
    (capped, first in the line) and its traceback; the client told only the reference.

    Parameters
    ----------
    scope : dict
        The request's ASGI scope (its method and path, capped, are logged).
    exc : BaseException
        The error (logged with its traceback).

    Returns
    -------
    JSONResponse
        Status 500, ``{"detail": "internal error (reference <8 hex>)"}``.
    """
    ref = uuid.uuid4().hex[:8]
    log.error("internal error ref=%s %s %s: %s", ref, scope.get("method"), shown(scope.get("path", "")),
              shown(f"{type(exc).__name__}: {exc}"), exc_info=exc)
    return JSONResponse({"detail": f"internal error (reference {ref})"}, status_code=500)


class InternalErrors:
    """ASGI middleware, the outermost of the app's own but for the browser headers: an error
    no handler took becomes a 500 answer (:func:`internal_error`) and goes no further.
    Starlette's own last handler re-raises after answering, and uvicorn then closes the
    client's kept-alive connection and logs the traceback a second time; here the connection
    stays open for the client's next request. An error after the answer started is logged and the connection closed
    (there is no way to tell the client).

    A client gone (its disconnect received, its connection reset, a send to a closed
    connection: :func:`client_gone`) is no internal error: it is logged at most one line per
    client address per interval (``fpscan.service.api.logcaps.RefusalLog``), and nothing is answered.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.

    Attributes
    ----------
    app : ASGI application
        As given.
    gone : RefusalLog
        The rate-limited log of clients gone mid-request.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.gone = RefusalLog(log)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False
        disconnected = False

        async def tracked_receive() -> Message:
            nonlocal disconnected
            message = await receive()
            if message["type"] == "http.disconnect":
                disconnected = True
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, tracked_receive, tracked_send)
        except Exception as exc:
            if disconnected or client_gone(exc):
                client = (scope.get("client") or ("?", 0))[0]
                self.gone.refused(client, "client gone client=%s method=%s path=%s: %s", client,
                                  shown(scope.get("method"), 16), shown(scope.get("path", "")),
                                  shown(type(exc).__name__, 60))
                return
            if started:
                raise
            await internal_error(scope, exc)(scope, receive, send)


def client_gone(exc: BaseException) -> bool:
    """Whether ``exc`` says the client went away: a connection reset or broken pipe, a stream
    whose other end closed (anyio), Starlette's ``ClientDisconnect``, or a group of only those.

    Parameters
    ----------
    exc : BaseException
        The error a request's handling raised.

    Returns
    -------
    bool
        True for a client gone; False for anything else (an internal error).
    """
    import anyio
    from starlette.requests import ClientDisconnect

    if isinstance(exc, BaseExceptionGroup):
        return all(client_gone(e) for e in exc.exceptions)
    return isinstance(exc, (ConnectionError, anyio.ClosedResourceError, anyio.BrokenResourceError,
                            ClientDisconnect))
