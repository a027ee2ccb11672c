"""HDF5 superblocks written by hand, for tests of the readers' superblock checks: the
superblock checksum (HDF5's ``H5_checksum_lookup3``, Bob Jenkins' lookup3 ``hashlittle``),
implemented here apart from ``fpscan.driver.scanfile``'s own so that each checks the other,
and the file-consistency flags a killed SWMR writer leaves."""
from __future__ import annotations

_M = 0xFFFFFFFF

#: the superblock's file-consistency flags of a writer that has the file open for SWMR
#: writing (``H5F_SUPER_WRITE_ACCESS | H5F_SUPER_SWMR_WRITE_ACCESS``)
SWMR_WRITER_FLAGS = 0x05


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _M


def _mix(a: int, b: int, c: int) -> tuple[int, int, int]:
    a = (a - c) & _M; a ^= _rot(c, 4); c = (c + b) & _M
    b = (b - a) & _M; b ^= _rot(a, 6); a = (a + c) & _M
    c = (c - b) & _M; c ^= _rot(b, 8); b = (b + a) & _M
    a = (a - c) & _M; a ^= _rot(c, 16); c = (c + b) & _M
    b = (b - a) & _M; b ^= _rot(a, 19); a = (a + c) & _M
    c = (c - b) & _M; c ^= _rot(b, 4); b = (b + a) & _M
    return a, b, c


def _final(a: int, b: int, c: int) -> int:
    c ^= b; c = (c - _rot(b, 14)) & _M
    a ^= c; a = (a - _rot(c, 11)) & _M
    b ^= a; b = (b - _rot(a, 25)) & _M
    c ^= b; c = (c - _rot(b, 16)) & _M
    a ^= c; a = (a - _rot(c, 4)) & _M
    b ^= a; b = (b - _rot(a, 14)) & _M
    c ^= b; c = (c - _rot(b, 24)) & _M
    return c


def _words(block: bytes) -> tuple[int, int, int]:
    """Three little-endian 32-bit words of a 12-byte block."""
    x, y, z = (int.from_bytes(block[j:j + 4], "little") for j in (0, 4, 8))
    return x, y, z


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle`` of ``data`` (HDF5's metadata checksum)."""
    a = b = c = (0xDEADBEEF + len(data) + initval) & _M
    rest = data
    while len(rest) > 12:
        x, y, z = _words(rest[:12])
        a, b, c = _mix((a + x) & _M, (b + y) & _M, (c + z) & _M)
        rest = rest[12:]
    if not rest:
        return c
    x, y, z = _words(rest + bytes(12 - len(rest)))
    return _final((a + x) & _M, (b + y) & _M, (c + z) & _M)


def set_status_flags(src: bytearray, flags: int = SWMR_WRITER_FLAGS) -> None:
    """Set, in place, the file-consistency flags of the version 2/3 superblock at the start
    of ``src`` (an HDF5 file's bytes, written with ``libver='latest'``) and rewrite its
    checksum, as a writer does: the superblock stays valid."""
    assert src[8] in (2, 3), "a version 2/3 superblock (libver latest)"
    n = 12 + 4 * src[9]
    src[11] = flags
    src[n:n + 4] = lookup3(bytes(src[:n])).to_bytes(4, "little")
