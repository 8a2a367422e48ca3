"""Tests of protocol.framing: golden bytes, every check_frame outcome, parse errors, properties.

The golden frames below were written by hand from the wire facts (sync 0x42, address,
u16 LE length, type, payload, CRC-16/XMODEM u16 LE over sync..payload); their CRCs were
computed with the independent bitwise CRC of this file (``_bitwise_crc16_xmodem``), never by
the code under test.
"""

from __future__ import annotations

import construct as c
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.crc import crc16_xmodem, crc16_xmodem_fast
from protocol.errors import CrcError, FrameError, FrameLengthError, ProtocolError
from protocol.framing import (
    BAD_CRC,
    BAD_LENGTH,
    CRC_SIZE,
    DEFAULT_MAX_PAYLOAD,
    FRAME,
    HAND_FRAME,
    HEADER_SIZE,
    NEED_MORE,
    OUTCOME_NAMES,
    OVERHEAD,
    SKIP,
    SYNC,
    Frame,
    build_frame_construct,
    check_frame,
    encode_frame,
    parse_frame,
)
from protocol.topology import ADDR_FMCB


def _bitwise_crc16_xmodem(data: bytes) -> int:
    """Reference CRC-16/XMODEM: poly 0x1021, init 0, MSB first, no reflection, no xorout."""
    reg = 0
    for byte in data:
        reg ^= byte << 8
        for _ in range(8):
            if reg & 0x8000:
                reg = ((reg << 1) ^ 0x1021) & 0xFFFF
            else:
                reg = (reg << 1) & 0xFFFF
    return reg


# --- golden bytes ---------------------------------------------------------------------------

#: ping (type 0x01, empty payload) to address 10; CRC 0x2D61 sent low byte first.
GOLDEN_PING = bytes([0x42, 0x0A, 0x00, 0x00, 0x01, 0x61, 0x2D])
#: fmcb.phalange_power (type 0x1E) on=1 to address 10; CRC 0xE117.
GOLDEN_PHALANGE_POWER = bytes([0x42, 0x0A, 0x01, 0x00, 0x1E, 0x01, 0x17, 0xE1])
#: hw_version reply (type 0xFA) to the host, version 0xBEEF0041 LE; CRC 0x7F31.
GOLDEN_HW_VERSION_REPLY = bytes(
    [0x42, 0x00, 0x04, 0x00, 0xFA, 0x41, 0x00, 0xEF, 0xBE, 0x31, 0x7F]
)

GOLDEN = [
    (GOLDEN_PING, 0x0A, 0x01, b""),
    (GOLDEN_PHALANGE_POWER, 0x0A, 0x1E, b"\x01"),
    (GOLDEN_HW_VERSION_REPLY, 0x00, 0xFA, bytes([0x41, 0x00, 0xEF, 0xBE])),
]


def test_reference_crc_check_value() -> None:
    assert _bitwise_crc16_xmodem(b"123456789") == 0x31C3


def test_product_crc_check_value() -> None:
    assert crc16_xmodem(b"123456789") == 0x31C3
    assert crc16_xmodem(bytearray(b"123456789")) == 0x31C3
    assert crc16_xmodem(memoryview(b"123456789")) == 0x31C3
    assert crc16_xmodem_fast(b"123456789") == 0x31C3
    assert crc16_xmodem(b"") == 0


@given(st.binary(max_size=300))
def test_product_crc_matches_reference(data: bytes) -> None:
    assert crc16_xmodem(data) == _bitwise_crc16_xmodem(data)


def test_golden_crcs_by_reference_crc() -> None:
    # The literal CRC bytes of the golden frames agree with the bitwise reference.
    for frame, *_ in GOLDEN:
        want = _bitwise_crc16_xmodem(frame[:-2])
        assert frame[-2:] == bytes([want & 0xFF, want >> 8])
    assert _bitwise_crc16_xmodem(GOLDEN_PING[:-2]) == 0x2D61
    assert _bitwise_crc16_xmodem(GOLDEN_PHALANGE_POWER[:-2]) == 0xE117
    assert _bitwise_crc16_xmodem(GOLDEN_HW_VERSION_REPLY[:-2]) == 0x7F31


@pytest.mark.parametrize(("golden", "address", "msg_type", "payload"), GOLDEN)
def test_golden_encode(golden: bytes, address: int, msg_type: int, payload: bytes) -> None:
    assert encode_frame(address, msg_type, payload) == golden
    assert build_frame_construct(address, msg_type, payload) == golden


