"""Link layer: COBS framing, CRC-32, resynchronisation; SCPI syntax; plan image."""
from __future__ import annotations

import numpy as np
import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from fpscan.driver.aline import ALINE_HEADER, pack_aline, unpack_aline
from fpscan.driver.commands import ScpiError, block, canonical_header, parse_command
from fpscan.driver.framing import (
    MAX_PAYLOAD,
    MAX_WIRE,
    PROTOCOL_VERSION,
    Deframer,
    FrameError,
    FrameType,
    decode_frame,
    encode_frame,
)
from fpscan.driver.plan import load_plan, plan_id_of
from fpscan.driver.plan_image import parse_plan_image, plan_image
from tests.driver.driver_helpers import grid_plan


def crc32_bitwise(data: bytes) -> int:
    """Reference CRC-32 (IEEE 802.3, reflected 0xEDB88320), bit by bit."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def test_reference_crc_and_cobs_vectors():
    assert crc32_bitwise(b"123456789") == 0xCBF43926  # the standard check value
    # examples from Cheshire & Baker's COBS paper / the usual test vectors
    assert cobs.encode(b"\x00") == b"\x01\x01"
    assert cobs.encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"


@settings(max_examples=60, deadline=None)
@given(payload=st.binary(max_size=2000), ftype=st.sampled_from(list(FrameType)),
       seq=st.integers(0, 2**32 - 1), ack=st.integers(0, 2**32 - 1),
       window=st.integers(0, 65535))
def test_frame_roundtrip_and_wire_format(payload, ftype, seq, ack, window):
    wire = encode_frame(ftype, payload, seq=seq, ack=ack, window=window)
    assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
    body = cobs.decode(wire[:-1])
    assert body[0] == PROTOCOL_VERSION == 2 and body[1] == ftype
    assert int.from_bytes(body[2:4], "little") == window
    assert int.from_bytes(body[4:8], "little") == seq
    assert int.from_bytes(body[8:12], "little") == ack
    assert body[12:-4] == payload
    assert int.from_bytes(body[-4:], "little") == crc32_bitwise(body[:-4])
    fr = decode_frame(wire[:-1])
    assert (fr.type, fr.seq, fr.ack, fr.window, fr.payload) == (ftype, seq, ack, window, payload)


@settings(max_examples=60, deadline=None)
@given(payload=st.binary(min_size=1, max_size=600), pos=st.integers(0, 10**6),
       flip=st.integers(1, 255))
def test_any_corrupted_byte_is_rejected(payload, pos, flip):
    wire = bytearray(encode_frame(FrameType.RSP, payload)[:-1])
    i = pos % len(wire)
    wire[i] ^= flip
    if 0 in wire:  # the damage produced a delimiter: the receiver sees two fragments
        frames = Deframer().feed(bytes(wire) + b"\x00")
        assert frames == [] or all(f.payload != payload for f in frames)
    else:
        with pytest.raises(FrameError):
            decode_frame(bytes(wire))


def test_deframer_resynchronises_after_garbage_and_drops():
    good = [encode_frame(FrameType.EVENT, f"E{i}".encode()) for i in range(5)]
    damaged = bytearray(good[1])
    del damaged[3]  # a dropped byte
    stream = b"\x17garbage" + good[0] + bytes(damaged) + good[2] + good[3][:5] + good[4]
    d = Deframer()
    frames = []
    for i in range(0, len(stream), 7):  # arbitrary chunking
        frames += d.feed(stream[i:i + 7])
    # frame 1 lost its byte, frame 3 was cut and merged into frame 4, the garbage was
    # glued to frame 0: only frame 2 survives intact, and everything damaged is counted
    assert [f.payload for f in frames] == [b"E2"]
    assert d.errors == 3


def _oversize_wire(n_payload: int) -> bytes:
    """A frame of ``n_payload`` bytes, well formed but for its size (encode_frame refuses it)."""
    import struct
    import zlib

    body = struct.pack("<BBHII", PROTOCOL_VERSION, int(FrameType.EVENT), 0, 0, 0) + b"\x01" * n_payload
    return cobs.encode(body + struct.pack("<I", zlib.crc32(body))) + b"\x00"


@pytest.mark.parametrize("read", [None, 4096, 7])
def test_an_oversize_frame_is_discarded_however_it_is_read(read):
    """A run over MAX_WIRE bytes is discarded up to its delimiter whether it arrives in one read or
    many (docs/protocol.md §2.1; in one read it was decoded, payload and all), and the frame after it
    is received."""
    stream = _oversize_wire(MAX_PAYLOAD + 34_000) + encode_frame(FrameType.EVENT, b"after")
    assert len(stream) > MAX_WIRE
    d = Deframer()
    step = read or len(stream)
    frames = [f for i in range(0, len(stream), step) for f in d.feed(stream[i:i + step])]
    assert [f.payload for f in frames] == [b"after"]
    assert d.errors == 1 and d.last_error == "oversize frame discarded"
    with pytest.raises(FrameError, match=f"over the {MAX_PAYLOAD} allowed"):
        decode_frame(_oversize_wire(MAX_PAYLOAD + 1)[:-1])


def test_aline_payload_roundtrip():
    s = np.array([-32767, -1, 0, 1, 32767], np.int16)
    payload = pack_aline(7, 99, 1234, 10**10, 12.5, 1.55e-6, 8e-9, 1e-3, 0.5, 0.9, 0.02, s,
                         3, 8.5e-7)
    assert len(payload) == ALINE_HEADER.size + 10 == 98
    a = unpack_aline(payload)
    assert (a.run_id, a.boot_id, a.point_index, a.pulse_number) == (7, 99, 1234, 10**10)
    assert (a.wavelength_index, a.excitation_wavelength_m) == (3, 8.5e-7)
    assert a.meta()["wavelength_index"] == 3 and a.meta()["excitation_wavelength_m"] == 8.5e-7
    assert a.samples.tolist() == s.tolist()
    assert abs(a.dc_level - 0.9) < 1e-7 and a.meta()["scale"] == 1e-3
    with pytest.raises(ValueError, match="n_t"):
        unpack_aline(payload[:-2])


def test_scpi_headers_blocks_and_errors():
    assert canonical_header("scan:star") == "SCAN:START"
    assert canonical_header(":SYSTem:ERRor?") == "SYSTEM:ERROR?"
    c = parse_command(b"PLAN:DATA 4096," + block(b"\x00\x01#,\n"))
    assert c.name == "PLAN:DATA" and c.args == ["4096"] and c.block == b"\x00\x01#,\n"
    for bad, code in [(b"SCAN:FOO 1", -113), (b"\xff\xfe", -102), (b"PLAN:DATA 0,#9999abc", -161),
                      (b"SCAN:STAR 1,", -109), (b"X" * 5000, -223)]:
        with pytest.raises(ScpiError) as err:
            parse_command(bad)
        assert err.value.code == code


def test_plan_json_checks_and_image_roundtrip():
    plan = grid_plan(5, 4, n_t=128)
    assert plan_id_of(plan) == plan["id"]
    dp = parse_plan_image(plan_image(plan))
    assert dp.plan_id == plan["id"] and dp.n_points == 20 and dp.n_t == 128
    assert np.allclose(dp.positions(), plan["points"]["positions"], rtol=0, atol=1e-15)
    bad = grid_plan(5, 4)
    bad["points"]["indices"][3] = [9, 0]
    with pytest.raises(ValueError, match="outside the lattice"):
        load_plan(bad)
    bad = grid_plan(5, 4)
    bad["points"]["indices"][3] = bad["points"]["indices"][2]
    with pytest.raises(ValueError, match="duplicate"):
        load_plan(bad)
    with pytest.raises(ValueError, match="format"):
        load_plan({"format": "x"})
    with pytest.raises(ValueError, match="JSON"):
        load_plan("{not json")
    with pytest.raises(ValueError):
        parse_plan_image(plan_image(plan)[:-1])


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=3000), cut=st.integers(1, 500))
def test_deframer_and_parser_never_raise_on_garbage(data, cut):
    d = Deframer()
    for i in range(0, len(data), cut):
        for fr in d.feed(data[i:i + cut]):  # whatever decodes is a checked frame
            assert fr.type in set(FrameType)
    try:
        parse_command(data)
    except ScpiError as exc:
        assert exc.code < 0
