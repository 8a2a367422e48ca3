"""Tests of protocol.topology and of the catalogue's frame builder.

Wire times are worked out by hand (8N1: 10 bits a character; Manchester: two chips a bit).
Golden frames are written byte by byte; their CRC-16/XMODEM is computed here with crcmod
directly (poly 0x1021, init 0, no reflection, no xorout), never by the code under test.
"""

from __future__ import annotations

import math
from fractions import Fraction

import crcmod
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.catalogue import NODES
from protocol.errors import FrameError, PayloadError
from protocol.interpret import candidate_nodes
from protocol.messages import CATALOGUE
from protocol.topology import (
    ADDR_BROADCAST,
    ADDR_F2,
    ADDR_F3,
    ADDR_FMCB,
    ADDR_HOST,
    ADDR_PALM,
    ARM_BUS_BAUD,
    ARM_JOINTS,
    ARM_MODEL_BY_ID,
    BITS_PER_CHAR,
    CAN_BITRATE,
    FINGERS,
    HOP_ADDRESS,
    HOP_NODE,
    HOST_LINK_BAUD,
    NODE_ADDRESS,
    POGO_BAUD,
    SERVO_IDS,
    STEPPER_IDS,
    TENDON_BAUD,
    TENDON_MANCHESTER,
    Hop,
    NodeKind,
    wire_time_us,
)

_XMODEM = crcmod.mkCrcFun(0x11021, initCrc=0x0000, rev=False, xorOut=0x0000)


def _with_crc(body: bytes) -> bytes:
    """``body`` followed by its CRC-16/XMODEM, little-endian."""
    return body + _XMODEM(body).to_bytes(2, "little")


# --- wire time ------------------------------------------------------------------------------


def test_bits_per_char_is_8n1() -> None:
    assert BITS_PER_CHAR == 10  # start + 8 data + stop


def test_a_148_byte_status_payload_at_2_mbaud_takes_740_us() -> None:
    # 148 × 10 bits / 2 000 000 bit/s = 740 µs.
    assert wire_time_us(148, 2_000_000) == 740


def test_the_framed_status_takes_775_us_and_twice_that_as_manchester_chips() -> None:
    # 148 + 7 = 155 bytes: 1550 bits at 2 Mbit/s = 775 µs; 3100 chips = 1550 µs.
    assert wire_time_us(155, 2_000_000) == 775
    assert wire_time_us(155, 2_000_000, manchester=True) == 1_550


def test_wire_time_on_the_arm_bus() -> None:
    # A 6-byte Dynamixel status packet at 1 Mbit/s: 60 bits → 60 µs.
    assert wire_time_us(6, ARM_BUS_BAUD) == 60


def test_wire_time_rounds_up_to_whole_microseconds() -> None:
    assert wire_time_us(0, 2_000_000) == 0
    assert wire_time_us(1, 2_000_000) == 5
    assert wire_time_us(1, 3_000_000) == 4  # 3.33 µs
    assert wire_time_us(1, 3_000_000, manchester=True) == 7  # 6.67 µs
    assert wire_time_us(3, 3_000_000) == 10  # exactly 10 µs: not rounded further
    assert wire_time_us(1, 57_600) == 174  # 173.6 µs


def test_wire_time_with_other_character_sizes() -> None:
    # 8E1 or 8N2: 11 bits a character.
    assert wire_time_us(10, 1_000_000, bits_per_char=11) == 110
    assert wire_time_us(10, 1_000_000, bits_per_char=11, manchester=True) == 220


@given(st.integers(0, 100_000), st.integers(1, 10_000_000), st.booleans())
def test_wire_time_is_the_exact_time_rounded_up(n_bytes: int, baud: int, manchester: bool
                                                ) -> None:
    exact = Fraction(n_bytes * 10 * (2 if manchester else 1) * 1_000_000, baud)
    assert wire_time_us(n_bytes, baud, manchester=manchester) == math.ceil(exact)


@given(st.integers(0, 100_000), st.integers(1, 10_000_000))
def test_manchester_is_the_time_of_twice_the_characters(n_bytes: int, baud: int) -> None:
    assert wire_time_us(n_bytes, baud, manchester=True) == wire_time_us(2 * n_bytes, baud)


# --- addresses, hops ------------------------------------------------------------------------