@pytest.mark.parametrize(("golden", "address", "msg_type", "payload"), GOLDEN)
def test_golden_parse(golden: bytes, address: int, msg_type: int, payload: bytes) -> None:
    frame = parse_frame(golden)
    assert (frame.address, frame.type, frame.payload) == (address, msg_type, payload)
    assert frame.crc_ok
    assert frame.size == len(golden)
    assert frame.to_bytes() == golden
    assert check_frame(golden) == (FRAME, len(golden))
    parsed = HAND_FRAME.parse(golden)
    assert parsed.body.value.address == address
    assert parsed.body.value.type == msg_type
    assert parsed.body.value.payload == payload
    assert parsed.crc == int.from_bytes(golden[-2:], "little")


def test_golden_messages_from_catalogue() -> None:
    from protocol.messages import CATALOGUE

    assert CATALOGUE["ping"].request_frame(ADDR_FMCB) == GOLDEN_PING
    assert CATALOGUE["fmcb.phalange_power"].request_frame(ADDR_FMCB, on=1) == (
        GOLDEN_PHALANGE_POWER
    )
    assert CATALOGUE["hw_version"].reply_frame(version=0xBEEF0041) == GOLDEN_HW_VERSION_REPLY


def test_constants() -> None:
    assert SYNC == 0x42
    assert (HEADER_SIZE, CRC_SIZE, OVERHEAD) == (5, 2, 7)
    assert DEFAULT_MAX_PAYLOAD == 1024 - 7
    assert set(OUTCOME_NAMES) == {NEED_MORE, FRAME, SKIP, BAD_LENGTH, BAD_CRC}
    assert len(set(OUTCOME_NAMES.values())) == 5


# --- check_frame: every outcome -------------------------------------------------------------


def test_check_need_more_empty_and_start_past_end() -> None:
    assert check_frame(b"") == (NEED_MORE, HEADER_SIZE)
    assert check_frame(GOLDEN_PING, start=len(GOLDEN_PING)) == (NEED_MORE, HEADER_SIZE)
    assert check_frame(GOLDEN_PING, start=100) == (NEED_MORE, HEADER_SIZE)


def test_check_need_more_every_prefix() -> None:
    frame = GOLDEN_HW_VERSION_REPLY
    for k in range(1, len(frame)):
        outcome, n = check_frame(frame[:k])
        assert outcome == NEED_MORE
        if k < HEADER_SIZE:
            assert n == HEADER_SIZE - k  # the header first
        else:
            assert n == len(frame) - k  # then the rest of the declared frame


def test_check_frame_ignores_trailing_bytes_and_honours_start() -> None:
    buf = b"\x00\x01" + GOLDEN_PING + b"\x42\x0a"
    assert check_frame(buf, 2) == (FRAME, len(GOLDEN_PING))
    assert check_frame(bytearray(buf), 2) == (FRAME, len(GOLDEN_PING))


def test_check_skip_up_to_next_sync() -> None:
    assert check_frame(b"\x00\x01\x02") == (SKIP, 3)
    assert check_frame(b"\x00\x01\x42\x00") == (SKIP, 2)
    assert check_frame(b"\x41" + GOLDEN_PING) == (SKIP, 1)
    assert check_frame(b"\x42\x00\x00\x42", start=1) == (SKIP, 2)
    # skip from a start offset counts from that offset
    assert check_frame(b"\x42\x10\x11\x12", start=1) == (SKIP, 3)


def test_check_bad_length() -> None:
    header = bytes([0x42, 0x0A]) + (DEFAULT_MAX_PAYLOAD + 1).to_bytes(2, "little") + b"\x01"
    assert check_frame(header) == (BAD_LENGTH, 1)
    at_bound = bytes([0x42, 0x0A]) + DEFAULT_MAX_PAYLOAD.to_bytes(2, "little") + b"\x01"
    assert check_frame(at_bound) == (NEED_MORE, DEFAULT_MAX_PAYLOAD + CRC_SIZE)
    # the bound is a parameter
    assert check_frame(GOLDEN_PHALANGE_POWER, max_payload=0) == (BAD_LENGTH, 1)
    assert check_frame(GOLDEN_PHALANGE_POWER, max_payload=1) == (FRAME, 8)
    assert check_frame(b"\x42\x00\xff\xff\x00") == (BAD_LENGTH, 1)


