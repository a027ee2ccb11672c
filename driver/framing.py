"""Link-layer framing of the FP scanner protocol (docs/protocol.md §2).

A frame on the wire is ``COBS(header ‖ payload ‖ CRC-32) ‖ 0x00``:

* header (12 bytes, little-endian, ``struct`` format ``<BBHII``): protocol version (u8),
  frame type (u8, :class:`FrameType`), window (u16, credit window in frames, host→device),
  seq (u32, sequence number), ack (u32, cumulative acknowledgement);
* payload: 0 … :data:`MAX_PAYLOAD` bytes;
* CRC-32 (IEEE 802.3 polynomial, as ``zlib.crc32``) of header ‖ payload, u32 little-endian.

COBS (Cheshire & Baker, IEEE/ACM Trans. Networking 7(2), 1999) removes every 0x00 from the
body so that 0x00 delimits frames; a receiver resynchronises at the next 0x00 after any
damage. The COBS codec is the ``cobs`` package (C implementation).
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

from cobs import cobs as _cobs

__all__ = [
    "PROTOCOL_VERSION", "HEADER", "CRC", "MAX_PAYLOAD", "MAX_WIRE", "FrameType", "FrameError", "Frame",
    "encode_frame", "decode_frame", "Deframer",
]

#: protocol version (docs/protocol.md §12): 2 adds the wavelength to A-lines and plan images
PROTOCOL_VERSION = 2
HEADER = struct.Struct("<BBHII")
CRC = struct.Struct("<I")
#: largest payload accepted (an A-line of 32768 int16 samples plus its header fits)
MAX_PAYLOAD = 65536 + 256
#: largest encoded frame (COBS adds one byte per 254 plus one, then the delimiter)
MAX_WIRE = MAX_PAYLOAD + HEADER.size + CRC.size + (MAX_PAYLOAD // 254) + 8


class FrameType(IntEnum):
    """Frame types (docs/protocol.md §2.3).

    Attributes
    ----------
    CMD : int
        1, host → device: one SCPI command (ASCII, may end in a binary block).
    RSP : int
        2, device → host: success reply to the CMD whose seq is in ``ack``.
    ERR : int
        3, device → host: failure reply ``<code>,"<message>"`` to the CMD in ``ack``.
    ALINE : int
        4, device → host: one A-line, ``seq`` = data sequence number.
    ACK : int
        5, host → device: ``ack`` = next expected data seq, ``window`` = credit.
    NAK : int
        6, host → device: like ACK plus payload = missing data seqs (u32 LE each).
    EVENT : int
        7, device → host: unsolicited notice (ASCII), e.g. ``BOOT 1234``.
    """

    CMD = 1  #: host → device: one SCPI command (ASCII, may end in a binary block)
    RSP = 2  #: device → host: success reply to the CMD whose seq is in ``ack``
    ERR = 3  #: device → host: failure reply ``<code>,"<message>"`` to the CMD in ``ack``
    ALINE = 4  #: device → host: one A-line, ``seq`` = data sequence number
    ACK = 5  #: host → device: ``ack`` = next expected data seq, ``window`` = credit
    NAK = 6  #: host → device: like ACK plus payload = missing data seqs (u32 LE each)
    EVENT = 7  #: device → host: unsolicited notice (ASCII), e.g. ``BOOT 1234``


class FrameError(ValueError):
    """A received frame is malformed (COBS, length, CRC, version or type).

    Parameters
    ----------
    *args : str
        The reason (as ``ValueError``).
    """


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame. ``payload`` is ``bytes``; integers are as in the header.

    Attributes
    ----------
    type : int
        The frame type (:class:`FrameType`).
    seq : int
        Sequence number (u32).
    ack : int
        Cumulative acknowledgement (u32).
    window : int
        Credit window in frames (u16, host → device).
    payload : bytes
        The payload, 0 … :data:`MAX_PAYLOAD` bytes.
    """

    type: int
    seq: int = 0
    ack: int = 0
    window: int = 0
    payload: bytes = b""


