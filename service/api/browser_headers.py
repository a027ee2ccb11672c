"""Headers a browser obeys, on every answer of the server: its pages may not be framed by
another site, and run only the server's own scripts.

:class:`BrowserHeaders` (the outermost ASGI middleware) adds to every HTTP response that does
not set them itself:

- ``Content-Security-Policy`` (W3C Content Security Policy Level 3): :data:`PAGE_POLICY`;
  ``frame-ancestors 'none'`` (no page of any origin, this one's included, may frame it:
  clickjacking), scripts and styles from this origin only (no inline script, no ``eval``),
  pictures from this origin, ``blob:`` and ``data:`` (the web page's pictures fetched with the
  token), requests to this origin only, no plugins, no ``<base>``, forms posted here only;
- ``X-Frame-Options: DENY`` (RFC 7034), the same frame rule for browsers without CSP Level 2;
- ``X-Content-Type-Options: nosniff``: a download is never run as a script or a page of
  this origin for its content.

Sources: OWASP Clickjacking Defense Cheat Sheet ("Content-Security-Policy: frame-ancestors",
"X-Frame-Options"), OWASP Content Security Policy Cheat Sheet ("Strict policy").
"""
from __future__ import annotations

from collections.abc import MutableMapping
from typing import Any

from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["PAGE_POLICY", "SECURITY_HEADERS", "BrowserHeaders"]

#: The Content-Security-Policy of every answer that sets none itself.
PAGE_POLICY = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
               "connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
               "frame-ancestors 'none'")

#: The headers :class:`BrowserHeaders` adds (lower-case names), in order.
SECURITY_HEADERS: tuple[tuple[bytes, bytes], ...] = (
    (b"content-security-policy", PAGE_POLICY.encode()),
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
)


class BrowserHeaders:
    """ASGI middleware: :data:`SECURITY_HEADERS` on every HTTP response that does not set
    the header itself (a page with a policy of its own keeps it).

    Parameters
    ----------
    app : ASGI application
        The application it wraps.

    Attributes
    ----------
    app : ASGI application
        As given.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def send_with_headers(message: MutableMapping[str, Any]) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers") or ())
                present = {name.lower() for name, _ in headers}
                headers += [(name, value) for name, value in SECURITY_HEADERS if name not in present]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)
