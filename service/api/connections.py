"""What a client's connection may hold of the server, decided before any request is read
(strangers hold no socket; docs/api.md, "Limits").

The server is uvicorn with its ``httptools`` HTTP protocol; :func:`server_config` gives it
this module's subclass of that protocol (:class:`GuardedHttp`) and the settings' timeouts:

- **Strangers share a budget; the token holder always gets in.** :class:`ConnectionGuard`
  counts the open connections of strangers (connections that have not shown the token) by
  client address and in all. A new connection within the strangers' budget (at most
  ``connections_per_address`` of one address; beyond ``max_connections`` strangers' in all,
  only an address's :data:`CONNECTION_ALLOWANCE`) is taken as a stranger's. Beyond it, the
  connection is taken **on probation** (a pool of its own, bounded: half of what the
  open-file limit leaves beyond ``max_connections``): its first request head must come within
  :data:`PROBATION_HEAD_S` and carry the token: without one it is answered ``503`` and
  closed; with a wrong one it is refused by the access gate (below), which closes it. A
  connection whose request head carries the valid token leaves the strangers' numbers for
  good: only the open-file limit (less :data:`FD_HEADROOM`) bounds such connections, so
  strangers holding their whole budget, from the token holder's own address or any other,
  never refuse the token holder. A wrong token on probation goes on to the access gate
  (``fpscan.service.api.access.AccessGate``, the one owner of wrong tokens: their count, the
  wait of an address that sent too many, its held ``429``), marked
  (``fpscan.service.api.access.PROBATION_EXTENSION``) so that the gate refuses it whatever its
  path: every token is compared, on every connection, and a wrong one is answered no sooner
  than it would be on a stranger's. Without a token configured every connection is a
  stranger's. A connection beyond every pool is refused at accept time (``503`` with the
  reason, ``Connection: close``, before anything of it is read).
- **A deadline in every phase** (:class:`GuardedHttp`, one timer per connection, token or
  not): a request head within ``header_timeout_s`` of the connection's start or of the first
  byte of its next request (nginx's ``client_header_timeout``); the unread rest of a body its
  answer went out before (the one-byte body) within ``body_rate_window_s`` plus its bytes at
  ``body_min_rate``; a response's bytes waiting on a reader that takes fewer than
  ``send_min_rate`` bytes/s of them over ``send_timeout_s`` (nginx's ``send_timeout``); an
  idle kept-alive connection after ``keep_alive_s`` (uvicorn's ``timeout_keep_alive``). A
  missed deadline closes the connection with a reset, its unsent bytes dropped and their
  memory returned (nginx's ``reset_timedout_connection``); a body the app reads is timed by
  ``fpscan.service.api.upload_limit.UploadLimit`` (408).
- **A bounded head.** A request line and headers of more than ``max_head_bytes`` are
  refused with ``431`` before they reach the app (uvicorn's ``httptools`` protocol has no
  such bound; its ``h11`` one has ``h11_max_incomplete_event_size``).
- **A client gone is not an error.** A response written to a connection that has closed is
  dropped (the request sees a disconnect), never a traceback.

Refusals are logged at most one line per client address per interval, fields capped
(:mod:`fpscan.service.api.logcaps`).
"""
from __future__ import annotations

import contextlib
import logging
import socket
import struct
import threading
from collections.abc import Callable
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from fpscan.service.api.browser_headers import SECURITY_HEADERS
from fpscan.service.api.logcaps import RefusalLog, install_log_caps, shown
from fpscan.service.settings import Settings

__all__ = ["CONNECTION_ALLOWANCE", "PROBATION_HEAD_S", "FD_HEADROOM", "BURST_CONNECTIONS", "return_memory", "open_file_limit", "ConnectionGuard", "GuardedHttp",
           "guarded_protocol", "server_config"]

log = logging.getLogger("fpscan.connections")

