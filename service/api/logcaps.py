"""What a request may put into the server's log: each field capped, refusals counted, not
written one line each.

A stranger's requests cost the server a log line each: before this, every refused request
was logged with its whole path (a 60 kB path, 60 kB of log; one client looping wrote 12 MB
in 1.1 s). Here, as Jupyter Server truncates its request log:

- :func:`shown`: a field a client chose (a path, a Host header, a method), as logged: up to
  :data:`FIELD_MAX` characters, with its length when cut;
- :class:`RefusalLog`: refusals are logged at most one line per client address per
  ``interval_s`` (the first at once; the next line says how many were not written since);
- :class:`CappedRecords`: a logging filter for the server's log handlers that cuts any record
  to :data:`RECORD_MAX` characters, its traceback included, keeping the traceback's last line
  (the exception's name and message: what a reader of the log looks for first) (a backstop for whatever else
  quotes a request: a library's message, an exception's text) and writes a message that uvicorn's connection
  logger repeats (its "Invalid HTTP request received." comes once per bad request) at most
  once per ``interval_s``, with the count of those left out;
- :class:`Thinning`: the one rate limit both use (one pass per key per interval).
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Hashable

__all__ = ["FIELD_MAX", "RECORD_MAX", "REPEAT_INTERVAL_S", "shown", "Thinning", "RefusalLog", "CappedRecords",
           "install_log_caps"]

#: characters of a client's field (a path, a header) a log line carries
FIELD_MAX = 200
#: characters of one log record's message at most (the rest is cut, its length said)
RECORD_MAX = 2000
#: one line per address (refusals) or per repeated message per this many seconds
REPEAT_INTERVAL_S = 10.0


def shown(text: object, limit: int = FIELD_MAX) -> str:
    """``text`` as a log line carries it: at most ``limit`` characters, and its length when longer.

    Parameters
    ----------
    text : object
        The field (converted with ``str``).
    limit : int, optional
        The most characters kept; default :data:`FIELD_MAX` (200).

    Returns
    -------
    str
        The text, or its first ``limit`` characters followed by ``"... (<n> characters)"``.

    Examples
    --------
    >>> shown("/api/health")
    '/api/health'
    >>> shown("/" + "a" * 300, limit=8)
    '/aaaaaaa... (301 characters)'
    """
    s = str(text)
    return s if len(s) <= limit else f"{s[:limit]}... ({len(s)} characters)"


class Thinning:
    """At most one pass per key per interval: the rate limit :class:`RefusalLog` (per client
    address) and :class:`CappedRecords` (per repeated message) share. Thread-safe; the table
    of keys is bounded (the oldest entries go first).

    Attributes
    ----------
    keys : int
        Keys remembered now.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: dict[Hashable, tuple[float, int]] = {}  # key -> (time of its last pass, left out since)

    @property
    def keys(self) -> int:
        """Keys remembered now."""
        return len(self._seen)

    def let_through(self, key: Hashable, interval_s: float, most_keys: int) -> tuple[bool, int]:
        """Whether ``key`` passes now, and how many of its were left out since its last pass.

        Parameters
        ----------
        key : hashable
            What is thinned (an address, a message).
        interval_s : float
            Seconds between two passes of one key.
        most_keys : int
            Keys remembered at most.

        Returns
        -------
        tuple of (bool, int)
            ``(passes, left_out)``: ``left_out`` counts the key's attempts not passed since its
            last pass (0 when it does not pass: it is counted instead).
        """
        now = time.monotonic()
        with self._lock:
            last, skipped = self._seen.get(key, (-float("inf"), 0))
            if now - last < interval_s:
                self._seen[key] = (last, skipped + 1)
                return False, 0
            self._seen.pop(key, None)
            self._seen[key] = (now, 0)
            while len(self._seen) > most_keys:
                self._seen.pop(next(iter(self._seen)))
        return True, skipped


class RefusalLog:
    """Log refusals of requests at most one line per client address per ``interval_s``
    (s): the first refusal from an address is logged at once, later ones in the interval
    are counted and the next line written says how many were left out. Thread-safe; the
    table of addresses is bounded (``max_addresses``; the oldest entries go first).

    Parameters
    ----------
    logger : logging.Logger
        The logger the lines go to.
    interval_s : float, optional
        Seconds between two lines for one address; default :data:`REPEAT_INTERVAL_S` (10 s).
    max_addresses : int, optional
        Addresses remembered at most; default 4096.

    Attributes
    ----------
    logger : logging.Logger
        As given.
    interval_s : float
        As given.
    max_addresses : int
        As given.
    """

    def __init__(self, logger: logging.Logger, interval_s: float = REPEAT_INTERVAL_S,
                 max_addresses: int = 4096) -> None:
        self.logger = logger
        self.interval_s = float(interval_s)
        self.max_addresses = int(max_addresses)
        self._thinning = Thinning()

    def refused(self, address: str | None, message: str, *args: object, level: int = logging.INFO) -> bool:
        """Log a refusal from ``address``, unless one was logged for it less than ``interval_s`` ago.

        A refusal not logged is counted; the next line for the address says how many were
        left out.

        Parameters
        ----------
        address : str or None
            The client's address (None counts as ``"?"``).
        message : str
            The %-format of the line.
        *args : object
            Its arguments.
        level : int, optional
            The logging level; default ``logging.INFO``.

        Returns
        -------
        bool
            Whether a line was written.
        """
        key = address or "?"
        passes, skipped = self._thinning.let_through(key, self.interval_s, self.max_addresses)
        if not passes:
            return False
        suffix = f" (and {skipped} more refusals from {key} not logged since)" if skipped else ""
        self.logger.log(level, message + "%s", *args, suffix)
        return True


