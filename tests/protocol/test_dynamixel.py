"""Tests of protocol.dynamixel: golden bytes, decode errors, framing, the stream decoder,
unit conversions and a wire-format cross-check against the real dynamixel_sdk.

Every golden packet below was written by hand from the protocol facts; each checksum is
worked out in the comment next to it (CHK = ~(ID + LEN + INST/ERR + sum(P)) & 0xFF), never
produced by the code under test.
"""

from __future__ import annotations

import math

import dynamixel_sdk
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from protocol.dynamixel import (
    BROADCAST_ID,
    MAX_PARAMS,
    Direction,
    DynamixelStreamDecoder,
    ErrorBit,
    FrameKind,
    Instruction,
    InstructionPacket,
    StatusPacket,
    baud_register_to_bps,
    bps_to_baud_register,
    check_packet,
    decode_packet,
    encode_packet,
    fraction_to_rx64_load,
    guess_direction,
    make_action,
    make_bulk_read,
    make_ping,
    make_read,
    make_reg_write,
    make_reset,
    make_sync_write,
    make_write,
    parse_bulk_read,
    parse_read,
    parse_sync_write,
    parse_write,
    rad_s_to_rx64_present_speed,
    radians_to_rx64_position,
    rpm_to_rx64_speed,
    rx64_load_to_fraction,
    rx64_position_to_radians,
    rx64_present_speed_to_rad_s,
    rx64_speed_to_rpm,
)
from protocol.errors import DynamixelChecksumError, DynamixelError, ProtocolError

# e-Manual WRITE example: id 1, address 0x0C, data 64 AA (min voltage 10.0 V, max 17.0 V).
# 01+05+03+0C+64+AA = 1+5+3+12+100+170 = 291 = 0x123 -> ~0x23 = 0xDC
WRITE_EMANUAL = bytes.fromhex("FF FF 01 05 03 0C 64 AA DC")
# PING id 1: 01+02+01 = 4 -> ~0x04 = 0xFB
PING_1 = bytes.fromhex("FF FF 01 02 01 FB")
# empty status from id 1, no error: 01+02+00 = 3 -> ~0x03 = 0xFC
STATUS_1 = bytes.fromhex("FF FF 01 02 00 FC")
# READ id 1, address 0, 2 bytes (the model number, as dynamixel-sdk's ping does):
# 01+04+02+00+02 = 9 -> ~0x09 = 0xF6
READ_MODEL_1 = bytes.fromhex("FF FF 01 04 02 00 02 F6")
# its reply, model 64 = 40 00: 01+04+00+40+00 = 69 = 0x45 -> ~0x45 = 0xBA
STATUS_MODEL_64 = bytes.fromhex("FF FF 01 04 00 40 00 BA")
# status from id 1 with OVERLOAD (0x20): 01+02+20 = 35 = 0x23 -> ~0x23 = 0xDC
STATUS_OVERLOAD = bytes.fromhex("FF FF 01 02 20 DC")
# e-Manual SYNC_WRITE: address 0x1E, 4 bytes each to ids 0..3.  LEN 0x18 = 22 params + 2.
# FE+18+83+1E+04 = 254+24+131+30+4 = 443; id 0: 00+10+00+50+01 = 97; id 1: 01+20+02+60+03 =
# 134; id 2: 02+30+00+70+01 = 163; id 3: 03+20+02+80+03 = 168; total 1005 = 0x3ED
# -> ~0xED = 0x12
SYNC_WRITE_EMANUAL = bytes.fromhex(
    "FF FF FE 18 83 1E 04 00 10 00 50 01 01 20 02 60 03 02 30 00 70 01 03 20 02 80 03 12"
)
# BULK_READ (ours): 2 bytes at 0x1E of id 1, 4 bytes at 0x24 of id 2.  LEN 9 = 7 params + 2.
# FE+09+92+00+02+01+1E+04+02+24 = 254+9+146+0+2+1+30+4+2+36 = 484 = 0x1E4 -> ~0xE4 = 0x1B
BULK_READ_2 = bytes.fromhex("FF FF FE 09 92 00 02 01 1E 04 02 24 1B")
# ACTION broadcast: FE+02+05 = 261 = 0x105 -> ~0x05 = 0xFA
ACTION_ALL = bytes.fromhex("FF FF FE 02 05 FA")
# RESET id 1: 01+02+06 = 9 -> ~0x09 = 0xF6
RESET_1 = bytes.fromhex("FF FF 01 02 06 F6")
# REG_WRITE id 1, goal position (0x1E) = 512 = 00 02: 01+05+04+1E+00+02 = 42 = 0x2A -> 0xD5
REG_WRITE_GOAL = bytes.fromhex("FF FF 01 05 04 1E 00 02 D5")