def test_check_bad_crc() -> None:
    bad = bytearray(GOLDEN_PING)
    bad[-1] ^= 0x01
    assert check_frame(bytes(bad)) == (BAD_CRC, 1)
    bad = bytearray(GOLDEN_PHALANGE_POWER)
    bad[5] = 0x00  # payload changed, CRC kept
    assert check_frame(bytes(bad)) == (BAD_CRC, 1)


def test_check_never_raises_on_odd_input_types() -> None:
    assert check_frame(bytearray()) == (NEED_MORE, HEADER_SIZE)
    assert check_frame(bytearray(b"\x42")) == (NEED_MORE, 4)


# --- parse_frame errors ---------------------------------------------------------------------


def test_parse_crc_error() -> None:
    bad = bytearray(GOLDEN_HW_VERSION_REPLY)
    bad[6] ^= 0x80
    with pytest.raises(CrcError) as info:
        parse_frame(bytes(bad))
    assert isinstance(info.value, FrameError)
    assert isinstance(info.value, ProtocolError)
    assert isinstance(info.value, ValueError)
    assert "CRC" in str(info.value)


def test_parse_length_error() -> None:
    with pytest.raises(FrameLengthError):
        parse_frame(GOLDEN_PHALANGE_POWER, max_payload=0)
    assert parse_frame(GOLDEN_PHALANGE_POWER, max_payload=1).payload == b"\x01"


@pytest.mark.parametrize(
    "data",
    [
        b"",
        GOLDEN_PING[:-1],  # shorter than the minimum
        b"\x41" + GOLDEN_PING[1:],  # wrong sync
        GOLDEN_PING + b"\x00",  # trailing byte
        GOLDEN_PHALANGE_POWER[:-1],  # truncated
        bytes([0x42, 0x0A, 0x05, 0x00, 0x01, 0x00, 0x00]),  # length says more than given
    ],
)
def test_parse_frame_errors(data: bytes) -> None:
    with pytest.raises(FrameError) as info:
        parse_frame(data)
    assert not isinstance(info.value, CrcError)


def test_parse_accepts_bytearray_and_memoryview() -> None:
    assert parse_frame(bytearray(GOLDEN_PING)).type == 1  # type: ignore[arg-type]
    assert parse_frame(memoryview(GOLDEN_PING)).type == 1  # type: ignore[arg-type]


# --- encode errors ----------------------------------------------------------------------------


@pytest.mark.parametrize(("address", "msg_type"), [(-1, 1), (256, 1), (10, -1), (10, 256)])
def test_encode_rejects_out_of_range(address: int, msg_type: int) -> None:
    with pytest.raises(FrameError):
        encode_frame(address, msg_type)
    with pytest.raises(FrameError):
        build_frame_construct(address, msg_type, b"")


def test_encode_rejects_oversized_payload() -> None:
    with pytest.raises(FrameLengthError):
        encode_frame(10, 1, bytes(0x10000))
    assert len(encode_frame(10, 1, bytes(0xFFFF))) == 0xFFFF + OVERHEAD


def test_frame_dataclass_defaults() -> None:
    frame = Frame(10, 1, b"")
    assert (frame.offset, frame.crc_ok, frame.t) == (0, True, None)
    assert frame.to_bytes() == GOLDEN_PING


# --- properties -----------------------------------------------------------------------------

addresses = st.integers(0, 0xFF)
types = st.integers(0, 0xFF)
payloads = st.binary(max_size=300)


@given(addresses, types, payloads)
def test_round_trip(address: int, msg_type: int, payload: bytes) -> None:
    wire = encode_frame(address, msg_type, payload)
    assert len(wire) == len(payload) + OVERHEAD
    assert wire[0] == SYNC
    assert wire[1] == address
    assert int.from_bytes(wire[2:4], "little") == len(payload)
    assert wire[4] == msg_type
    assert wire[5:-2] == payload
    assert int.from_bytes(wire[-2:], "little") == _bitwise_crc16_xmodem(wire[:-2])
    frame = parse_frame(wire)
    assert (frame.address, frame.type, frame.payload) == (address, msg_type, payload)
    assert check_frame(wire, 0, 0xFFFF) == (FRAME, len(wire))


@given(addresses, types, payloads)
def test_fast_path_agrees_with_construct_declaration(
    address: int, msg_type: int, payload: bytes
) -> None:
    wire = encode_frame(address, msg_type, payload)
    assert build_frame_construct(address, msg_type, payload) == wire
    parsed = HAND_FRAME.parse(wire)
    body = parsed.body.value
    assert (body.sync, body.address, body.length, body.type, bytes(body.payload)) == (
        bytes([SYNC]), address, len(payload), msg_type, payload,
    )
    assert parsed.body.data == wire[:-2]


