"""Host driver of the FP scanner link (docs/protocol.md): identify, upload a plan, scan.

:class:`Scanner` opens a serial port by device path or pyserial URL
(``serial.serial_for_url``) with an exclusive lock, and implements the host side of the
protocol: commands with retransmission and a reply timeout, chunked plan upload with hash
verification, and :meth:`Scanner.scan`, which streams A-lines into a sink (a
:class:`driver.scanfile.ScanFile`, or anything with its ``completed()`` / ``append()``)
under a credit window, NAKs gaps, and recovers from CRC errors, lost bytes, stalls and
device resets, resuming from the sink's record of completed points, which is the truth.

Threading: one thread runs :meth:`Scanner.scan`; :meth:`pause`, :meth:`resume` and
:meth:`abort` may be called from any other thread (they queue a request the scan loop
carries out within ~20 ms). Every wait has a timeout; failures raise :class:`DriverError`
subclasses with the reason.
"""
from __future__ import annotations

import collections
import hashlib
import os
import queue
import secrets
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from driver.aline import unpack_aline
from driver.commands import MAX_CHUNK, block
from driver.framing import PROTOCOL_VERSION, Deframer, FrameType, encode_frame
from driver.plan import load_plan, plan_image


class DriverError(RuntimeError):
    """The scanner link failed (base class of the driver's errors)."""


class DeviceTimeout(DriverError):
    """The device did not answer within the timeout (after retransmissions)."""


class DeviceError(DriverError):
    """The device rejected a command: ``code`` and ``message`` from its ERR reply."""

    def __init__(self, code: int, message: str, command: str = ""):
        super().__init__(f"device error {code} ({message})" + (f" on {command!r}" if command
                                                               else ""))
        self.code = code
        self.message = message


class InterlockOpen(DeviceError):
    """The laser interlock is open: the device cannot fire (no automatic recovery)."""


@dataclass
class DeviceStatus:
    """Parsed ``SCAN:STAT?`` reply."""

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
class Progress:
    """What a progress callback receives (about every ``progress_interval`` s)."""

    points_done: int  #: points complete in the sink
    n_points: int
    rate: float  #: points/s landed in this call of scan()
    eta_s: float  #: remaining points / rate (inf if unknown)
    faults_recovered: int  #: link faults recovered so far (bad frames, NAKs, timeouts, resets)
    state: str  #: "running", "paused", "recovering", "done", "aborted"
    elapsed_s: float


@dataclass
class ScanResult:
    """Outcome of :meth:`Scanner.scan`."""

    n_points: int
    points_done: int
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
    #: ``duplicate_points`` (points already in the file), ``stale`` (other run or boot)
    link: dict = field(default_factory=dict)

    @property
    def faults_recovered(self) -> int:
        return int(sum(self.faults.values()))


