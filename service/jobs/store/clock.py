"""The job store's clocks: the wall clock for display, the store's monotonic time for durations.

The wall clock (``time.time()``, POSIX ``CLOCK_REALTIME``) is what a person reads, and it
steps: NTP's correction, a changed time zone setting done wrong, an administrator's
``date -s``. A duration taken from it across a step is wrong by the step (an hour back made a
ten-second run ``-3590 s``). ``time.monotonic()`` (``CLOCK_MONOTONIC``, one clock for every
process of the machine) never steps, but starts again at each boot. The store's time joins the
two: store time = ``time.monotonic() + offset``, with one ``offset`` per boot, kept in the
store (the ``config`` row :data:`CLOCK_KEY`), so that the server and its worker processes,
each with a store of its own, share one time line:

- the first store opened in a boot whose offset is not stored yet sets it so that the store
  time goes on from the newest time the store recorded, plus the wall clock's time since
  then when that is positive (the machine was off that long), never less: store time never
  goes back, across a reboot neither; a database without a recorded time starts at the wall
  clock (so that the times of jobs an earlier release recorded, which take their wall times,
  come before);
- every later store of that boot reads that offset.

A job records both at each of its moments (``created``/``created_mono``, ``started``/
``started_mono``, ``finished``/``finished_mono``): its durations (``queued_s``, ``run_s``) are
differences of store times, immune to steps of the wall clock; the wall times are for display.
A dataset records both at its upload (``created``/``created_mono``) and its latest use (its
meta's ``last_used``/``used_mono``): retention by age counts on the store time.
Durations across a reboot count the time the machine was off by the wall clock, clamped at 0.
The boot is ``/proc/sys/kernel/random/boot_id`` (Linux); elsewhere the boot's wall time to
the minute (a wall step of a minute or more between two stores' opening then starts a new
time line: it still never goes back).

Sources: POSIX ``clock_gettime`` (``CLOCK_REALTIME`` may be set, ``CLOCK_MONOTONIC`` may not);
Python's :func:`time.monotonic`; proc(5) ``boot_id``.
"""
from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

__all__ = ["CLOCK_KEY", "wall_time", "boot_id", "StoreClock"]

#: the ``config`` key of the store time's offset: ``{"boot": boot_id(), "offset": s}``
CLOCK_KEY = "store_clock"


def wall_time() -> float:
    """The wall clock, UNIX s (``time.time()``): for display only, never for a duration.

    Returns
    -------
    float
        Seconds since the UNIX epoch.
    """
    return time.time()


def boot_id() -> str:
    """The current boot of the machine: Linux's ``/proc/sys/kernel/random/boot_id``, else the boot's
    wall time to the minute (``"wall-<s>"``).

    Returns
    -------
    str
        An id that stays the same from boot to shutdown.
    """
    try:
        text = Path("/proc/sys/kernel/random/boot_id").read_text(encoding="ascii").strip()
        if text:
            return text
    except OSError:
        pass
    return f"wall-{round((time.time() - time.monotonic()) / 60.0) * 60}"


#: the store times recorded, each with the wall time of the same moment: (table, store time, wall time)
_MOMENTS = (("jobs", "created_mono", "created"), ("jobs", "started_mono", "started"),
            ("jobs", "finished_mono", "finished"), ("datasets", "created_mono", "created"),
            ("datasets", "used_mono", "COALESCE(json_extract(meta, '$.last_used'), created)"))


class StoreClock:
    """The store's time of one store (module docstring).

    Parameters
    ----------
    offset : float
        Store time - ``time.monotonic()``, s.

    Attributes
    ----------
    offset : float
        As given.
    """

    def __init__(self, offset: float) -> None:
        self.offset = float(offset)

    def monotonic(self) -> float:
        """The store time now, s (never less than any earlier reading, in any process)."""
        return time.monotonic() + self.offset

    def now(self) -> tuple[float, float]:
        """``(wall, store)``: the wall time (UNIX s, :func:`wall_time`) and the store time (s)
        of this moment."""
        return wall_time(), self.monotonic()

    @classmethod
    def open(cls, db: sqlite3.Connection) -> StoreClock:
        """The clock of the store ``db`` in the current boot: its stored offset, or a new one (module
        docstring), in one ``BEGIN IMMEDIATE`` transaction (two processes opening the store
        at once agree on one).

        Parameters
        ----------
        db : sqlite3.Connection
            The store's connection (autocommit, ``sqlite3.Row`` rows), under the store's lock,
            its schema applied.

        Returns
        -------
        StoreClock
        """
        boot = boot_id()
        db.execute("BEGIN IMMEDIATE")
        try:
            row = db.execute("SELECT value FROM config WHERE key = ?", (CLOCK_KEY,)).fetchone()
            stored = json.loads(row["value"]) if row is not None else None
            if isinstance(stored, dict) and stored.get("boot") == boot:
                offset = float(stored["offset"])
            else:
                union = " UNION ALL ".join(f"SELECT {m} AS mono, {w} AS wall FROM {t} WHERE {m} IS NOT NULL"
                                           for t, m, w in _MOMENTS)
                last = db.execute(f"SELECT mono, wall FROM ({union}) ORDER BY mono DESC LIMIT 1").fetchone()
                wall, mono = wall_time(), time.monotonic()
                if last is None:
                    offset = wall - mono
                else:  # on from the newest recorded time, plus the time off by the wall clock
                    offset = float(last["mono"]) + max(0.0, wall - float(last["wall"])) - mono
                db.execute("INSERT INTO config (key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE"
                           " SET value = excluded.value", (CLOCK_KEY, json.dumps({"boot": boot, "offset": offset})))
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                db.execute("ROLLBACK")
            raise
        return cls(offset)
