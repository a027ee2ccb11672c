"""The ``ShortIds`` ASGI middleware: a unique prefix of a job id works wherever a job id is
in the path."""
from __future__ import annotations

import re

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["ShortIds"]


class ShortIds:
    """ASGI middleware: a unique prefix of a job id works wherever a job id is in the path.

    A prefix of 4 to 31 hex characters (as the CLI and the web page show ids) in
    ``/api/jobs/…``, ``/api/scans/…`` or ``/api/reconstructions/…`` is rewritten to the full
    id; an ambiguous prefix is a 409 naming the matches; a prefix of no job is passed on as
    it is.

    Parameters
    ----------
    app : ASGI application
        The application it wraps.

    Attributes
    ----------
    app : ASGI application
        As given.
    PATH : re.Pattern
        The paths it rewrites (class attribute).
    """

    PATH = re.compile(r"^/api/(jobs|scans|reconstructions)/([0-9a-fA-F]{4,31})(/.*)?$")

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            m = self.PATH.match(scope.get("path", ""))
            context = getattr(getattr(scope.get("app"), "state", None), "ctx", None)
            if m and context is not None:
                import anyio

                found = await anyio.to_thread.run_sync(context.store.resolve, m.group(2))
                if len(found) > 1:
                    resp = JSONResponse({"detail": f"job id prefix {m.group(2)!r} matches several jobs "
                                                   f"({', '.join(found)}, ...): give more characters"}, 409)
                    return await resp(scope, receive, send)
                if len(found) == 1:
                    path = f"/api/{m.group(1)}/{found[0]}{m.group(3) or ''}"
                    scope = dict(scope, path=path, raw_path=path.encode())
        return await self.app(scope, receive, send)
