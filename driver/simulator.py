"""The simulated Fabry–Pérot scanner: the device side of docs/protocol.md on a pseudo-terminal.

:class:`SimulatedScanner` opens a pty (``pty.openpty``), puts it in raw mode and runs the
device firmware's loop in a background thread: it deframes host frames, executes SCPI
commands, and streams A-line frames under the host's credit window, resending on NAK or
timeout. The host opens :attr:`SimulatedScanner.path` exactly like a real USB-CDC port, so
tests exercise the same serial code path as hardware.

Signal model, per plan point k at lattice point (i_x, i_y) (all deterministic given the seed):

* pressure p_k(t) in Pa from the source (:mod:`fpscan.driver.sources`);
* DC level d_k = ``dc_level``·(1 + ``dc_variation``·m_1(i_x, i_y)) in V and sensitivity
  s_k = 1 + ``sensitivity_variation``·m_2(i_x, i_y), with smooth maps m_1, m_2 ∈ [−1, 1];
* FP output v_k = s_k·d_k·p_k (Pa·V), low-passed by a 2nd-order Butterworth filter at
  ``bandwidth`` Hz (if given; ``scipy.signal``), plus white Gaussian noise of standard
  deviation d_k·peak/``snr``/sqrt(averages) (if given; peak = the source's reference
  amplitude; the plan's ``averages`` pulses are averaged);
* int16 quantisation: scale = max|v_k|/32767, offset = 0, sample = round(v_k/scale).

Wavelengths: a plan with N excitation wavelengths is acquired as N·n_points A-lines in
the plan's order (``per_point`` or ``per_pass``, :func:`fpscan.driver.plan.aline_order`); the
source renders each A-line at its wavelength (wavelength-dependent phantoms:
:class:`fpscan.driver.sources.BallSource` with ``so2``). Fault positions (stall, reset, interlock
at K) count A-lines in acquisition order (= points for one wavelength).

Timing: with ``prf`` > 0 the laser fires on a clock of period 1/prf started by SCAN:STAR;
A-line s uses the first ``averages`` ticks after the previous A-line and after its
preparation: galvo move and bias tuning (``tuning_delay`` s) when the point changes,
excitation laser tuning (``laser_tuning_delay`` s) when the wavelength changes, the
longer of the two when both do (they run in parallel). So N points at one wavelength
take N·averages/prf s; ``prf`` = 0 is unthrottled. With ``prf_from_plan`` the clock runs at
the PRF the plan asks for (its image's ``prf``, when > 0), ``prf`` otherwise.
``byte_rate`` limits the device's output bytes/s (a UART-like link).

Faults (:mod:`fpscan.driver.faults`) are seeded by ``seed``. The ground truth (every A-line as
sent) can be recorded to HDF5 (:meth:`SimulatedScanner.write_record`).
"""
from __future__ import annotations

import collections
import hashlib
import math
import os
import pty
import secrets
import select
import threading
import time
import tty
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.driver import commands as scpi
from fpscan.driver.aline import pack_aline, quantise
from fpscan.driver.faults import FaultSpec, damage
from fpscan.driver.framing import Deframer, Frame, FrameType, encode_frame
from fpscan.driver.plan_image import DevicePlan, image_size_limit, parse_plan_image

if TYPE_CHECKING:
    from collections.abc import Callable

    from fpscan.driver.sources import PressureFn, Source

__all__ = ["FIRMWARE_VERSION", "INITIAL_WINDOW", "BLOCK", "SimConfig", "SimulatedScanner", "sensor_response"]

FIRMWARE_VERSION = "1.0"
INITIAL_WINDOW = 8
BLOCK = 128