class CappedRecords(logging.Filter):
    """A handler filter: each record's message, with the traceback it carries (``exc_info``,
    ``stack_info``: folded into the message), cut to ``limit`` characters (its length said; a
    traceback cut keeps its last line, the exception's name and message), and a message repeated by one of ``repeat_loggers`` written at most once per
    ``interval_s`` (the next one says how many were left out). Records of level ERROR and
    above always pass (cut, never dropped).

    Parameters
    ----------
    limit : int, optional
        The most characters of a message; default :data:`RECORD_MAX` (2000).
    interval_s : float, optional
        Seconds between two records of one repeated message; default
        :data:`REPEAT_INTERVAL_S` (10 s).
    max_messages : int, optional
        Repeated messages remembered at most (the oldest go first); default 1024.
    repeat_loggers : tuple of str, optional
        The loggers whose repeated messages are thinned; default ``("uvicorn.error",)``.

    Attributes
    ----------
    limit : int
        As given.
    interval_s : float
        As given.
    max_messages : int
        As given.
    repeat_loggers : frozenset of str
        As given.
    """

    def __init__(self, limit: int = RECORD_MAX, interval_s: float = REPEAT_INTERVAL_S,
                 max_messages: int = 1024, repeat_loggers: tuple[str, ...] = ("uvicorn.error",)) -> None:
        super().__init__()
        self.repeat_loggers = frozenset(repeat_loggers)
        self.limit = int(limit)
        self.interval_s = float(interval_s)
        self.max_messages = int(max_messages)
        self._thinning = Thinning()

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a record that cannot format itself is passed on as it is
            return True
        if record.levelno < logging.ERROR and record.name in self.repeat_loggers:
            passes, skipped = self._thinning.let_through((record.name, message[:FIELD_MAX]), self.interval_s,
                                                         self.max_messages)
            if not passes:
                return False
            if skipped:
                message = f"{message} (repeated {skipped} more times, not logged)"
        changed = message != record.getMessage()
        trace = _traceback_of(record)
        if trace:  # a traceback counts against the same cap: it becomes part of the message
            message = f"{message}\n{trace}"
            record.exc_info, record.exc_text, record.stack_info = None, None, None
            changed = True
        if len(message) > self.limit:
            # a traceback cut keeps its last line: the exception's name and message (capped)
            last = "\n" + shown(trace.rstrip().rsplit("\n", 1)[-1]) if trace else ""
            message = shown(message, max(0, self.limit - len(last))) + last
            changed = True
        if changed:
            record.msg, record.args = message, None
            if hasattr(record, "message_json"):  # `fpscan serve`'s JSON lines carry it made already
                import json

                record.message_json = json.dumps(message)
        return True


def _traceback_of(record: logging.LogRecord) -> str:
    """The traceback and stack a record carries (``exc_info``, ``stack_info``), as a handler
    would write them after its message; ``""`` when it carries none."""
    parts = []
    if record.exc_info:
        parts.append(logging.Formatter().formatException(record.exc_info))
    elif record.exc_text:
        parts.append(record.exc_text)
    if record.stack_info:
        parts.append(record.stack_info)
    return "\n".join(parts)


def install_log_caps(limit: int = RECORD_MAX, interval_s: float = REPEAT_INTERVAL_S) -> CappedRecords:
    """Add one :class:`CappedRecords` to every handler of the root logger and of uvicorn's loggers.

    A handler that has a :class:`CappedRecords` already is left as it is.

    Parameters
    ----------
    limit : int, optional
        The most characters of a message; default :data:`RECORD_MAX` (2000).
    interval_s : float, optional
        Seconds between two records of one repeated message; default
        :data:`REPEAT_INTERVAL_S` (10 s).

    Returns
    -------
    CappedRecords
        The filter added.
    """
    caps = CappedRecords(limit, interval_s)
    for name in ("", "uvicorn", "uvicorn.error", "uvicorn.access"):
        for handler in logging.getLogger(name).handlers:
            if not any(isinstance(f, CappedRecords) for f in handler.filters):
                handler.addFilter(caps)
    return caps
