"""Who may talk to the service, decided before any work is done for a request.

:class:`AccessGate` (the outermost ASGI middleware but for health's lane,
``fpscan.service.api.lanes.HealthLane``, which applies its rules first) answers a request from
its headers alone, before a slot is counted, a turn or a thread taken or a byte of the
body read:

- ``Host``: a request whose ``Host`` header is not a loopback name (``localhost``,
  ``127.0.0.1`` and the rest of 127.0.0.0/8, ``[::1]``; any port), the server's own bind
  address or one the operator listed (``settings.allowed_hosts``, ``fpscan serve
  --allowed-host NAME``) is refused with 403: a web page on another site that rebinds its
  DNS name to this machine (DNS rebinding) gets nothing, with or without a token.
- the bearer token, when one is configured: every ``/api/...`` route needs it (reads
  included), checked in constant time (``hmac.compare_digest``); a request without it is
  answered 401 at once, so clients without the token never occupy an upload or plan slot.
  ``GET /api/auth`` (does the server need a token; is the one sent right), the web page's
  static files and the API schema pages need none.
- ``Origin``/``Referer``, when no token is configured (the server then binds loopback
  only): a state-changing request (POST, PUT, PATCH, DELETE) from a page of another origin
  (its ``Origin``, or its ``Referer`` when it sends no ``Origin``) is refused with 403, so a
  web page the lab's browser visits cannot abort a scan with a form post (CSRF). Clients
  that send neither header (the CLI, the Python client, curl) are not browsers and pass.
"""
from __future__ import annotations

import hmac
import logging
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from fpscan.service.api.logcaps import RefusalLog, shown
from fpscan.service.settings import Settings, is_loopback

__all__ = [
    "STATE_CHANGING", "PUBLIC_API_PATHS", "WILDCARD_BINDS", "host_name", "host_allowed", "same_origin",
    "token_matches", "AccessGate",
]

log = logging.getLogger("fpscan.api")

#: Methods that change the server's state (the Origin rule applies to them).
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: API paths answered without the token.
PUBLIC_API_PATHS = frozenset({"/api/auth"})
#: Bind addresses that listen on every interface (they name no host a client would use).
WILDCARD_BINDS = frozenset({"0.0.0.0", "::", ""})


def host_name(host_header: str) -> str:
    """The host part of a ``Host`` header, lower case, without port or trailing dot.

    ``"[::1]:8000"`` → ``"::1"``, ``"Example.org.:80"`` → ``"example.org"``.

    Parameters
    ----------
    host_header : str
        The ``Host`` header's value.

    Returns
    -------
    str
        The host name (``""`` for an empty header).
    """
    h = host_header.strip().lower()
    if h.startswith("["):
        h = h[1:h.find("]")] if "]" in h else h[1:]
    elif h.count(":") == 1:
        h = h.rsplit(":", 1)[0]
    return h.rstrip(".")


def host_allowed(name: str, settings: Settings) -> bool:
    """Whether clients may reach the server by host name ``name``.

    Allowed: a loopback name, the server's own (non-wildcard) bind address, or one of
    ``settings.allowed_hosts`` (``"*"``: any, honoured only when a token is configured:
    without one, any name would reopen the DNS-rebinding door, however the server was
    started; ``fpscan serve`` refuses that combination up front).

    Parameters
    ----------
    name : str
        The host name, as :func:`host_name` gives it.
    settings : Settings
        The service's settings (``allowed_hosts``, ``host``, the token).

    Returns
    -------
    bool
        True when the name is allowed; False for ``""``.

    Raises
    ------
    ValueError
        When ``"*"`` is allowed and the token file cannot be read (``Settings.token_value``).
    """
    if not name:
        return False
    if is_loopback(name):
        return True
    allowed = set(settings.allowed_hosts)
    bind = settings.host.strip().lower().strip("[]")
    if bind not in WILDCARD_BINDS:
        allowed.add(bind)
    if "*" in allowed and settings.token_value() is not None:
        return True
    return name in allowed