SYNC_DATA = {
    0: bytes.fromhex("10 00 50 01"),
    1: bytes.fromhex("20 02 60 03"),
    2: bytes.fromhex("30 00 70 01"),
    3: bytes.fromhex("20 02 80 03"),
}


# --------------------------------------------------------------------------- golden bytes


@pytest.mark.parametrize(
    ("packet", "wire"),
    [
        (make_write(1, 0x0C, b"\x64\xaa"), WRITE_EMANUAL),
        (make_ping(1), PING_1),
        (make_read(1, 0, 2), READ_MODEL_1),
        (make_sync_write(0x1E, 4, SYNC_DATA), SYNC_WRITE_EMANUAL),
        (make_bulk_read([(2, 1, 0x1E), (4, 2, 0x24)]), BULK_READ_2),
        (make_action(), ACTION_ALL),
        (make_reset(1), RESET_1),
        (make_reg_write(1, 0x1E, b"\x00\x02"), REG_WRITE_GOAL),
        (StatusPacket(1), STATUS_1),
        (StatusPacket(1, 0, b"\x40\x00"), STATUS_MODEL_64),
        (StatusPacket(1, ErrorBit.OVERLOAD), STATUS_OVERLOAD),
    ],
)
def test_golden_encode_and_decode(packet: InstructionPacket | StatusPacket, wire: bytes) -> None:
    assert packet.encode() == wire
    assert type(packet).decode(wire) == packet


def test_golden_decoded_fields() -> None:
    write = InstructionPacket.decode(WRITE_EMANUAL)
    assert (write.id, write.instruction, write.params) == (1, Instruction.WRITE, b"\x0c\x64\xaa")
    assert isinstance(write.instruction, Instruction)
    assert parse_write(write.params) == (0x0C, b"\x64\xaa")
    assert parse_read(InstructionPacket.decode(READ_MODEL_1).params) == (0, 2)
    sync = InstructionPacket.decode(SYNC_WRITE_EMANUAL)
    assert sync.is_broadcast and sync.instruction == Instruction.SYNC_WRITE
    assert parse_sync_write(sync.params) == (0x1E, 4, SYNC_DATA)
    assert parse_bulk_read(InstructionPacket.decode(BULK_READ_2).params) == [
        (2, 1, 0x1E),
        (4, 2, 0x24),
    ]
    status = StatusPacket.decode(STATUS_MODEL_64)
    assert (status.id, status.error, status.params) == (1, 0, b"\x40\x00")
    assert StatusPacket.decode(STATUS_OVERLOAD).errors == ErrorBit.OVERLOAD
    assert decode_packet(PING_1) == (1, 1, b"")


def test_enum_values_are_the_documented_ones() -> None:
    assert [int(i) for i in Instruction] == [1, 2, 3, 4, 5, 6, 0x83, 0x92]
    assert [int(e) for e in ErrorBit] == [1, 2, 4, 8, 16, 32, 64]
    assert BROADCAST_ID == 0xFE


def test_unknown_instruction_is_kept_as_int() -> None:
    packet = InstructionPacket.decode(bytes.fromhex("FF FF 01 02 10 EC"))  # 1+2+16=19 -> 0xEC
    assert packet.instruction == 0x10 and not isinstance(packet.instruction, Instruction)


# --------------------------------------------------------------------------- decode errors


@pytest.mark.parametrize(
    ("wire", "match"),
    [
        (b"", "at least 6"),
        (bytes.fromhex("FF FF 01 02 01"), "at least 6"),
        (bytes.fromhex("FF FE 01 02 01 FB"), "not ff ff"),
        (bytes.fromhex("FF FF FF 02 01 FB"), "not ff ff"),
        (bytes.fromhex("FF FF 01 01 01 FC"), "LEN 1"),
        (bytes.fromhex("FF FF 01 FB 01 02 03"), "LEN 251"),
        (PING_1 + b"\x00", "means 6 bytes, got 7"),
        (WRITE_EMANUAL[:-2] + WRITE_EMANUAL[-1:], "means 9 bytes, got 8"),
    ],
)
def test_decode_malformed(wire: bytes, match: str) -> None:
    with pytest.raises(DynamixelError, match=match) as info:
        decode_packet(wire)
    assert not isinstance(info.value, DynamixelChecksumError)