#: connections every client address may open however many the server holds (as long as the
#: process has file handles to spare: :data:`FD_HEADROOM`)
CONNECTION_ALLOWANCE = 4
#: seconds a connection taken on probation (beyond the strangers' budget) has for its first
#: request head, which must carry the token
PROBATION_HEAD_S = 1.0
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


#: connections closed in a burst before the heap's free memory is given back (:func:`return_memory`)
BURST_CONNECTIONS = 256
#: seconds without a close after a burst's last ones before their memory is given back too
#: (a burst's tail: fewer than :data:`BURST_CONNECTIONS` closed after its last return)
BURST_TAIL_S = 1.0


def return_memory() -> bool:
    """Free what thousands of closed connections left and give the heap's free pages back to
    the system: their protocol, request and task objects refer to each other (only the
    cyclic collector frees them, and its next full pass may be far off), and glibc keeps
    freed pages (``malloc_trim`` returns them); without this the process's RSS stays at its
    peak. Where there is no glibc, only the collection.

    Returns
    -------
    bool
        Whether memory was given back (glibc's answer); False where there is no glibc.
    """
    import ctypes
    import ctypes.util
    import gc

    gc.collect()
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.malloc_trim(0))
    except (OSError, AttributeError, TypeError):
        return False


_TAIL_TIMERS: dict[int, Any] = {}


def _return_tail(loop: Any, guard: ConnectionGuard) -> None:
    """Return the memory of a burst's tail :data:`BURST_TAIL_S` after its last close (one
    timer per guard, pushed back by each close)."""
    timer = _TAIL_TIMERS.pop(id(guard), None)
    if timer is not None:
        timer.cancel()

    def fire() -> None:
        _TAIL_TIMERS.pop(id(guard), None)
        guard.tail_returned()
        return_memory()

    _TAIL_TIMERS[id(guard)] = loop.call_later(BURST_TAIL_S, fire)


