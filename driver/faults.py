"""Seeded fault injection for the simulated scanner (docs/protocol.md Appendix B).

A fault spec is a comma-separated list of ``key=value`` items (keys may repeat):

=================  =====================================================================
``corrupt=RATE``   probability per byte (both directions) that the byte is replaced
``drop=RATE``      probability per byte (both directions) that the byte is lost
``stall=K:SEC``    before acquiring point K (once), the device goes silent for SEC s
``reset=K``        before acquiring point K (once), the device resets (new boot id)
``interlock=K``    before acquiring point K (once), the laser interlock opens
``interlock=K:SEC``  … and closes again after SEC s
``seq=K:SEQ``      before acquiring point K (once), the data sequence skips to SEQ (a
                   firmware fault): that A-line is sent with seq SEQ (0 … 2³² − 1), the
                   next ones continue from SEQ + 1 (mod 2³²)
``point=K:P``      A-line K is sent (once) as point P (0 … 2³² − 1), a firmware fault
=================  =====================================================================

Example: ``corrupt=1e-4,drop=1e-4,stall=800:2,reset=1200``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FaultSpec", "damage"]


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
    resets : set[int]
        Points before which the device resets (once; new boot id).
    interlocks : dict[int, float]
        Point k -> seconds the laser interlock stays open from before acquiring it (once;
        ``inf``: until it is closed by hand).
    seq_skips : dict[int, int]
        Point k -> the data sequence number (u32) the device skips to before acquiring it
        (once): a device fault the host must stop at (docs/protocol.md §7).
    bad_points : dict[int, int]
        Point k -> the point index (u32) its A-line frame carries instead (once): a device
        fault too.
    """

    corrupt: float = 0.0
    drop: float = 0.0
    stalls: dict[int, float] = field(default_factory=dict)
    resets: set[int] = field(default_factory=set)
    interlocks: dict[int, float] = field(default_factory=dict)
    seq_skips: dict[int, int] = field(default_factory=dict)
    bad_points: dict[int, int] = field(default_factory=dict)

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
        elif key == "reset":
            if int(value) < 0:
                raise ValueError("K must be >= 0")
            self.resets.add(int(value))
        elif key == "interlock":
            k, _, sec = value.partition(":")
            seconds = float(sec) if sec else float("inf")
            if int(k) < 0 or not seconds > 0:
                raise ValueError("interlock needs K >= 0 and SEC > 0")
            self.interlocks[int(k)] = seconds
        elif key == "seq":
            k, _, seq = value.partition(":")
            if int(k) < 0 or not 0 <= int(seq) <= 0xFFFFFFFF:
                raise ValueError("seq needs K >= 0 and 0 <= SEQ <= 4294967295")
            self.seq_skips[int(k)] = int(seq)
        elif key == "point":
            k, _, point = value.partition(":")
            if int(k) < 0 or not 0 <= int(point) <= 0xFFFFFFFF:
                raise ValueError("point needs K >= 0 and 0 <= P <= 4294967295")
            self.bad_points[int(k)] = int(point)
        else:
            raise ValueError("unknown fault")

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
