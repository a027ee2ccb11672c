"""The running service's shared state (one per app) and the request dependencies that
reach it: settings, job store, reconstruction queue, scan manager, live previews."""
from __future__ import annotations

import contextlib
import hmac
import logging
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from fastapi import Depends, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from fpscan.service.jobs.store import JobStore
from fpscan.service.settings import Settings

__all__ = ["bearer", "Slots", "default_slots", "Context", "ctx", "require_token", "read_access", "DETAIL_MAX", "capped",
           "reason", "validation_reason"]

log = logging.getLogger("fpscan.api")

bearer = HTTPBearer(auto_error=False, description="Bearer token (settings.token)")


class Slots:
    """Bounded admission for requests that do expensive work (an upload's import, building
    a plan): at most ``running`` of them work at once, at most ``waiting`` more wait for a
    turn, and any further one is refused at once with 429 and ``Retry-After`` — so a flood
    neither queues without bound (each waiting request holds a server thread; an import
    also a child process) nor starves the cheap routes (``/api/health``, status reads).

    ``enter``/``leave`` count a request in and out (the ``UploadLimit`` middleware does it
    before the body is read); the route's ``turn()`` waits for one of the ``running``
    turns. With ``per_client``, slots go per client first: a client address holding
    ``per_client`` of them already gets another only while more than ``per_client`` stay
    free for the others, so no one client takes them all (ten uploads trickling in from
    one address left none for anyone else). Thread-safe.

    Parameters
    ----------
    what : str
        What is admitted, as the 429's reason names it (``"uploads"``, ``"plan requests"``).
    running : int
        Requests that may work at once.
    waiting : int
        Requests that may wait for a turn beyond them.
    retry_after_s : int, optional
        The ``Retry-After`` of a refusal in s; default 5.
    per_client : int or None, optional
        A client's share (see above); default None: no per-client rule.

    Attributes
    ----------
    what : str
        As given.
    limit : int
        ``running + waiting``: requests counted in at most.
    retry_after_s : int
        As given.
    per_client : int or None
        As given.
    """

    def __init__(self, what: str, running: int, waiting: int, retry_after_s: int = 5, per_client: int | None = None):
        self.what = what
        self.limit = running + waiting
        self.retry_after_s = retry_after_s
        self.per_client = per_client
        self._turns = threading.BoundedSemaphore(running)
        self._lock = threading.Lock()
        self._inside = 0
        self._by_client: dict[str | None, int] = {}

    def enter(self, client: str | None = None) -> bool:
        """Count one more request of ``client`` in.

        Parameters
        ----------
        client : str or None, optional
            The client's address; default None.

        Returns
        -------
        bool
            True when counted in; False (not counted) when ``running + waiting`` are in, or
            when ``client`` holds its share and no more than that share is free for the others.
        """
        with self._lock:
            if self._inside >= self.limit:
                return False
            mine = self._by_client.get(client, 0)
            if self.per_client is not None and mine >= self.per_client \
                    and self.limit - self._inside <= self.per_client:
                return False
            self._inside += 1
            self._by_client[client] = mine + 1
            return True

    def leave(self, client: str | None = None) -> None:
        with self._lock:
            self._inside = max(0, self._inside - 1)
            mine = self._by_client.get(client, 0) - 1
            if mine > 0:
                self._by_client[client] = mine
            else:
                self._by_client.pop(client, None)

    def held(self, client: str | None = None) -> int:
        """Slots ``client`` holds now."""
        with self._lock:
            return self._by_client.get(client, 0)

    def busy_reason(self, client: str | None = None) -> str:
        mine = self.held(client)
        if self.per_client is not None and mine >= self.per_client:
            return (f"too many {self.what} at once from this client ({mine} in progress or waiting; the rest of the "
                    f"server's {self.limit} are kept for others); retry in {self.retry_after_s} s")
        return f"too many {self.what} at once ({self.limit} in progress or waiting); retry in {self.retry_after_s} s"

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        """Hold one of the ``running`` turns for the block (waits for it)."""
        with self._turns:
            yield


def default_slots(settings: Settings) -> dict[str, Slots]:
    """The admission bounds of a service.

    Parameters
    ----------
    settings : Settings
        The service's settings (``import_workers``, ``uploads_per_client``).

    Returns
    -------
    dict of str to Slots
        ``uploads`` (``settings.import_workers`` imports at once, 4x as many waiting),
        ``plans`` (one plan built at a time, 8 waiting: plan work is mostly JSON and
        validation holding the GIL, so a second thread would only slow the other routes
        down), both per client first (``settings.uploads_per_client``, default
        ``import_workers``: :class:`Slots`' ``per_client``), and ``exports``
        (``settings.export_workers`` export builds at once, 4x as many waiting:
        ``fpscan.service.api.exports``).
    """
    n = settings.import_workers
    share = settings.uploads_per_client or n
    e = settings.export_workers
    return {"uploads": Slots("uploads", n, 4 * n, per_client=share),
            "plans": Slots("plan requests", 1, 8, per_client=share),
            "exports": Slots("exports", e, 4 * e)}


