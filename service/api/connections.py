"""What a client's connection may hold of the server, decided before any request is read
(issue 50.1: strangers hold no socket).

The server is uvicorn with its ``httptools`` HTTP protocol; :func:`server_config` gives it
this module's subclass of that protocol (:class:`GuardedHttp`) and the settings' timeouts:

- **Connections per address.** :class:`ConnectionGuard` counts the open connections of each
  client address. A new one is refused at accept time (answered ``503`` with the reason,
  ``Connection: close``, before anything of it is read) when its address already holds
  ``connections_per_address``, or when the server holds ``max_connections`` in all and the
  address holds its :data:`CONNECTION_ALLOWANCE` already (below that allowance an address is
  refused only near the process's open-file limit): one client cannot take the file handles
  that every other client needs (1000 idle sockets under a 1024-handle limit made every
  other request fail with a connection reset before this).
- **A request head within a few seconds.** A connection that has not sent a complete
  request head (request line and headers) ``header_timeout_s`` after it was accepted, or
  after the first byte of its next request, is closed, token or not (nginx's
  ``client_header_timeout``); idle kept-alive connections close after ``keep_alive_s``
  (uvicorn's ``timeout_keep_alive``).
- **A bounded head.** A request line and headers of more than ``max_head_bytes`` are
  refused with ``431`` before they reach the app (uvicorn's ``httptools`` protocol has no
  such bound; its ``h11`` one has ``h11_max_incomplete_event_size``).

Refusals are logged at most one line per client address per interval, fields capped
(:mod:`service.api.logcaps`).
"""
from __future__ import annotations

import logging
import threading
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from service.api.logcaps import RefusalLog, install_log_caps, shown
from service.settings import Settings

__all__ = ["CONNECTION_ALLOWANCE", "FD_HEADROOM", "open_file_limit", "ConnectionGuard", "GuardedHttp",
           "guarded_protocol", "server_config"]

log = logging.getLogger("fpscan.connections")

#: connections every client address may open however many the server holds (as long as the
#: process has file handles to spare: :data:`FD_HEADROOM`)
CONNECTION_ALLOWANCE = 4
#: file handles kept free of connections for the server's own files (database, uploads,
#: results, scan files, worker pipes)
FD_HEADROOM = 128


def open_file_limit() -> int | None:
    """The process's soft limit of open files (``RLIMIT_NOFILE``).

    Returns
    -------
    int or None
        The limit; None where unknown or unlimited.
    """
    try:
        import resource

        soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    except (ImportError, OSError, ValueError):
        return None
    return None if soft == resource.RLIM_INFINITY or soft <= 0 else int(soft)