def test_decode_bad_checksum_is_a_checksum_error_with_both_values() -> None:
    with pytest.raises(DynamixelChecksumError, match="0xDD != 0xDC") as info:
        InstructionPacket.decode(WRITE_EMANUAL[:-1] + b"\xdd")
    assert isinstance(info.value, DynamixelError)
    assert isinstance(info.value, ProtocolError) and isinstance(info.value, ValueError)


def test_status_decode_rejects_bit7_and_broadcast_id() -> None:
    with pytest.raises(DynamixelError, match="bit 7"):
        StatusPacket.decode(bytes.fromhex("FF FF 01 02 80 7C"))  # 1+2+0x80=0x83 -> 0x7C
    with pytest.raises(DynamixelError, match="status packet id 254"):
        StatusPacket.decode(ACTION_ALL)


# --------------------------------------------------------------------------- builders


@pytest.mark.parametrize(
    "build",
    [
        lambda: make_ping(0xFF),
        lambda: make_ping(-1),
        lambda: make_read(1, 256, 1),
        lambda: make_read(1, 0, 0),
        lambda: make_read(1, 0, MAX_PARAMS + 1),
        lambda: make_write(1, 0, b""),
        lambda: make_write(1, 0, bytes(MAX_PARAMS)),
        lambda: make_sync_write(30, 2, {}),
        lambda: make_sync_write(30, 2, {1: b"\x00"}),
        lambda: make_sync_write(30, 2, {BROADCAST_ID: b"\x00\x00"}),
        lambda: make_sync_write(30, 4, {i: bytes(4) for i in range(60)}),
        lambda: make_bulk_read([]),
        lambda: make_bulk_read([(0, 1, 30)]),
        lambda: InstructionPacket(1, 256),
        lambda: StatusPacket(1, 0, bytes(MAX_PARAMS + 1)),
    ],
)
def test_builders_reject_bad_arguments(build: object) -> None:
    with pytest.raises(DynamixelError):
        build()  # type: ignore[operator]


def test_largest_packets_fit() -> None:
    write = make_write(1, 0, bytes(MAX_PARAMS - 1))
    assert write.encode()[3] == 250 and len(write.encode()) == 254
    # 2 + 49 * 5 = 247 parameter bytes
    sync = make_sync_write(30, 4, {i: bytes(4) for i in range(49)})
    assert len(parse_sync_write(sync.params)[2]) == 49


@pytest.mark.parametrize(
    ("parse", "params", "match"),
    [
        (parse_read, b"\x00", "read"),
        (parse_read, b"\x00\x00", "read"),
        (parse_write, b"\x1e", "write"),
        (parse_sync_write, b"\x1e", "sync write"),
        (parse_sync_write, b"\x1e\x02\x01\x00", "sync write"),  # truncated entry
        (parse_sync_write, b"\x1e\x01\x01\x00\x01\x05", "twice"),
        (parse_bulk_read, b"\x01\x02\x01\x1e", "bulk read"),  # first byte must be 0
        (parse_bulk_read, b"\x00\x02\x01", "bulk read"),
    ],
)
def test_parsers_reject_malformed_params(parse: object, params: bytes, match: str) -> None:
    with pytest.raises(DynamixelError, match=match):
        parse(params)  # type: ignore[operator]


# --------------------------------------------------------------------------- check_packet


