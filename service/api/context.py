"""The running service's shared state (one per app) and the request dependencies that
reach it: settings, job store, reconstruction queue, scan manager, live previews."""
from __future__ import annotations

import hmac
import logging
from dataclasses import dataclass, field
from typing import Any

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.jobs.store import JobStore
from service.settings import Settings

log = logging.getLogger("fpscan.api")

bearer = HTTPBearer(auto_error=False, description="Bearer token (settings.token)")


@dataclass
class Context:
    settings: Settings
    store: JobStore
    queue: Any = None          # service.jobs.queue.ReconQueue
    scans: Any = None          # service.scanning.ScanManager
    extras: dict = field(default_factory=dict)


async def ctx(request: Request) -> Context:
    """FastAPI dependency: the service's shared :class:`Context` (app state)."""
    return request.app.state.ctx


def _check(settings: Settings, creds: HTTPAuthorizationCredentials | None) -> None:
    expected = settings.token_value()
    if expected is None:
        return
    if creds is None or creds.scheme.lower() != "bearer":
        raise HTTPException(401, "missing bearer token", headers={"WWW-Authenticate": "Bearer"})
    if not hmac.compare_digest(creds.credentials.encode(), expected.encode()):
        raise HTTPException(401, "invalid bearer token", headers={"WWW-Authenticate": "Bearer"})


async def require_token(request: Request, creds: HTTPAuthorizationCredentials | None = Depends(bearer)) -> None:
    """Mutating routes: the bearer token when one is configured (401 otherwise)."""
    _check(request.app.state.ctx.settings, creds)


async def read_access(request: Request, creds: HTTPAuthorizationCredentials | None = Depends(bearer)) -> None:
    """Reading routes: the bearer token only when the server is bound beyond loopback."""
    settings = request.app.state.ctx.settings
    if not settings.loopback_only:
        _check(settings, creds)


def reason(exc: BaseException) -> str:
    """The one-line reason for a refused input: a pydantic ``ValidationError`` as
    ``field: message; ...`` (no documentation URLs, no input echo), anything else as its
    text with line breaks folded."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        parts = [f"{'.'.join(str(p) for p in e.get('loc', ())) or 'value'}: "
                 f"{e.get('msg', 'invalid').removeprefix('Value error, ')}" for e in exc.errors()[:5]]
        return "; ".join(parts) or "invalid value"
    lines = [ln.strip() for ln in str(exc).splitlines()
             if ln.strip() and not ln.strip().startswith("For further information visit")]
    return "; ".join(lines) or type(exc).__name__