@dataclass
class Context:
    """The running service's shared state, one per app (``app.state.ctx``).

    Attributes
    ----------
    settings : Settings
        The service's settings.
    store : JobStore
        The job store.
    queue : fpscan.service.jobs.queue.ReconQueue or None
        The reconstruction queue (None when the app runs without workers).
    scans : fpscan.service.jobs.scan_manager.ScanManager or None
        The scan manager (None without workers or without a scanner driver).
    wakeups : fpscan.service.api.jobs.EventWakeups or None
        The store's events wake the job streams through it.
    extras : dict
        Other shared objects, by name.
    slots : dict of str to Slots
        The admission bounds (:func:`default_slots`).
    """

    settings: Settings
    store: JobStore
    queue: Any = None          # fpscan.service.jobs.queue.ReconQueue
    scans: Any = None          # fpscan.service.jobs.scan_manager.ScanManager
    wakeups: Any = None        # fpscan.service.api.jobs.EventWakeups: the store's events wake the job streams
    extras: dict = field(default_factory=dict)
    slots: dict[str, Slots] = field(default_factory=dict)  # default_slots(settings)


async def ctx(request: Request) -> Context:
    """FastAPI dependency: the service's shared :class:`Context` (app state).

    Parameters
    ----------
    request : fastapi.Request
        The request.

    Returns
    -------
    Context
        ``request.app.state.ctx``.
    """
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
    """FastAPI dependency of the mutating routes: the bearer token when one is configured.

    Parameters
    ----------
    request : fastapi.Request
        The request.
    creds : HTTPAuthorizationCredentials or None
        Its ``Authorization`` header, as :data:`bearer` reads it.

    Raises
    ------
    fastapi.HTTPException
        401 (``WWW-Authenticate: Bearer``) for a missing or wrong token.
    ValueError
        When the token file cannot be read (``Settings.token_value``).
    """
    _check(request.app.state.ctx.settings, creds)


async def read_access(request: Request, creds: HTTPAuthorizationCredentials | None = Depends(bearer)) -> None:
    """FastAPI dependency of the reading routes: the bearer token whenever one is configured.

    On a loopback bind too (``fpscan.service.api.access.AccessGate`` has already refused a request
    without it, before anything was reserved; this is the route's own check).

    Parameters
    ----------
    request : fastapi.Request
        The request.
    creds : HTTPAuthorizationCredentials or None
        Its ``Authorization`` header, as :data:`bearer` reads it.

    Raises
    ------
    fastapi.HTTPException
        401 (``WWW-Authenticate: Bearer``) for a missing or wrong token.
    ValueError
        When the token file cannot be read (``Settings.token_value``).
    """
    _check(request.app.state.ctx.settings, creds)


#: longest reason a 4xx carries (characters): a refused value is echoed in part, never whole
#: (a request may carry a 60 kB string; its echo would be the answer's bulk)
DETAIL_MAX = 1000


def capped(text: str, limit: int = DETAIL_MAX) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was when cut.

    Parameters
    ----------
    text : str
        The text.
    limit : int, optional
        The most characters kept; default :data:`DETAIL_MAX` (1000).

    Returns
    -------
    str
        ``text`` itself, or its first ``limit`` characters followed by
        ``"... (<n> characters in all)"``.
    """
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters in all)"


def validation_reason(exc: RequestValidationError) -> str:
    """The one-line reason of a 422 for a request FastAPI refused.

    Parameters
    ----------
    exc : RequestValidationError
        FastAPI's refusal.

    Returns
    -------
    str
        ``field: message; ...`` (at most five, each capped, naming a refused literal value),
        or ``"malformed JSON: ..."`` with the JSON parser's message for a malformed body.
    """
    from fpscan.service.api.models import DEFAULT_METHOD_TAG, REQUEST_MODELS

    tags = {*REQUEST_MODELS, DEFAULT_METHOD_TAG}  # a union's variant in a location is the body's own method
    parts = []
    for err in exc.errors()[:5]:
        where = list(err.get("loc", ()))
        if len(where) > 2 and where[0] == "body" and where[1] in tags:
            del where[1]
        loc = ".".join(str(p) for p in where if p != "body") or "body"
        msg = err.get("msg", "invalid").removeprefix("Value error, ")
        if loc == "params" and err.get("type") == "value_error":  # a rule across a method's options names them
            parts.append(capped(msg, DETAIL_MAX // 4))
            continue
        if err.get("type") == "json_invalid":
            return f"malformed JSON: {err.get('ctx', {}).get('error', msg)}"
        if err.get("type") in ("literal_error", "enum") and isinstance(err.get("input"), (str, int, float)):
            msg = f"{msg}, got {str(err['input'])[:64]!r}"  # name the refused value
        parts.append(capped(f"{loc}: {msg}", DETAIL_MAX // 4))
    return "; ".join(parts) or "invalid request"


def reason(exc: BaseException) -> str:
    """The one-line reason for a refused input.

    Parameters
    ----------
    exc : BaseException
        The error.

    Returns
    -------
    str
        A pydantic ``ValidationError`` as ``field: message; ...`` (at most five; no
        documentation URLs, no input echo), anything else as its text with line breaks
        folded (its type's name when it has none); capped at :data:`DETAIL_MAX` characters.
    """
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        parts = [capped(f"{'.'.join(str(p) for p in e.get('loc', ())) or 'value'}: "
                        f"{e.get('msg', 'invalid').removeprefix('Value error, ')}", DETAIL_MAX // 4)
                 for e in exc.errors()[:5]]
        return "; ".join(parts) or "invalid value"
    lines = [ln.strip() for ln in str(exc).splitlines()
             if ln.strip() and not ln.strip().startswith("For further information visit")]
    return capped("; ".join(lines) or type(exc).__name__)