@pytest.mark.parametrize(
    ("buf", "start", "expected"),
    [
        (b"", 0, (FrameKind.NEED_MORE, 6)),
        (b"\xff", 0, (FrameKind.NEED_MORE, 5)),
        (b"\xff\xff\x01", 0, (FrameKind.NEED_MORE, 3)),
        (b"\xff\xff\x01\x05\x03", 0, (FrameKind.NEED_MORE, 4)),  # LEN 5: 9 bytes in all
        (b"\x00\x01\x02", 0, (FrameKind.DISCARD, 3)),
        (b"\x00\x01\xff", 0, (FrameKind.DISCARD, 2)),  # keep a trailing FF
        (b"\x00\xff\xff\x01", 0, (FrameKind.DISCARD, 1)),
        (b"\xff\x00\xff\xff", 0, (FrameKind.DISCARD, 2)),
        (b"\xff\xff\xff\xff" + PING_1[2:], 0, (FrameKind.DISCARD, 2)),  # FF run: last pair
        (b"\xff\xff\x01\x01\x01\xfc", 0, (FrameKind.DISCARD, 6)),  # LEN 1
        (b"\xff\xff\x01\xfb", 0, (FrameKind.DISCARD, 4)),  # LEN 251
        (PING_1[:-1] + b"\x00", 0, (FrameKind.BAD_CHECKSUM, 6)),
        (PING_1, 0, (FrameKind.PACKET, 6)),
        (b"\x00" + PING_1, 1, (FrameKind.PACKET, 6)),
        (memoryview(WRITE_EMANUAL + PING_1), 9, (FrameKind.PACKET, 6)),
        (PING_1, 6, (FrameKind.NEED_MORE, 6)),
    ],
)
def test_check_packet_outcomes(
    buf: bytes | memoryview, start: int, expected: tuple[FrameKind, int]
) -> None:
    assert check_packet(buf, start) == expected


def test_check_packet_refuses_a_start_outside_the_buffer() -> None:
    with pytest.raises(ValueError):
        check_packet(PING_1, 7)


def test_bad_checksum_rescans_inside_the_candidate() -> None:
    # A corrupted packet whose parameters hide a valid PING: the scan must restart right
    # after the candidate's first FF, find nothing at +1 and then the hidden ping.
    # outer: FF FF 01 08 03 <FF FF 01 02 01 FB> CHK(wrong=00)
    outer = b"\xff\xff\x01\x08\x03" + PING_1 + b"\x00"
    assert check_packet(outer) == (FrameKind.BAD_CHECKSUM, 5)
    assert check_packet(outer, 5) == (FrameKind.PACKET, 6)


# --------------------------------------------------------------------------- stream decoder


def test_decoder_offsets_counters_and_classification() -> None:
    stream = b"\x00\x13" + PING_1 + STATUS_MODEL_64 + PING_1[:-1] + b"\x00" + SYNC_WRITE_EMANUAL
    decoder = DynamixelStreamDecoder()
    found = decoder.feed(stream, t=1.5)
    assert [(p.offset, p.raw, p.is_status) for p in found] == [
        (2, PING_1, False),
        (8, STATUS_MODEL_64, True),
        (22, SYNC_WRITE_EMANUAL, False),
    ]
    assert found[1].packet == StatusPacket(1, 0, b"\x40\x00") and found[0].t == 1.5
    assert decoder.packets == 3 and decoder.checksum_failures == 1
    assert decoder.bytes_discarded == 2 + 6 and decoder.resyncs == 2
    assert decoder.pending == 0 and decoder.offset == len(stream)


def test_decoder_byte_at_a_time_keeps_half_packets() -> None:
    decoder = DynamixelStreamDecoder(direction="instruction")
    found = [p for byte in WRITE_EMANUAL + RESET_1 for p in decoder.feed(bytes([byte]))]
    assert [p.raw for p in found] == [WRITE_EMANUAL, RESET_1]
    assert decoder.bytes_discarded == 0 and decoder.resyncs == 0


def test_status_direction_rejects_what_no_servo_sends() -> None:
    decoder = DynamixelStreamDecoder(direction="status")
    found = decoder.feed(SYNC_WRITE_EMANUAL + STATUS_OVERLOAD + PING_1)
    # the sync write (ID FE, byte 4 = 0x83) is rejected; PING_1 is a valid status (error 1)
    assert [p.packet for p in found] == [StatusPacket(1, ErrorBit.OVERLOAD), StatusPacket(1, 1)]
    assert decoder.rejected == 1 and decoder.bytes_discarded == len(SYNC_WRITE_EMANUAL)


@pytest.mark.parametrize(
    ("wire", "expected"),
    [
        (PING_1, "instruction"),
        (READ_MODEL_1, "instruction"),
        (WRITE_EMANUAL, "instruction"),
        (SYNC_WRITE_EMANUAL, "instruction"),
        (ACTION_ALL, "instruction"),
        (STATUS_1, "status"),
        (STATUS_MODEL_64, "status"),
        (STATUS_OVERLOAD, "status"),
        # error 0x01 (input voltage) with 2 data bytes: not a PING shape -> status
        # 01+04+01+40+00 = 70 = 0x46 -> ~0x46 = 0xB9
        (bytes.fromhex("FF FF 01 04 01 40 00 B9"), "status"),
    ],
)
def test_guess_direction(wire: bytes, expected: str) -> None:
    assert guess_direction(wire) == expected


