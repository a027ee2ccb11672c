"""Host driver of the FP scanner link (docs/protocol.md): identify, upload a plan, scan.

:class:`Scanner` opens a serial port by device path or pyserial URL
(``serial.serial_for_url``) with an exclusive lock, and implements the host side of the
protocol: commands with retransmission and a reply timeout, chunked plan upload with hash
verification, and :meth:`Scanner.scan`, which streams A-lines into a sink (a
:class:`fpscan.driver.scanfile.ScanFile`, or anything with its ``completed()`` / ``append()``)
under a credit window, NAKs gaps, and recovers from CRC errors, lost bytes, stalls and
device resets, resuming from the sink's record of completed points, which is the truth.

Layers (the pyserial ``serial.threaded`` split): a transport reader
(:mod:`fpscan.driver.transport`) moves bytes off the port; :class:`Scanner` deframes them and
dispatches frames (replies to its commands, events, A-lines); a :class:`ScanSession`
holds one scan's receive state and record. Command strings come from
:mod:`fpscan.driver.commands`.

Threading: one thread runs :meth:`Scanner.scan`; :meth:`pause`, :meth:`resume` and
:meth:`abort` may be called from any other thread (they queue a request the scan loop
carries out within ~20 ms). Every wait has a timeout; failures raise :class:`DriverError`
subclasses with the reason.
"""
from __future__ import annotations

import collections
import hashlib
import math
import queue
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.driver import commands as cmd
from fpscan.driver.aline import ALINE_HEADER, ALine, check_aline, unpack_aline
from fpscan.driver.commands import MAX_CHUNK, MIN_CHUNK
from fpscan.driver.framing import PROTOCOL_VERSION, Deframer, Frame, FrameType, encode_frame
from fpscan.driver.plan import aline_index, aline_order, load_plan, wavelength_order
from fpscan.driver.plan_image import plan_image
from fpscan.driver.transport import READER_MODES, TransportError, open_reader

if TYPE_CHECKING:
    import os

    import serial

__all__ = [
    "MAX_RESETS", "MAX_IDLE_RUNS", "DriverError", "DeviceTimeout", "DeviceError", "InterlockOpen", "DeviceFault", "DeviceStatus",
    "ScanProgress", "ScanResult", "Scanner", "ScanSession",
]

_SEQ_MASK = 0xFFFFFFFF  #: data sequence numbers are u32 (docs/protocol.md §2.2)
_NAK_MAX = 256  #: sequence numbers per NAK frame (docs/protocol.md §7)
_NAK_EVERY = 0.1  #: shortest interval between two NAKs of one sequence number, s
_NAK_LOOK = 8192  #: most sequence numbers above the cumulative ACK looked at for one NAK
_EARLY_MAX = 64  #: most A-line frames kept that overtook their run's SCAN:STAR reply
#: device resets (or plans lost) one call of :meth:`Scanner.scan` recovers from by default; the
#: next one is a device fault (docs/protocol.md §10). A sound scanner resets rarely (a power
#: glitch, a watchdog): eight in one scan is a scanner that will not get through it, and a
#: scanner that resets at one point every time would otherwise keep the host re-uploading forever
MAX_RESETS = 8
#: runs in a row that end (the device IDLE) with A-lines missing and none new on disk, after which
#: the scan ends with a device fault (docs/protocol.md §7): a sound device ends a run early only when
#: frames were lost on the link, and the next run delivers them; one that ends every run without a
#: new A-line would otherwise be restarted for ever
MAX_IDLE_RUNS = 3


class DriverError(RuntimeError):
    """The scanner link failed (base class of the driver's errors).

    Parameters
    ----------
    *args : str
        The message (as ``RuntimeError``).
    """


class DeviceTimeout(DriverError):
    """The device did not answer within the timeout (after retransmissions).

    Parameters
    ----------
    *args : str
        The message (as ``RuntimeError``).
    """


class DeviceError(DriverError):
    """The device rejected a command: ``code`` and ``message`` from its ERR reply.

    Parameters
    ----------
    code : int
        The SCPI error number of the ERR reply.
    message : str
        Its message.
    command : str, optional
        The command it answered (named in the exception's text when given).

    Attributes
    ----------
    code : int
        As given.
    message : str
        As given.
    """

    def __init__(self, code: int, message: str, command: str = ""):
        super().__init__(f"device error {code} ({message})" + (f" on {command!r}" if command
                                                               else ""))
        self.code = code
        self.message = message


class InterlockOpen(DeviceError):
    """The laser interlock is open: the device cannot fire (no automatic recovery).

    Parameters
    ----------
    code, message, command
        As :class:`DeviceError`.
    """


class DeviceFault(DriverError):
    """The device sent a number that no plan allows: a data sequence number outside its run,
    an A-line of a point, wavelength or length the plan does not have, an A-line field out of
    its documented range (a ``dc_level`` ≤ 0, a NaN ``scale``), a malformed ``SCAN:STAR`` or
    ``SYST:LIM?`` reply, a ``max_chunk`` below the protocol's minimum; or it reset more often
    than one scan recovers from (``max_resets``). Its frame's CRC-32 was good, so this is the
    device's (firmware's) fault, not the link's: :meth:`Scanner.scan` stops at the first one
    (the device left idle), its scan file keeps every A-line received so far, and a new call
    resumes from there (docs/protocol.md §7, §10).

    Parameters
    ----------
    reason : str
        What the device sent, and what the plan allows.
    detail : str, optional
        Appended to the message (e.g. how many A-lines are on disk).

    Attributes
    ----------
    reason : str
        As given.
    """

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"device fault: {reason}" + (f"; {detail}" if detail else ""))
        self.reason = reason


@dataclass
class DeviceStatus:
    """Parsed ``SCAN:STAT?`` reply.

    Attributes
    ----------
    state : str
        ``IDLE``, ``RUNNING``, ``PAUSED`` or ``FAULT``.
    boot_id : int
        The device's boot id (new at every power-up or reset).
    run_id : int
        The current (or last) run.
    next_index : int
        The next A-line index to acquire (docs/protocol.md §4.1).
    n_points : int
        The reply's ``n_alines``: A-lines of the uploaded plan, points × wavelengths.
    next_seq : int
        The next data sequence number.
    unacked : int
        A-line frames awaiting an ACK.
    """

    state: str
    boot_id: int
    run_id: int
    next_index: int
    n_points: int
    next_seq: int
    unacked: int

    @classmethod
    def parse(cls, text: str) -> DeviceStatus:
        parts = text.split(",")
        if len(parts) != 7:
            raise DriverError(f"malformed SCAN:STAT? reply {text!r}")
        try:
            return cls(parts[0], *(int(p) for p in parts[1:]))
        except ValueError:
            raise DriverError(f"malformed SCAN:STAT? reply {text!r}") from None