class ConnectionGuard:
    """Open connections by pool and client address, and the rules that admit a new one
    (module docstring).

    Three pools: **strangers** (connections that have not shown the token), counted per
    address and in all; connections **on probation** (taken beyond the strangers' budget, for
    one request head that must carry the token); **trusted** ones (they showed it), bounded
    only by ``hard_limit``. Thread-safe.

    Parameters
    ----------
    per_address : int
        Most strangers' connections of one address, >= 1.
    max_connections : int
        Strangers' connections in all beyond which an address gets only its ``allowance``, >= 1.
    allowance : int, optional
        Strangers' connections every address may open however many the others hold, >= 0;
        default :data:`CONNECTION_ALLOWANCE` (4).
    hard_limit : int or None, optional
        Connections in all (every pool) never exceeded; default None: the open-file limit less
        :data:`FD_HEADROOM` (at least ``max_connections``), or 2**30 where that is unknown.
    probation_limit : int or None, optional
        Connections on probation at once, >= 0; default None: half of what ``hard_limit``
        leaves beyond ``max_connections`` (at most ``max_connections``, at least the
        allowance), so trusted connections keep the other half.

    Attributes
    ----------
    per_address, max_connections, allowance, hard_limit, probation_limit : int
        The limits.
    total : int
        Connections open now (every pool).
    strangers, on_probation, trusted : int
        Connections open now in each pool.
    refused_count : int
        Connections refused so far.

    Raises
    ------
    ValueError
        If ``per_address`` or ``max_connections`` is below 1, or ``allowance`` or
        ``probation_limit`` below 0.
    """

    def __init__(self, per_address: int, max_connections: int, allowance: int = CONNECTION_ALLOWANCE,
                 hard_limit: int | None = None, probation_limit: int | None = None) -> None:
        if per_address < 1 or max_connections < 1 or allowance < 0 or (probation_limit or 0) < 0:
            raise ValueError(f"connection limits must be positive, got per_address={per_address}, "
                             f"max_connections={max_connections}, allowance={allowance}, "
                             f"probation_limit={probation_limit}")
        self.per_address = int(per_address)
        self.max_connections = int(max_connections)
        self.allowance = int(allowance)
        limit = open_file_limit()
        self.hard_limit = int(hard_limit) if hard_limit is not None else \
            (max(limit - FD_HEADROOM, self.max_connections) if limit is not None else 1 << 30)
        self.probation_limit = int(probation_limit) if probation_limit is not None else \
            max(self.allowance, min((self.hard_limit - self.max_connections) // 2, self.max_connections))
        self._lock = threading.Lock()
        self._open: dict[str, int] = {}  # strangers' connections by address
        self.total = self.strangers = self.on_probation = self.trusted = 0
        self.refused_count = 0
        self._peak = 0  # most connections at once since memory was last returned
        self._closed = 0  # connections closed since then
        self._in_burst = False  # memory was returned amid a burst, and its tail may follow

    @classmethod
    def from_settings(cls, settings: Settings) -> ConnectionGuard:
        """The guard the settings ask for (``max_connections`` None: half the open-file limit)."""
        limit = open_file_limit()
        most = settings.max_connections or (max(64, limit // 2) if limit is not None else 4096)
        return cls(settings.connections_per_address, most)

    def admit(self, address: str) -> str | None:
        """Count a new stranger's connection of ``address`` in, or return why it is refused
        (not counted)."""
        with self._lock:
            mine = self._open.get(address, 0)
            why = None
            if self.total >= self.hard_limit:
                why = f"the server holds {self.total} connections, as many as it can"
            elif mine >= self.per_address:
                why = f"this address holds {mine} connections to the server already (at most {self.per_address})"
            elif mine >= self.allowance and self.strangers >= self.max_connections:
                why = (f"the server holds {self.strangers} connections without the token (at most "
                       f"{self.max_connections} beyond {self.allowance} per address) and this address {mine}")
            if why is not None:
                self.refused_count += 1
                return why
            self._open[address] = mine + 1
            self.strangers += 1
            self.total += 1
            self._peak = max(self._peak, self.total)
            return None

    def admit_on_probation(self) -> str | None:
        """Count a connection in on probation (beyond the strangers' budget: its first request
        head must carry the token), or return why it is refused (not counted)."""
        with self._lock:
            why = None
            if self.total >= self.hard_limit:
                why = f"the server holds {self.total} connections, as many as it can"
            elif self.on_probation >= self.probation_limit:
                why = f"{self.on_probation} connections wait to show the token already"
            if why is not None:
                self.refused_count += 1
                return why
            self.on_probation += 1
            self.total += 1
            self._peak = max(self._peak, self.total)
            return None

    def trust(self, address: str, pool: str) -> None:
        """Move a connection of ``address`` from ``pool`` (``"stranger"``, ``"probation"``) to
        the trusted pool: it showed the token."""
        with self._lock:
            self._leave(address, pool)
            self.trusted += 1

    def release(self, address: str, pool: str = "stranger") -> None:
        """Count a connection of ``address`` in ``pool`` out (``"stranger"``, ``"probation"``,
        ``"trusted"``)."""
        with self._lock:
            self._leave(address, pool)
            self.total = max(0, self.total - 1)

    def burst_over(self) -> bool:
        """Count a closed connection; True once a burst is over (at least
        :data:`BURST_CONNECTIONS` closed since the last True, and at most a quarter of the
        most held meanwhile still open): the time to return the heap's free memory."""
        with self._lock:
            self._closed += 1
            if self._closed < BURST_CONNECTIONS or self.total > self._peak // 4:
                return False
            self._closed, self._peak, self._in_burst = 0, self.total, True
            return True

    def tail_due(self) -> bool:
        """Whether connections closed since a burst's last :meth:`burst_over` (its tail):
        their memory is to be returned once closes stop (:meth:`tail_returned`)."""
        with self._lock:
            return self._in_burst and self._closed > 0

    def tail_returned(self) -> None:
        """The memory of a burst's tail was returned: the burst is over."""
        with self._lock:
            self._closed, self._peak, self._in_burst = 0, self.total, False

    def _leave(self, address: str, pool: str) -> None:
        if pool == "stranger":
            mine = self._open.get(address, 0) - 1
            if mine > 0:
                self._open[address] = mine
            else:
                self._open.pop(address, None)
            self.strangers = max(0, self.strangers - 1)
        elif pool == "probation":
            self.on_probation = max(0, self.on_probation - 1)
        else:
            self.trusted = max(0, self.trusted - 1)

    def held(self, address: str) -> int:
        """Strangers' connections ``address`` holds now."""
        with self._lock:
            return self._open.get(address, 0)


class _HeadTooLarge(Exception):
    pass


class _NoToken(Exception):
    pass


class GuardedHttp(HttpToolsProtocol):
    """uvicorn's ``httptools`` protocol with this module's rules (module docstring).

    Made per server by :func:`guarded_protocol`, which sets the class attributes below; uvicorn
    makes one instance per connection. Each connection is in one phase at a time, each with
    its deadline (one timer per connection; a missed deadline closes the connection at once,
    its unsent bytes dropped): its request **head** (``header_timeout_s``; a connection on
    probation :data:`PROBATION_HEAD_S`), the rest of a **body** its answer left unread
    (``body_rate_window_s`` plus its remaining bytes at ``body_min_rate``, else
    ``body_timeout_s``; a body the app reads is timed by ``fpscan.service.api.upload_limit.UploadLimit``,
    which answers 408), a **response** the reader does not take (``send_timeout_s`` for
    ``send_min_rate`` bytes/s of it) and **idle** keep-alive (uvicorn's ``timeout_keep_alive``).

    Attributes
    ----------
    guard : ConnectionGuard
        The server's count of connections by pool and address.
    header_timeout_s : float
        Seconds a request head may take to arrive (default 5).
    max_head_bytes : int
        The longest request line and headers in bytes (default 16384); longer is a 431.
    body_timeout_s, body_min_rate, body_rate_window_s : float
        The body's rules (``Settings``).
    send_timeout_s, send_min_rate : float
        The reader's rule (``Settings``).
    send_buffer_bytes : int or None
        The kernel's send buffer of each connection (``SO_SNDBUF``; None: autotuned).
    token_value : callable or None
        Returns the configured token (None: no token; every connection stays a stranger). Every
        token is compared: the right one makes the connection trusted, whatever its address sent
        before; a wrong one on probation goes on to the access gate, marked
        (``fpscan.service.api.access.PROBATION_EXTENSION``), which counts it and refuses it
        (``401``; ``429`` after the wait of an address that must wait).
    refusals : RefusalLog
        The rate-limited log of refusals.
    """

    guard: ConnectionGuard
    header_timeout_s: float = 5.0
    max_head_bytes: int = 16384
    body_timeout_s: float = 30.0
    body_min_rate: float = 100 * 1024
    body_rate_window_s: float = 10.0
    send_timeout_s: float = 30.0
    send_min_rate: float = 1024.0
    send_buffer_bytes: int | None = 64 * 1024
    token_value: Callable[[], str | None] | None = None
    refusals: RefusalLog

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        self._address = self.client[0] if self.client else "?"
        self._pool: str | None = None
        self._closed_by_us = False
        self._timer: Any = None  # the head's or the unread body's deadline
        self._write_timer: Any = None  # the unread response's deadline
        self._head_bytes = 0
        self._in_body = False
        self._body_left = 0
        self._write_left = 0
        # every byte the kernel does not take at once pauses the writer (uvicorn's flow
        # control) until all are taken: a reader's pace is seen, and timed, from the first one;
        # the kernel takes at most twice send_buffer_bytes of it
        with contextlib.suppress(AttributeError, NotImplementedError, ValueError):
            transport.set_write_buffer_limits(high=0, low=0)
        if self.send_buffer_bytes:
            with contextlib.suppress(AttributeError, OSError, TypeError):
                transport.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF,
                                                              self.send_buffer_bytes)
        why = self.guard.admit(self._address)
        if why is None:
            self._pool = "stranger"
        elif self._token_expected() and self.guard.admit_on_probation() is None:
            self._pool = "probation"
        if self._pool is None:
            self.refusals.refused(self._address, "connection refused client=%s: %s", self._address, why)
            self._answer_and_close(503, f"connection refused: {why}; close some, then retry")
            return
        self._arm(self._head_deadline(), self._head_timed_out)

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel()
        self._cancel_write_timer()
        pool, self._pool = getattr(self, "_pool", None), None
        if pool is not None:
            self.guard.release(self._address, pool)
        super().connection_lost(exc)
        if self.guard.burst_over():
            self.loop.call_soon(return_memory)
        elif self.guard.tail_due():  # once closes stop, the rest of the burst's memory too
            _return_tail(self.loop, self.guard)

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
            if self._closed_by_us:
                return
            if isinstance(exc.__context__, _HeadTooLarge):
                self.refusals.refused(self._address, "request refused client=%s: head over %d bytes", self._address,
                                      self.max_head_bytes)
                self._answer_and_close(431, f"request line and headers longer than {self.max_head_bytes} bytes")
            elif isinstance(exc.__context__, _NoToken):
                self.refusals.refused(self._address, "connection refused client=%s: beyond the strangers' budget, "
                                      "no token", self._address)
                self._answer_and_close(503, "connection refused: the server holds as many connections without "
                                            "the token as it takes; close some, or send the token, then retry")
            else:
                self.refusals.refused(self._address, "request refused client=%s: invalid HTTP (%s)", self._address,
                                      shown(exc, 100))
                self._answer_and_close(400, "invalid HTTP request")

    # -- the parser's callbacks: count the head, start and stop the phases' clocks ----------
    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._head_bytes = 0
        if self._timer is None:  # the next request on a kept-alive connection: its head's clock starts
            self._arm(self._head_deadline(), self._head_timed_out)

    def on_url(self, url: bytes) -> None:
        self._count_head(len(url))
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self._count_head(len(name) + len(value) + 4)
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self._cancel()
        if self._pool in ("stranger", "probation") and self._shows_token():
            self.guard.trust(self._address, self._pool)
            self._pool = "trusted"
        elif self._pool == "probation":
            if self._token_state() != "wrong":
                raise _NoToken()
            # a wrong token: the gate's to count, hold and refuse (whatever the path), as on any connection
            from fpscan.service.api.access import PROBATION_EXTENSION

            self.scope.setdefault("extensions", {})[PROBATION_EXTENSION] = {}
        self._in_body, self._body_left = True, self._declared_length()
        cycle = self.cycle
        super().on_headers_complete()
        if self.cycle is not cycle:
            self._quiet_when_gone(self.cycle)

    def on_body(self, body: bytes) -> None:
        self._body_left -= len(body)
        super().on_body(body)

    def on_message_complete(self) -> None:
        self._in_body = False
        if self._timer is not None and self._timer_kind == "body":
            self._cancel()
        super().on_message_complete()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self._in_body and not self.transport.is_closing():
            # answered before its body came: the rest must come at the body's pace (then
            # the next request can be read), else the connection closes
            self._unset_keepalive_if_required()
            left = max(self._body_left, 0)
            allowed = (self.body_rate_window_s + left / self.body_min_rate) if self.body_min_rate \
                else self.body_timeout_s
            self._arm(min(allowed, self.body_timeout_s), self._body_timed_out, kind="body")

    # -- the response's clock: the transport says when its bytes wait for the reader --------
    def pause_writing(self) -> None:
        super().pause_writing()
        if self._write_timer is None:
            self._write_left = self._buffered()
            self._write_timer = self.loop.call_later(self.send_timeout_s, self._write_check)

    def resume_writing(self) -> None:
        self._cancel_write_timer()
        super().resume_writing()

    def _write_check(self) -> None:
        self._write_timer = None
        left = self._buffered()
        if left == 0:
            return
        taken = self._write_left - left
        if taken > 0 and taken >= self.send_min_rate * self.send_timeout_s:
            self._write_left = left
            self._write_timer = self.loop.call_later(self.send_timeout_s, self._write_check)
            return
        self._close_now("connection closed client=%s: the reader took %d of its response's %d waiting bytes in %g s",
                        self._address, max(taken, 0), self._write_left, self.send_timeout_s)

    def timeout_keep_alive_handler(self) -> None:
        """Idle past ``keep_alive_s``: closed; with a reset when the kernel still holds bytes
        of its answers that the reader never took (a FIN would wait behind them)."""
        if self._unsent() > 0:
            self._close_now("connection closed client=%s: idle %g s with %d bytes of its answers unread",
                            self._address, float(self.timeout_keep_alive), self._unsent())
        else:
            super().timeout_keep_alive_handler()

    # -- helpers -----------------------------------------------------------------------
    def _unsent(self) -> int:
        """Bytes of this connection's answers the kernel still holds (Linux ``SIOCOUTQ``; 0 elsewhere)."""
        try:
            import fcntl
            import termios

            fd = self.transport.get_extra_info("socket").fileno()
            return struct.unpack("i", fcntl.ioctl(fd, termios.TIOCOUTQ, b"\0\0\0\0"))[0]
        except (AttributeError, ImportError, OSError, TypeError, ValueError):
            return 0

    def _token_expected(self) -> bool:
        try:
            return self.token_value is not None and self.token_value() is not None
        except ValueError:  # an unreadable token file: the gate answers 503 for it
            return False

    def _shows_token(self) -> bool:
        return self._token_state() == "right"

    def _token_state(self) -> str:
        """The request head's token: ``"right"``, ``"wrong"``, ``"none"`` (no token sent or
        configured)."""
        if self.token_value is None:
            return "none"
        try:
            expected = self.token_value()
        except ValueError:
            return "none"
        if expected is None:
            return "none"
        from fpscan.service.api.access import token_matches

        given = next((v.decode("latin-1") for k, v in self.headers if k == b"authorization"), None)
        if given is None:
            return "none"
        why = token_matches(given, expected)
        return "right" if why is None else "wrong" if why == "invalid bearer token" else "none"

    def _declared_length(self) -> int:
        for name, value in self.headers:
            if name == b"content-length":
                try:
                    return int(value)
                except ValueError:
                    return 0
        return 0

    def _head_deadline(self) -> float:
        return min(self.header_timeout_s, PROBATION_HEAD_S) if self._pool == "probation" else self.header_timeout_s

    def _buffered(self) -> int:
        try:
            return int(self.transport.get_write_buffer_size())
        except (AttributeError, RuntimeError):
            return 0

    def _count_head(self, n: int) -> None:
        self._head_bytes += n
        if self._head_bytes > self.max_head_bytes:
            raise _HeadTooLarge()

    def _arm(self, delay: float, callback: Callable[[], None], kind: str = "head") -> None:
        self._cancel()
        if not self._closed_by_us:
            self._timer = self.loop.call_later(delay, callback)
            self._timer_kind = kind

    def _cancel(self) -> None:
        timer = getattr(self, "_timer", None)
        if timer is not None:
            timer.cancel()
            self._timer = None

    def _cancel_write_timer(self) -> None:
        timer = getattr(self, "_write_timer", None)
        if timer is not None:
            timer.cancel()
            self._write_timer = None

    def _head_timed_out(self) -> None:
        self._timer = None
        self._close_now("connection closed client=%s: no complete request head within %g s", self._address,
                        self._head_deadline())

    def _body_timed_out(self) -> None:
        self._timer = None
        if self._in_body:
            self._close_now("connection closed client=%s: the rest of a request body (%d bytes) did not come in "
                            "time after its answer", self._address, max(self._body_left, 0))

    def _close_now(self, message: str, *args: object) -> None:
        """Close the connection at once, its unsent bytes dropped (their memory returned), the
        request in progress told its client is gone; one line per address per interval."""
        if not self._closed_by_us:
            self.refusals.refused(self._address, message, *args)
        self._closed_by_us = True
        self._cancel()
        self._cancel_write_timer()
        cycle = self.cycle
        if cycle is not None and not cycle.response_complete:
            cycle.disconnected = True
            cycle.message_event.set()
        sock = self.transport.get_extra_info("socket")
        with contextlib.suppress(AttributeError, OSError, TypeError, ValueError):
            # a reset, not a FIN behind the unread bytes: the kernel's send queue goes too
            # (nginx's reset_timedout_connection)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.transport.abort()

    def _quiet_when_gone(self, cycle: Any) -> None:
        """A response written to a connection that has closed is a client gone, not an
        error: ``cycle``'s ``send`` then drops the message (the transport would raise)."""
        send, transport = cycle.send, self.transport

        async def send_while_open(message: Any) -> None:
            if transport.is_closing():
                cycle.disconnected = True
                return
            try:
                await send(message)
            except RuntimeError:
                if not transport.is_closing():
                    raise
                cycle.disconnected = True

        cycle.send = send_while_open

    def _answer_and_close(self, status: int, detail: str) -> None:
        """Write a JSON error answer with ``Connection: close`` and the headers browsers obey on
        every answer (``fpscan.service.api.browser_headers.SECURITY_HEADERS``), and close the
        connection."""
        import json

        self._closed_by_us = True
        self._cancel()
        body = json.dumps({"detail": detail}).encode()
        phrase = {400: "Bad Request", 431: "Request Header Fields Too Large", 503: "Service Unavailable"}[status]
        head = (f"HTTP/1.1 {status} {phrase}\r\ncontent-type: application/json\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n"
                + ("retry-after: 5\r\n" if status == 503 else "")).encode()
        head += b"".join(name + b": " + value + b"\r\n" for name, value in SECURITY_HEADERS) + b"\r\n"
        if not self.transport.is_closing():
            self.transport.write(head + body)
            self.transport.close()  # a reader that does not take even this: dropped at its deadline


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
    token_value = settings.token_value if settings.token is not None or settings.token_file is not None else None
    return type("GuardedHttp", (GuardedHttp,), {
        "guard": guard or ConnectionGuard.from_settings(settings),
        "header_timeout_s": float(settings.header_timeout_s),
        "max_head_bytes": int(settings.max_head_bytes),
        "body_timeout_s": float(settings.body_timeout_s),
        "body_min_rate": float(settings.body_min_rate),
        "body_rate_window_s": float(settings.body_rate_window_s),
        "send_timeout_s": float(settings.send_timeout_s),
        "send_min_rate": float(settings.send_min_rate),
        "send_buffer_bytes": settings.send_buffer_bytes,
        "token_value": staticmethod(token_value) if token_value is not None else None,
        "refusals": RefusalLog(log),
    })


def server_config(app: Any, settings: Settings) -> Any:
    """The ``uvicorn.Config`` that serves ``app`` by ``settings``.

    Bind address and port, the guarded protocol (:func:`guarded_protocol`; no WebSocket
    upgrades: the service has no WebSocket route), the keep-alive timeout
    (``settings.keep_alive_s``), the graceful-shutdown bound (``settings.shutdown_grace_s``:
    open connections, SSE streams included, are closed after it), no access log; then every
    log handler is capped (:func:`fpscan.service.api.logcaps.install_log_caps`).

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