def test_gap_timeout_drops_a_stale_partial_packet() -> None:
    decoder = DynamixelStreamDecoder(gap_timeout=0.002)
    assert decoder.feed(WRITE_EMANUAL[:4], t=0.0) == []
    assert decoder.feed(WRITE_EMANUAL[4:], t=0.0015) != []  # within the gap: completes
    assert decoder.feed(WRITE_EMANUAL[:4], t=1.0) == []
    assert decoder.feed(PING_1, t=1.01)[0].raw == PING_1  # the stale half is dropped first
    assert decoder.gap_drops == 1 and decoder.bytes_discarded == 4
    untimed = DynamixelStreamDecoder(gap_timeout=0.002)
    untimed.feed(WRITE_EMANUAL[:4])
    assert untimed.feed(WRITE_EMANUAL[4:])[0].raw == WRITE_EMANUAL  # no t: no gap detection


def test_decoder_reset_and_bad_arguments() -> None:
    decoder = DynamixelStreamDecoder()
    decoder.feed(PING_1[:3])
    decoder.reset()
    assert decoder.pending == 0 and decoder.bytes_discarded == 3
    assert decoder.feed(PING_1)[0].offset == 3
    with pytest.raises(ValueError):
        DynamixelStreamDecoder(direction="sideways")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        DynamixelStreamDecoder(gap_timeout=-1.0)


# --------------------------------------------------------------------------- properties

instruction_packets = st.builds(
    InstructionPacket,
    id=st.integers(0, 0xFE),
    instruction=st.integers(0, 0xFF),
    params=st.binary(max_size=MAX_PARAMS),
)
status_packets = st.builds(
    StatusPacket,
    id=st.integers(0, 0xFD),
    error=st.integers(0, 0x7F),
    params=st.binary(max_size=MAX_PARAMS),
)
any_packets = st.one_of(instruction_packets, status_packets)


def _independent_checksum_ok(raw: bytes) -> bool:
    return (sum(raw[2:]) & 0xFF) == 0xFF  # ID+LEN+..+CHK is 0xFF when CHK = ~sum


@given(any_packets)
def test_packets_round_trip(packet: InstructionPacket | StatusPacket) -> None:
    raw = packet.encode()
    assert raw[:2] == b"\xff\xff" and raw[3] == len(packet.params) + 2
    assert len(raw) == len(packet.params) + 6 and _independent_checksum_ok(raw)
    assert type(packet).decode(raw) == packet
    assert check_packet(raw) == (FrameKind.PACKET, len(raw))


@settings(max_examples=300)
@given(st.binary(max_size=600), st.lists(st.integers(0, 600), max_size=8), st.data())
def test_decoder_never_raises_and_yields_only_valid_packets(
    stream: bytes, cuts: list[int], data: st.DataObject
) -> None:
    directions: list[Direction] = ["auto", "instruction", "status"]
    direction = data.draw(st.sampled_from(directions))
    spacing = data.draw(st.sampled_from([0.3, 1.0]))  # seconds between chunks
    decoder = DynamixelStreamDecoder(direction=direction, gap_timeout=0.5)
    bounds = sorted({0, len(stream), *(c for c in cuts if c < len(stream))})
    found = []
    for i, (a, b) in enumerate(zip(bounds, bounds[1:], strict=False)):
        found += decoder.feed(stream[a:b], t=i * spacing)
    for p in found:
        assert stream[p.offset : p.offset + len(p.raw)] == p.raw
        assert _independent_checksum_ok(p.raw)
        decode_packet(p.raw)
    assert decoder.packets == len(found)
    used = sum(len(p.raw) for p in found)
    assert used + decoder.bytes_discarded + decoder.pending == len(stream)


@settings(max_examples=200)
@given(
    st.lists(st.one_of(any_packets.map(lambda p: p.encode()), st.binary(max_size=12),
                       st.sampled_from([b"\xff", b"\xff\xff", b"\xff\xff\xff"])), max_size=8),
    st.integers(1, 30),
)
def test_decoded_packets_do_not_depend_on_chunking(pieces: list[bytes], step: int) -> None:
    stream = b"".join(pieces)
    whole = [(p.offset, p.raw) for p in DynamixelStreamDecoder().feed(stream)]
    decoder = DynamixelStreamDecoder()
    chunked = [(p.offset, p.raw) for i in range(0, len(stream), step)
               for p in decoder.feed(stream[i : i + step])]
    assert chunked == whole