@dataclass
class ScanProgress:
    """What a scan's progress callback receives (about every ``progress_interval`` s): a record
    of the run, not a fraction (the fraction-and-stage callback of the reconstructions is
    ``fpscan.service.progress.Progress``; the service turns this record into the job's progress).

    Attributes
    ----------
    points_done : int
        Points complete in the sink (at every wavelength).
    n_points : int
        Points of the plan.
    rate : float
        A-lines/s landed in this call of scan(), over its acquiring time (pauses not counted).
    eta_s : float
        Remaining A-lines / rate, s (inf if unknown, and while paused).
    faults_recovered : int
        Link faults recovered so far (bad frames, NAKs, timeouts, resets).
    state : str
        ``"running"``, ``"paused"``, ``"recovering"``, ``"done"`` or ``"aborted"``.
    elapsed_s : float
        Time since the call started, s.
    alines_done : int
        A-lines complete in the sink (points × wavelengths).
    n_alines : int
        A-lines of the plan.
    """

    points_done: int  #: points complete in the sink (at every wavelength)
    n_points: int
    rate: float  #: A-lines/s landed in this call of scan(), pauses not counted
    eta_s: float  #: remaining A-lines / rate (inf if unknown, and while paused)
    faults_recovered: int  #: link faults recovered so far (bad frames, NAKs, timeouts, resets)
    state: str  #: "running", "paused", "recovering", "done", "aborted"
    elapsed_s: float
    alines_done: int = 0  #: A-lines complete in the sink (points × wavelengths)
    n_alines: int = 0


@dataclass
class ScanResult:
    """Outcome of :meth:`Scanner.scan`.

    Attributes
    ----------
    n_points : int
        Points of the plan.
    points_done : int
        Points complete at every wavelength.
    complete : bool
        Whether every A-line of the plan is in the sink.
    aborted : bool
        Whether the scan was aborted.
    elapsed_s : float
        The whole call, s.
    acquisition_s : float
        From the first SCAN:STAR reply to the last new A-line, less the time paused, s.
    alines_received : int
        New A-line frames received (first copies; points may repeat).
    faults : dict
        Link faults detected and recovered since the port was opened (see below).
    link : dict
        Link statistics that are not faults (see below).
    n_alines : int
        A-lines of the plan: points × wavelengths.
    alines_done : int
        A-lines complete in the sink.
    """

    n_points: int
    points_done: int  #: points complete at every wavelength
    complete: bool
    aborted: bool
    elapsed_s: float  #: whole call
    acquisition_s: float  #: from the first SCAN:STAR reply to the last new A-line
    alines_received: int  #: new A-line frames received (first copies; points may repeat)
    #: link faults detected and recovered since the port was opened: ``bad_frames``
    #: (CRC/COBS/length), ``bad_alines``, ``naks`` (sequence numbers NAKed),
    #: ``command_retries``, ``upload_retries``, ``stall_polls``, ``resets``
    faults: dict = field(default_factory=dict)
    #: link statistics (not faults): ``duplicates`` (frames received twice),
    #: ``duplicate_points`` (points already in the file), ``stale`` (other run or boot),
    #: ``slow_replies`` (commands retransmitted while their reply was on its way)
    link: dict = field(default_factory=dict)
    n_alines: int = 0  #: A-lines of the plan: points × wavelengths
    alines_done: int = 0

    @property
    def faults_recovered(self) -> int:
        return int(sum(self.faults.values()))


