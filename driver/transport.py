"""Transport readers of the host driver: how received bytes get off the serial port.

The split follows pyserial's ``serial.threaded`` model: a *reader* only moves bytes off
the port, and the protocol (:class:`fpscan.driver.host.Scanner`, which deframes and dispatches
them) consumes what it delivered. Every reader offers the same two calls:

- ``read() -> bytes``: the bytes received since the last call, waiting at most ~20 ms
  for the first one; raises :class:`TransportError` with the reason if the port failed.
- ``close()``: stop reading (the serial port itself is closed by its owner).

Readers (``open_reader(ser, mode)``):

- :class:`RelayReader` (``"process"``, the default for local ttys): the relay process
  :mod:`fpscan.driver.relay` drains the tty into a 1 MiB pipe, immune to this interpreter's lock;
  if the relay ends, the port is read directly from then on.
- :class:`ThreadReader` (``"thread"``): pyserial's :class:`serial.threaded.ReaderThread`
  with a protocol that queues what it receives, at most :data:`THREAD_QUEUE_BYTES` not yet
  read: a device that sends more while nobody reads (a flood) has it discarded, and the next
  ``read()`` raises :class:`TransportError` saying so (the host's "device lost").
- :class:`DirectReader` (``"direct"``, and always for URL transports such as
  ``socket://`` or ``loop://``, which have no descriptor): pyserial reads in the calling
  thread.
"""
from __future__ import annotations

import collections
import os
import select
import subprocess
import sys
import threading

import serial
from serial.threaded import Protocol, ReaderThread

__all__ = [
    "READER_MODES", "RELAY_START_TIMEOUT", "THREAD_QUEUE_BYTES", "TransportError", "DirectReader", "ThreadReader", "RelayReader",
    "open_reader",
]

READER_MODES = ("process", "thread", "direct")
_WAIT = 0.02  #: longest wait for the first byte of a read(), s
RELAY_START_TIMEOUT = 10.0  #: longest wait for the relay process to start reading, s
#: most bytes the reader thread holds that nobody has read yet. Twice what a device under the
#: host's credit window has in flight at most (256 A-line frames of the longest A-line,
#: 65 kB each: 17 MB), so a sound device never reaches it while the host is slow to read; a
#: device that sends more (a flood) has the excess discarded and the next read says so
THREAD_QUEUE_BYTES = 32 << 20


class TransportError(OSError):
    """Reading from the serial port failed (the message names the port and the cause).

    Parameters
    ----------
    *args : str
        The message (as ``OSError``).
    """


class DirectReader:
    """Read the port through pyserial in the calling thread.

    Parameters
    ----------
    ser : serial.Serial
        The open pyserial port.
    port : str, optional
        Its name in error messages (default the port's own ``port`` attribute).
    """

    def __init__(self, ser: serial.SerialBase, port: str = "") -> None:
        self._ser = ser
        self._port = port or getattr(ser, "port", "")

    def read(self) -> bytes:
        ser = self._ser
        try:
            n = ser.in_waiting
            data = ser.read(n if n else 1)  # the port's timeout (20 ms) bounds the wait
            if len(data) == 1:
                n = ser.in_waiting
                if n:
                    data += ser.read(n)
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"read from {self._port} failed: {exc}") from None
        return data

    def close(self) -> None:
        pass


class _ByteQueue:
    """Chunks received and not yet read, at most ``max_bytes`` of them (thread-safe).

    Once a chunk would take it past ``max_bytes``, everything held and everything that
    arrives after is discarded (and counted) until :meth:`take` reports it: memory stays
    bounded whatever the device sends."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._cond = threading.Condition()
        self._chunks: collections.deque[bytes] = collections.deque()
        self._size = 0
        self._discarded = 0
        self._error: BaseException | None = None

    def put(self, data: bytes) -> None:
        with self._cond:
            if self._discarded or self._size + len(data) > self.max_bytes:
                self._discarded += self._size + len(data)
                self._chunks.clear()
                self._size = 0
            else:
                self._chunks.append(data)
                self._size += len(data)
            self._cond.notify()

    def fail(self, exc: BaseException) -> None:
        with self._cond:
            self._error = exc
            self._cond.notify()

    def take(self, timeout: float) -> tuple[bytes, int, BaseException | None]:
        """What arrived (waiting up to ``timeout`` s for it), the bytes discarded since the
        last call, and the reader's error (it stopped) once every byte before it was taken."""
        with self._cond:
            if not (self._chunks or self._discarded or self._error):
                self._cond.wait(timeout)
            data = b"".join(self._chunks)
            self._chunks.clear()
            self._size = 0
            discarded, self._discarded = self._discarded, 0
            return data, discarded, None if data else self._error


class _QueueProtocol(Protocol):
    """A ``serial.threaded`` protocol that hands received chunks to a :class:`_ByteQueue`."""

    def __init__(self, q: _ByteQueue) -> None:
        self._q = q

    def connection_made(self, transport: ReaderThread) -> None:
        pass

    def data_received(self, data: bytes) -> None:
        self._q.put(bytes(data))

    def connection_lost(self, exc: BaseException | None) -> None:
        if exc is not None:
            self._q.fail(exc)