def same_origin(source: str, host_header: str) -> bool:
    """Whether ``source`` names the host and port the request was sent to.

    Parameters
    ----------
    source : str
        An ``Origin`` or ``Referer`` header's value.
    host_header : str
        The request's ``Host`` header.

    Returns
    -------
    bool
        True when ``source``'s network location (lower case, without a trailing dot) equals
        the ``Host`` header; False for ``"null"`` (a sandboxed or file page), an unparsable
        URL or one with user information.
    """
    try:
        netloc = urlsplit(source.strip()).netloc.lower()
    except ValueError:
        return False
    if not netloc or "@" in netloc:
        return False
    return netloc.rstrip(".") == host_header.strip().lower()


def token_matches(authorization: str | None, expected: str) -> str | None:
    """Check the bearer token of an ``Authorization`` header, in constant time.

    Parameters
    ----------
    authorization : str or None
        The ``Authorization`` header's value (None: no header).
    expected : str
        The configured token.

    Returns
    -------
    str or None
        None when the header carries ``Bearer <expected>``, else the reason for the refusal
        (``"missing bearer token"`` or ``"invalid bearer token"``).
    """
    if not authorization:
        return "missing bearer token"
    scheme, _, value = authorization.strip().partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return "missing bearer token"
    if not hmac.compare_digest(value.strip().encode(), expected.encode()):
        return "invalid bearer token"
    return None


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers") or ():
        if key == name:
            return value.decode("latin-1")
    return None


class AccessGate:
    """ASGI middleware: the Host, token and Origin rules of this module.

    They apply to every HTTP request (and websocket) from its headers alone: nothing of the
    body is read for a refusal, and the refusal closes the connection (401 with
    ``WWW-Authenticate: Bearer``, 403, or 503 when the token file cannot be read). Refusals
    are logged at most one line per client address per interval, each field capped
    (``fpscan.service.api.logcaps``).

    Parameters
    ----------
    app : ASGI application
        The application it guards.
    settings : Settings
        The service's settings (the token is read on each request, so a rotated
        ``token_file`` takes effect at once).

    Attributes
    ----------
    app : ASGI application
        As given.
    settings : Settings
        As given.
    refusals : RefusalLog
        The rate-limited log of refusals.
    """

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.settings = settings
        self.refusals = RefusalLog(log)  # one line per client address per interval, fields capped

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        refusal = self.refusal(scope)
        if refusal is not None:
            status, detail = refusal
            headers = {"Connection": "close"}
            if status == 401:
                headers["WWW-Authenticate"] = "Bearer"
            client = scope.get("client") or ("?", 0)
            self.refusals.refused(client[0], "refused client=%s method=%s path=%s status=%s: %s", client[0],
                                  shown(scope.get("method"), 16), shown(scope.get("path", "")), status, detail)
            if scope["type"] == "websocket":
                return await send({"type": "websocket.close", "code": 1008})
            return await JSONResponse({"detail": detail}, status, headers=headers)(scope, receive, send)
        return await self.app(scope, receive, send)

    def refusal(self, scope: Scope) -> tuple[int, str] | None:
        """The refusal of a request, from its headers.

        Parameters
        ----------
        scope : dict
            The ASGI scope.

        Returns
        -------
        tuple of (int, str) or None
            ``(status, reason)`` when the request is refused, else None.
        """
        host = _header(scope, b"host")
        if host is None:
            return 403, "the request has no Host header; send the name the server is reached by"
        name = host_name(host)
        if not host_allowed(name, self.settings):
            return 403, (f"this server does not answer to the host name {name[:100]!r}; reach it as localhost "
                         "(or 127.0.0.1), or have the operator allow the name (fpscan serve --allowed-host NAME, "
                         "setting allowed_hosts)")
        path = scope.get("path", "")
        try:
            expected = self.settings.token_value()
        except ValueError as exc:  # an unreadable token file: refuse rather than run open
            log.error("token unreadable: %s", exc)
            return 503, "the server cannot read its token file; the operator must fix it"
        if expected is not None:
            if path.startswith("/api/") and path.rstrip("/") not in PUBLIC_API_PATHS:
                why = token_matches(_header(scope, b"authorization"), expected)
                if why is not None:
                    return 401, why
            return None
        if scope.get("method", "").upper() in STATE_CHANGING:
            origin = _header(scope, b"origin")
            source, what = (origin, "Origin") if origin is not None else (_header(scope, b"referer"), "Referer")
            if source is not None and not same_origin(source, host):
                return 403, (f"cross-origin request refused: its {what} {source[:100]!r} is not this server's "
                             "own origin (without a token only the server's own web page may change state)")
        return None