class Scanner:
    """The host side of one scanner link.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyACM0``, ``/dev/pts/3``) or pyserial URL.
    window : int, optional
        Credit window in A-line frames, 1 … 65535 (default 256).
    retry : float, optional
        Command retransmission interval, s (default 0.15).
    response_timeout : float, optional
        Longest wait for a command reply or for a stalled device, s (default 10).
    stall_timeout : float, optional
        Silence during a scan after which the host polls the device, s (default 1).
    baudrate : int, optional
        The serial port's baud rate (default 115200).
    reader : str, optional
        How a local tty is drained (:mod:`fpscan.driver.transport`): ``"process"``
        (default: the relay process :mod:`fpscan.driver.relay`, immune to the interpreter lock),
        ``"thread"`` (pyserial's ``ReaderThread``) or ``"direct"`` (read in the calling
        thread). URL transports are always read directly.
    lock_timeout : float, optional
        How long to retry a port locked by another process, s (default 2).
    max_resets : int, optional
        Device resets (or plans lost) one call of :meth:`scan` recovers from, 0 … 1000
        (default :data:`MAX_RESETS`, 8); the next one stops the scan with a
        :class:`DeviceFault` (a rerun starts a new count).

    Attributes
    ----------
    port : str
        As given.
    window, retry, response_timeout, stall_timeout, max_resets
        The settings as given (int, floats, int).
    faults : collections.Counter
        Link faults recovered since the port was opened (``bad_frames``, ``bad_alines``,
        ``naks``, ``command_retries``, ``upload_retries``, ``stall_polls``, ``resets``).
    link_stats : collections.Counter
        Link statistics that are not faults (``slow_replies``).

    Raises
    ------
    DriverError
        The port cannot be opened or is locked by another process (exclusive ``flock``).
    ValueError
        A bad ``reader``, ``window`` or ``max_resets``.
    """

    def __init__(self, port: str, *, window: int = 256, retry: float = 0.15,
                 response_timeout: float = 10.0, stall_timeout: float = 1.0,
                 baudrate: int = 115200, reader: str = "process", lock_timeout: float = 2.0,
                 max_resets: int = MAX_RESETS):
        if reader not in READER_MODES:
            raise ValueError(f"reader must be 'process', 'thread' or 'direct', not {reader!r}")
        if not 1 <= int(window) <= 65535:
            raise ValueError(f"window must be in 1..65535 A-lines, got {window}")
        if not 0 <= int(max_resets) <= 1000:
            raise ValueError(f"max_resets must be in 0..1000, got {max_resets}")
        self.max_resets = int(max_resets)
        self.port = port
        self.window = int(window)
        self.retry = float(retry)
        self.response_timeout = float(response_timeout)
        self.stall_timeout = float(stall_timeout)
        self._ser = _open_port(port, baudrate, lock_timeout)
        self._reader = open_reader(self._ser, reader, port)
        self._deframer = Deframer()
        self._seq = secrets.randbits(30) + 1
        self._pending_seq: int | None = None
        self._reply: Frame | None = None
        self._boot_id: int | None = None
        self._requests: queue.Queue = queue.Queue()
        self._scanning = threading.Event()
        self._io = threading.RLock()
        self._session: ScanSession | None = None
        self._events: collections.deque = collections.deque(maxlen=64)
        self.faults: collections.Counter = collections.Counter()
        #: link statistics that are not faults: ``slow_replies`` (a command retransmitted
        #: while its reply was on its way: the device answered every copy)
        self.link_stats: collections.Counter = collections.Counter()
        #: seq -> retransmissions of a recent command still counted as faults
        self._retransmitted: dict[int, int] = {}
        self._device_busy = False
        #: boot ids of the device's last boots before this one: A-lines of those are stale,
        #: not a reset. One scan sees at most max_resets + 1 boots, and an old boot's A-lines
        #: arrive just after its reset or never, so the last max_resets + 1 are kept
        self._old_boots: collections.deque[int] = collections.deque(maxlen=self.max_resets + 1)
        self._max_chunk = MAX_CHUNK
        self._write(b"\x00")  # terminate any partial frame a previous host left behind

    # ------------------------------------------------------------------ basics
    def close(self) -> None:
        """Leave the device idle (abort a scan this host started) and close the port.

        From another thread while :meth:`scan` runs, call :meth:`abort` first: ``close``
        waits for the scan to return."""
        if self._ser is None:
            return
        if self._device_busy:
            try:
                self.query(cmd.SCAN_ABORT, timeout=2.0)
            except DriverError:
                pass
        self._reader.close()
        self._ser.close()
        self._ser = None

    def __enter__(self) -> Scanner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write(self, data: bytes) -> None:
        import serial

        try:
            self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise DriverError(f"write to {self.port} failed: {exc}") from None

    def _pump(self) -> None:
        """Read what arrived (waiting at most ~20 ms) and dispatch every good frame."""
        try:
            data = self._reader.read()
        except TransportError as exc:
            raise DriverError(str(exc)) from None
        if not data:
            return
        frames = self._deframer.feed(data)
        if self._deframer.errors:
            self.faults["bad_frames"] += self._deframer.errors
            self._deframer.errors = 0
        for fr in frames:
            t = fr.type
            if t == FrameType.ALINE:
                if self._session is not None:
                    self._session.on_aline(fr)
            elif t in (FrameType.RSP, FrameType.ERR):
                if fr.ack == self._pending_seq and self._reply is None:
                    self._reply = fr
                else:
                    self._on_repeated_reply(fr.ack)
            elif t == FrameType.EVENT:
                self._on_event(fr.payload.decode("ascii", "replace"))

    def _on_event(self, text: str) -> None:
        self._events.append(text[:256])  # a note for debugging: the device decides its length
        run = self._session.current if self._session is not None else None
        word, _, arg = text.partition(" ")
        if word == "BOOT" and run is not None:
            try:
                if int(arg) != run.boot_id and int(arg) not in self._old_boots:
                    run.reset_seen = True
            except ValueError:
                pass
        elif word == "INTERLOCK" and arg.strip() == "1" and run is not None:
            run.interlock = True

    def _on_repeated_reply(self, ack: int) -> None:
        """A further reply to a command already answered: the device got one more copy of
        it (it repeats its reply to each retransmission, docs/protocol.md §3.2), so one
        retransmission was not needed (the reply was slow, not lost) and is no link fault."""
        if self._retransmitted.get(ack, 0) > 0:
            self._retransmitted[ack] -= 1
            self.faults["command_retries"] -= 1
            self.link_stats["slow_replies"] += 1

    def _settle_replies(self) -> None:
        """Read the repeated replies still on their way to recently retransmitted commands
        (for up to two retry intervals), so the fault count is final when a scan returns."""
        deadline = time.monotonic() + 2 * self.retry + 0.05
        while any(n > 0 for n in self._retransmitted.values()) and time.monotonic() < deadline:
            self._pump()
        self._retransmitted.clear()  # what is left was lost: faults indeed

    def query(self, command: str | bytes, timeout: float | None = None) -> str:
        """Send one command and return its reply text ('' for set commands).

        Retransmits every ``retry`` s (the device answers a repeated command once);
        raises :class:`DeviceTimeout` after ``timeout`` (default ``response_timeout``) s,
        :class:`DeviceError` (:class:`InterlockOpen` for code 101) if the device rejects it.
        Callable from any thread; it waits while another thread is mid-command, and
        while :meth:`scan` runs (use :meth:`pause`/:meth:`resume`/:meth:`abort` and the
        progress callback then).
        """
        payload = command.encode("ascii") if isinstance(command, str) else bytes(command)
        timeout = self.response_timeout if timeout is None else float(timeout)
        with self._io:
            if self._ser is None:
                raise DriverError("scanner port is closed")
            self._seq = (self._seq + 1) & 0xFFFFFFFF
            seq = self._seq
            wire = encode_frame(FrameType.CMD, payload, seq=seq)
            self._pending_seq, self._reply = seq, None
            t0 = time.monotonic()
            deadline = t0 + timeout
            next_send = t0
            try:
                while self._reply is None:
                    now = time.monotonic()
                    if now >= deadline:
                        shown = payload[:40].decode("ascii", "replace")
                        raise DeviceTimeout(f"no reply to {shown!r} from {self.port} within "
                                            f"{timeout:g} s")
                    if now >= next_send:
                        if next_send > t0:  # until a repeated reply shows it was not lost
                            self.faults["command_retries"] += 1
                            self._retransmitted[seq] = self._retransmitted.get(seq, 0) + 1
                        self._write(wire)
                        next_send = now + self.retry
                    self._pump()
            finally:
                self._pending_seq = None
                for answered in [k for k, n in self._retransmitted.items() if n <= 0]:
                    del self._retransmitted[answered]
                while len(self._retransmitted) > 16:  # repeated replies come soon after or never
                    del self._retransmitted[next(iter(self._retransmitted))]
            reply = self._reply
        text = reply.payload.decode("ascii", "replace")
        if reply.type == FrameType.ERR:
            code_s, _, msg = text.partition(",")
            try:
                code = int(code_s)
            except ValueError:
                code = -100
            shown = payload[:40].decode("ascii", "replace")
            cls = InterlockOpen if code == 101 else DeviceError
            raise cls(code, msg.strip('"'), shown)
        return text

    # ------------------------------------------------------------------ device queries
    def identify(self) -> dict:
        """``*IDN?`` and protocol checks. Returns the instrument dict for the scan file.

        Raises :class:`DriverError` if the device speaks another protocol version,
        :class:`DeviceFault` if its ``SYST:LIM?`` reply is not four non-negative integers or
        its ``max_chunk`` is below :data:`fpscan.driver.commands.MIN_CHUNK` (64 bytes: the
        protocol's minimum; plan chunks are never smaller than that).
        """
        idn = self.query(cmd.IDN)
        version = self.query(cmd.SYST_PROTOCOL)
        if version.strip() != str(PROTOCOL_VERSION):
            raise DriverError(f"device speaks protocol {version!r}, host {PROTOCOL_VERSION}")
        parts = [p.strip() for p in idn.split(",")] + [""] * 4
        reply = self.query(cmd.SYST_LIMITS)
        try:
            limits = [int(x) for x in reply.split(",")]
        except ValueError:
            limits = []
        if len(limits) != 4 or min(limits) < 0:
            raise DeviceFault(f"malformed SYST:LIM? reply {reply[:80]!r}: four non-negative integers "
                              "(max_points, max_samples, max_window, max_chunk) expected")
        if limits[3] < MIN_CHUNK:
            raise DeviceFault(f"the scanner's max_chunk is {limits[3]} bytes, below the protocol's "
                              f"minimum of {MIN_CHUNK} (docs/protocol.md §3.3): no plan can be uploaded "
                              "in chunks it takes")
        status = self.status()
        self._boot_id = status.boot_id
        self._max_chunk = min(MAX_CHUNK, limits[3])
        return {"idn": idn, "manufacturer": parts[0], "model": parts[1], "serial": parts[2],
                "firmware": parts[3], "protocol": PROTOCOL_VERSION, "port": self.port,
                "boot_id": status.boot_id,
                "limits": dict(zip(["max_points", "max_samples", "max_window", "max_chunk"],
                                   limits))}

    def status(self, timeout: float | None = None) -> DeviceStatus:
        """``SCAN:STAT?`` parsed."""
        return DeviceStatus.parse(self.query(cmd.SCAN_STATUS, timeout=timeout))

    def errors(self) -> list[tuple[int, str]]:
        """Drain the device's error queue (``SYST:ERR?`` until ``0``)."""
        out = []
        for _ in range(64):
            code_s, _, msg = self.query(cmd.SYST_ERROR).partition(",")
            try:
                code = int(code_s)
            except ValueError:
                raise DriverError(f"malformed SYST:ERR? reply {code_s!r}") from None
            if code == 0:
                break
            out.append((code, msg.strip('"')))
        return out

    def upload_plan(self, plan: dict | str | os.PathLike, *, on_reset: Callable[[], None] | None = None) -> str:
        """Upload a plan (dict or path) in chunks; verify its SHA-256 and ``PLAN:ID?``.

        Aborts a run the device still has (and clears a FAULT whose interlock closed)
        first. A device that resets during the upload (a new boot id after a refused or
        unanswered step: docs/protocol.md §10) gets the whole upload again, up to
        ``max_resets`` times in one call (``on_reset``, given, counts them instead: a scan's
        resets). Returns the plan id. Raises ``ValueError``
        for a bad plan, :class:`DeviceError` if the device refuses it (over its limits,
        hash mismatch), :class:`DriverError` if the plan id read back differs, or
        :class:`DeviceFault` past the resets it recovers from.
        """
        plan = load_plan(plan)
        image = plan_image(plan)
        resets = 0
        while True:
            st = self.status()
            self._boot_id = st.boot_id
            try:
                return self._upload(plan, image, st)
            except DriverError:
                if not self._reset_since(st.boot_id):
                    raise
            if st.boot_id not in self._old_boots:  # its A-lines, if any come, are stale (§10)
                self._old_boots.append(st.boot_id)
            self.faults["upload_resets"] += 1
            if on_reset is not None:
                on_reset()
                continue
            resets += 1
            if resets > self.max_resets:
                raise DeviceFault(f"the scanner reset {resets} times during the plan upload; the host recovers "
                                  f"from {self.max_resets}")

    def _reset_since(self, boot_id: int) -> bool:
        """Whether the device now reports another boot id than ``boot_id`` (it reset)."""
        try:
            return self.status().boot_id != boot_id
        except DriverError:
            return False

    def _upload(self, plan: dict, image: bytes, st: DeviceStatus) -> str:
        """:meth:`upload_plan`'s steps once, from the device's status ``st``."""
        if st.state in ("RUNNING", "PAUSED", "FAULT"):
            # ends a run a previous host left, and clears a fault whose cause is gone (a
            # closed interlock); an open interlock stays FAULT and SCAN:STAR will say so
            self.query(cmd.SCAN_ABORT)
        self.query(cmd.plan_begin(len(image)))
        self._send_image(image)
        self.query(cmd.plan_end(hashlib.sha256(image).hexdigest()))
        got = self.query(cmd.PLAN_ID).strip()
        if got != plan["id"]:
            raise DriverError(f"device holds plan {got}, uploaded {plan['id']}")
        return got

    def _send_image(self, image: bytes) -> None:
        """``PLAN:DATA`` chunks of up to max_chunk bytes. On a noisy link a long command
        rarely arrives intact, so a chunk that gets no reply is retried 8 times smaller
        (>= :data:`~fpscan.driver.commands.MIN_CHUNK` B, which :meth:`identify` made sure the
        device takes), and the size doubles again after 4 chunks in a row got through."""
        chunk = self._max_chunk
        off = streak = 0
        last = time.monotonic()
        per_try = min(self.response_timeout, max(0.3, 2 * self.retry))
        while off < len(image):
            piece = image[off:off + chunk]
            try:
                self.query(cmd.plan_data(off, piece), timeout=per_try)
            except DeviceTimeout:
                if time.monotonic() - last > self.response_timeout:
                    raise
                chunk, streak = max(MIN_CHUNK, chunk // 8), 0
                self.faults["upload_retries"] += 1
                continue
            off += len(piece)
            last = time.monotonic()
            streak += 1
            if streak >= 4 and chunk < self._max_chunk:
                chunk, streak = min(self._max_chunk, 2 * chunk), 0

    # ------------------------------------------------------------------ thread controls
    def pause(self) -> None:
        """Pause the scan (the device stops after the A-lines in flight)."""
        self._control("pause")

    def resume(self) -> None:
        """Resume a paused scan."""
        self._control("resume")

    def abort(self) -> None:
        """Abort the scan; :meth:`scan` returns with ``aborted=True`` and the device idle."""
        self._control("abort")

    def _control(self, what: str) -> None:
        if self._scanning.is_set():
            self._requests.put(what)
        else:
            self.query(_CONTROL_COMMANDS[what])

    # ------------------------------------------------------------------ scanning
    def scan(self, plan: dict | str | os.PathLike, sink: Any, *, progress: Callable[[ScanProgress], None] | None = None,
             progress_interval: float = 0.25, upload: bool = True) -> ScanResult:
        """Acquire every A-line (point × wavelength) of ``plan`` not yet complete in ``sink``.

        ``plan``: plan dict or path (docs/architecture.md). ``sink``: object with
        ``completed_by_wavelength() -> bool (n_wavelengths, n_points)`` (or, for a
        one-wavelength plan, ``completed() -> bool (n_points,)``) and ``append(k, samples
        int16 (n_t,), meta) -> bool`` (the scan file API; ``meta["wavelength_index"]`` says
        which wavelength), written before the A-line is acknowledged, so the sink's record
        is the truth a later call resumes from. ``progress``: called with
        :class:`ScanProgress` from this thread. Returns a :class:`ScanResult`.

        Raises ``ValueError`` (plan and sink disagree), :class:`InterlockOpen`,
        :class:`DeviceTimeout` (device silent for ``response_timeout``),
        :class:`DeviceFault` (the device sent a number no plan allows),
        :class:`DeviceError`. On any exit the device is left idle (best effort).
        The work is done by a :class:`ScanSession`.
        """
        session = ScanSession(self, load_plan(plan), sink, progress=progress,
                              progress_interval=progress_interval)
        return session.run(upload=upload)

    def faults_recovered(self) -> int:
        f = self.faults
        return (f["bad_frames"] + f["bad_alines"] + f["naks"] + f["command_retries"]
                + f["stall_polls"] + f["resets"] + f["upload_retries"])

    def _recover_reset(self, plan: dict, on_reset: Callable[[], None] | None = None) -> None:
        """The device rebooted: wait for it, re-identify and re-upload the plan (``on_reset``: a
        reset during that upload, :meth:`upload_plan`)."""
        if self._boot_id is not None and self._boot_id not in self._old_boots:
            self._old_boots.append(self._boot_id)
        deadline = time.monotonic() + self.response_timeout
        while True:
            try:
                self.identify()
                break
            except DeviceTimeout:
                if time.monotonic() > deadline:
                    raise
        self.upload_plan(plan, on_reset=on_reset)

    def _leave_idle(self) -> None:
        """Best effort after a failure: abort the run this host started."""
        if self._device_busy and self._ser is not None:
            try:
                self.query(cmd.SCAN_ABORT, timeout=2.0)
                self._device_busy = False
            except DriverError:
                pass


_CONTROL_COMMANDS = {"pause": cmd.SCAN_PAUSE, "resume": cmd.SCAN_RESUME,
                     "abort": cmd.SCAN_ABORT}


def _open_port(port: str, baudrate: int, lock_timeout: float) -> serial.SerialBase:
    """``serial.serial_for_url`` with an exclusive lock, retrying a held lock (a host that
    just died may hold it for a moment through its reader process)."""
    import serial

    deadline = time.monotonic() + lock_timeout
    while True:
        try:
            return serial.serial_for_url(port, baudrate=baudrate, timeout=0.02,
                                         write_timeout=5.0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            if "lock" in str(exc).lower() and time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            raise DriverError(f"cannot open scanner port {port}: {exc}") from None


class ScanSession:
    """One call of :meth:`Scanner.scan`: the host's receive side of a plan's acquisition.

    It owns the record of what is complete per (wavelength, point) (read from the sink at
    the start, updated as A-lines land), starts runs at the first missing A-line in
    acquisition order (``fpscan.driver.plan.aline_order``), accepts A-line frames from the
    scanner's dispatch (:meth:`on_aline`: sequence bookkeeping, duplicates, stale runs),
    acknowledges and NAKs them under the credit window, polls a silent device, recovers
    from resets, and reports progress. The :class:`Scanner` it runs on provides the link
    (commands, frame dispatch); the transport reader below that moves the bytes.

    Parameters
    ----------
    scanner : Scanner
        The open link the session runs on.
    plan : dict
        The checked plan (:func:`fpscan.driver.plan.load_plan`).
    sink : object
        The scan file API: ``completed_by_wavelength()`` (bool ``(n_wavelengths, n_points)``)
        or ``completed()`` (bool ``(n_points,)``, one wavelength), ``append(k, samples, meta)``
        and optionally ``plan_id`` (:meth:`Scanner.scan`).
    progress : callable, optional
        Called with a :class:`ScanProgress` about every ``progress_interval`` s.
    progress_interval : float, optional
        Seconds between progress reports (default 0.25).

    Raises
    ------
    ValueError
        The sink's record does not match the plan's shape, or the sink is for another plan.
    """

    def __init__(self, scanner: Scanner, plan: dict, sink: Any, *,
                 progress: Callable[[ScanProgress], None] | None = None,
                 progress_interval: float = 0.25) -> None:
        self.sc = scanner
        self.plan = plan
        self.sink = sink
        acq = plan["acquisition"]
        self.n = len(plan["points"]["indices"])
        self.n_t = int(acq["n_t"])
        self.n_w = len(acq["wavelengths"])
        self.order = wavelength_order(acq)
        if hasattr(sink, "completed_by_wavelength"):
            record = np.array(sink.completed_by_wavelength(), dtype=bool)
        else:
            record = np.array(sink.completed(), dtype=bool)[None]
        if record.shape != (self.n_w, self.n):
            raise ValueError(f"sink records {record.shape} (wavelengths, points), plan "
                             f"{(self.n_w, self.n)}")
        self.record = record  # (n_wavelengths, n_points)
        k_of, w_of = aline_order(self.n, self.n_w, self.order)
        self.done_s = record[w_of, k_of]  # the record in acquisition order
        if getattr(sink, "plan_id", plan["id"]) != plan["id"]:
            raise ValueError(f"sink is for plan {sink.plan_id}, not {plan['id']}")
        self.progress = progress
        self.progress_interval = progress_interval
        self.current: _Run | None = None
        self.counters: collections.Counter = collections.Counter()
        self.early: list = []  # A-lines that overtook the SCAN:STAR reply
        self.aline_bytes = ALINE_HEADER.size + 2 * self.n_t  # an A-line frame's payload
        self.t_start = time.monotonic()
        self.done0 = self.done = int(self.done_s.sum())
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.paused_s = 0.0  #: time paused so far (ended pauses), s: not acquiring time
        self.paused_since: float | None = None  #: when the pause now on began
        self.last_prog = 0.0
        self.aborted = False
        self.resets = 0  #: device resets (or plans lost) recovered in this call
        self.idle_runs = 0  #: runs in a row that ended with A-lines missing and none new (MAX_IDLE_RUNS)
        # silence that means a stall: at least stall_timeout, and 3 point periods at the
        # plan's PRF (a slow laser or many averages is not a stall)
        prf = float(acq.get("prf") or 0.0)
        self.silence = scanner.stall_timeout
        if prf > 0:
            self.silence = max(self.silence, 3.0 * int(acq.get("averages", 1)) / prf)
        #: the longest a running (not paused) device may go without a new A-line, silent or
        #: repeating old ones, before the scan ends with DeviceTimeout, s
        self.no_progress = max(3 * scanner.response_timeout, 10 * self.silence)

    # ------------------------------------------------------------------ the call
    def run(self, upload: bool = True) -> ScanResult:
        """Acquire what is missing; returns the :class:`ScanResult` (see Scanner.scan)."""
        sc = self.sc
        sc._scanning.set()
        sc._session = self
        try:
            with sc._io:
                self._prepare_device(upload)
                sc._device_busy = True
                self.report("running", force=True)
                self._acquire()
                # the host's record is complete (or aborted): leave the device idle
                if sc.status().state in ("RUNNING", "PAUSED"):
                    sc.query(cmd.SCAN_ABORT)
                sc._device_busy = False
                sc._settle_replies()
        except BaseException:
            self.current = None
            sc._leave_idle()
            raise
        finally:
            sc._scanning.clear()
            sc._session = None
            while not sc._requests.empty():
                sc._requests.get_nowait()
            if hasattr(self.sink, "flush"):
                self.sink.flush()
        self.report("aborted" if self.aborted else "done", force=True)
        return self.result()

    def _prepare_device(self, upload: bool) -> None:
        sc, plan = self.sc, self.plan
        if upload:
            sc.identify()
            sc.upload_plan(plan, on_reset=self._count_reset)
            return
        # the caller uploaded it: check that the device holds this plan
        sc._boot_id = sc.status().boot_id
        held = sc.query(cmd.PLAN_ID).strip()
        if held == "NONE":  # no plan: the device reset since that upload (docs/protocol.md §10)
            self._count_reset()
            sc._recover_reset(plan, self._count_reset)
        elif held != plan["id"]:
            raise DriverError(f"device holds plan {held}, not {plan['id']}: another host uploaded a plan "
                              "since (Scanner.scan(..., upload=True) uploads this one again)")

    def _acquire(self) -> None:
        """Runs from the first missing A-line until the record is complete or aborted."""
        sc = self.sc
        while not self.done_s.all():
            start = int(np.argmin(self.done_s))
            try:
                reply = sc.query(cmd.scan_start(start))
            except DeviceError as exc:
                if exc.code != 103:
                    raise
                self._count_reset()  # "no plan": the device reset since the upload
                sc._recover_reset(self.plan, self._count_reset)
                continue
            try:
                run_id, first_seq = (int(x) for x in reply.split(","))
            except ValueError:
                raise DeviceFault(f"malformed SCAN:STAR reply {reply[:80]!r}") from None
            if not (0 <= run_id <= _SEQ_MASK and 0 <= first_seq <= _SEQ_MASK):
                raise DeviceFault(f"SCAN:STAR reply {reply[:80]!r}: the run id and the first "
                                  "sequence number are u32")
            if self.t_first is None:
                self.t_first = time.monotonic()
            # the run's A-lines: from `start` through the plan's last (docs/protocol.md §3.3)
            self.current = _Run(run_id, sc._boot_id, first_seq, self.done_s.size - start)
            early, self.early = self.early, []
            for fr in early:
                self.on_aline(fr)
            before = int(self.done_s.sum())
            self.send_ack()
            outcome = self._stream()
            self.current = None
            self.early.clear()
            if outcome == "abort":
                self.aborted = True
                return
            if outcome == "reset":
                self._count_reset()
                self.report("recovering", force=True)
                sc._recover_reset(self.plan, self._count_reset)
            elif int(self.done_s.sum()) > before:
                self.idle_runs = 0
            elif not self.done_s.all():
                self._count_idle_run()

    def _count_idle_run(self) -> None:
        """Count one run that ended (the device IDLE) with A-lines missing and none new on disk; the
        one past `MAX_IDLE_RUNS` in a row raises :class:`DeviceFault` instead of a new ``SCAN:STAR``."""
        self.idle_runs += 1
        if self.idle_runs > MAX_IDLE_RUNS:
            self._raise_fault(f"the scanner ended {self.idle_runs} runs in a row without a new A-line "
                              f"(it reports IDLE with A-lines missing); the host restarts {MAX_IDLE_RUNS}")

    def _count_reset(self) -> None:
        """Count one device reset of this scan (a new boot id, or a plan lost: the device reset
        unseen); the one past ``max_resets`` raises :class:`DeviceFault` instead of being
        recovered."""
        sc = self.sc
        self.resets += 1
        if self.resets > sc.max_resets:
            self._raise_fault(f"the scanner reset {self.resets} times during this scan; the host "
                              f"recovers from {sc.max_resets}")
        sc.faults["resets"] += 1

    def result(self) -> ScanResult:
        t_end = time.monotonic()
        faults = {k: v for k, v in self.sc.faults.items() if v}
        link = {k: v for k, v in self.counters.items() if k != "alines"}
        link.update((k, v) for k, v in self.sc.link_stats.items() if v)
        acq = ((self.t_last or t_end) - self.t_first - self.paused_s) if self.t_first else 0.0  # pauses not counted
        return ScanResult(self.n, int(self.record.all(axis=0).sum()), bool(self.done_s.all()),
                          self.aborted, t_end - self.t_start, acq, self.counters["alines"],
                          faults, link, self.done_s.size, int(self.done_s.sum()))

    def report(self, label: str, force: bool = False) -> None:
        """Call the progress callback (at most every ``progress_interval`` s unless forced)."""
        now = time.monotonic()
        if self.progress is None or (not force and now - self.last_prog < self.progress_interval):
            return
        self.last_prog = now
        t_first = self.t_first or now
        paused = self.paused_s + (now - self.paused_since if self.paused_since is not None else 0.0)
        rate = (self.done - self.done0) / max(now - t_first - paused, 1e-9)  # over the time spent acquiring
        eta = (self.done_s.size - self.done) / rate if rate > 0 and self.paused_since is None else float("inf")
        points = int(self.record.all(axis=0).sum()) if self.n_w > 1 else self.done
        self.progress(ScanProgress(points, self.n, rate, eta, self.sc.faults_recovered(), label,
                               now - self.t_start, self.done, self.done_s.size))

    # ------------------------------------------------------------------ receiving
    def on_aline(self, fr: Frame) -> None:
        """One ALINE frame from the dispatch: checks, sequence bookkeeping, then the sink.

        What the frame claims is checked against the plan before anything is kept: a
        sequence number outside the run, a point, wavelength or sample count the plan does
        not have, a field out of its documented range (``fpscan.driver.aline.check_aline``:
        a ``dc_level`` ≤ 0, a NaN ``scale``, …) or a payload that does not parse is a device fault (:class:`DeviceFault`,
        raised by the receive loop; no A-line after it is taken), never bookkeeping of the
        size the device claims."""
        run = self.current
        if run is None:  # overtook the SCAN:STAR reply: keep a few for the run
            if len(self.early) < _EARLY_MAX and len(fr.payload) == self.aline_bytes:
                self.early.append(fr)
            return
        if run.fault is not None:  # the run ends at its first fault: nothing after it is taken
            return
        try:
            a = unpack_aline(fr.payload)
        except ValueError as exc:
            self._device_fault(run, f"malformed A-line frame (seq {fr.seq}): {exc}")
            return
        if a.run_id != run.run_id or a.boot_id != run.boot_id:
            self.counters["stale"] += 1
            if a.boot_id != run.boot_id and a.boot_id not in self.sc._old_boots:
                run.reset_seen = True
            return
        off = run.offset(fr.seq)
        if off is None:
            self._device_fault(run, f"A-line sequence number {fr.seq} is outside run {run.run_id}, whose "
                                    f"{run.n_alines} A-lines are numbered {run.first_seq} to "
                                    f"{run.seq(run.n_alines - 1)}")
            return
        k, w = a.point_index, a.wavelength_index
        if not (0 <= k < self.n and 0 <= w < self.n_w) or a.samples.size != self.n_t:
            self._device_fault(run, f"A-line (seq {fr.seq}) of point {k}, wavelength {w} with "
                                    f"{a.samples.size} samples; the plan has {self.n} points, {self.n_w} "
                                    f"wavelengths, {self.n_t} samples")
            return
        try:
            check_aline(a)  # every field in its documented range (docs/protocol.md §5)
        except ValueError as exc:
            self._device_fault(run, f"A-line (seq {fr.seq}) of point {k}, wavelength {w}: {exc}")
            return
        if not run.accept(off):
            self.counters["duplicates"] += 1
            return
        self.counters["alines"] += 1
        self._store(a, run.last_rx)

    def _device_fault(self, run: _Run, reason: str) -> None:
        """Note a device fault of ``run`` (the first reason is kept; the receive loop raises it)."""
        self.sc.faults["bad_alines"] += 1
        if run.fault is None:
            run.fault = reason

    def _store(self, a: ALine, t_rx: float) -> None:
        k, w = a.point_index, a.wavelength_index
        s = aline_index(k, w, self.n, self.n_w, self.order)
        if self.done_s[s]:
            self.counters["duplicate_points"] += 1
            return
        self.sink.append(k, a.samples, a.meta())
        self.done_s[s] = self.record[w, k] = True
        self.done += 1
        self.t_last = t_rx

    def _run(self) -> _Run:
        """The run being received (the receive methods are only called during one)."""
        if self.current is None:
            raise DriverError("no scan run in progress")
        return self.current

    def send_ack(self, nak: list[int] | None = None) -> None:
        """ACK (or NAK the seqs in ``nak``) with the current run's next expected seq."""
        run, sc = self._run(), self.sc
        if nak:
            payload = np.asarray(nak, dtype="<u4").tobytes()
            sc._write(encode_frame(FrameType.NAK, payload, ack=run.expected,
                                   window=sc.window))
        else:
            sc._write(encode_frame(FrameType.ACK, ack=run.expected, window=sc.window))
        run.since_ack = 0
        run.need_ack = False
        run.last_ack = time.monotonic()

    def _stream(self) -> str:
        """Receive one run until the record is complete; returns 'done', 'reset', 'abort'
        or 'restart' (the device ended the run with A-lines missing)."""
        run, sc = self._run(), self.sc
        paused = False
        while True:
            paused, outcome = self._handle_requests(paused)
            if outcome:
                return outcome
            sc._pump()
            if run.fault is not None:
                self._raise_fault(run.fault)
            if run.reset_seen:
                return "reset"
            if run.interlock:  # an event is a hint (docs/protocol.md §9.3): the device's state decides
                run.interlock = False
                if sc.status().state == "FAULT":
                    self._raise_interlock()
            self._acknowledge()
            if self.done_s.all():
                self.send_ack()
                return "done"
            self.report("paused" if paused else "running")
            now = time.monotonic()
            # a silent device, or one whose frames all repeat what is already here (a device that
            # ignores ACKs resends its oldest A-line for ever): poll it
            if now - run.last_rx > (2 * self.silence if paused else self.silence) or \
                    not paused and now - run.last_new > self.no_progress:
                outcome = self._on_silence(paused)
                if outcome:
                    return outcome

    def _handle_requests(self, paused: bool) -> tuple[bool, str | None]:
        """Carry out pause/resume/abort requests from other threads."""
        sc = self.sc
        while not sc._requests.empty():
            what = sc._requests.get_nowait()
            if what == "abort":
                sc.query(cmd.SCAN_ABORT)
                sc._device_busy = False
                return paused, "abort"
            if what == "pause" and not paused:
                sc.query(cmd.SCAN_PAUSE)
                paused = True
                self.paused_since = time.monotonic()
            elif what == "resume" and paused:
                sc.query(cmd.SCAN_RESUME)
                paused = False
                run = self._run()
                run.last_rx = run.last_new = time.monotonic()
                if self.paused_since is not None:
                    self.paused_s += run.last_rx - self.paused_since
                    self.paused_since = None
        return paused, None

    def _acknowledge(self) -> None:
        """ACK every window/2 new A-lines or after 20 ms; NAK gaps (each seq ≤ every 0.1 s,
        the first 256 missing, :meth:`_Run.missing`)."""
        run, sc = self._run(), self.sc
        now = time.monotonic()
        if run.since_ack >= max(1, sc.window // 2) or (run.since_ack or run.need_ack) and \
                now - run.last_ack > 0.02:
            self.send_ack()
        if not run.ooo:
            return
        missing = run.missing(now)
        if len(run.nak_time) > 4096:  # keep what still holds a NAK back
            run.nak_time = {o: t for o, t in run.nak_time.items()
                            if o >= run.next and now - t <= _NAK_EVERY}
        if missing:
            for o in missing:
                run.nak_time[o] = now
            sc.faults["naks"] += len(missing)
            self.send_ack([run.seq(o) for o in missing])

    def _on_silence(self, paused: bool) -> str | None:
        """Poll a silent device (this waits out a stall up to response_timeout)."""
        run, sc = self._run(), self.sc
        if not paused:
            sc.faults["stall_polls"] += 1
        st = sc.status()
        run.last_rx = time.monotonic()
        if st.boot_id != run.boot_id:
            return "reset"
        if st.state == "FAULT":
            self._raise_interlock()
        if st.state == "IDLE" and not self.done_s.all():
            return "restart"  # the run ended with A-lines missing: start again
        if not paused and time.monotonic() - run.last_new > self.no_progress:
            raise DeviceTimeout(f"{sc.port} reports {st.state} but delivered no new "
                                f"A-line for {time.monotonic() - run.last_new:.0f} s")
        self.send_ack([run.seq(o) for o in run.missing()] or None)
        return None

    def _raise_interlock(self) -> None:
        raise InterlockOpen(101, f"Laser interlock open; {int(self.done_s.sum())} of "
                                 f"{self.done_s.size} A-lines are on disk, re-run to resume")

    def _raise_fault(self, reason: str) -> None:
        raise DeviceFault(reason, f"{int(self.done_s.sum())} of {self.done_s.size} A-lines are on "
                                  "disk, re-run to resume")


class _Run:
    """Receive state of one run (SCAN:STAR … completion).

    The run's ``n_alines`` A-lines carry the data sequence numbers ``first_seq`` …
    ``first_seq + n_alines − 1`` (mod 2³²; docs/protocol.md §5): its bookkeeping is in
    offsets from ``first_seq``, so it holds at most ``n_alines`` of them (the plan's A-lines,
    never a number the device claims); a sequence number outside the run has no offset
    (:meth:`offset` is None), a device fault.
    """

    def __init__(self, run_id: int, boot_id: int | None, first_seq: int, n_alines: int):
        self.run_id = run_id
        self.boot_id = boot_id
        self.first_seq = first_seq
        self.n_alines = n_alines
        self.next = 0  #: offset of the next A-line expected: every one below it was received
        self.max_seen = 0  #: the highest offset received out of order
        self.ooo: set[int] = set()  #: offsets received above ``next``
        self.nak_time: dict[int, float] = {}  #: offset -> when it was last NAKed
        self.since_ack = 0
        self.need_ack = False
        self.last_ack = 0.0
        self.last_rx = self.last_new = time.monotonic()
        self.reset_seen = False
        self.interlock = False
        self.fault: str | None = None  #: the first device fault seen in this run

    @property
    def expected(self) -> int:
        """The next data sequence number expected (an ACK's ``ack``)."""
        return self.seq(self.next)

    def seq(self, off: int) -> int:
        """The data sequence number of offset ``off``."""
        return (self.first_seq + off) & _SEQ_MASK

    def offset(self, seq: int) -> int | None:
        """The offset of data sequence number ``seq`` in this run; None outside it."""
        off = (seq - self.first_seq) & _SEQ_MASK
        return off if off < self.n_alines else None

    def accept(self, off: int) -> bool:
        """Book offset ``off`` as received; False for a duplicate (which asks for an ACK)."""
        self.last_rx = time.monotonic()
        if off < self.next or off in self.ooo:
            self.need_ack = True
            return False
        if off == self.next:
            self.next += 1
            while self.next in self.ooo:
                self.ooo.discard(self.next)
                self.next += 1
        else:
            self.ooo.add(off)
            self.max_seen = max(self.max_seen, off)
        self.since_ack += 1
        self.last_new = self.last_rx  # the device makes progress
        return True

    def missing(self, now: float | None = None) -> list[int]:
        """Offsets not received between ``next`` and the highest received, in order: of the
        first 256 such gaps (within :data:`_NAK_LOOK` offsets of ``next``), those not
        NAKed in the last 0.1 s before ``now`` (all of them when ``now`` is None)."""
        out: list[int] = []
        off, end, gaps = self.next, min(self.max_seen, self.next + _NAK_LOOK), 0
        while off < end and gaps < _NAK_MAX:
            if off not in self.ooo:
                gaps += 1
                if now is None or now - self.nak_time.get(off, -math.inf) > _NAK_EVERY:
                    out.append(off)
            off += 1
        return out
