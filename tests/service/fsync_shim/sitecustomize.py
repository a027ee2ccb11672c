"""An fsync and SQLite recorder for a server under test (tests/service/test_acknowledged_on_disk.py).

Put on ``PYTHONPATH`` of ``fpscan serve`` (and so of its worker processes) with
``FSYNC_RECORD`` naming a file, it records, in the order they happen, one line per event:

- ``fsync <pid> <path>`` after each ``os.fsync``/``os.fdatasync`` returned (the path of the
  descriptor, ``/proc/self/fd``);
- ``sql <pid> <connection> <database> <statement>`` as SQLite begins each statement that
  writes or bounds a transaction (``BEGIN``, ``INSERT``, ``UPDATE``, ``DELETE``, ``COMMIT``,
  ``ROLLBACK``, ``PRAGMA synchronous``; with its values, from ``sqlite3``'s trace callback).

It only records: each call goes on to the real function. Lines are appended with one
``write`` to a file opened ``O_APPEND``, so the processes' lines interleave whole and in order.
``sys.addaudithook`` would not do: CPython raises no audit event for ``os.fsync``.
"""
from __future__ import annotations

import os

_PATH = os.environ.get("FSYNC_RECORD")

if _PATH:
    import sqlite3

    _fd = os.open(_PATH, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def _line(text: str) -> None:
        os.write(_fd, (" ".join(text.split()) + "\n").encode("utf-8", "replace"))

    def _recorded(real):
        def call(fd, *args, **kwargs):
            out = real(fd, *args, **kwargs)
            try:
                where = os.readlink(f"/proc/self/fd/{int(fd if isinstance(fd, int) else fd.fileno())}")
            except OSError:
                where = "?"
            _line(f"fsync {os.getpid()} {where}")
            return out
        return call

    os.fsync = _recorded(os.fsync)
    os.fdatasync = _recorded(os.fdatasync)

    _connect = sqlite3.connect
    _WRITES = ("BEGIN", "INSERT", "UPDATE", "DELETE", "COMMIT", "ROLLBACK", "PRAGMA SYNCHRONOUS")

    def _traced(*args, **kwargs):
        conn = _connect(*args, **kwargs)
        database, cid = str(args[0] if args else kwargs.get("database")), id(conn)

        def trace(statement: str) -> None:
            if statement.lstrip().upper().startswith(_WRITES):
                _line(f"sql {os.getpid()} {cid} {database} {statement}")

        conn.set_trace_callback(trace)
        return conn

    sqlite3.connect = _traced
