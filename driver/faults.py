"""Seeded fault injection for the simulated scanner (docs/protocol.md Appendix B).

A fault spec is a comma-separated list of ``key=value`` items (keys may repeat):

=====================  =====================================================================
``corrupt=RATE``       probability per byte (both directions) that the byte is replaced
``drop=RATE``          probability per byte (both directions) that the byte is lost
``stall=K:SEC``        before acquiring point K (once), the device goes silent for SEC s
``reset=K``            before acquiring point K (once), the device resets (new boot id)
``reset=K:N``          … each of the first N times it comes to point K (N ≥ 1): a device that
                       resets at one point over and over (N = 1000: every time, in practice)
``stop=K``             before acquiring point K (once), the device ends its run (IDLE, no
                       ``EVENT DONE``) with A-lines missing, a firmware fault the host restarts
``stop=K:N``           … each of the first N times it comes to point K (N = 1000: every time)
``upload_reset=C``     on the C-th ``PLAN:DATA`` chunk of a plan upload (once), the device resets
``upload_reset=C:N``   … each of the first N uploads that come to chunk C (the chunk is lost)
``event=K:TEXT``       before acquiring point K (once), the device sends ``EVENT TEXT`` and
                       changes nothing (an event that does not hold: ``event=5:INTERLOCK 1``)
``interlock=K``        before acquiring point K (once), the laser interlock opens
``interlock=K:SEC``    … and closes again after SEC s
``seq=K:SEQ``          before acquiring point K (once), the data sequence skips to SEQ (a
                       firmware fault): that A-line is sent with seq SEQ (0 … 2³² − 1), the
                       next ones continue from SEQ + 1 (mod 2³²)
``point=K:P``          A-line K is sent (once) as point P (0 … 2³² − 1), a firmware fault
``ignore_acks=K``      from A-line K on (once), the device ignores ACK and NAK frames until the
                       run ends, a firmware fault: it resends its oldest unacknowledged A-line
                       every RTO and acquires nothing new once its window is full
``field=K:NAME:V``     A-line K is sent (once) with its field NAME set to V, a firmware fault:
                       NAME one of the A-line's float fields as on the wire (``timestamp``,
                       ``bias_wavelength``, ``dt``, ``scale``, ``offset``, ``dc_level``,
                       ``pulse_energy``, ``excitation_wavelength``; V a float, ``nan`` and
                       ``inf`` included) or ``sample`` (its first sample, V an int16)
=====================  =====================================================================

Example: ``corrupt=1e-4,drop=1e-4,stall=800:2,reset=1200``,
``field=40:dc_level:0``, ``reset=60:1000``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FIELD_NAMES", "FaultSpec", "damage"]

#: the A-line fields ``field=K:NAME:V`` may set (docs/protocol.md §5), by their wire names
FIELD_NAMES = ("timestamp", "bias_wavelength", "dt", "scale", "offset", "dc_level", "pulse_energy",
               "excitation_wavelength", "sample")


@dataclass
class FaultSpec:
    """Parsed fault spec; point indices are plan point indices k.

    Attributes
    ----------
    corrupt : float
        Probability per byte (both directions) that the byte is replaced, in [0, 1).
    drop : float
        Probability per byte (both directions) that the byte is lost, in [0, 1).
    stalls : dict[int, float]
        Point k -> seconds the device goes silent before acquiring it (once).
    resets : dict[int, int]
        Point k -> how many times the device resets (new boot id) when it comes to it.
    stops : dict[int, int]
        Point k -> how many times the device ends its run (IDLE) when it comes to it.
    upload_reset : tuple[int, int]
        ``(C, N)``: the device resets on the C-th ``PLAN:DATA`` chunk of each of the next N plan
        uploads that reach it (``(0, 0)``: never).
    events : dict[int, str]
        Point k -> the text of an ``EVENT`` frame the device sends before acquiring it, its state
        unchanged (once).
    interlocks : dict[int, float]
        Point k -> seconds the laser interlock stays open from before acquiring it (once;
        ``inf``: until it is closed by hand).
    seq_skips : dict[int, int]
        Point k -> the data sequence number (u32) the device skips to before acquiring it
        (once): a device fault the host must stop at (docs/protocol.md §7).
    bad_points : dict[int, int]
        Point k -> the point index (u32) its A-line frame carries instead (once): a device
        fault too.
    ignore_acks : set[int]
        A-lines from which on the device ignores ACKs and NAKs until the run ends (once).
    bad_fields : dict[int, tuple[str, float]]
        Point k -> (field name of :data:`FIELD_NAMES`, value) its A-line frame carries
        instead (once): a field out of its range is a device fault too.
    """

    corrupt: float = 0.0
    drop: float = 0.0
    stalls: dict[int, float] = field(default_factory=dict)
    resets: dict[int, int] = field(default_factory=dict)
    stops: dict[int, int] = field(default_factory=dict)
    events: dict[int, str] = field(default_factory=dict)
    upload_reset: tuple[int, int] = (0, 0)
    interlocks: dict[int, float] = field(default_factory=dict)
    seq_skips: dict[int, int] = field(default_factory=dict)
    bad_points: dict[int, int] = field(default_factory=dict)
    bad_fields: dict[int, tuple[str, float]] = field(default_factory=dict)
    ignore_acks: set[int] = field(default_factory=set)

    @classmethod
    def parse(cls, spec: str | None) -> FaultSpec:
        """Parse a spec string (see module doc). Raises ``ValueError`` with the bad item."""
        out = cls()
        if not spec:
            return out
        for item in spec.split(","):
            item = item.strip()
            if not item:
                continue
            key, sep, value = item.partition("=")
            key = key.strip().lower()
            try:
                if not sep:
                    raise ValueError("expected key=value")
                out._add(key, value)
            except ValueError as exc:
                raise ValueError(f"bad fault spec item {item!r}: {exc}") from None
        return out

    def _add(self, key: str, value: str) -> None:
        """Add one ``key=value`` item; raises ``ValueError`` with what is wrong."""
        if key in ("corrupt", "drop"):
            rate = float(value)
            if not 0.0 <= rate < 1.0:
                raise ValueError("rate must be in [0, 1)")
            setattr(self, key, rate)
        elif key == "stall":
            k, _, sec = value.partition(":")
            seconds = float(sec or 1.0)
            if int(k) < 0 or not 0 <= seconds <= 3600:
                raise ValueError("stall needs K >= 0 and 0 <= SEC <= 3600")
            self.stalls[int(k)] = seconds
        elif key in ("reset", "stop", "upload_reset", "event"):
            self._add_device_fault(key, value)
        elif key == "interlock":
            k, _, sec = value.partition(":")
            seconds = float(sec) if sec else float("inf")
            if int(k) < 0 or not seconds > 0:
                raise ValueError("interlock needs K >= 0 and SEC > 0")
            self.interlocks[int(k)] = seconds
        elif key in ("seq", "point"):  # K:SEQ, K:P: a u32 at A-line K
            k, _, number = value.partition(":")
            if int(k) < 0 or not 0 <= int(number) <= 0xFFFFFFFF:
                raise ValueError(f"{key} needs K >= 0 and 0 <= {'SEQ' if key == 'seq' else 'P'} <= 4294967295")
            (self.seq_skips if key == "seq" else self.bad_points)[int(k)] = int(number)
        elif key == "field":
            self._add_field(value)
        elif key == "ignore_acks":
            if int(value) < 0:
                raise ValueError("K must be >= 0")
            self.ignore_acks.add(int(value))
        else:
            raise ValueError("unknown fault")

    def _add_device_fault(self, key: str, value: str) -> None:
        """Add one ``reset``, ``stop``, ``upload_reset`` or ``event`` item; raises ``ValueError``."""
        at, _, rest = value.partition(":")
        if key == "event":
            if int(at) < 0 or not rest.strip() or len(rest) > 64 or not rest.isprintable():
                raise ValueError("event needs K >= 0 and a TEXT of 1-64 printable characters")
            self.events[int(at)] = rest.strip()
            return
        first = 1 if key == "upload_reset" else 0  # a chunk is counted from 1, a point from 0
        if int(at) < first or int(rest or 1) < 1:
            raise ValueError(f"{key} needs {'C' if first else 'K'} >= {first} and N >= 1")
        if key == "upload_reset":
            self.upload_reset = (int(at), int(rest or 1))
        else:
            (self.resets if key == "reset" else self.stops)[int(at)] = int(rest or 1)

    def _add_field(self, value: str) -> None:
        """Add one ``field=K:NAME:V`` item; raises ``ValueError`` with what is wrong."""
        k, _, rest = value.partition(":")
        name, _, v = rest.partition(":")
        if int(k) < 0 or name not in FIELD_NAMES:
            raise ValueError(f"field needs K >= 0 and a NAME of {', '.join(FIELD_NAMES)}")
        number = float(v)
        if name == "sample" and not (number.is_integer() and -32768 <= number <= 32767):
            raise ValueError("a sample is an int16")
        self.bad_fields[int(k)] = (name, number)

    @property
    def damages_bytes(self) -> bool:
        return self.corrupt > 0 or self.drop > 0


def damage(data: bytes, corrupt: float, drop: float, rng: np.random.Generator) -> bytes:
    """Return ``data`` with bytes replaced (rate ``corrupt``) and removed (rate ``drop``).

    Parameters
    ----------
    data : bytes
        The bytes on the wire.
    corrupt : float
        Probability per byte that it is replaced (XOR with a random non-zero byte).
    drop : float
        Probability per byte that it is removed.
    rng : numpy.random.Generator
        The seeded generator that draws the faults.

    Returns
    -------
    bytes
        The damaged bytes (``data`` itself when nothing is hit).
    """
    n = len(data)
    if n == 0:
        return data
    n_bad = rng.binomial(n, corrupt) if corrupt else 0
    n_drop = rng.binomial(n, drop) if drop else 0
    if not n_bad and not n_drop:
        return data
    buf = bytearray(data)
    for pos, x in zip(rng.integers(0, n, n_bad), rng.integers(1, 256, n_bad)):
        buf[pos] ^= int(x)
    if n_drop:
        for pos in sorted(set(rng.integers(0, n, n_drop).tolist()), reverse=True):
            del buf[pos]
    return bytes(buf)