@dataclass
class SimConfig:
    """Settings of the simulated scanner (SI units; see the module docstring).

    Raises ``ValueError`` (on construction) naming the first setting out of range.

    Attributes
    ----------
    source : Source or None
        A :mod:`fpscan.driver.sources` source; None = ``BallSource(default_phantom())``.
    prf : float
        Laser pulse repetition frequency, Hz (0 = unthrottled).
    prf_from_plan : bool
        Fire at the PRF the plan asks for (the plan image's ``prf``, when > 0) instead of
        ``prf``, which then holds for plans that ask for none (``fpscan sim`` without ``--prf``).
    tuning_delay : float
        Bias-wavelength tuning time per point, s.
    laser_tuning_delay : float
        Excitation-wavelength tuning time, s.
    dc_level : float
        Mean photodiode DC level, V (> 0).
    dc_variation : float
        Relative amplitude of the DC-level map, in [0, 1).
    sensitivity_variation : float
        Relative amplitude of the sensitivity map, in [0, 1).
    bandwidth : float or None
        Sensor −3 dB bandwidth, Hz (None = unlimited).
    snr : float or None
        Peak signal / noise standard deviation (None = no noise).
    byte_rate : float or None
        Output byte-rate limit, bytes/s, at least 100 (None = none).
    faults : FaultSpec
        Injected link and device faults (:mod:`fpscan.driver.faults`).
    seed : int
        Seed of the noise, the maps and the faults.
    record : Path or None
        Ground-truth HDF5 file written by ``write_record()`` (at :meth:`SimulatedScanner.stop`).
    pulse_energy : float
        Mean excitation pulse energy, J.
    bias_wavelength : float
        Centre bias wavelength, m.
    max_points : int
        Most A-lines (points × wavelengths) of a plan the device takes, 1 … 2²⁴.
    max_samples : int
        Most samples per A-line, 1 … 32768.
    max_window : int
        Largest credit window the device honours, frames, 1 … 65535.
    max_chunk : int
        Largest ``PLAN:DATA`` block the device takes (and ``SYST:LIM?`` reports), bytes,
        1 … 4096; below 64 (the protocol's minimum) it is a faulty device the host refuses.
    rto : float
        Retransmission timeout without ACK progress, s.
    serial : str
        The serial number ``*IDN?`` reports.
    precompute : bool
        Generate all A-lines of a plan at ``PLAN:END``.
    """

    source: Source | None = None  #: a fpscan.driver.sources source; None = BallSource(default_phantom())
    prf: float = 50.0  #: laser pulse repetition frequency, Hz (0 = unthrottled)
    prf_from_plan: bool = False  #: fire at the PRF the plan asks for (its image's prf > 0) instead of ``prf``
    tuning_delay: float = 0.0  #: bias-wavelength tuning time per point, s
    laser_tuning_delay: float = 0.0  #: excitation-wavelength tuning time, s
    dc_level: float = 1.0  #: mean photodiode DC level, V
    dc_variation: float = 0.0  #: relative amplitude of the DC-level map
    sensitivity_variation: float = 0.0  #: relative amplitude of the sensitivity map
    bandwidth: float | None = None  #: sensor −3 dB bandwidth, Hz (None = unlimited)
    snr: float | None = None  #: peak signal / noise std (None = no noise)
    byte_rate: float | None = None  #: output byte-rate limit, bytes/s (None = none)
    faults: FaultSpec = field(default_factory=FaultSpec)
    seed: int = 0
    record: Path | None = None  #: ground-truth HDF5 file written by write_record()
    pulse_energy: float = 20e-3  #: mean excitation pulse energy, J
    bias_wavelength: float = 1550e-9  #: centre bias wavelength, m
    max_points: int = 1 << 20
    max_samples: int = 32768
    max_window: int = 256
    max_chunk: int = scpi.MAX_CHUNK
    rto: float = 0.1  #: retransmission timeout without ack progress, s
    serial: str = "SIM0001"
    precompute: bool = False  #: generate all A-lines of a plan at PLAN:END

    def __post_init__(self) -> None:
        """Raises ``ValueError`` naming the first setting out of range."""
        checks = [
            ("prf", self.prf >= 0, ">= 0 Hz"),
            ("tuning_delay", self.tuning_delay >= 0, ">= 0 s"),
            ("laser_tuning_delay", self.laser_tuning_delay >= 0, ">= 0 s"),
            ("dc_level", self.dc_level > 0, "> 0 V"),
            ("dc_variation", 0 <= self.dc_variation < 1, "in [0, 1)"),
            ("sensitivity_variation", 0 <= self.sensitivity_variation < 1, "in [0, 1)"),
            ("bandwidth", self.bandwidth is None or self.bandwidth > 0, "> 0 Hz"),
            ("snr", self.snr is None or self.snr > 0, "> 0"),
            ("byte_rate", self.byte_rate is None or self.byte_rate >= 100, ">= 100 bytes/s"),
            ("max_points", 1 <= self.max_points <= 1 << 24, "in 1..2^24"),
            ("max_samples", 1 <= self.max_samples <= 32768, "in 1..32768"),
            ("max_window", 1 <= self.max_window <= 65535, "in 1..65535"),
            ("max_chunk", 1 <= self.max_chunk <= scpi.MAX_CHUNK, f"in 1..{scpi.MAX_CHUNK}"),
            ("rto", self.rto > 0, "> 0 s"),
        ]
        for name, ok, what in checks:
            if not ok:
                raise ValueError(f"simulator setting {name} = {getattr(self, name)!r} must be "
                                 f"{what}")


_Error = scpi.ScpiError


class _LostInReset(Exception):
    """A command the device reset on while receiving it: no reply (the reset lost it)."""


class _Held:
    """:meth:`SimulatedScanner.hold`'s context: entering asks the device loop to park and
    waits until it has (the step it was in, and any reply of it, done), so nothing sent from
    then on is read until the context ends. Raises RuntimeError when the loop does not park
    (a stopped device)."""

    def __init__(self, sim: SimulatedScanner) -> None:
        self.sim = sim

    def __enter__(self) -> SimulatedScanner:
        self.sim._hold.set()
        if not self.sim._parked.wait(30.0):  # a guard: the loop parks within one of its steps
            self.sim._hold.clear()
            raise RuntimeError("the simulated device did not stop reading (is it running?)")
        return self.sim

    def __exit__(self, *exc: object) -> None:
        self.sim._hold.clear()


