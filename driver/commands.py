"""SCPI-style command syntax of the FP scanner protocol (docs/protocol.md §3).

A command frame's payload is ``HEADER[ ARG[,ARG...]]`` in ASCII, where an argument is a
decimal number, a token, a quoted string, or an IEEE 488.2 definite-length block
``#<d><len><bytes>`` (binary-safe, used by ``PLAN:DATA``). Headers follow SCPI
(IEEE 488.2 / SCPI-1999): each node is accepted in its short form (the capitals of the
table below) or its long form, in any case, with an optional leading colon; ``*XXX``
common commands are literal.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "MAX_CHUNK", "MIN_CHUNK", "MAX_COMMAND", "IDN", "RESET", "CLEAR", "OPC", "SYST_ERROR", "SYST_ERROR_NEXT",
    "SYST_PROTOCOL", "SYST_BOOT", "SYST_LIMITS", "PLAN_BEGIN", "PLAN_DATA", "PLAN_END", "PLAN_ID",
    "PLAN_HASH", "PLAN_POINTS", "SCAN_START", "SCAN_PAUSE", "SCAN_RESUME", "SCAN_ABORT", "SCAN_STATUS",
    "LASER_INTERLOCK", "NODES", "ScpiError", "Command", "canonical_header", "parse_command", "int_arg",
    "plan_begin", "plan_data", "plan_end", "scan_start", "block", "error_of",
]

#: largest PLAN:DATA block, bytes
MAX_CHUNK = 4096
#: the least ``max_chunk`` a device may report (``SYST:LIM?``), bytes: every device takes
#: PLAN:DATA blocks this long, the host's smallest retry chunk (docs/protocol.md §3.3, §4)
MIN_CHUNK = 64
#: largest command payload, bytes
MAX_COMMAND = MAX_CHUNK + 256

# The commands the host sends, in their short forms (docs/protocol.md §3.3). The device
# side dispatches on their canonical long forms: ``canonical_header(SCAN_ABORT)`` is
# ``"SCAN:ABORT"``. Commands with arguments are built by the functions below.
IDN = "*IDN?"
RESET = "*RST"
CLEAR = "*CLS"
OPC = "*OPC?"
SYST_ERROR = "SYST:ERR?"
SYST_ERROR_NEXT = "SYST:ERR:NEXT?"
SYST_PROTOCOL = "SYST:PROT?"
SYST_BOOT = "SYST:BOOT?"
SYST_LIMITS = "SYST:LIM?"
PLAN_BEGIN = "PLAN:BEG"
PLAN_DATA = "PLAN:DATA"
PLAN_END = "PLAN:END"
PLAN_ID = "PLAN:ID?"
PLAN_HASH = "PLAN:HASH?"
PLAN_POINTS = "PLAN:POIN?"
SCAN_START = "SCAN:STAR"
SCAN_PAUSE = "SCAN:PAUS"
SCAN_RESUME = "SCAN:RES"
SCAN_ABORT = "SCAN:ABOR"
SCAN_STATUS = "SCAN:STAT?"
LASER_INTERLOCK = "LAS:INT?"

NODES = ["SYSTem", "ERRor", "NEXT", "PROTocol", "BOOT", "LIMits", "PLAN", "BEGin", "DATA",
         "END", "ID", "HASH", "POINts", "SCAN", "STARt", "PAUSe", "RESume", "ABORt",
         "STATus", "LASer", "INTerlock"]
_CANON: dict[str, str] = {}
for _node in NODES:
    _short = "".join(ch for ch in _node if ch.isupper())
    _CANON[_short] = _node.upper()
    _CANON[_node.upper()] = _node.upper()


class ScpiError(ValueError):
    """A command failed; ``code`` is the SCPI error number (negative: standard).

    Parameters
    ----------
    code : int
        The SCPI error number, e.g. -113 (undefined header).
    message : str
        The error queue text, ``"<description>; <detail>"``.

    Attributes
    ----------
    code : int
        As given.
    message : str
        As given (also the exception's text).
    """

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


@dataclass
class Command:
    """One parsed command payload (:func:`parse_command`).

    Attributes
    ----------
    header : str
        The header as received, e.g. ``"scan:star"``.
    name : str
        Its canonical long form, upper case, e.g. ``"SCAN:START"``.
    args : list of str
        The comma-separated arguments before any block, stripped of blanks.
    block : bytes or None
        The data of a trailing definite-length block (``PLAN:DATA``), else None.
    """

    header: str  #: as received
    name: str  #: canonical long form, upper case, e.g. ``SCAN:START``
    args: list[str]
    block: bytes | None = None


def canonical_header(header: str) -> str:
    """``scan:star`` → ``SCAN:START``. Raises :class:`ScpiError` (-113) if unknown.

    Parameters
    ----------
    header : str
        A header in short or long form, any case, with an optional leading colon and
        trailing ``?``; a ``*XXX`` common command is upper-cased only.

    Returns
    -------
    str
        The canonical long form, upper case (``?`` kept).

    Raises
    ------
    ScpiError
        -113 (undefined header) when a node is not in :data:`NODES`.
    """
    h = header.upper()
    if h.startswith("*"):
        return h
    query = h.endswith("?")
    nodes = h.lstrip(":").rstrip("?").split(":")
    try:
        out = ":".join(_CANON[n] for n in nodes)
    except KeyError:
        raise ScpiError(-113, f"Undefined header; {header}") from None
    return out + ("?" if query else "")


def parse_command(payload: bytes) -> Command:
    """Parse one command payload. Raises :class:`ScpiError` with the SCPI code.

    Parameters
    ----------
    payload : bytes
        ``HEADER[ ARG[,ARG...]]`` in ASCII, optionally ending in one definite-length block.

    Returns
    -------
    Command
        The header, its canonical name, the arguments and the block.

    Raises
    ------
    ScpiError
        -223 a payload over :data:`MAX_COMMAND` bytes; -102 a non-ASCII or malformed header;
        -113 an unknown header; -161 a bad block length field or a block shorter than its
        length; -108 data after the block; -104 a non-ASCII argument; -109 a trailing comma.
    """
    if len(payload) > MAX_COMMAND:
        raise ScpiError(-223, f"Too much data; command of {len(payload)} bytes")
    head, _, rest = payload.partition(b" ")
    head = head.rstrip(b"\r\n")
    try:
        header = head.decode("ascii")
    except UnicodeDecodeError:
        raise ScpiError(-102, "Syntax error; non-ASCII header") from None
    if not header or not all(ch.isalnum() or ch in "*:?" for ch in header):
        raise ScpiError(-102, f"Syntax error; bad header {header!r}")
    name = canonical_header(header)
    args: list[str] = []
    block = None
    rest = rest.lstrip(b" ")
    while rest:
        if rest[:1] == b"#":
            try:
                d = int(rest[1:2])
                length = int(rest[2:2 + d])
            except ValueError:
                raise ScpiError(-161, "Invalid block data; bad length field") from None
            if d < 1 or len(rest) < 2 + d + length:
                raise ScpiError(-161, "Invalid block data; block shorter than its length")
            block = bytes(rest[2 + d:2 + d + length])
            rest = rest[2 + d + length:].lstrip(b" ")
            if rest:
                raise ScpiError(-108, "Parameter not allowed; data after the block")
            break
        arg, sep, rest = rest.partition(b",")
        arg = arg.rstrip(b"\r\n")
        try:
            args.append(arg.decode("ascii").strip())
        except UnicodeDecodeError:
            raise ScpiError(-104, "Data type error; non-ASCII argument") from None
        rest = rest.lstrip(b" ")
        if sep and not rest:
            raise ScpiError(-109, "Missing parameter; trailing comma")
    return Command(header, name, args, block)


def int_arg(cmd: Command, i: int) -> int:
    """Argument ``i`` as an integer. Raises :class:`ScpiError` (-109 missing, -104 type).

    Parameters
    ----------
    cmd : Command
        The parsed command.
    i : int
        The argument's index (0-based).

    Returns
    -------
    int
        Its value.

    Raises
    ------
    ScpiError
        -109 when the command has no argument ``i``, -104 when it is not an integer.
    """
    if i >= len(cmd.args):
        raise ScpiError(-109, f"Missing parameter; {cmd.header} needs argument {i + 1}")
    try:
        return int(cmd.args[i])
    except ValueError:
        raise ScpiError(-104, f"Data type error; {cmd.args[i]!r} is not an integer") from None


def plan_begin(n_bytes: int) -> str:
    """``PLAN:BEG <n_bytes>``: start a plan upload of ``n_bytes``.

    Parameters
    ----------
    n_bytes : int
        Size of the plan image, bytes.

    Returns
    -------
    str
        The command text.
    """
    return f"{PLAN_BEGIN} {int(n_bytes)}"


def plan_data(offset: int, chunk: bytes) -> bytes:
    """``PLAN:DATA <offset>,#<block>``: one chunk of the plan image (binary-safe).

    Parameters
    ----------
    offset : int
        Byte offset of the chunk in the plan image.
    chunk : bytes
        The chunk (at most :data:`MAX_CHUNK` bytes for the device to take it).

    Returns
    -------
    bytes
        The command payload.
    """
    return f"{PLAN_DATA} {int(offset)},".encode() + block(chunk)


def plan_end(sha256_hex: str) -> str:
    """``PLAN:END <sha256 hex>``: finish the upload; the device checks the image's hash.

    Parameters
    ----------
    sha256_hex : str
        SHA-256 of the whole plan image, hex.

    Returns
    -------
    str
        The command text.
    """
    return f"{PLAN_END} {sha256_hex}"


def scan_start(index: int) -> str:
    """``SCAN:STAR <index>``: start a run at acquisition index ``index``.

    Parameters
    ----------
    index : int
        The first A-line (acquisition index, docs/protocol.md §4.1) of the run.

    Returns
    -------
    str
        The command text.
    """
    return f"{SCAN_START} {int(index)}"


def block(data: bytes) -> bytes:
    """Encode ``data`` as an IEEE 488.2 definite-length block ``#<d><len><data>``.

    Parameters
    ----------
    data : bytes
        The block's content.

    Returns
    -------
    bytes
        ``#``, the number of digits of the length, the length in decimal, then ``data``.
    """
    n = str(len(data)).encode()
    return b"#" + str(len(n)).encode() + n + data


def error_of(exc: Exception) -> tuple[int, str]:
    """The SCPI error queue entry ``(code, message)`` that reports ``exc``.

    Parameters
    ----------
    exc : Exception
        The failure of a command.

    Returns
    -------
    tuple of (int, str)
        A :class:`ScpiError`'s own code and message; otherwise ``-100`` (command error)
        and ``"Command error; <exc>"``.
    """
    if isinstance(exc, ScpiError):
        return exc.code, exc.message
    return -100, f"Command error; {exc}"