def _corrupt(data: bytes, positions: list[int], xors: list[int]) -> bytes:
    out = bytearray(data)
    for pos, x in zip(positions, xors, strict=False):
        if out:
            out[pos % len(out)] ^= x
    return bytes(out)


@st.composite
def near_frames(draw: st.DrawFn) -> bytes:
    """Valid frames, possibly corrupted, truncated or extended: the interesting inputs."""
    wire = encode_frame(draw(addresses), draw(types), draw(st.binary(max_size=40)))
    choice = draw(st.integers(0, 3))
    if choice == 1:
        wire = _corrupt(wire, draw(st.lists(st.integers(0, 100), max_size=3)),
                        draw(st.lists(st.integers(1, 255), max_size=3)))
    elif choice == 2:
        wire = wire[: draw(st.integers(0, len(wire)))]
    elif choice == 3:
        wire = b"\x42" + draw(st.binary(max_size=50))
    return wire


@given(near_frames())
def test_check_frame_agrees_with_construct_declaration(buf: bytes) -> None:
    outcome, n = check_frame(buf, 0, 0xFFFF)
    if outcome == FRAME:
        parsed = HAND_FRAME.parse(buf[:n])
        body = parsed.body.value
        frame = parse_frame(buf[:n])
        assert (frame.address, frame.type, frame.payload) == (
            body.address, body.type, bytes(body.payload),
        )
    elif outcome == BAD_CRC:
        assert n == 1
        length = buf[2] | (buf[3] << 8)
        with pytest.raises(c.ChecksumError):
            HAND_FRAME.parse(buf[: length + OVERHEAD])
        with pytest.raises(CrcError):
            parse_frame(buf[: length + OVERHEAD])
    elif outcome == NEED_MORE:
        assert n >= 1
        with pytest.raises(c.StreamError):
            HAND_FRAME.parse(buf)
    elif outcome == SKIP:
        assert 1 <= n <= len(buf)
        assert buf[0] != SYNC
        assert SYNC not in buf[1:n]
        assert n == len(buf) or buf[n] == SYNC
    else:  # BAD_LENGTH cannot happen with a bound of 0xFFFF
        pytest.fail(f"unexpected outcome {OUTCOME_NAMES[outcome]}")


@given(st.binary(max_size=200), st.integers(0, 210), st.integers(0, 2000))
def test_check_frame_never_raises(buf: bytes, start: int, max_payload: int) -> None:
    outcome, n = check_frame(buf, start, max_payload)
    assert outcome in OUTCOME_NAMES
    assert n >= 1
    if outcome in (SKIP, FRAME):
        assert start + n <= len(buf)


@settings(max_examples=60)
@given(addresses, types, st.binary(max_size=64))
def test_every_single_bit_flip_is_rejected(address: int, msg_type: int, payload: bytes) -> None:
    wire = encode_frame(address, msg_type, payload)
    for bit in range(len(wire) * 8):
        flipped = bytearray(wire)
        flipped[bit // 8] ^= 1 << (bit % 8)
        data = bytes(flipped)
        byte = bit // 8
        # parse_frame rejects every flip, with the error the flipped field calls for.
        with pytest.raises(FrameError) as info:
            parse_frame(data)
        if byte == 0:
            assert not isinstance(info.value, CrcError)  # wrong sync
        elif byte in (2, 3):
            assert not isinstance(info.value, CrcError)  # length disagrees with the size
        else:
            assert isinstance(info.value, CrcError)  # CRC-16 catches every single-bit error
        outcome, n = check_frame(data, 0, 0xFFFF)
        assert (outcome, n) != (FRAME, len(wire))
        if byte == 0:
            assert outcome == SKIP
        elif byte in (2, 3):
            # a longer length waits for more; a shorter one checks a CRC over other bytes,
            # which can only by chance (2^-16) look like a different, shorter frame.
            assert outcome in (NEED_MORE, BAD_CRC) or (outcome == FRAME and n < len(wire))
            assert check_frame(data) != (FRAME, len(wire))
        else:
            assert outcome == BAD_CRC


def test_single_bit_flips_of_golden_frames() -> None:
    for wire, *_ in GOLDEN:
        for bit in range(len(wire) * 8):
            flipped = bytearray(wire)
            flipped[bit // 8] ^= 1 << (bit % 8)
            outcome, _n = check_frame(bytes(flipped))
            assert outcome != FRAME
            with pytest.raises(FrameError):
                parse_frame(bytes(flipped))