def encode_frame(ftype: int, payload: bytes = b"", *, seq: int = 0, ack: int = 0,
                 window: int = 0) -> bytes:
    """Encode one frame for the wire, delimiter included.

    Raises ``ValueError`` if the payload exceeds :data:`MAX_PAYLOAD` or a header field is
    out of range.

    Parameters
    ----------
    ftype : int
        The frame type (:class:`FrameType`).
    payload : bytes, optional
        At most :data:`MAX_PAYLOAD` bytes (default empty).
    seq, ack : int, optional
        Sequence number and cumulative acknowledgement (taken modulo 2³²; default 0).
    window : int, optional
        Credit window in frames, 0 … 65535 (default 0).

    Returns
    -------
    bytes
        ``COBS(header ‖ payload ‖ CRC-32) ‖ 0x00``.

    Raises
    ------
    ValueError
        The payload is too long, or ``ftype`` or ``window`` does not fit its header field.
    """
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    try:
        head = HEADER.pack(PROTOCOL_VERSION, int(ftype), window, seq & 0xFFFFFFFF,
                           ack & 0xFFFFFFFF)
    except struct.error as exc:
        raise ValueError(f"frame header field out of range: {exc}") from None
    crc = zlib.crc32(payload, zlib.crc32(head))
    return _cobs.encode(head + payload + CRC.pack(crc)) + b"\x00"


def decode_frame(wire: bytes) -> Frame:
    """Decode one frame body (the bytes between two 0x00 delimiters).

    Raises :class:`FrameError` with the reason (bad COBS, too short, CRC mismatch, wrong
    version, unknown type).

    Parameters
    ----------
    wire : bytes
        The COBS-encoded frame without its delimiter.

    Returns
    -------
    Frame
        The decoded frame.

    Raises
    ------
    FrameError
        Bad COBS encoding, a body shorter than header + CRC or a payload over
        :data:`MAX_PAYLOAD`, a CRC mismatch, another protocol version or an unknown frame type.
    """
    try:
        body = _cobs.decode(wire)
    except _cobs.DecodeError as exc:
        raise FrameError(f"bad COBS encoding: {exc}") from None
    if len(body) < HEADER.size + CRC.size:
        raise FrameError(f"frame of {len(body)} bytes is shorter than header + CRC")
    if len(body) - HEADER.size - CRC.size > MAX_PAYLOAD:
        raise FrameError(f"payload of {len(body) - HEADER.size - CRC.size} bytes is over the {MAX_PAYLOAD} allowed")
    (crc,) = CRC.unpack_from(body, len(body) - 4)
    if zlib.crc32(memoryview(body)[:-4]) != crc:
        raise FrameError("CRC-32 mismatch")
    version, ftype, window, seq, ack = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError(f"protocol version {version} (expected {PROTOCOL_VERSION})")
    if ftype not in _TYPES:
        raise FrameError(f"unknown frame type {ftype}")
    return Frame(ftype, seq, ack, window, body[HEADER.size:-4])


_TYPES = frozenset(int(t) for t in FrameType)


class Deframer:
    """Incremental receiver: feed bytes, get the frames that decoded cleanly.

    Damaged frames are counted in :attr:`errors` (and the last reason kept in
    :attr:`last_error`) and skipped; the stream resynchronises at the next 0x00.
    A run of more than :data:`MAX_WIRE` bytes without a delimiter is discarded, up to its
    delimiter, however the bytes arrive (in one read or many: docs/protocol.md §2.1).

    Parameters
    ----------
    max_wire : int, optional
        The longest partial frame kept, bytes (default :data:`MAX_WIRE`).

    Attributes
    ----------
    errors : int
        Damaged or oversize frames so far.
    frames : int
        Frames decoded so far.
    last_error : str
        The reason of the last error ("" before any).
    """

    def __init__(self, max_wire: int = MAX_WIRE):
        self._buf = b""
        self._max = max_wire
        self._skipping = False  # inside an oversize run: its bytes are dropped up to its delimiter
        self.errors = 0
        self.frames = 0
        self.last_error = ""

    def feed(self, data: bytes) -> list[Frame]:
        if self._skipping:
            cut = data.find(b"\x00")
            if cut < 0:
                return []
            data, self._skipping = data[cut + 1:], False
        if not data:
            return []
        parts = (self._buf + data).split(b"\x00") if self._buf else data.split(b"\x00")
        self._buf = parts.pop()
        if len(self._buf) > self._max:
            self._oversize()
            self._buf, self._skipping = b"", True
        out = []
        for part in parts:
            if not part:
                continue
            if len(part) > self._max:
                self._oversize()
                continue
            try:
                out.append(decode_frame(part))
            except FrameError as exc:
                self.errors += 1
                self.last_error = str(exc)
        self.frames += len(out)
        return out

    def _oversize(self) -> None:
        self.errors += 1
        self.last_error = "oversize frame discarded"

    def reset(self) -> None:
        """Forget a partial frame (e.g. after a device reset)."""
        self._buf, self._skipping = b"", False