class ConnectionGuard:
    """Open connections by client address, and the rule that admits a new one (module docstring).

    Thread-safe.

    Parameters
    ----------
    per_address : int
        Most connections of one address, >= 1.
    max_connections : int
        Connections in all beyond which an address gets only its ``allowance``, >= 1.
    allowance : int, optional
        Connections every address may open however many the server holds, >= 0; default
        :data:`CONNECTION_ALLOWANCE` (4).
    hard_limit : int or None, optional
        Connections in all never exceeded; default None: the open-file limit less
        :data:`FD_HEADROOM` (at least ``max_connections``), or 2**30 where that is unknown.

    Attributes
    ----------
    per_address, max_connections, allowance, hard_limit : int
        The limits.
    total : int
        Connections open now.
    refused_count : int
        Connections refused so far.

    Raises
    ------
    ValueError
        If ``per_address`` or ``max_connections`` is below 1, or ``allowance`` below 0.
    """

    def __init__(self, per_address: int, max_connections: int, allowance: int = CONNECTION_ALLOWANCE,
                 hard_limit: int | None = None) -> None:
        if per_address < 1 or max_connections < 1 or allowance < 0:
            raise ValueError(f"connection limits must be positive, got per_address={per_address}, "
                             f"max_connections={max_connections}, allowance={allowance}")
        self.per_address = int(per_address)
        self.max_connections = int(max_connections)
        self.allowance = int(allowance)
        limit = open_file_limit()
        self.hard_limit = int(hard_limit) if hard_limit is not None else \
            (max(limit - FD_HEADROOM, self.max_connections) if limit is not None else 1 << 30)
        self._lock = threading.Lock()
        self._open: dict[str, int] = {}
        self.total = 0
        self.refused_count = 0

    @classmethod
    def from_settings(cls, settings: Settings) -> ConnectionGuard:
        """The guard the settings ask for (``max_connections`` None: half the open-file limit)."""
        limit = open_file_limit()
        most = settings.max_connections or (max(64, limit // 2) if limit is not None else 4096)
        return cls(settings.connections_per_address, most)

    def admit(self, address: str) -> str | None:
        """Count a new connection of ``address`` in, or return why it is refused (not counted)."""
        with self._lock:
            mine = self._open.get(address, 0)
            why = None
            if self.total >= self.hard_limit:
                why = f"the server holds {self.total} connections, as many as it can"
            elif mine >= self.per_address:
                why = f"this address holds {mine} connections to the server already (at most {self.per_address})"
            elif mine >= self.allowance and self.total >= self.max_connections:
                why = (f"the server holds {self.total} connections (at most {self.max_connections} beyond "
                       f"{self.allowance} per address) and this address {mine}")
            if why is not None:
                self.refused_count += 1
                return why
            self._open[address] = mine + 1
            self.total += 1
            return None

    def release(self, address: str) -> None:
        """Count a connection of ``address`` out (one :meth:`admit` let in)."""
        with self._lock:
            mine = self._open.get(address, 0) - 1
            if mine > 0:
                self._open[address] = mine
            else:
                self._open.pop(address, None)
            self.total = max(0, self.total - 1)

    def held(self, address: str) -> int:
        """Connections ``address`` holds now."""
        with self._lock:
            return self._open.get(address, 0)


class _HeadTooLarge(Exception):
    pass


class GuardedHttp(HttpToolsProtocol):
    """uvicorn's ``httptools`` protocol with this module's rules (module docstring).

    Made per server by :func:`guarded_protocol`, which sets the class attributes below; uvicorn
    makes one instance per connection.

    Attributes
    ----------
    guard : ConnectionGuard
        The server's count of connections by address.
    header_timeout_s : float
        Seconds a request head may take to arrive (default 5).
    max_head_bytes : int
        The longest request line and headers in bytes (default 16384); longer is a 431.
    refusals : RefusalLog
        The rate-limited log of refusals.
    """

    guard: ConnectionGuard
    header_timeout_s: float = 5.0
    max_head_bytes: int = 16384
    refusals: RefusalLog

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        self._address = self.client[0] if self.client else "?"
        self._counted = False
        self._closed_by_us = False
        self._head_timer: Any = None
        self._head_bytes = 0
        why = self.guard.admit(self._address)
        if why is not None:
            self.refusals.refused(self._address, "connection refused client=%s: %s", self._address, why)
            self._answer_and_close(503, f"connection refused: {why}; close some, then retry")
            return
        self._counted = True
        self._arm_head_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        if getattr(self, "_counted", False):
            self._counted = False
            self.guard.release(self._address)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._closed_by_us:
            return
        self._unset_keepalive_if_required()
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserUpgrade:
            if self._should_upgrade():
                self.handle_websocket_upgrade()
            else:
                self._unsupported_upgrade_warning()
        except httptools.HttpParserError as exc:
            if isinstance(exc.__context__, _HeadTooLarge):
                self.refusals.refused(self._address, "request refused client=%s: head over %d bytes", self._address,
                                      self.max_head_bytes)
                self._answer_and_close(431, f"request line and headers longer than {self.max_head_bytes} bytes")
            else:
                self.refusals.refused(self._address, "request refused client=%s: invalid HTTP (%s)", self._address,
                                      shown(exc, 100))
                self._answer_and_close(400, "invalid HTTP request")

    # -- the parser's callbacks: count the head, stop its clock when it is complete --------
    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._head_bytes = 0
        self._arm_head_timer()  # the next request on a kept-alive connection: its head's clock starts

    def on_url(self, url: bytes) -> None:
        self._count_head(len(url))
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self._count_head(len(name) + len(value) + 4)
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self._cancel_head_timer()
        super().on_headers_complete()

    # -- helpers -----------------------------------------------------------------------
    def _count_head(self, n: int) -> None:
        self._head_bytes += n
        if self._head_bytes > self.max_head_bytes:
            raise _HeadTooLarge()

    def _arm_head_timer(self) -> None:
        if self._head_timer is None and not self._closed_by_us:
            self._head_timer = self.loop.call_later(self.header_timeout_s, self._head_timed_out)

    def _cancel_head_timer(self) -> None:
        timer = getattr(self, "_head_timer", None)
        if timer is not None:
            timer.cancel()
            self._head_timer = None

    def _head_timed_out(self) -> None:
        self._head_timer = None
        if self._closed_by_us or self.transport.is_closing():
            return
        self.refusals.refused(self._address, "connection closed client=%s: no complete request head within %g s",
                              self._address, self.header_timeout_s)
        self._closed_by_us = True
        self.transport.close()

    def _answer_and_close(self, status: int, detail: str) -> None:
        """Write a JSON error answer with ``Connection: close`` and close the connection."""
        import json

        self._closed_by_us = True
        self._cancel_head_timer()
        body = json.dumps({"detail": detail}).encode()
        phrase = {400: "Bad Request", 431: "Request Header Fields Too Large", 503: "Service Unavailable"}[status]
        head = (f"HTTP/1.1 {status} {phrase}\r\ncontent-type: application/json\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n"
                + ("retry-after: 5\r\n" if status == 503 else "") + "\r\n").encode()
        if not self.transport.is_closing():
            self.transport.write(head + body)
            self.transport.close()


def guarded_protocol(settings: Settings, guard: ConnectionGuard | None = None) -> type[GuardedHttp]:
    """A :class:`GuardedHttp` subclass with the rules of ``settings`` and its own guard.

    Parameters
    ----------
    settings : Settings
        The service's settings (``header_timeout_s``, ``max_head_bytes``, the connection
        limits).
    guard : ConnectionGuard or None, optional
        The guard to use; default None: ``ConnectionGuard.from_settings(settings)`` (one per
        server).

    Returns
    -------
    type
        The subclass of :class:`GuardedHttp`, for ``uvicorn.Config(http=...)``.
    """
    return type("GuardedHttp", (GuardedHttp,), {
        "guard": guard or ConnectionGuard.from_settings(settings),
        "header_timeout_s": float(settings.header_timeout_s),
        "max_head_bytes": int(settings.max_head_bytes),
        "refusals": RefusalLog(log),
    })


def server_config(app: Any, settings: Settings) -> Any:
    """The ``uvicorn.Config`` that serves ``app`` by ``settings``.

    Bind address and port, the guarded protocol (:func:`guarded_protocol`; no WebSocket
    upgrades: the service has no WebSocket route), the keep-alive timeout
    (``settings.keep_alive_s``), the graceful-shutdown bound (``settings.shutdown_grace_s``:
    open connections, SSE streams included, are closed after it), no access log; then every
    log handler is capped (:func:`service.api.logcaps.install_log_caps`).

    Parameters
    ----------
    app : ASGI application
        The application to serve.
    settings : Settings
        The service's settings.

    Returns
    -------
    uvicorn.Config
        The server's configuration.
    """
    import uvicorn

    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=settings.log_level.lower(),
                            access_log=False, lifespan="on", http=guarded_protocol(settings),
                            ws="none",  # no WebSocket routes: an upgrade would leave the guard's count behind
                            timeout_keep_alive=max(1, int(round(settings.keep_alive_s))),
                            timeout_graceful_shutdown=max(1, int(round(settings.shutdown_grace_s))))
    install_log_caps()
    return config