class Scanner:
    """The host side of one scanner link.

    ``port``: device path (``/dev/ttyACM0``, ``/dev/pts/3``) or pyserial URL.
    ``window``: credit window in A-line frames. ``retry``: command retransmission interval,
    s. ``response_timeout``: longest wait for a command reply or for a stalled device, s.
    ``stall_timeout``: silence during a scan after which the host polls the device, s.
    ``reader``: how a local tty is drained: ``"process"`` (default: the relay process
    :mod:`driver.relay`, immune to the interpreter lock), ``"thread"`` or ``"direct"``
    (read in the calling thread). URL transports are always read directly.
    ``lock_timeout``: how long to retry a port locked by another process, s.

    Raises :class:`DriverError` if the port cannot be opened or is locked by another
    process (exclusive ``flock``).
    """

    def __init__(self, port: str, *, window: int = 256, retry: float = 0.15,
                 response_timeout: float = 10.0, stall_timeout: float = 1.0,
                 baudrate: int = 115200, reader: str = "process", lock_timeout: float = 2.0):
        import serial

        if reader not in ("process", "thread", "direct"):
            raise ValueError(f"reader must be 'process', 'thread' or 'direct', not {reader!r}")
        if not 1 <= int(window) <= 65535:
            raise ValueError(f"window must be in 1..65535 A-lines, got {window}")
        self.port = port
        self.window = int(window)
        self.retry = float(retry)
        self.response_timeout = float(response_timeout)
        self.stall_timeout = float(stall_timeout)
        deadline = time.monotonic() + lock_timeout
        while True:
            try:
                self._ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0.02,
                                                  write_timeout=5.0, exclusive=True)
                break
            except (serial.SerialException, OSError, ValueError) as exc:
                # a host that just died may hold the lock for a moment (its reader process)
                if "lock" in str(exc).lower() and time.monotonic() < deadline:
                    time.sleep(0.05)
                    continue
                raise DriverError(f"cannot open scanner port {port}: {exc}") from None
        # pyserial's POSIX ports expose their descriptor; URL transports (socket://, loop://)
        # do not and are read through pyserial
        fd = getattr(self._ser, "fd", None)
        self._rx: queue.SimpleQueue | None = None
        self._rx_stop = threading.Event()
        self._rx_thread = None
        self._relay = None
        self._relay_fd: int | None = None
        if isinstance(fd, int) and reader == "process":
            self._start_relay(fd)
        elif isinstance(fd, int) and reader == "thread":
            self._rx = queue.SimpleQueue()
            self._rx_thread = threading.Thread(target=self._reader, args=(fd,),
                                               name=f"fpscan-rx {port}", daemon=True)
            self._rx_thread.start()
        self._deframer = Deframer()
        self._seq = secrets.randbits(30) + 1
        self._pending_seq: int | None = None
        self._reply = None
        self._boot_id: int | None = None
        self._requests: queue.Queue = queue.Queue()
        self._scanning = threading.Event()
        self._io = threading.RLock()
        self._run = None
        self._events: collections.deque = collections.deque(maxlen=64)
        self.faults = collections.Counter()
        self._device_busy = False
        self._old_boots: set[int] = set()
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
                self.query("SCAN:ABOR", timeout=2.0)
            except DriverError:
                pass
        self._rx_stop.set()
        if self._rx_thread is not None:
            self._rx_thread.join(timeout=2)
        if self._relay is not None:
            self._relay.kill()
            self._relay.wait(timeout=5)
            self._relay.stdout.close()
            self._relay = None
        self._ser.close()
        self._ser = None

    def __enter__(self) -> Scanner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _write(self, data: bytes) -> None:
        import serial

        try:
            self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise DriverError(f"write to {self.port} failed: {exc}") from None

    def _read_some(self) -> bytes:
        """Bytes received since the last call, waiting at most ~20 ms for the first."""
        import serial

        if self._relay_fd is not None:  # a local tty drained by the relay process
            try:
                if not select.select([self._relay_fd], [], [], 0.02)[0]:
                    return b""
                data = os.read(self._relay_fd, 1 << 20)
            except OSError as exc:
                raise DriverError(f"read from {self.port} failed: {exc}") from None
            if not data:  # the relay ended (killed?): read the tty here from now on
                self._relay.wait(timeout=5)
                self._relay.stdout.close()
                self._relay = self._relay_fd = None
            return data
        if self._rx is not None:  # a local tty drained by the reader thread
            try:
                chunks = [self._rx.get(timeout=0.02)]
            except queue.Empty:
                chunks = []
            while True:
                try:
                    chunks.append(self._rx.get_nowait())
                except queue.Empty:
                    break
            for c in chunks:
                if isinstance(c, Exception):
                    raise DriverError(f"read from {self.port} failed: {c}")
            return b"".join(chunks)
        ser = self._ser
        try:
            n = ser.in_waiting
            data = ser.read(n if n else 1)
            if len(data) == 1:
                n = ser.in_waiting
                if n:
                    data += ser.read(n)
        except (serial.SerialException, OSError) as exc:
            raise DriverError(f"read from {self.port} failed: {exc}") from None
        return data

    def _start_relay(self, fd: int) -> None:
        """Start the relay process (driver.relay) that drains the tty into a 1 MiB pipe."""
        import fcntl
        import subprocess
        import sys

        try:
            self._relay = subprocess.Popen(
                [sys.executable, "-m", "driver.relay", str(fd), str(os.getpid())],
                pass_fds=(fd,), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                bufsize=0, cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        except OSError:  # no interpreter to start: read with a thread instead
            self._relay = None
            self._rx = queue.SimpleQueue()
            self._rx_thread = threading.Thread(target=self._reader, args=(fd,),
                                               name=f"fpscan-rx {self.port}", daemon=True)
            self._rx_thread.start()
            return
        self._relay_fd = self._relay.stdout.fileno()
        try:
            fcntl.fcntl(self._relay_fd, 1031, 1 << 20)  # F_SETPIPE_SZ: 1 MiB
        except OSError:
            pass

    def _reader(self, fd: int) -> None:
        """Reader thread for local ttys: keeps the (4 KiB deep) tty buffer drained while
        the scan thread decodes and writes, so the link never waits for the host."""
        while not self._rx_stop.is_set():
            try:
                if select.select([fd], [], [], 0.1)[0]:
                    data = os.read(fd, 1 << 18)
                    if data:
                        self._rx.put(data)
            except BlockingIOError:
                continue
            except (OSError, ValueError) as exc:
                if not self._rx_stop.is_set():
                    self._rx.put(exc)
                return

    def _pump(self) -> None:
        """Read what arrived (waiting at most ~20 ms) and dispatch every good frame."""
        data = self._read_some()
        if not data:
            return
        frames = self._deframer.feed(data)
        if self._deframer.errors:
            self.faults["bad_frames"] += self._deframer.errors
            self._deframer.errors = 0
        for fr in frames:
            t = fr.type
            if t == FrameType.ALINE:
                self._on_aline(fr)
            elif t in (FrameType.RSP, FrameType.ERR):
                if fr.ack == self._pending_seq:
                    self._reply = fr
            elif t == FrameType.EVENT:
                self._on_event(fr.payload.decode("ascii", "replace"))

    def _on_event(self, text: str) -> None:
        self._events.append(text)
        word, _, arg = text.partition(" ")
        if word == "BOOT" and self._run is not None:
            try:
                if int(arg) != self._run.boot_id and int(arg) not in self._old_boots:
                    self._run.reset_seen = True
            except ValueError:
                pass
        elif word == "INTERLOCK" and arg.strip() == "1" and self._run is not None:
            self._run.interlock = True

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
                        if next_send > t0:
                            self.faults["command_retries"] += 1
                        self._write(wire)
                        next_send = now + self.retry
                    self._pump()
            finally:
                self._pending_seq = None
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

        Raises :class:`DriverError` if the device speaks another protocol version.
        """
        idn = self.query("*IDN?")
        version = self.query("SYST:PROT?")
        if version.strip() != str(PROTOCOL_VERSION):
            raise DriverError(f"device speaks protocol {version!r}, host {PROTOCOL_VERSION}")
        parts = [p.strip() for p in idn.split(",")] + [""] * 4
        try:
            limits = [int(x) for x in self.query("SYST:LIM?").split(",")]
        except ValueError:
            raise DriverError("malformed SYST:LIM? reply") from None
        status = self.status()
        self._boot_id = status.boot_id
        if len(limits) == 4 and limits[3] > 0:
            self._max_chunk = min(MAX_CHUNK, limits[3])
        return {"idn": idn, "manufacturer": parts[0], "model": parts[1], "serial": parts[2],
                "firmware": parts[3], "protocol": PROTOCOL_VERSION, "port": self.port,
                "boot_id": status.boot_id,
                "limits": dict(zip(["max_points", "max_samples", "max_window", "max_chunk"],
                                   limits))}

    def status(self, timeout: float | None = None) -> DeviceStatus:
        """``SCAN:STAT?`` parsed."""
        return DeviceStatus.parse(self.query("SCAN:STAT?", timeout=timeout))

    def errors(self) -> list[tuple[int, str]]:
        """Drain the device's error queue (``SYST:ERR?`` until ``0``)."""
        out = []
        for _ in range(64):
            code_s, _, msg = self.query("SYST:ERR?").partition(",")
            try:
                code = int(code_s)
            except ValueError:
                raise DriverError(f"malformed SYST:ERR? reply {code_s!r}") from None
            if code == 0:
                break
            out.append((code, msg.strip('"')))
        return out

    def upload_plan(self, plan) -> str:
        """Upload a plan (dict or path) in chunks; verify its SHA-256 and ``PLAN:ID?``.

        Aborts a run the device still has (and clears a FAULT whose interlock closed)
        first. Returns the plan id. Raises ``ValueError``
        for a bad plan, :class:`DeviceError` if the device refuses it (over its limits,
        hash mismatch) or :class:`DriverError` if the plan id read back differs.
        """
        plan = load_plan(plan)
        image = plan_image(plan)
        st = self.status()
        self._boot_id = st.boot_id
        if st.state in ("RUNNING", "PAUSED", "FAULT"):
            # ends a run a previous host left, and clears a fault whose cause is gone (a
            # closed interlock); an open interlock stays FAULT and SCAN:STAR will say so
            self.query("SCAN:ABOR")
        self.query(f"PLAN:BEG {len(image)}")
        # chunks of up to max_chunk bytes; on a noisy link a long command rarely arrives
        # intact, so a chunk that gets no reply is retried 8 times smaller (>= 64 B), and
        # the size doubles again after 4 chunks in a row got through
        chunk = self._max_chunk
        off = streak = 0
        last = time.monotonic()
        per_try = min(self.response_timeout, max(0.3, 2 * self.retry))
        while off < len(image):
            piece = image[off:off + chunk]
            try:
                self.query(f"PLAN:DATA {off},".encode() + block(piece), timeout=per_try)
            except DeviceTimeout:
                if time.monotonic() - last > self.response_timeout:
                    raise
                chunk, streak = max(64, chunk // 8), 0
                self.faults["upload_retries"] += 1
                continue
            off += len(piece)
            last = time.monotonic()
            streak += 1
            if streak >= 4 and chunk < self._max_chunk:
                chunk, streak = min(self._max_chunk, 2 * chunk), 0
        self.query(f"PLAN:END {hashlib.sha256(image).hexdigest()}")
        got = self.query("PLAN:ID?").strip()
        if got != plan["id"]:
            raise DriverError(f"device holds plan {got}, uploaded {plan['id']}")
        return got

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
            self.query({"pause": "SCAN:PAUS", "resume": "SCAN:RES",
                        "abort": "SCAN:ABOR"}[what])

    # ------------------------------------------------------------------ scanning
    def scan(self, plan, sink, *, progress: Callable[[Progress], None] | None = None,  # noqa: C901 -- split into a scan session by helper "driver"
             progress_interval: float = 0.25, upload: bool = True) -> ScanResult:
        """Acquire every point of ``plan`` not yet complete in ``sink``.

        ``plan``: plan dict or path (docs/architecture.md). ``sink``: object with
        ``completed() -> bool (n_points,)`` and ``append(k, samples int16 (n_t,), meta) ->
        bool`` (the scan file API), written before the A-line is acknowledged, so the sink's
        record is the truth a later call resumes from. ``progress``: called with
        :class:`Progress` from this thread. Returns a :class:`ScanResult`.

        Raises ``ValueError`` (plan and sink disagree), :class:`InterlockOpen`,
        :class:`DeviceTimeout` (device silent for ``response_timeout``),
        :class:`DeviceError`. On any exit the device is left idle (best effort).
        """
        plan = load_plan(plan)
        n = len(plan["points"]["indices"])
        n_t = int(plan["acquisition"]["n_t"])
        completed = np.array(sink.completed(), dtype=bool)
        if completed.shape != (n,):
            raise ValueError(f"sink holds {completed.shape} points, plan {n}")
        if getattr(sink, "plan_id", plan["id"]) != plan["id"]:
            raise ValueError(f"sink is for plan {sink.plan_id}, not {plan['id']}")
        t_start = time.monotonic()
        done0 = int(completed.sum())
        counters = collections.Counter()
        state = {"done": done0, "t_first": None, "t_last": None, "last_prog": 0.0,
                 "label": "running"}

        def report(label: str, force: bool = False) -> None:
            now = time.monotonic()
            if progress is None or (not force and now - state["last_prog"] < progress_interval):
                return
            state["last_prog"] = now
            t_first = state["t_first"] or now
            rate = (state["done"] - done0) / max(now - t_first, 1e-9)
            eta = (n - state["done"]) / rate if rate > 0 else float("inf")
            progress(Progress(state["done"], n, rate, eta, self.faults_recovered(), label,
                              now - t_start))

        def on_aline(fr) -> None:
            run = self._run
            if run is None:  # A-lines that overtook the SCAN:STAR reply: keep for the run
                if len(early) < 4096:
                    early.append(fr)
                return
            try:
                a = unpack_aline(fr.payload)
            except ValueError:
                self.faults["bad_alines"] += 1
                return
            if a.run_id != run.run_id or a.boot_id != run.boot_id:
                counters["stale"] += 1
                if a.boot_id != run.boot_id and a.boot_id not in self._old_boots:
                    run.reset_seen = True
                return
            seq = fr.seq
            run.last_rx = time.monotonic()
            if seq < run.expected or seq in run.ooo:
                counters["duplicates"] += 1
                run.need_ack = True
                return
            if seq == run.expected:
                run.expected += 1
                while run.expected in run.ooo:
                    run.ooo.discard(run.expected)
                    run.expected += 1
            else:
                run.ooo.add(seq)
                run.max_seen = max(run.max_seen, seq)
            run.since_ack += 1
            run.last_new = run.last_rx  # the device makes progress
            counters["alines"] += 1
            k = a.point_index
            if not 0 <= k < n or a.samples.size != n_t:
                self.faults["bad_alines"] += 1
                return
            if not completed[k]:
                sink.append(k, a.samples, a.meta())
                completed[k] = True
                state["done"] += 1
                state["t_last"] = run.last_rx
            else:
                counters["duplicate_points"] += 1

        early: list = []
        self._on_aline = on_aline
        # silence that means a stall: at least stall_timeout, and 3 point periods at the
        # plan's PRF (a slow laser or many averages is not a stall)
        acq = plan["acquisition"]
        prf = float(acq.get("prf") or 0.0)
        silence = self.stall_timeout
        if prf > 0:
            silence = max(silence, 3.0 * int(acq.get("averages", 1)) / prf)
        aborted = False
        self._scanning.set()
        try:
            with self._io:
                if upload:
                    self.identify()
                    self.upload_plan(plan)
                else:  # the caller uploaded it: check that the device holds this plan
                    self._boot_id = self.status().boot_id
                    held = self.query("PLAN:ID?").strip()
                    if held != plan["id"]:
                        raise DriverError(f"device holds plan {held}, not {plan['id']}; "
                                          "scan with upload=True")
                self._device_busy = True
                report("running", force=True)
                lost_plan = 0
                while not completed.all():
                    k0 = int(np.argmin(completed))
                    try:
                        reply = self.query(f"SCAN:STAR {k0}")
                    except DeviceError as exc:
                        if exc.code != 103 or lost_plan >= 3:
                            raise
                        lost_plan += 1  # "no plan": the device reset since the upload
                        self.faults["resets"] += 1
                        self._recover_reset(plan)
                        continue
                    try:
                        run_id, first_seq = (int(x) for x in reply.split(","))
                    except ValueError:
                        raise DriverError(f"malformed SCAN:STAR reply {reply!r}") from None
                    if state["t_first"] is None:
                        state["t_first"] = time.monotonic()
                    self._run = _Run(run_id, self._boot_id, first_seq)
                    for fr in early:
                        on_aline(fr)
                    early.clear()
                    self._send_ack()
                    outcome = self._stream(completed, report, silence)
                    self._run = None
                    early.clear()
                    if outcome == "abort":
                        aborted = True
                        break
                    if outcome == "reset":
                        self.faults["resets"] += 1
                        report("recovering", force=True)
                        self._recover_reset(plan)
                # the host's record is complete: leave the device idle
                st = self.status()
                if st.state in ("RUNNING", "PAUSED"):
                    self.query("SCAN:ABOR")
                self._device_busy = False
        except BaseException:
            self._run = None
            if self._device_busy and self._ser is not None:
                try:
                    self.query("SCAN:ABOR", timeout=2.0)
                    self._device_busy = False
                except DriverError:
                    pass
            raise
        finally:
            self._scanning.clear()
            self._on_aline = _ignore
            while not self._requests.empty():
                self._requests.get_nowait()
            if hasattr(sink, "flush"):
                sink.flush()
        report("aborted" if aborted else "done", force=True)
        t_end = time.monotonic()
        faults = {k: v for k, v in self.faults.items() if v}
        link = {k: v for k, v in counters.items() if k != "alines"}
        acq = ((state["t_last"] or t_end) - state["t_first"]) if state["t_first"] else 0.0
        return ScanResult(n, int(completed.sum()), bool(completed.all()), aborted,
                          t_end - t_start, acq, counters["alines"], faults, link)

    def faults_recovered(self) -> int:
        f = self.faults
        return (f["bad_frames"] + f["bad_alines"] + f["naks"] + f["command_retries"]
                + f["stall_polls"] + f["resets"] + f["upload_retries"])

    def _on_aline(self, fr) -> None:  # replaced during scan()
        pass

    def _send_ack(self, nak: list[int] | None = None) -> None:
        run = self._run
        if nak:
            payload = np.asarray(nak, dtype="<u4").tobytes()
            self._write(encode_frame(FrameType.NAK, payload, ack=run.expected,
                                     window=self.window))
        else:
            self._write(encode_frame(FrameType.ACK, ack=run.expected, window=self.window))
        run.since_ack = 0
        run.need_ack = False
        run.last_ack = time.monotonic()

    def _stream(self, completed: np.ndarray, report, silence: float) -> str:  # noqa: C901 -- split into transport readers by helper "driver"
        """Receive one run until the record is complete; returns 'done', 'reset', 'abort'."""
        run = self._run
        paused = False
        ack_every = max(1, self.window // 2)
        while True:
            # requests from other threads
            while not self._requests.empty():
                what = self._requests.get_nowait()
                if what == "abort":
                    self.query("SCAN:ABOR")
                    self._device_busy = False
                    return "abort"
                if what == "pause" and not paused:
                    self.query("SCAN:PAUS")
                    paused = True
                elif what == "resume" and paused:
                    self.query("SCAN:RES")
                    paused = False
                    run.last_rx = run.last_new = time.monotonic()
            self._pump()
            now = time.monotonic()
            if run.reset_seen:
                return "reset"
            if run.interlock:
                self._raise_interlock(completed)
            if run.since_ack >= ack_every or (run.since_ack or run.need_ack) and \
                    now - run.last_ack > 0.02:
                self._send_ack()
            if run.ooo:  # gap: NAK the missing sequence numbers not NAKed recently
                missing = [s for s in range(run.expected, run.max_seen)
                           if s not in run.ooo and now - run.nak_time.get(s, 0.0) > 0.1]
                if len(run.nak_time) > 4096:
                    run.nak_time = {s: t for s, t in run.nak_time.items() if s >= run.expected}
                if missing:
                    for s in missing:
                        run.nak_time[s] = now
                    self.faults["naks"] += len(missing)
                    self._send_ack(missing[:256])
            if completed.all():
                self._send_ack()
                return "done"
            report("paused" if paused else "running")
            if now - run.last_rx > (2 * silence if paused else silence):
                # silence: poll the device (this waits out a stall up to response_timeout)
                if not paused:
                    self.faults["stall_polls"] += 1
                st = self.status()
                run.last_rx = time.monotonic()
                if st.boot_id != run.boot_id:
                    return "reset"
                if st.state == "FAULT":
                    self._raise_interlock(completed)
                if st.state == "IDLE" and not completed.all():
                    return "restart"  # the run ended with points missing: start again
                if not paused and time.monotonic() - run.last_new > max(
                        3 * self.response_timeout, 10 * silence):
                    raise DeviceTimeout(f"{self.port} reports {st.state} but delivered no new "
                                        f"A-line for {time.monotonic() - run.last_new:.0f} s")
                self._send_ack(self._missing_tail(run))

    @staticmethod
    def _missing_tail(run) -> list[int] | None:
        if run.ooo:
            return [s for s in range(run.expected, run.max_seen) if s not in run.ooo][:256]
        return None

    def _raise_interlock(self, completed) -> None:
        raise InterlockOpen(101, f"Laser interlock open; {int(completed.sum())} of "
                                 f"{completed.size} points are on disk, re-run to resume")

    def _recover_reset(self, plan: dict) -> None:
        """The device rebooted: wait for it, re-identify and re-upload the plan."""
        if self._boot_id is not None:
            self._old_boots.add(self._boot_id)
        deadline = time.monotonic() + self.response_timeout
        while True:
            try:
                self.identify()
                break
            except DeviceTimeout:
                if time.monotonic() > deadline:
                    raise
        self.upload_plan(plan)


def _ignore(fr) -> None:
    pass


class _Run:
    """Receive state of one run (SCAN:STAR … completion)."""

    def __init__(self, run_id: int, boot_id: int | None, first_seq: int):
        self.run_id = run_id
        self.boot_id = boot_id
        self.expected = first_seq
        self.max_seen = first_seq
        self.ooo: set[int] = set()
        self.nak_time: dict[int, float] = {}
        self.since_ack = 0
        self.need_ack = False
        self.last_ack = 0.0
        self.last_rx = self.last_new = time.monotonic()
        self.reset_seen = False
        self.interlock = False
