"""One build at a time per file: the requests that come while a file is being built wait
for that build and serve its file (the exports of ``fpscan.service.api.exports``: 20
concurrent first requests of a volume's OME-TIFF build it once and all serve the same
bytes).

A :class:`SingleFlight` holds a lock per key (an output path), made at its first user and
dropped with its last, and counts the builds made under it: a request's :class:`Turn` says
whether a build ended while the request waited (its file is then the one to serve) or the
request must build it itself.
"""
from __future__ import annotations

import contextlib
import threading
from collections.abc import Hashable, Iterator

__all__ = ["SingleFlight", "Turn"]


class _Flight:
    """One key's build lock, its users (waiting or building) and its builds so far."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.users = 0
        self.builds = 0


class Turn:
    """A request's turn at a file (:meth:`SingleFlight.turn`): whether a build of it ended
    while the request waited, and :meth:`built` to count the build it made.

    Made by :meth:`SingleFlight.turn`, not by hand.

    Parameters
    ----------
    flight : object
        The key's flight (its lock, users and builds).
    seen : int
        The number of the key's builds when the request came.

    Attributes
    ----------
    built_meanwhile : bool
        A build of the file ended between the request's arrival and its turn.
    """

    def __init__(self, flight: _Flight, seen: int) -> None:
        self._flight, self._seen = flight, seen

    @property
    def built_meanwhile(self) -> bool:
        """True when a build ended while the request waited for its turn."""
        return self._flight.builds != self._seen

    def built(self) -> None:
        """Count the build this turn made (the requests waiting behind it serve its file)."""
        self._flight.builds += 1


class SingleFlight:
    """Build turns per key: one holder at a time, in turn, the key's entry gone with its
    last user.

    Examples
    --------
    >>> flights = SingleFlight()
    >>> with flights.turn("volume.ome.tif") as turn:
    ...     if not turn.built_meanwhile:
    ...         turn.built()  # after writing the file
    >>> flights.users("volume.ome.tif")
    0
    """

    def __init__(self) -> None:
        self._flights: dict[Hashable, _Flight] = {}
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def turn(self, key: Hashable) -> Iterator[Turn]:
        """Hold the build of ``key``; a context manager.

        Parameters
        ----------
        key : hashable
            What is built (an output path).

        Returns
        -------
        contextlib.AbstractContextManager of Turn
            Entered once the requests before this one have left theirs: the request's
            :class:`Turn` (``built_meanwhile``: a build ended while it waited).
        """
        with self._lock:
            flight = self._flights.setdefault(key, _Flight())
            flight.users += 1
            seen = flight.builds
        try:
            with flight.lock:
                yield Turn(flight, seen)
        finally:
            with self._lock:
                flight.users -= 1
                if flight.users == 0:
                    del self._flights[key]

    def users(self, key: Hashable) -> int:
        """The requests holding or waiting for ``key``'s turn.

        Parameters
        ----------
        key : hashable
            What is built.

        Returns
        -------
        int
            Their number (0 when none).
        """
        with self._lock:
            flight = self._flights.get(key)
            return flight.users if flight is not None else 0