def test_addresses() -> None:
    assert (ADDR_HOST, ADDR_F2, ADDR_F3, ADDR_FMCB, ADDR_PALM, ADDR_BROADCAST) == (
        0, 1, 2, 10, 10, 0xFF,
    )
    assert NODE_ADDRESS == {"palm": 10, "fmcb": 10, "f2": 1, "f3": 2}


def test_hops() -> None:
    assert [(h.name, int(h)) for h in Hop] == [("FMCB", 0), ("F2", 1), ("F3", 2)]
    assert HOP_NODE == {0: "fmcb", 1: "f2", 2: "f3"}
    assert HOP_ADDRESS == {0: 10, 1: 1, 2: 2}
    assert FINGERS == 4


def test_node_kinds_are_the_catalogues() -> None:
    assert [str(k) for k in NodeKind] == ["palm", "fmcb", "f2", "f3"]
    assert NODES == ("common", "palm", "fmcb", "f2", "f3", "bootloader")


def test_interpret_candidates_follow_the_addresses() -> None:
    assert candidate_nodes(1) == ("f2", "bootloader")
    assert candidate_nodes(2) == ("f3", "bootloader")
    assert candidate_nodes(10) == ("fmcb", "palm", "bootloader")
    assert candidate_nodes(0) == candidate_nodes(0xFF) == candidate_nodes(7)


# --- arm ------------------------------------------------------------------------------------


def test_arm_ids_and_models() -> None:
    assert STEPPER_IDS == (1, 2, 3, 4)
    assert SERVO_IDS == (5, 6, 7)
    # Stepper nodes report 0x5E50; the RX-64 reports model 64.
    assert ARM_MODEL_BY_ID == {1: 0x5E50, 2: 0x5E50, 3: 0x5E50, 4: 0x5E50, 5: 64, 6: 64, 7: 64}
    assert [j.name for j in ARM_JOINTS] == ["J1", "J2", "J3", "J4", "J5", "J6", "J7"]
    assert [j.is_stepper for j in ARM_JOINTS] == [True] * 4 + [False] * 3


def test_link_rates() -> None:
    assert (HOST_LINK_BAUD, POGO_BAUD, TENDON_BAUD) == (2_000_000,) * 3
    assert TENDON_MANCHESTER
    assert (ARM_BUS_BAUD, CAN_BITRATE) == (1_000_000, 1_000_000)


# --- the frame builder ----------------------------------------------------------------------


def test_ping_request_frame_golden() -> None:
    # sync 42, address 0a, length 0000, type 01, no payload.
    assert CATALOGUE["ping"].request_frame(10) == _with_crc(bytes.fromhex("42 0a 00 00 01"))


def test_request_frame_with_keyword_fields_golden() -> None:
    # fmcb.phalange_power (0x1e), payload on = 01.
    assert CATALOGUE["fmcb.phalange_power"].request_frame(ADDR_FMCB, on=1) == _with_crc(
        bytes.fromhex("42 0a 01 00 1e 01"))


def test_request_frame_with_a_dict_and_keywords_golden() -> None:
    # palm.route (0x62): finger 02, hop 02, timeout 0014 (20 ms LE), then a ping to f3.
    inner = _with_crc(bytes.fromhex("42 02 00 00 01"))
    assert CATALOGUE["ping"].request_frame(HOP_ADDRESS[Hop.F3]) == inner
    frame = CATALOGUE["palm.route"].request_frame(
        ADDR_PALM, {"finger": 2, "hop": Hop.F3}, timeout_ms=20, frame=inner)
    assert frame == _with_crc(bytes.fromhex("42 0a 0b 00 62 02 02 14 00") + inner)


def test_reply_frame_goes_to_the_host_golden() -> None:
    # hw_version (0xfa) reply: version 0xBEEF0041 as u32 LE, to address 00.
    assert CATALOGUE["hw_version"].reply_frame(version=0xBEEF0041) == _with_crc(
        bytes.fromhex("42 00 04 00 fa 41 00 ef be"))


def test_frame_builder_errors() -> None:
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.effort_cap"].reply_frame(cap=1)  # the fmcb never answers it
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.phalange_power"].request_frame(10)  # field "on" missing
    with pytest.raises(FrameError):
        CATALOGUE["ping"].request_frame(0x100)