class ThreadReader:
    """pyserial's ``ReaderThread`` drains the port; :meth:`read` collects its chunks.

    At most ``max_bytes`` received bytes wait for :meth:`read`: beyond that (a device that
    floods a host that is not reading) what is held and what follows is discarded until the
    next :meth:`read`, which raises :class:`TransportError` with the count instead of
    returning data (the bytes are lost: the caller's protocol recovers or gives up).

    Parameters
    ----------
    ser : serial.Serial
        The open pyserial port.
    port : str, optional
        Its name in error messages (default the port's own ``port`` attribute).
    max_bytes : int, optional
        The most bytes held for :meth:`read` (default :data:`THREAD_QUEUE_BYTES`, 32 MiB).
    """

    def __init__(self, ser: serial.SerialBase, port: str = "",
                 max_bytes: int = THREAD_QUEUE_BYTES) -> None:
        if max_bytes < 1:
            raise ValueError(f"max_bytes must be >= 1, got {max_bytes}")
        self._port = port or getattr(ser, "port", "")
        self._q = _ByteQueue(int(max_bytes))
        self._thread = ReaderThread(ser, lambda: _QueueProtocol(self._q))
        self._thread.name = f"fpscan-rx {self._port}"
        self._thread.start()

    def read(self) -> bytes:
        data, discarded, error = self._q.take(_WAIT)
        if discarded:
            raise TransportError(f"{self._port} sent more than the {self._q.max_bytes} bytes held "
                                 f"until they are read (a flood): {discarded} bytes were discarded")
        if error is not None:
            raise TransportError(f"read from {self._port} failed: {error}")
        return data

    def close(self) -> None:
        if self._thread.alive:
            self._thread.stop()


class RelayReader:
    """The relay process (:mod:`fpscan.driver.relay`) drains the tty descriptor ``fd`` into a
    pipe; :meth:`read` reads that pipe. Raises ``OSError`` if the relay cannot start.

    Parameters
    ----------
    ser : serial.Serial
        The open pyserial port (read directly should the relay end).
    fd : int
        Its tty descriptor, handed to the relay process.
    port : str, optional
        Its name in error messages (default the port's own ``port`` attribute).

    Raises
    ------
    OSError
        The relay process did not start reading within :data:`RELAY_START_TIMEOUT` s.
    """

    def __init__(self, ser: serial.SerialBase, fd: int, port: str = "") -> None:
        import fcntl

        self._ser = ser
        self._port = port or getattr(ser, "port", "")
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        proc = subprocess.Popen(
            [sys.executable, "-m", "fpscan.driver.relay", str(fd), str(os.getpid())],
            pass_fds=(fd,), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, bufsize=0,
            cwd=root)
        assert proc.stdout is not None  # stdout=PIPE
        self._proc: subprocess.Popen | None = proc
        self._stdout = proc.stdout
        self._fd = proc.stdout.fileno()
        self._direct: DirectReader | None = None
        try:
            fcntl.fcntl(self._fd, 1031, 1 << 20)  # F_SETPIPE_SZ: 1 MiB
        except OSError:
            pass
        self._wait_ready(RELAY_START_TIMEOUT)

    def _wait_ready(self, timeout: float) -> None:
        """Wait for the relay's first byte (``fpscan.driver.relay.READY``): until then nobody reads
        the tty, and a reply that waited for the relay to start would look like a lost
        command (a retransmission counted as a link fault). Raises ``OSError`` (after
        ending the relay) if it does not come within ``timeout`` s."""
        from fpscan.driver.relay import READY

        first = b""
        try:
            if select.select([self._fd], [], [], timeout)[0]:
                first = os.read(self._fd, len(READY))
        except OSError:
            first = b""
        if first != READY:
            self._stop()
            raise OSError(f"the relay process for {self._port} did not start within {timeout:g} s")

    def read(self) -> bytes:
        if self._direct is not None:
            return self._direct.read()
        try:
            if not select.select([self._fd], [], [], _WAIT)[0]:
                return b""
            data = os.read(self._fd, 1 << 20)
        except OSError as exc:
            raise TransportError(f"read from {self._port} failed: {exc}") from None
        if not data:  # the relay ended (killed?): read the tty here from now on
            self._stop()
            self._direct = DirectReader(self._ser, self._port)
        return data

    @property
    def process(self) -> subprocess.Popen | None:
        """The relay process; None once it ended and the port is read directly."""
        return self._proc

    def _stop(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait(timeout=5)
            self._stdout.close()
            self._proc = None

    def close(self) -> None:
        self._stop()


def open_reader(ser: serial.SerialBase, mode: str = "process",
                port: str = "") -> RelayReader | ThreadReader | DirectReader:
    """The reader for an open pyserial port ``ser`` (module docstring).

    ``mode``: ``"process"``, ``"thread"`` or ``"direct"``; ports without a descriptor
    (URL transports) are always read directly; if no relay process can be started, a
    reader thread is used. Raises ``ValueError`` for an unknown mode.

    Parameters
    ----------
    ser : serial.Serial
        The open pyserial port.
    mode : str, optional
        ``"process"`` (default), ``"thread"`` or ``"direct"``.
    port : str, optional
        The port's name in error messages.

    Returns
    -------
    RelayReader, ThreadReader or DirectReader
        The reader (``read()`` and ``close()``).

    Raises
    ------
    ValueError
        An unknown ``mode``.
    """
    if mode not in READER_MODES:
        raise ValueError(f"reader must be 'process', 'thread' or 'direct', not {mode!r}")
    fd = getattr(ser, "fd", None)  # POSIX ports have one; URL transports do not
    if not isinstance(fd, int) or mode == "direct":
        return DirectReader(ser, port)
    if mode == "process":
        try:
            return RelayReader(ser, fd, port)
        except OSError:  # no interpreter to start
            pass
    return ThreadReader(ser, port)