garbage = st.binary(max_size=20).filter(lambda g: b"\xff\xff" not in g)


@settings(max_examples=300)
@given(st.lists(st.tuples(garbage, any_packets), max_size=6), garbage, st.data())
def test_packets_between_garbage_are_all_recovered(
    parts: list[tuple[bytes, InstructionPacket | StatusPacket]], tail: bytes, data: st.DataObject
) -> None:
    stream, expected = b"", []
    for junk, packet in parts:
        expected.append((len(stream) + len(junk), packet.encode()))
        stream += junk + packet.encode()
    stream += tail
    decoder = DynamixelStreamDecoder(direction="instruction")
    step = data.draw(st.integers(1, 40))
    found = [p for i in range(0, len(stream), step) for p in decoder.feed(stream[i : i + step])]
    assert [(p.offset, p.raw) for p in found] == expected


@given(any_packets, st.data())
def test_every_single_bit_flip_is_detected(
    packet: InstructionPacket | StatusPacket, data: st.DataObject
) -> None:
    # A one-byte sum detects every single-bit error: a flip changes one byte by +-2**k
    # (k < 8), which changes the sum modulo 256.  In the header it breaks FF FF; in LEN it
    # contradicts the packet's length (for a complete packet).
    raw = bytearray(packet.encode())
    bit = data.draw(st.integers(0, 8 * len(raw) - 1))
    raw[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(DynamixelError):
        decode_packet(bytes(raw))
    # In a stream, a flip outside LEN never yields a packet where the original one started.
    # (A flipped LEN moves the checksum position, and the byte found there can match.)
    assume(bit // 8 != 3)
    found = DynamixelStreamDecoder(direction="instruction").feed(bytes(raw))
    assert all(p.offset != 0 for p in found)


# --------------------------------------------------------------------------- unit conversions


def test_rx64_position_conversions() -> None:
    assert rx64_position_to_radians(512) == 0.0
    # 300 degrees over 1024 units: 0 is -150 degrees
    assert math.isclose(rx64_position_to_radians(0), -math.radians(150.0))
    assert math.isclose(rx64_position_to_radians(1023), math.radians(300.0 * 511 / 1024))
    assert radians_to_rx64_position(0.0) == 512
    assert radians_to_rx64_position(math.radians(90.0)) == 512 + 307  # 90 / (300/1024) = 307.2
    assert radians_to_rx64_position(10.0) == 1023 and radians_to_rx64_position(-10.0) == 0
    for units in range(1024):
        assert radians_to_rx64_position(rx64_position_to_radians(units)) == units


def test_rx64_speed_load_and_baud_conversions() -> None:
    assert math.isclose(rx64_speed_to_rpm(1023), 113.553)  # 1023 * 0.111
    assert rpm_to_rx64_speed(11.1) == 100 and rpm_to_rx64_speed(0.0) == 1
    assert rpm_to_rx64_speed(1000.0) == 1023
    one_rpm = 2 * math.pi / 60
    assert math.isclose(rx64_present_speed_to_rad_s(100), 11.1 * one_rpm)
    assert math.isclose(rx64_present_speed_to_rad_s(1024 + 100), -11.1 * one_rpm)
    assert rad_s_to_rx64_present_speed(-11.1 * one_rpm) == 1024 + 100
    assert rx64_load_to_fraction(1023) == 1.0 and rx64_load_to_fraction(1024 + 1023) == -1.0
    assert rx64_load_to_fraction(0) == 0.0 and rx64_load_to_fraction(1024) == 0.0
    assert fraction_to_rx64_load(-0.5) == 1024 + 512 and fraction_to_rx64_load(2.0) == 1023
    assert baud_register_to_bps(1) == 1_000_000 and baud_register_to_bps(3) == 500_000
    assert round(baud_register_to_bps(16)) == 117_647 and round(baud_register_to_bps(34)) == 57_143
    assert [bps_to_baud_register(b) for b in (1e6, 5e5, 115200, 57600)] == [1, 3, 16, 34]
    with pytest.raises(DynamixelError):
        baud_register_to_bps(255)


# --------------------------------------------------------------------------- dynamixel_sdk


class _CapturePort(dynamixel_sdk.PortHandler):  # type: ignore[misc]
    """A PortHandler without a serial port: captures writes, serves canned replies."""

    def __init__(self, replies: bytes = b"") -> None:
        super().__init__("capture://")
        self.is_open = True
        self.written = bytearray()
        self.replies = bytearray(replies)

    def clearPort(self) -> None:
        pass

    def writePort(self, packet: list[int]) -> int:
        self.written += bytes(packet)
        return len(packet)

    def readPort(self, length: int) -> bytes:
        out = bytes(self.replies[:length])
        del self.replies[:length]
        return out


def test_dynamixel_sdk_sends_what_the_builders_build() -> None:
    sdk = dynamixel_sdk
    handler = sdk.PacketHandler(1.0)
    cap = _CapturePort()
    assert handler.writeTxOnly(cap, 1, 0x0C, 2, [0x64, 0xAA]) == sdk.COMM_SUCCESS
    assert handler.readTx(cap, 1, 0, 2) == sdk.COMM_SUCCESS
    cap.is_using = False  # readTx leaves the port "in use", waiting for readRx
    assert handler.regWriteTxOnly(cap, 1, 0x1E, 2, [0x00, 0x02]) == sdk.COMM_SUCCESS
    assert handler.action(cap, BROADCAST_ID) == sdk.COMM_SUCCESS
    group = sdk.GroupSyncWrite(cap, handler, 0x1E, 4)
    for id_, value in SYNC_DATA.items():
        assert group.addParam(id_, list(value))
    assert group.txPacket() == sdk.COMM_SUCCESS
    params = [2, 1, 0x1E, 4, 2, 0x24]
    assert handler.bulkReadTx(cap, params, len(params)) == sdk.COMM_SUCCESS
    expected = [
        make_write(1, 0x0C, b"\x64\xaa"),
        make_read(1, 0, 2),
        make_reg_write(1, 0x1E, b"\x00\x02"),
        make_action(),
        make_sync_write(0x1E, 4, SYNC_DATA),
        make_bulk_read([(2, 1, 0x1E), (4, 2, 0x24)]),
    ]
    assert bytes(cap.written) == b"".join(p.encode() for p in expected)
    decoded = DynamixelStreamDecoder(direction="instruction").feed(bytes(cap.written))
    assert [p.packet for p in decoded] == expected


def test_dynamixel_sdk_accepts_our_status_packets() -> None:
    sdk = dynamixel_sdk
    handler = sdk.PacketHandler(1.0)
    model = StatusPacket(7, 0, (64).to_bytes(2, "little"))
    cap = _CapturePort(StatusPacket(7).encode() + model.encode())
    assert handler.ping(cap, 7) == (64, sdk.COMM_SUCCESS, 0)
    assert bytes(cap.written) == make_ping(7).encode() + make_read(7, 0, 2).encode()
    cap = _CapturePort(StatusPacket(7, ErrorBit.RANGE | ErrorBit.OVERLOAD).encode())
    assert handler.write2ByteTxRx(cap, 7, 30, 512) == (sdk.COMM_SUCCESS, 0x28)
    assert bytes(cap.written) == make_write(7, 30, (512).to_bytes(2, "little")).encode()


@given(st.binary(max_size=40))
def test_sync_write_fast_parse_agrees_with_the_declaration(params: bytes) -> None:
    """The hand-written SYNC_WRITE parser accepts exactly what the construct declaration
    accepts (and gives the same entries), or raises DynamixelError."""
    from protocol.dynamixel import _SYNC_WRITE

    try:
        parsed = _SYNC_WRITE.parse(params)
        ids = [int(e.id) for e in parsed.entries]
        reference = None if len(params) < 2 or params[1] == 0 or len(set(ids)) != len(ids) \
            else (int(parsed.address), int(parsed.length),
                  {int(e.id): bytes(e.data) for e in parsed.entries})
    except Exception:  # noqa: BLE001 - any construct error means "rejected"
        reference = None
    if reference is None:
        with pytest.raises(DynamixelError):
            parse_sync_write(params)
    else:
        assert parse_sync_write(params) == reference


@given(st.binary(max_size=40))
def test_bulk_read_fast_parse_agrees_with_the_declaration(params: bytes) -> None:
    from protocol.dynamixel import _BULK_READ

    try:
        parsed = _BULK_READ.parse(params)
        reference = [(int(e.length), int(e.id), int(e.address)) for e in parsed.entries]
    except Exception:  # noqa: BLE001 - any construct error means "rejected"
        reference = None
    if reference is None:
        with pytest.raises(DynamixelError):
            parse_bulk_read(params)
    else:
        assert parse_bulk_read(params) == reference


@given(st.integers(0, 0xFE), st.integers(0, 0xFF), st.binary(max_size=MAX_PARAMS))
def test_hand_written_encoder_matches_the_declaration(id_: int, code: int, params: bytes) -> None:
    from protocol.dynamixel import PACKET, encode_packet

    body = {"value": {"id": id_, "code": code, "params": params}}
    assert encode_packet(id_, code, params) == PACKET.build({"body": body})


def _state(decoder: DynamixelStreamDecoder) -> tuple[object, ...]:
    return (decoder.packets, decoder.checksum_failures, decoder.resyncs,
            decoder.bytes_discarded, decoder.rejected, decoder.gap_drops, decoder.offset,
            decoder.pending)


def test_take_whole_decodes_a_whole_instruction_as_feed_does() -> None:
    fed, taken = (DynamixelStreamDecoder("instruction", gap_timeout=0.01) for _ in range(2))
    for k, wire in enumerate((WRITE_EMANUAL, PING_1, SYNC_WRITE_EMANUAL)):
        (decoded,) = fed.feed(wire, t=k * 1.0)
        packet = taken.take_whole(wire, t=k * 1.0)
        assert packet == decoded.packet and _state(taken) == _state(fed)
    # the arrival time counts as feed's: a half packet after it is dropped on the same gap
    for decoder in (fed, taken):
        decoder.feed(PING_1[:3], t=2.5)
        assert decoder.feed(PING_1, t=2.6)[0].raw == PING_1 and decoder.gap_drops == 1


def test_take_whole_shares_one_decoded_packet_between_decoders() -> None:
    first, second = DynamixelStreamDecoder("instruction"), DynamixelStreamDecoder("instruction")
    wire = make_bulk_read([(2, 5, 36), (2, 6, 36)]).encode()
    assert first.take_whole(wire) is second.take_whole(bytes(bytearray(wire)))


@pytest.mark.parametrize("wire", [
    PING_1[:-1] + bytes([PING_1[-1] ^ 1]),  # bad checksum
    PING_1 + PING_1,  # two packets
    PING_1[:5],  # half a packet
    b"\x00" + PING_1,  # a byte before the header
    bytes.fromhex("FF FF FF 02 01 FB"),  # ID 0xFF: a header byte
])
def test_take_whole_leaves_anything_but_one_whole_good_packet_to_feed(wire: bytes) -> None:
    decoder = DynamixelStreamDecoder("instruction")
    before = _state(decoder)
    assert decoder.take_whole(wire) is None and _state(decoder) == before


def test_take_whole_only_with_nothing_held_and_instructions() -> None:
    held = DynamixelStreamDecoder("instruction")
    held.feed(PING_1[:2])
    assert held.take_whole(PING_1) is None and held.pending == 2
    assert DynamixelStreamDecoder("status").take_whole(STATUS_1) is None


_PACKETS = st.builds(encode_packet, st.integers(0, 0xFE), st.integers(0, 0xFF),
                     st.binary(max_size=12))


@settings(deadline=None)
@given(st.binary(max_size=12) | _PACKETS, st.binary(max_size=40) | _PACKETS)
def test_take_whole_agrees_with_feed(first: bytes, wire: bytes) -> None:
    """Whatever came before, take_whole gives feed's one packet and state, or does nothing."""
    fed, taken = (DynamixelStreamDecoder("instruction") for _ in range(2))
    fed.feed(first)
    taken.feed(first)
    packet = taken.take_whole(wire, t=1.0)
    found = fed.feed(wire, t=1.0)
    if packet is not None:
        assert [d.packet for d in found] == [packet] and _state(taken) == _state(fed)


@given(st.integers(0, 255), st.integers(1, 8), st.data())
def test_the_hand_written_sync_write_builds_what_the_declaration_does(
        address: int, length: int, data: st.DataObject) -> None:
    from protocol.dynamixel import _SYNC_WRITE, MAX_ID

    ids = data.draw(st.lists(st.integers(0, MAX_ID), min_size=1, max_size=10, unique=True))
    entries = {i: data.draw(st.binary(min_size=length, max_size=length)) for i in ids}
    built = _SYNC_WRITE.build({"address": address, "length": length,
                               "entries": [{"id": i, "data": v} for i, v in entries.items()]})
    assert make_sync_write(address, length, entries).params == built
