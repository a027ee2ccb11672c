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
- wrong tokens, counted per client address (:class:`TokenFailures`): after
  :data:`FREE_FAILURES` wrong tokens an address waits, twice as long after each further one
  (1 s, 2 s, 4 s ... at most :data:`MOST_WAIT_S`). Every token is still compared, so the right
  token is answered at once from any address, the waiting one included; a wrong one from a
  waiting address is answered 429 with ``Retry-After``, but only after the wait it owes (at
  most :data:`HOLD_S`; the answer is held on the event loop, which goes on serving everyone
  else) and it doubles the wait. This gate is the one place that holds and answers a wrong
  token, on every kind of connection: a connection the server took on probation (beyond its
  strangers' budget, ``fpscan.service.api.connections``) passes its wrong token on here too
  (:data:`PROBATION_EXTENSION`), and it is refused whatever its path. A guesser therefore
  learns nothing faster than the waits allow, one guess per connection per wait, and the
  server's per-client connection caps bound its connections (OWASP Authentication Cheat Sheet,
  "Protect against automated attacks": throttle the failures, not the account's owner).
- ``Origin``/``Referer``, when no token is configured (the server then binds loopback
  only): a state-changing request (POST, PUT, PATCH, DELETE) from a page of another origin
  (its ``Origin``, or its ``Referer`` when it sends no ``Origin``) is refused with 403, so a
  web page the lab's browser visits cannot abort a scan with a form post (CSRF). Clients
  that send neither header (the CLI, the Python client, curl) are not browsers and pass.
"""
from __future__ import annotations

import asyncio
import collections
import hmac
import ipaddress
import logging
import math
import time
from collections.abc import Callable
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from fpscan.service.api.logcaps import RefusalLog, shown
from fpscan.service.settings import Settings, is_loopback

__all__ = [
    "STATE_CHANGING", "PUBLIC_API_PATHS", "WILDCARD_BINDS", "FREE_FAILURES", "FIRST_WAIT_S", "MOST_WAIT_S",
    "HOLD_S", "PROBATION_EXTENSION", "host_name", "host_allowed", "same_origin", "token_matches", "failure_key", "TokenFailures", "AccessGate",
]

log = logging.getLogger("fpscan.api")

#: Methods that change the server's state (the Origin rule applies to them).
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: API paths answered without the token.
PUBLIC_API_PATHS = frozenset({"/api/auth"})
#: Bind addresses that listen on every interface (they name no host a client would use).
WILDCARD_BINDS = frozenset({"0.0.0.0", "::", ""})
#: Wrong tokens a client address may send before it waits (a person's typos, and a burst of
#: clients on one address sent with a stale token, never wait).
FREE_FAILURES = 32
#: The wait after the first wrong token beyond :data:`FREE_FAILURES`, s; doubled after each further one.
FIRST_WAIT_S = 1.0
#: The longest wait, s: at most one guess per 5 minutes per connection of an address once reached.
MOST_WAIT_S = 300.0
#: The longest a wrong token from a waiting address is held before its 429, s (a connection
#: left open longer would cost the server more than the guess is worth).
HOLD_S = 30.0
#: The ASGI scope extension (``scope["extensions"]``, ASGI "Extensions") the server's connection
#: layer (``fpscan.service.api.connections.GuardedHttp``) sets on a request with a wrong token from
#: a connection on probation: :class:`AccessGate` refuses it whatever its path (a probation
#: connection is served for the right token only).
PROBATION_EXTENSION = "fpscan.probation"


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


def failure_key(address: str) -> str:
    """The key wrong tokens are counted under for a client address: the address itself, or its
    /64 network for IPv6 (one host there commonly holds a whole /64: RFC 4291 section 2.5.1),
    an IPv4-mapped IPv6 address as its IPv4 address.

    Parameters
    ----------
    address : str
        The client's address, as the server saw it (anything that is not an IP address is its
        own key).

    Returns
    -------
    str
        The key.

    Examples
    --------
    >>> failure_key("2001:db8::1:2")
    '2001:db8::/64'
    >>> failure_key("::ffff:192.0.2.7")
    '192.0.2.7'
    """
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return address
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.IPv6Network((ip, 64), strict=False))
    return str(ip)


class TokenFailures:
    """Wrong bearer tokens counted per client address (:func:`failure_key`), and the wait
    each address owes.

    An address's first ``free`` wrong tokens cost nothing; the next one starts a wait of
    ``first_wait_s``, each further one twice the last, at most ``most_wait_s``. Every token is
    still compared: a wrong one sent during the wait is answered (429) only when the wait is over
    (:meth:`wait_s` says how long is left; :class:`AccessGate` holds the answer, at most
    :data:`HOLD_S`) and counts as a further one; the right one is answered at once.
    ``2 * most_wait_s`` without a wrong token clear the address's count (a right token does not: a guesser sharing an address with a busy client
    would get its free guesses again and again). At most ``max_addresses`` addresses are
    remembered (the one whose last wrong token is the oldest goes first), some 100 bytes
    each. Used from the event loop only (not thread-safe).

    Parameters
    ----------
    free : int, optional
        Wrong tokens before the first wait; default :data:`FREE_FAILURES`.
    first_wait_s : float, optional
        The first wait, s; default :data:`FIRST_WAIT_S`.
    most_wait_s : float, optional
        The longest wait, s; default :data:`MOST_WAIT_S`.
    max_addresses : int, optional
        Addresses remembered at most; default 10 000.
    clock : callable, optional
        The clock, s (default ``time.monotonic``).

    Raises
    ------
    ValueError
        A negative ``free``, a wait that is not positive or ``max_addresses`` below 1.

    Examples
    --------
    >>> now = [0.0]
    >>> failures = TokenFailures(free=2, clock=lambda: now[0])
    >>> [failures.failed("192.0.2.7") for _ in range(4)]
    [0.0, 0.0, 1.0, 2.0]
    >>> failures.wait_s("192.0.2.7"), failures.wait_s("192.0.2.8")
    (2.0, 0.0)
    """

    def __init__(self, free: int = FREE_FAILURES, first_wait_s: float = FIRST_WAIT_S,
                 most_wait_s: float = MOST_WAIT_S, max_addresses: int = 10_000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if free < 0 or not first_wait_s > 0 or not most_wait_s >= first_wait_s or max_addresses < 1:
            raise ValueError("free >= 0, 0 < first_wait_s <= most_wait_s and max_addresses >= 1 are needed")
        self.free, self.first_wait_s, self.most_wait_s = int(free), float(first_wait_s), float(most_wait_s)
        self.max_addresses = int(max_addresses)
        self.clock = clock
        # key -> (wrong tokens counted, time of the last one, end of its wait)
        self._table: collections.OrderedDict[str, tuple[int, float, float]] = collections.OrderedDict()

    def __len__(self) -> int:
        return len(self._table)

    def _entry(self, key: str, now: float) -> tuple[int, float, float] | None:
        entry = self._table.get(key)
        if entry is not None and now - entry[1] > 2 * self.most_wait_s and now >= entry[2]:
            del self._table[key]  # forgiven
            return None
        return entry

    def wait_s(self, address: str) -> float:
        """Seconds ``address`` must still wait before a wrong token of its is answered (0: none).

        Parameters
        ----------
        address : str
            The client's address.

        Returns
        -------
        float
            The wait left, s.
        """
        if not self._table:
            return 0.0
        now = self.clock()
        entry = self._entry(failure_key(address), now)
        return 0.0 if entry is None else max(0.0, entry[2] - now)

    def failed(self, address: str) -> float:
        """Count a wrong token from ``address``; return the wait it starts (0 within the free ones), s.

        Parameters
        ----------
        address : str
            The client's address.

        Returns
        -------
        float
            The wait now owed, s.
        """
        now = self.clock()
        key = failure_key(address)
        entry = self._entry(key, now)
        count = 1 if entry is None else entry[0] + 1
        beyond = count - self.free
        wait = 0.0 if beyond <= 0 else min(self.most_wait_s, self.first_wait_s * 2.0 ** min(beyond - 1, 64))
        self._table[key] = (count, now, now + wait)
        self._table.move_to_end(key)
        while len(self._table) > self.max_addresses:
            self._table.popitem(last=False)
        return wait


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers") or ():
        if key == name:
            return value.decode("latin-1")
    return None


class AccessGate:
    """ASGI middleware: the Host, token and Origin rules of this module.

    They apply to every HTTP request (and websocket) from its headers alone: nothing of the
    body is read for a refusal, and the refusal closes the connection (401 with
    ``WWW-Authenticate: Bearer``, 403, 429 with ``Retry-After`` for a wrong token from an
    address that sent too many, held until its wait is over (at most :data:`HOLD_S`), or 503
    when the token file cannot be read). A wrong token on a connection on probation
    (:data:`PROBATION_EXTENSION`) is refused whatever its path. Refusals are logged at most
    one line per client address per interval, each field capped
    (``fpscan.service.api.logcaps``).

    Parameters
    ----------
    app : ASGI application
        The application it guards.
    settings : Settings
        The service's settings (the token is read on each request, so a rotated
        ``token_file`` takes effect at once).
    failures : TokenFailures or None, optional
        The count of wrong tokens per address, shared with health's lane
        (``fpscan.service.api.lanes.HealthLane``), which applies these rules first; default None:
        a count of its own.

    Attributes
    ----------
    app : ASGI application
        As given.
    settings : Settings
        As given.
    failures : TokenFailures
        The count of wrong tokens per address.
    refusals : RefusalLog
        The rate-limited log of refusals.
    """

    def __init__(self, app: ASGIApp, settings: Settings, failures: TokenFailures | None = None) -> None:
        self.app = app
        self.settings = settings
        self.failures = failures if failures is not None else TokenFailures()
        self.refusals = RefusalLog(log)  # one line per client address per interval, fields capped

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        refusal = self.refusal(scope)
        client = scope.get("client") or ("?", 0)
        self._count_token(scope, client[0], refusal)
        if refusal is not None:
            status, detail = refusal
            headers = {"Connection": "close"}
            if status == 401:
                headers["WWW-Authenticate"] = "Bearer"
            if status == 429:
                hold = min(self.failures.wait_s(client[0]), HOLD_S)
                await asyncio.sleep(hold)  # the wrong token's answer comes after the wait it owes
                self.failures.failed(client[0])  # and it doubles the wait
                headers["Retry-After"] = str(max(1, math.ceil(self.failures.wait_s(client[0]))))
            self.refusals.refused(client[0], "refused client=%s method=%s path=%s status=%s: %s", client[0],
                                  shown(scope.get("method"), 16), shown(scope.get("path", "")), status, detail)
            if scope["type"] == "websocket":
                return await send({"type": "websocket.close", "code": 1008})
            return await JSONResponse({"detail": detail}, status, headers=headers)(scope, receive, send)
        return await self.app(scope, receive, send)

    def _count_token(self, scope: Scope, address: str, refusal: tuple[int, str] | None) -> None:
        """Count a wrong token (refused with 401, or sent to ``GET /api/auth``, which answers
        whether it is right) against its address."""
        if refusal is not None:
            if refusal == (401, "invalid bearer token"):
                self.failures.failed(address)
            return
        authorization = _header(scope, b"authorization")
        if authorization is None or scope.get("path", "").rstrip("/") not in PUBLIC_API_PATHS:
            return
        try:
            expected = self.settings.token_value()
        except ValueError:
            return
        if expected is not None and token_matches(authorization, expected) == "invalid bearer token":
            self.failures.failed(address)

    def refusal(self, scope: Scope) -> tuple[int, str] | None:
        """The refusal of a request, from its headers (it counts nothing: the caller does).

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
            # a request on probation is served for the right token only, whatever its path
            probation = PROBATION_EXTENSION in (scope.get("extensions") or {})
            if not path.startswith("/api/") and not probation:
                return None
            authorization = _header(scope, b"authorization")
            public = path.rstrip("/") in PUBLIC_API_PATHS and not probation
            if authorization is not None and token_matches(authorization, expected) == "invalid bearer token":
                client = scope.get("client") or ("?", 0)
                wait = self.failures.wait_s(client[0])
                if wait > 0:  # answered after the wait (``__call__``): a guess tells nothing sooner
                    return 429, (f"too many wrong tokens from this address: wait {math.ceil(wait)} s "
                                 "(Retry-After) before the next; the right token is answered at once")
            if not public:
                why = token_matches(authorization, expected)
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