class SimulatedScanner:
    """Device side of the FP scanner protocol on a pty, run in a background thread.

    Use as a context manager or call :meth:`start` / :meth:`stop`. :attr:`path` is the
    device path for the host (``/dev/pts/N``). Thread-safe accessors: :attr:`boot_id`,
    :attr:`state`. Raises ``OSError`` if no pty can be opened.

    Parameters
    ----------
    config : SimConfig, optional
        The settings; None: ``SimConfig(**kwargs)``.
    **kwargs
        :class:`SimConfig` fields, used when ``config`` is None.

    Attributes
    ----------
    config : SimConfig
        The settings (its ``source`` filled in).
    path : str
        The pty's device path for the host (``/dev/pts/N``).
    stats : collections.Counter
        Counts of what the device did: ``alines`` sent, ``tx_bytes``, ``resent``, ``timeouts``,
        ``rx_bad_frames``, ``duplicate_commands``, ``stalls``, ``resets``, ``early_stops``,
        ``false_events``, ``seq_skips``, ``internal_errors``.

    Raises
    ------
    OSError
        No pty can be opened.
    ValueError
        A setting out of range (from :class:`SimConfig`).
    """

    def __init__(self, config: SimConfig | None = None, **kwargs: Any) -> None:
        self.config = config or SimConfig(**kwargs)
        if self.config.source is None:
            from fpscan.driver.sources import BallSource, default_phantom

            self.config.source = BallSource(default_phantom())
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._stall_until = 0.0
        self._hold, self._parked = threading.Event(), threading.Event()  # hold(): asked, and done
        self._peak = 1.0
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._fault_rng = np.random.default_rng([self.config.seed, 1])
        self._stalls = dict(self.config.faults.stalls)
        self._resets = dict(self.config.faults.resets)
        self._stops = dict(self.config.faults.stops)
        self._upload_reset_at, self._upload_resets = self.config.faults.upload_reset
        self._events = dict(self.config.faults.events)
        self._interlocks = dict(self.config.faults.interlocks)
        self._seq_skips = dict(self.config.faults.seq_skips)
        self._bad_points = dict(self.config.faults.bad_points)
        self._bad_fields = dict(self.config.faults.bad_fields)
        self._ignore_acks_at = set(self.config.faults.ignore_acks)
        self._records: dict[str, dict] = {}
        self._record_order: list[str] = []
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="fpsim-gen")
        self.stats: collections.Counter[str] = collections.Counter()
        self._boot()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimulatedScanner:
        self._thread = threading.Thread(target=self._run, name="fpsim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the device loop, write the record (if configured) and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self._pool.shutdown(wait=True)
        if self.config.record:
            self.write_record(self.config.record)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> SimulatedScanner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def hold(self) -> _Held:
        """A context in which the device reads and answers nothing: what the host sends waits
        in the pty and is read, in order, when the context ends (nothing is lost, no fault is
        counted). A device busy for exactly as long as its caller needs, e.g. a test's slow
        reply made by an event (the host has resent its command) rather than by a clock."""
        return _Held(self)

    def reset(self) -> None:
        """Reset the device now, as a power glitch or a watchdog would (docs/protocol.md §10): a
        new boot id; its plan, run and unacknowledged A-lines lost; ``EVENT BOOT`` sent. Counted
        in ``stats["resets"]``."""
        with self.hold():
            self.stats["resets"] += 1
            self._do_reset()

    @property
    def boot_id(self) -> int:
        return self._boot_id

    @property
    def state(self) -> str:
        return self._state

    # ------------------------------------------------------------------ device state
    def _boot(self) -> None:
        self._boot_id = secrets.randbits(31) + 1
        self._boot_time = time.monotonic()
        self._state = "IDLE"
        self._plan: DevicePlan | None = None
        self._order: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64),) * 2
        self._plan_image = bytearray()
        self._plan_expected = 0
        self._plan_chunks = 0  # PLAN:DATA commands since the last PLAN:BEG (the upload_reset fault)
        self._plan_hash = ""
        self._pressure: PressureFn | None = None
        self._blocks: dict[int, Future] = {}
        self._errors: collections.deque = collections.deque()
        self._last_cmd: tuple[int, bytes] | None = None
        self._last_reply = b""
        self._run_id = 0
        self._next_seq = 0
        self._next_k = 0
        self._unacked: collections.OrderedDict[int, bytes] = collections.OrderedDict()
        self._resend: collections.deque = collections.deque()
        self._resend_set: set[int] = set()
        self._window = INITIAL_WINDOW
        self._last_progress = time.monotonic()
        self._pulses = 0
        self._last_tick = 0
        self._clock0 = 0.0
        self._clock_pending = False
        self._held = False
        self._last_fire = 0.0
        self._run_from = 0
        self._ready_k = -1
        self._ready_t = 0.0
        self._interlock_until = 0.0
        self._ignoring_acks = False  #: the ignore_acks fault holds until the run ends
        self._out = bytearray()
        self._deframer = Deframer()
        self._tokens = 0.0
        self._token_time = time.monotonic()
        self._wake = math.inf

    def _push_error(self, code: int, message: str) -> None:
        if len(self._errors) >= 16:
            self._errors[-1] = (-350, "Queue overflow")
        else:
            self._errors.append((code, message))

    # ------------------------------------------------------------------ main loop
    def _run(self) -> None:
        self._send(FrameType.EVENT, f"BOOT {self._boot_id}".encode())
        fd = self._master
        while not self._stop.is_set():
            if self._hold.is_set():  # hold(): read and answer nothing until it ends
                self._parked.set()
                time.sleep(0.002)
                continue
            self._parked.clear()
            now = time.monotonic()
            if now < self._stall_until:
                time.sleep(min(0.02, self._stall_until - now))
                continue
            wlist = [fd] if self._out and self._may_write(now) else []
            timeout = 0.05
            if self._wake < math.inf:
                timeout = max(0.0, min(timeout, self._wake - now))
            try:
                r, _, _ = select.select([fd], wlist, [], timeout)
            except (OSError, ValueError):
                break
            data = b""
            if r:
                try:
                    data = os.read(fd, 1 << 16)
                except BlockingIOError:
                    data = b""
                except OSError:  # EIO: no slave open (cannot happen: we hold one)
                    data = b""
                    time.sleep(0.01)
            try:
                if r and data:
                    self._receive(data)
                now = time.monotonic()
                self._check_interlock(now)
                self._produce(now)
                self._retransmit(now)
                if self._out:
                    self._write(now)
            except Exception as exc:  # a firmware bug must not kill the device
                self.stats["internal_errors"] += 1
                self._push_error(-310, f"System error; {type(exc).__name__}: {exc}"[:200])
                self._abort()
                self._wake = math.inf

    def _receive(self, data: bytes) -> None:
        f = self.config.faults
        if f.damages_bytes:
            data = damage(data, f.corrupt, f.drop, self._fault_rng)
        for frame in self._deframer.feed(data):
            self._on_frame(frame)
        if self._deframer.errors:
            self.stats["rx_bad_frames"] += self._deframer.errors
            self._push_error(-310, f"System error; frame discarded: "
                                   f"{self._deframer.last_error}")
            self._deframer.errors = 0

    def _may_write(self, now: float) -> bool:
        rate = self.config.byte_rate
        if not rate:
            return True
        self._tokens = min(rate * 0.05 + 64, self._tokens + (now - self._token_time) * rate)
        self._token_time = now
        if self._tokens < 1:
            self._wake = min(self._wake, now + (1 - self._tokens) / rate)
            return False
        return True

    def _write(self, now: float) -> None:
        n = len(self._out)
        if self.config.byte_rate:
            if not self._may_write(now):
                return
            n = min(n, int(self._tokens))
        try:
            written = os.write(self._master, memoryview(self._out)[:n])
        except BlockingIOError:
            return
        except OSError:
            return
        del self._out[:written]
        self.stats["tx_bytes"] += written
        if self.config.byte_rate:
            self._tokens -= written

    def _send(self, ftype: int, payload: bytes = b"", *, seq: int = 0, ack: int = 0) -> bytes:
        wire = encode_frame(ftype, payload, seq=seq, ack=ack)
        self._emit(wire)
        return wire

    def _emit(self, wire: bytes) -> None:
        f = self.config.faults
        if f.damages_bytes:
            wire = damage(wire, f.corrupt, f.drop, self._fault_rng)
        self._out += wire

    # ------------------------------------------------------------------ frames
    def _on_frame(self, frame: Frame) -> None:
        t = frame.type
        if t == FrameType.CMD:
            key = (frame.seq, frame.payload)
            if key == self._last_cmd:  # retransmitted command: repeat the reply
                self.stats["duplicate_commands"] += 1
                self._emit(self._last_reply)
                return
            try:
                reply = self._execute(frame.payload)
                wire = encode_frame(FrameType.RSP, reply, ack=frame.seq)
            except _LostInReset:
                return
            except _Error as err:
                self._push_error(err.code, err.message)
                wire = encode_frame(FrameType.ERR, f'{err.code},"{err.message}"'.encode(),
                                    ack=frame.seq)
            except Exception as exc:  # a firmware bug must not kill the device
                msg = f"System error; {type(exc).__name__}: {exc}"[:200].replace('"', "'")
                self._push_error(-310, msg)
                wire = encode_frame(FrameType.ERR, f'-310,"{msg}"'.encode(), ack=frame.seq)
            self._last_cmd, self._last_reply = key, wire
            self._emit(wire)
        elif t in (FrameType.ACK, FrameType.NAK):
            if self._ignoring_acks:
                return
            self._on_ack(frame.ack, frame.window)
            if t == FrameType.NAK:
                n = len(frame.payload) // 4
                for seq in np.frombuffer(frame.payload[:4 * n], dtype="<u4").tolist():
                    if seq in self._unacked and seq not in self._resend_set:
                        self._resend.append(seq)
                        self._resend_set.add(seq)
        else:
            self._push_error(-310, f"System error; unexpected frame type {t} from host")

    def _on_ack(self, ack: int, window: int) -> None:
        if window:
            self._window = max(1, min(window, self.config.max_window))
        progressed = False
        while self._unacked:
            seq = next(iter(self._unacked))
            if seq >= ack or ack > self._next_seq:
                break
            del self._unacked[seq]
            progressed = True
        if progressed:
            self._last_progress = time.monotonic()
        self._maybe_finish()

    def _maybe_finish(self) -> None:
        if (self._state == "RUNNING" and self._plan is not None
                and self._next_k >= self._plan.n_alines and not self._unacked):
            self._state = "IDLE"
            self._send(FrameType.EVENT, f"DONE {self._run_id}".encode())
            if self.config.record:
                self.write_record(self.config.record)

    def _retransmit(self, now: float) -> None:
        while self._resend and len(self._out) < (1 << 18):
            seq = self._resend.popleft()
            self._resend_set.discard(seq)
            wire = self._unacked.get(seq)
            if wire is not None:
                self.stats["resent"] += 1
                self._emit(wire)
        if (self._unacked and not self._out and self._state in ("RUNNING", "PAUSED")
                and now - self._last_progress > self.config.rto):
            seq = next(iter(self._unacked))
            self.stats["timeouts"] += 1
            self._emit(self._unacked[seq])
            self._last_progress = now
        if self._unacked:
            self._wake = min(self._wake, self._last_progress + self.config.rto)

    # ------------------------------------------------------------------ acquisition
    def _check_interlock(self, now: float) -> None:
        if self._interlock_until and now >= self._interlock_until:
            self._interlock_until = 0.0
            self._send(FrameType.EVENT, b"INTERLOCK 0")

    def _produce(self, now: float) -> None:
        self._wake = math.inf
        plan = self._plan
        if self._state != "RUNNING" or plan is None:
            return
        cfg = self.config
        while (self._next_k < plan.n_alines and len(self._unacked) < self._window
               and len(self._out) < (1 << 18)):
            k = self._next_k
            if self._fault_before(k, now):
                return
            fut = self._block(k // BLOCK)
            if not fut.done():  # the source is still computing: look again in 5 ms
                self._wake = now + 0.005
                self._held = True
                return
            if fut.exception() is not None:
                self._push_error(-200, f"Execution error; A-line source failed: "
                                       f"{fut.exception()}")
                self._abort()
                self._blocks.clear()
                return
            if self._clock_pending:  # the PRF clock starts when the first A-line is ready
                self._clock_pending = False
                self._clock0 = self._last_fire = now
            prf = plan.prf if cfg.prf_from_plan and plan.prf > 0 else cfg.prf
            if prf > 0:
                if self._ready_k != k:
                    # galvo move, bias and laser tuning start right after the previous
                    # pulse, or when the A-line could not start earlier (no credit, data
                    # not ready)
                    prev = self._clock0 if k == self._run_from else self._last_fire
                    ready = prev + self._preparation(k)
                    if self._held:
                        ready = max(ready, now)
                    self._ready_k, self._ready_t = k, ready
                ready = self._ready_t
                first = max(self._last_tick + 1,
                            math.ceil((ready - self._clock0) * prf - 1e-9))
                last = first + plan.averages - 1
                fire_at = self._clock0 + last / prf
                if now < fire_at:
                    self._wake = fire_at
                    return
                self._last_tick = last
                self._last_fire = fire_at
                timestamp = fire_at - self._boot_time
            else:
                timestamp = now - self._boot_time
            self._pulses += plan.averages
            self._send_point(k, timestamp)
            self._next_k += 1
            self._held = False
        if self._next_k < plan.n_alines and self._state == "RUNNING":
            self._held = True  # out of credit or output space: the next point waits
            self.stats["waits_credit" if len(self._unacked) >= self._window
                       else "waits_output"] += 1
        self._maybe_finish()

    def _fault_before(self, k: int, now: float) -> bool:
        """Inject the faults set for A-line ``k`` (:mod:`fpscan.driver.faults`); True when one
        stops the acquisition (a stall, a reset, an early end of the run or an open interlock)."""
        if k in self._stalls:
            self._stall_until = now + self._stalls.pop(k)
            self.stats["stalls"] += 1
            return True
        if k in self._resets:
            self._resets[k] -= 1
            if not self._resets[k]:
                del self._resets[k]
            self.stats["resets"] += 1
            self._do_reset()
            return True
        if k in self._stops:  # a firmware fault: the run ends with A-lines missing
            self._stops[k] -= 1
            if not self._stops[k]:
                del self._stops[k]
            self.stats["early_stops"] += 1
            self._state = "IDLE"
            return True
        if k in self._events:  # an event that does not hold: the state stays as it is
            self._send(FrameType.EVENT, self._events.pop(k).encode("ascii", "replace"))
            self.stats["false_events"] += 1
        if k in self._interlocks:
            duration = self._interlocks.pop(k)
            self._interlock_until = now + duration if math.isfinite(duration) else math.inf
            self._state = "FAULT"
            self._push_error(101, "Laser interlock open")
            self._send(FrameType.EVENT, b"INTERLOCK 1")
            return True
        if k in self._seq_skips:  # a firmware fault: the data sequence skips ahead
            self._next_seq = self._seq_skips.pop(k)
            self.stats["seq_skips"] += 1
        if k in self._ignore_acks_at:  # a firmware fault: ACKs and NAKs ignored until the run ends
            self._ignore_acks_at.discard(k)
            self._ignoring_acks = True
        return False

    def _preparation(self, s: int) -> float:
        """Seconds before A-line ``s`` can fire after the previous one (module docstring)."""
        cfg = self.config
        kk, ww = self._order
        if s == self._run_from:
            multi = len(self._loaded_plan().wavelengths) > 1
            return max(cfg.tuning_delay, cfg.laser_tuning_delay if multi else 0.0)
        delay = cfg.tuning_delay if kk[s] != kk[s - 1] else 0.0
        if ww[s] != ww[s - 1]:
            delay = max(delay, cfg.laser_tuning_delay)
        return delay

    def _send_point(self, s: int, timestamp: float) -> None:
        plan = self._loaded_plan()
        b = self._block(s // BLOCK).result()
        j = s % BLOCK
        k, w = int(self._order[0][s]), int(self._order[1][s])
        fields = {"timestamp": timestamp, "bias_wavelength": b["bias"][j], "dt": plan.dt,
                  "scale": b["scale"][j], "offset": 0.0, "dc_level": b["dc"][j],
                  "pulse_energy": b["energy"][j], "excitation_wavelength": plan.wavelengths[w]}
        samples = b["samples"][j]
        if s in self._bad_fields:  # a firmware fault: one field out of its range
            name, value = self._bad_fields.pop(s)
            if name == "sample":
                samples = samples.copy()
                samples[0] = int(value)
            else:
                fields[name] = value
        payload = pack_aline(self._run_id, self._boot_id, self._bad_points.pop(s, k), self._pulses,
                             fields["timestamp"], fields["bias_wavelength"], fields["dt"], fields["scale"],
                             fields["offset"], fields["dc_level"], fields["pulse_energy"], samples, w,
                             fields["excitation_wavelength"])
        seq = self._next_seq
        self._next_seq = (seq + 1) & 0xFFFFFFFF
        wire = encode_frame(FrameType.ALINE, payload, seq=seq, ack=self._last_cmd[0]
                            if self._last_cmd else 0)
        self._unacked[seq] = wire
        if len(self._unacked) == 1:
            self._last_progress = time.monotonic()
        self._emit(wire)
        self.stats["alines"] += 1
        rec = self._records.get(plan.plan_id)
        if rec is not None:
            rec["samples"][w, k] = b["samples"][j]
            rec["scale"][w, k] = b["scale"][j]
            rec["dc"][w, k] = b["dc"][j]
            rec["sent"][w, k] = True

    def _loaded_plan(self) -> DevicePlan:
        if self._plan is None:  # only called while a plan runs
            raise RuntimeError("no plan loaded")
        return self._plan

    def _block(self, bi: int) -> Future:
        """Future of block ``bi``'s A-lines (generated in the helper thread), prefetching
        the next block and forgetting old ones."""
        plan, pressure = self._loaded_plan(), self._pressure
        assert pressure is not None  # set with the plan (PLAN:END)
        got = self._blocks.get(bi)
        if got is None:
            got = self._blocks[bi] = self._pool.submit(self._generate, plan, pressure, bi)
        n_blocks = math.ceil(plan.n_alines / BLOCK)
        if bi + 1 < n_blocks and bi + 1 not in self._blocks:
            self._blocks[bi + 1] = self._pool.submit(self._generate, plan, pressure, bi + 1)
        if not self.config.precompute:
            for old in [b for b in self._blocks if b < bi - 1 or b > bi + 2]:
                del self._blocks[old]
        return got

    def _generate(self, plan: DevicePlan, pressure: PressureFn, bi: int) -> dict:
        """A-lines [bi·BLOCK, (bi+1)·BLOCK) in acquisition order as int16 with their
        metadata."""
        cfg = self.config
        ks, ws = plan.aline_order(np.arange(bi * BLOCK, min((bi + 1) * BLOCK, plan.n_alines)))
        p = np.asarray(pressure(ks, ws), dtype=np.float64).reshape(len(ks), plan.n_t)
        ix = plan.indices[ks, 0].astype(np.float64) / max(plan.n_x - 1, 1)
        iy = plan.indices[ks, 1].astype(np.float64) / max(plan.n_y - 1, 1)
        m1 = np.cos(2 * np.pi * (ix - 0.3)) * np.cos(np.pi * (iy - 0.5))
        m2 = np.sin(np.pi * (ix + 0.25)) * np.cos(1.5 * np.pi * (iy - 0.4))
        # the A-line frame carries dc_level as f32: model with exactly that value
        dc = (cfg.dc_level * (1 + cfg.dc_variation * m1)).astype(np.float32).astype(np.float64)
        sens = 1 + cfg.sensitivity_variation * m2
        v = p * (sens * dc)[:, None]
        if cfg.bandwidth:
            v = sensor_response(v, cfg.bandwidth, plan.dt)
        digest = int.from_bytes(hashlib.sha256(plan.plan_id.encode()).digest()[:4], "little")
        rng = np.random.default_rng([cfg.seed, digest, bi])
        if cfg.snr:  # white noise per pulse; averaging N pulses divides its std by sqrt(N)
            sigma = dc * self._peak / cfg.snr / np.sqrt(plan.averages)
            v = v + rng.standard_normal(v.shape) * sigma[:, None]
        samples, scale = quantise(v)
        energy = cfg.pulse_energy * (1 + 0.02 * rng.standard_normal(len(ks)))
        bias = cfg.bias_wavelength + 0.5e-9 * m1
        return {"samples": samples, "scale": scale, "dc": dc, "energy": energy, "bias": bias}

    def _do_reset(self) -> None:
        """Simulated device reset: all volatile state is lost; silent 0.3 s; BOOT event."""
        self._blocks.clear()
        self._boot()
        self._stall_until = time.monotonic() + 0.3
        self._send(FrameType.EVENT, f"BOOT {self._boot_id}".encode())

    # ------------------------------------------------------------------ commands
    def _execute(self, payload: bytes) -> bytes:
        cmd = scpi.parse_command(payload)
        handler = _HANDLERS.get(cmd.name)
        if handler is None:
            raise _Error(-113, f"Undefined header; {cmd.header}")
        return handler(self, cmd) or b""

    def _cmd_idn(self, cmd: scpi.Command) -> bytes:
        return f"fpscan,FP-SIM,{self.config.serial},{FIRMWARE_VERSION}".encode()

    def _cmd_rst(self, cmd: scpi.Command) -> bytes:
        self._abort()
        return b""

    def _cmd_cls(self, cmd: scpi.Command) -> None:
        self._errors.clear()

    def _cmd_opc(self, cmd: scpi.Command) -> bytes:
        return b"1"

    def _cmd_err(self, cmd: scpi.Command) -> bytes:
        if not self._errors:
            return b'0,"No error"'
        code, msg = self._errors.popleft()
        return f'{code},"{msg}"'.encode()

    def _cmd_prot(self, cmd: scpi.Command) -> bytes:
        from fpscan.driver.framing import PROTOCOL_VERSION

        return str(PROTOCOL_VERSION).encode()

    def _cmd_boot(self, cmd: scpi.Command) -> bytes:
        return str(self._boot_id).encode()

    def _cmd_lim(self, cmd: scpi.Command) -> bytes:
        c = self.config
        return f"{c.max_points},{c.max_samples},{c.max_window},{c.max_chunk}".encode()

    def _require_idle(self) -> None:
        if self._state in ("RUNNING", "PAUSED"):
            raise _Error(-221, "Settings conflict; scan running (SCAN:ABOR first)")

    def _cmd_plan_begin(self, cmd: scpi.Command) -> None:
        self._require_idle()
        n = scpi.int_arg(cmd, 0)
        limit = image_size_limit(self.config.max_points)
        if not 100 < n <= limit:
            raise _Error(-222, f"Data out of range; plan image of {n} bytes (max {limit})")
        self._plan = None
        self._pressure = None
        self._blocks.clear()
        self._plan_image = bytearray()
        self._plan_expected = n
        self._plan_chunks = 0
        self._plan_hash = ""

    def _cmd_plan_data(self, cmd: scpi.Command) -> None:
        self._require_idle()
        if self._plan_expected == 0:
            raise _Error(-200, "Execution error; PLAN:DATA without PLAN:BEG")
        self._plan_chunks += 1
        if self._upload_resets and self._plan_chunks == self._upload_reset_at:
            self._upload_resets -= 1  # a fault: the device resets on this chunk, which is lost with it
            self.stats["resets"] += 1
            self._do_reset()
            raise _LostInReset
        offset = scpi.int_arg(cmd, 0)
        block = cmd.block
        if block is None:
            raise _Error(-104, "Data type error; PLAN:DATA needs a definite-length block")
        if len(block) > self.config.max_chunk:
            raise _Error(-223, f"Too much data; chunk of {len(block)} bytes "
                               f"(max {self.config.max_chunk})")
        have = len(self._plan_image)
        if not 0 <= offset <= have:
            raise _Error(-222, f"Data out of range; chunk offset {offset}, expected <= {have}")
        if offset + len(block) > self._plan_expected:
            raise _Error(-223, "Too much data; chunk runs past the announced size")
        overlap = min(have - offset, len(block))  # a repeated chunk: must match what we have
        if self._plan_image[offset:offset + overlap] != block[:overlap]:
            raise _Error(-222, f"Data out of range; chunk at {offset} differs from the data "
                               "already received")
        self._plan_image += block[overlap:]

    def _cmd_plan_end(self, cmd: scpi.Command) -> None:
        self._require_idle()
        if self._plan_expected == 0:
            raise _Error(-200, "Execution error; PLAN:END without PLAN:BEG")
        want = cmd.args[0].strip('"').lower() if cmd.args else ""
        image = bytes(self._plan_image)
        if len(image) != self._plan_expected:
            raise _Error(-200, f"Execution error; plan image has {len(image)} of "
                               f"{self._plan_expected} bytes")
        got = hashlib.sha256(image).hexdigest()
        self._plan_expected = 0  # the upload ends here, whether the plan is loaded or not
        if got != want:
            raise _Error(102, "Plan hash mismatch")
        try:
            plan = parse_plan_image(image)
        except ValueError as exc:
            raise _Error(-224, f"Illegal parameter value; {exc}") from None
        c = self.config
        source = c.source
        assert source is not None  # set in __init__
        if plan.n_alines > c.max_points or plan.n_t > c.max_samples:
            raise _Error(-222, f"Data out of range; plan of {plan.n_points} points × "
                               f"{plan.n_t} samples exceeds the device's {c.max_points} × "
                               f"{c.max_samples}")
        try:
            pressure = source.prepare(plan)
        except ValueError as exc:
            raise _Error(-221, f"Settings conflict; {exc}") from None
        self._peak = float(source.peak)
        self._plan, self._pressure, self._plan_hash = plan, pressure, got
        self._order = plan.aline_order()
        self._plan_expected = 0
        self._blocks.clear()
        if plan.plan_id not in self._records:
            self._records[plan.plan_id] = {
                "plan": plan,
                "samples": np.zeros((plan.n_wavelengths, plan.n_points, plan.n_t), np.int16),
                "scale": np.zeros((plan.n_wavelengths, plan.n_points)),
                "dc": np.zeros((plan.n_wavelengths, plan.n_points)),
                "sent": np.zeros((plan.n_wavelengths, plan.n_points), bool)}
            self._record_order.append(plan.plan_id)
        if c.precompute:
            for bi in range(math.ceil(plan.n_alines / BLOCK)):
                self._blocks[bi] = done = Future[dict]()
                done.set_result(self._generate(plan, pressure, bi))
        else:
            self._blocks[0] = self._pool.submit(self._generate, plan, pressure, 0)

    def _cmd_plan_id(self, cmd: scpi.Command) -> bytes:
        return (self._plan.plan_id if self._plan else "NONE").encode()

    def _cmd_plan_hash(self, cmd: scpi.Command) -> bytes:
        return (self._plan_hash or "NONE").encode()

    def _cmd_plan_points(self, cmd: scpi.Command) -> bytes:
        return str(self._plan.n_points if self._plan else 0).encode()

    def _cmd_scan_start(self, cmd: scpi.Command) -> bytes:
        self._require_idle()
        if self._state == "FAULT" or self._interlock_until:
            raise _Error(101, "Laser interlock open")
        if self._plan is None:
            raise _Error(103, "No plan loaded")
        k = scpi.int_arg(cmd, 0) if cmd.args else 0
        if not 0 <= k < self._plan.n_alines:
            raise _Error(-222, f"Data out of range; start index {k} not in "
                               f"[0, {self._plan.n_alines})")
        self._block(k // BLOCK)
        self._clock_pending = True
        self._run_id += 1
        self._state = "RUNNING"
        self._next_k = self._run_from = k
        self._unacked.clear()
        self._resend.clear()
        self._resend_set.clear()
        self._window = INITIAL_WINDOW
        self._clock0 = self._last_fire = time.monotonic()
        self._last_tick = 0
        return f"{self._run_id},{self._next_seq}".encode()

    def _cmd_scan_pause(self, cmd: scpi.Command) -> None:
        if self._state == "RUNNING":
            self._state = "PAUSED"
        elif self._state != "PAUSED":
            raise _Error(-221, "Settings conflict; no scan running")

    def _cmd_scan_resume(self, cmd: scpi.Command) -> None:
        if self._state == "PAUSED":
            self._state = "RUNNING"
            self._clock0 = self._last_fire = time.monotonic()
            self._last_tick = 0
            self._run_from = self._next_k
        elif self._state != "RUNNING":
            raise _Error(-221, "Settings conflict; no paused scan")

    def _abort(self) -> None:
        if self._state != "FAULT" or not self._interlock_until:
            self._state = "IDLE"
        self._unacked.clear()
        self._resend.clear()
        self._resend_set.clear()
        self._ignoring_acks = False

    def _cmd_scan_abort(self, cmd: scpi.Command) -> None:
        self._abort()

    def _cmd_scan_status(self, cmd: scpi.Command) -> bytes:
        n = self._plan.n_alines if self._plan else 0
        return (f"{self._state},{self._boot_id},{self._run_id},{self._next_k},{n},"
                f"{self._next_seq},{len(self._unacked)}").encode()

    def _cmd_interlock(self, cmd: scpi.Command) -> bytes:
        return b"1" if self._interlock_until else b"0"

    # ------------------------------------------------------------------ record
    def write_record(self, path: str | os.PathLike) -> None:
        """Write the ground truth — every A-line as last sent, per plan — to HDF5.

        Layout: group ``/plans/<plan_id>`` with ``samples`` int16
        ``(n_wavelengths, n_points, n_t)``, ``scale``, ``offset``, ``dc_level``
        ``(n_wavelengths, n_points)`` (value = sample·scale + offset, in Pa·V; pressure =
        value/dc_level in Pa), ``sent`` bool ``(n_wavelengths, n_points)``, ``indices``
        ``(n_points, 2)``, ``wavelengths_m`` ``(n_wavelengths,)``, attributes ``dt_s``,
        ``n_t``; root attribute
        ``last_plan_id``. The file is replaced atomically.
        """
        import h5py

        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with self._lock:
            with h5py.File(tmp, "w") as f:
                for pid in self._record_order:
                    rec = self._records[pid]
                    g = f.create_group(f"plans/{pid}")
                    g.create_dataset("samples", data=rec["samples"])
                    g.create_dataset("scale", data=rec["scale"])
                    g.create_dataset("offset", data=np.zeros_like(rec["scale"]))
                    g.create_dataset("dc_level", data=rec["dc"])
                    g.create_dataset("sent", data=rec["sent"])
                    g.create_dataset("indices", data=rec["plan"].indices)
                    g.create_dataset("wavelengths_m", data=np.asarray(rec["plan"].wavelengths))
                    g.attrs["dt_s"] = rec["plan"].dt
                    g.attrs["n_t"] = rec["plan"].n_t
                f.attrs["last_plan_id"] = self._record_order[-1] if self._record_order else ""
                src = self.config.source  # set in __init__
                f.attrs["source"] = src.describe() if src is not None else ""
            os.replace(tmp, path)


def sensor_response(alines: np.ndarray, bandwidth: float, dt: float) -> np.ndarray:
    """The simulated FP sensor's frequency response: a causal 2nd-order Butterworth low-pass
    at ``bandwidth`` (−3 dB; clamped to 0.45 of the sampling rate), applied along time.

    Parameters
    ----------
    alines : ndarray, shape ``(..., n_t)``
        Samples, time last (any unit: the filter is linear).
    bandwidth : float
        The sensor's −3 dB frequency, Hz.
    dt : float
        Sample interval, s.

    Returns
    -------
    ndarray, shape ``(..., n_t)``, float64

    Raises
    ------
    ValueError
        ``bandwidth`` or ``dt`` not finite and > 0.

    Source: ``scipy.signal.butter`` (second-order sections) and ``sosfilt``; the module doc's
    signal model.
    """
    if not (np.isfinite(bandwidth) and bandwidth > 0 and np.isfinite(dt) and dt > 0):
        raise ValueError(f"bandwidth and dt must be finite and > 0, got {bandwidth!r} Hz, {dt!r} s")
    from scipy.signal import butter, sosfilt

    fc = min(bandwidth, 0.45 / dt)
    return sosfilt(butter(2, fc, fs=1 / dt, output="sos"), alines, axis=-1)


def _handlers() -> dict[str, Callable[[SimulatedScanner, scpi.Command], bytes | None]]:
    """Command dispatch on the canonical long header of each command of fpscan.driver.commands."""
    c, s = scpi, SimulatedScanner
    table = {
        c.IDN: s._cmd_idn, c.RESET: s._cmd_rst, c.CLEAR: s._cmd_cls, c.OPC: s._cmd_opc,
        c.SYST_ERROR: s._cmd_err, c.SYST_ERROR_NEXT: s._cmd_err,
        c.SYST_PROTOCOL: s._cmd_prot, c.SYST_BOOT: s._cmd_boot, c.SYST_LIMITS: s._cmd_lim,
        c.PLAN_BEGIN: s._cmd_plan_begin, c.PLAN_DATA: s._cmd_plan_data,
        c.PLAN_END: s._cmd_plan_end, c.PLAN_ID: s._cmd_plan_id, c.PLAN_HASH: s._cmd_plan_hash,
        c.PLAN_POINTS: s._cmd_plan_points, c.SCAN_START: s._cmd_scan_start,
        c.SCAN_PAUSE: s._cmd_scan_pause, c.SCAN_RESUME: s._cmd_scan_resume,
        c.SCAN_ABORT: s._cmd_scan_abort, c.SCAN_STATUS: s._cmd_scan_status,
        c.LASER_INTERLOCK: s._cmd_interlock,
    }
    return {c.canonical_header(k): v for k, v in table.items()}


_HANDLERS = _handlers()
