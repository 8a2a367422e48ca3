"""Coded fields: IntEnum members on parse, member / int / name on build, unknown codes kept."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import construct as c
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.catalogue import REPLY, REQUEST, Catalogue, Message, describe_layout
from protocol.enum_field import EnumField
from protocol.errors import PayloadError
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import BootResult, BootState, ImageStatus, WriteStatus
from protocol.messages.common import Running, TxnStatus
from protocol.messages.fmcb import ControlMode
from protocol.messages.palm import FingerEvent, FingerPower, RouteStatus
from protocol.messages.slots import ConfirmBy, SlotEvent, SlotResult, SlotState
from protocol.topology import Hop


@dataclass(frozen=True)
class Case:
    """One coded field of one message: its fields around a code, and the golden bytes.

    ``golden`` holds the bytes for ``code``; ``offset`` is where the code's byte is.
    """

    message: str
    direction: str
    field: str
    code: enum.IntEnum
    fields: Callable[[Any], dict[str, Any]]
    golden: bytes
    offset: int


CASES = [
    Case("palm.route", REPLY, "status", RouteStatus.NO_REPLY,
         lambda v: {"finger": 1, "hop": 2, "status": v, "frame": b""},
         bytes([0x01, 0x02, 0x01]), 2),
    Case("palm.route", REQUEST, "hop", Hop.F3,
         lambda v: {"finger": 2, "hop": v, "timeout_ms": 20, "frame": b""},
         bytes([0x02, 0x02, 0x14, 0x00]), 1),
    Case("palm.finger_power", REQUEST, "state", FingerPower.FULL,
         lambda v: {"finger": 0xFF, "state": v, "stagger_ms": 100},
         bytes([0xFF, 0x02, 0x64, 0x00]), 1),
    Case("palm.finger_event", REPLY, "event", FingerEvent.BREAKER_TRIP,
         lambda v: {"finger": 3, "event": v, "time": 0x01020304},
         bytes([0x03, 0x02, 0x04, 0x03, 0x02, 0x01]), 1),
    Case("fmcb.control", REQUEST, "mode", ControlMode.JOINT_FIXED,
         lambda v: {"mode": v, "args": {"target": [1000, -1, 0]}},
         bytes([0x03, 0xE8, 0x03, 0xFF, 0xFF, 0x00, 0x00]), 0),
    Case("txn", REPLY, "status", TxnStatus.BUSY,
         lambda v: {"seq": 7, "board": BoardType.FMCB, "address": 10, "inner_type": 0x21,
                    "status": v, "inner": b""},
         bytes([0x07, 0x02, 0x0A, 0x21, 0x03]), 4),
    Case("txn", REPLY, "board", BoardType.F3,
         lambda v: {"seq": 7, "board": v, "address": 2, "inner_type": 0x10,
                    "status": TxnStatus.OK, "inner": b"\xab"},
         bytes([0x07, 0x04, 0x02, 0x10, 0x00, 0xAB]), 1),
    Case("identify", REPLY, "running", Running.BOOTLOADER,
         lambda v: {"board": BoardType.F2, "address": 1, "running": v,
                    "hw_version": 0xBEEF0041, "fw_version": {"major": 1, "minor": 2, "patch": 3},
                    "catalogue": bytes(range(8)), "uid": 0x12345678, "uptime_us": 5},
         bytes([0x03, 0x01, 0x00, 0x41, 0x00, 0xEF, 0xBE, 0x01, 0x02, 0x03, 0x00,
                0, 1, 2, 3, 4, 5, 6, 7, 0x78, 0x56, 0x34, 0x12, 0x05, 0x00, 0x00, 0x00]), 2),
    Case("bl.status", REPLY, "state", BootState.NO_VALID_IMAGE,
         lambda v: {"state": v, "image_status": ImageStatus.HASH_MISMATCH, "last_error": 3,
                    "last_page": 0xFFFFFFFF, "text": "x"},
         bytes([0x03, 0x04, 0x03, 0xFF, 0xFF, 0xFF, 0xFF, 0x01, 0x78]), 0),
    Case("bl.activate", REPLY, "image_status", ImageStatus.WRONG_BOARD,
         lambda v: {"status": BootResult.WRONG_BOARD, "image_status": v},
         bytes([0x04, 0x03]), 1),
    Case("bl.activate", REPLY, "status", BootResult.HASH_MISMATCH,
         lambda v: {"status": v, "image_status": ImageStatus.NOT_ACTIVATED},
         bytes([0x03, 0x05]), 0),
    Case("bl.write_page", REPLY, "status", WriteStatus.PAGE_PROTECTED,
         lambda v: {"page": 40, "status": v},
         bytes([0x28, 0x00, 0x00, 0x00, 0x02]), 4),
    Case("slot.swap", REQUEST, "confirm_by", ConfirmBy.APPLICATION,
         lambda v: {"sha256": bytes(range(32)), "confirm_by": v},
         bytes(range(32)) + bytes([0x01]), 32),
    Case("slot.confirm", REPLY, "status", SlotResult.NOT_IN_TRIAL,
         lambda v: {"status": v, "state": SlotState.TRIAL}, bytes([0x05, 0x03]), 0),
    Case("slot.confirm", REPLY, "state", SlotState.REVERTING,
         lambda v: {"status": SlotResult.OK, "state": v}, bytes([0x00, 0x04]), 1),
    Case("slot.info", REPLY, "event", SlotEvent.REVERTED,
         lambda v: {"primary_page": 32, "secondary_page": 524, "slot_pages": 492,
                    "state": SlotState.CONFIRMED, "event": v, "confirm_by": ConfirmBy.HOST,
                    "swap_pages": 14, "swap_done": 14, "primary_status": ImageStatus.VALID,
                    "primary_version": {"major": 1, "minor": 0, "patch": 0},
                    "primary_sha256": b"\xaa" * 32, "secondary_status": ImageStatus.VALID,
                    "secondary_version": {"major": 2, "minor": 0, "patch": 0},
                    "secondary_sha256": b"\xbb" * 32},
         bytes([0x20, 0x00, 0x0C, 0x02, 0xEC, 0x01, 0x00, 0x03, 0x00, 0x0E, 0x00, 0x0E, 0x00,
                0x00, 0x01, 0x00, 0x00, 0x00]) + b"\xaa" * 32
         + bytes([0x00, 0x02, 0x00, 0x00, 0x00]) + b"\xbb" * 32, 7),
]
IDS = [f"{case.message}.{case.field}" for case in CASES]


def _msg(case: Case) -> Message:
    return CATALOGUE[case.message]


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_golden_bytes_from_a_member_an_int_or_a_name(case: Case) -> None:
    msg = _msg(case)
    for value in (case.code, int(case.code), case.code.name, case.code.name.lower()):
        assert msg.build(case.direction, case.fields(value)) == case.golden, value
    parsed = msg.parse(case.direction, case.golden)
    assert parsed[case.field] is case.code  # the member itself, equal to its int
    assert parsed[case.field] == int(case.code)


def _enums_in(con: Any) -> set[type[enum.IntEnum]]:
    if isinstance(con, EnumField):
        return {con.enum_type}
    found: set[type[enum.IntEnum]] = set()
    for sub in [*getattr(con, "subcons", ()), getattr(con, "subcon", None),
                *getattr(con, "cases", {}).values()]:
        if isinstance(sub, c.Construct):
            found |= _enums_in(sub)
    return found


def test_every_enum_of_the_catalogue_has_a_case() -> None:
    in_catalogue = {e for msg in CATALOGUE for con in (msg.request, msg.reply)
                    for e in _enums_in(con)}
    assert in_catalogue == {RouteStatus, FingerPower, FingerEvent, ControlMode, TxnStatus,
                            BoardType, Running, BootState, ImageStatus, BootResult, WriteStatus, Hop,
                            SlotState, SlotEvent, SlotResult, ConfirmBy}
    assert {type(case.code) for case in CASES} == in_catalogue


@pytest.mark.parametrize("case", [c for c in CASES if c.message != "fmcb.control"],
                         ids=[i for c, i in zip(CASES, IDS, strict=True)
                              if c.message != "fmcb.control"])
@given(code=st.integers(0, 255))
def test_any_code_parses_without_raising(case: Case, code: int) -> None:
    """A known code is its member, any other code the plain int (fmcb.control: below)."""
    payload = bytearray(case.golden)
    payload[case.offset] = code
    value = _msg(case).parse(case.direction, bytes(payload))[case.field]
    enum_type = type(case.code)
    if code in {int(m) for m in enum_type}:
        assert type(value) is enum_type and value == code
    else:
        assert type(value) is int and value == code
    # Unknown codes build back too (fuzzers send anything).
    assert _msg(case).build(case.direction, case.fields(value)) == bytes(payload)


def test_an_unknown_control_mode_is_a_payload_error_not_a_crash() -> None:
    """The mode selects the arguments' layout, so an unknown one cannot be parsed further."""
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.control"].parse_request(bytes([0x09]))


@pytest.mark.parametrize("case", CASES, ids=IDS)
@given(data=st.data())
def test_every_member_round_trips(case: Case, data: st.DataObject) -> None:
    enum_type = type(case.code)
    member = data.draw(st.sampled_from(list(enum_type)))
    spelling = data.draw(st.sampled_from([member, int(member), member.name,
                                          member.name.lower()]))
    fields = case.fields(spelling)
    if case.message == "fmcb.control":  # the arguments follow the mode
        fields["args"] = {
            ControlMode.IDLE: {},
            ControlMode.MOTOR: {"hall_target": [1, -2, 3]},
            ControlMode.JOINT: {"target": [0.5, -0.25, 0.0]},
            ControlMode.JOINT_FIXED: {"target": [1000, -1, 0]},
            ControlMode.JOINT_EFFORT: {"target": [0.5, 0.0, 1.0], "max_effort": [1, 2, 3]},
            ControlMode.RELATIVE: {"target": [0.5, 0.0, 1.0], "max_effort": [1, 2, 3]},
        }[ControlMode(member)]
    msg = _msg(case)
    payload = msg.build(case.direction, fields)
    assert payload[case.offset] == int(member)
    parsed = msg.parse(case.direction, payload)
    assert parsed[case.field] is member
    assert msg.build(case.direction, parsed) == payload


def test_an_unknown_name_is_a_payload_error() -> None:
    with pytest.raises(PayloadError, match="RouteStatus"):
        CATALOGUE["palm.route"].build_reply(finger=0, hop=0, status="lost", frame=b"")
    with pytest.raises(PayloadError):
        CATALOGUE["palm.finger_power"].build_request(finger=0, state="half", stagger_ms=0)


def test_a_code_out_of_the_fields_range_is_a_payload_error() -> None:
    with pytest.raises(PayloadError):
        CATALOGUE["palm.route"].build_reply(finger=0, hop=0, status=256, frame=b"")


def test_arrays_of_codes() -> None:
    msg = CATALOGUE["palm.finger_power"]
    payload = msg.build_reply(states=[FingerPower.FULL, 0, "low", 7])
    assert payload == bytes([0x02, 0x00, 0x01, 0x07])
    states = msg.parse_reply(payload)["states"]
    assert states == [FingerPower.FULL, FingerPower.OFF, FingerPower.LOW, 7]
    assert [type(s) for s in states] == [FingerPower, FingerPower, FingerPower, int]


def test_nested_codes_in_hand_status() -> None:
    msg = CATALOGUE["palm.hand_status"]
    finger = {"present": 1, "power": "full", "current": 0, "last_seen_ms": 0,
              "hall_pos": [0, 0, 0], "effort": [0, 0, 0]}
    fields = {"time": 0, "effort_cap": 255, "poll_hz": 0, "bus_voltage": 0,
              "fingers": [finger, {**finger, "power": 9}, {**finger, "power": 0},
                          {**finger, "power": FingerPower.LOW}]}
    payload = msg.build_reply(fields)
    assert [payload[8 + 24 * k + 1] for k in range(4)] == [2, 9, 0, 1]
    powers = [f["power"] for f in msg.parse_reply(payload)["fingers"]]
    assert powers == [FingerPower.FULL, 9, FingerPower.OFF, FingerPower.LOW]
    assert type(powers[1]) is int


# --- the wire, and so the fingerprint, do not see the enum ------------------------------------

class _Colour(enum.IntEnum):
    RED = 0
    GREEN = 1


def test_an_enum_field_is_described_like_its_integer() -> None:
    plain = c.Struct("a" / c.Int8ul, "b" / c.Array(2, c.Int16ul))
    coded = c.Struct("a" / EnumField(c.Int8ul, _Colour), "b" / c.Array(2, EnumField(c.Int16ul,
                                                                                    _Colour)))
    assert describe_layout(coded) == describe_layout(plain)
    switch_plain = c.Struct("k" / c.Int8ul, "v" / c.Switch(c.this.k, {0: c.Int8ul, 1: c.Int16ul}))
    switch_coded = c.Struct("k" / EnumField(c.Int8ul, _Colour),
                            "v" / c.Switch(c.this.k, {_Colour.RED: c.Int8ul,
                                                      _Colour.GREEN: c.Int16ul}))
    assert describe_layout(switch_coded) == describe_layout(switch_plain)

    def one(con: c.Construct) -> Catalogue:
        return Catalogue([Message("x", "palm", 0x70, con, None, "test")])

    assert one(coded).fingerprint() == one(plain).fingerprint()
    assert one(switch_coded).fingerprint() == one(switch_plain).fingerprint()


def test_the_switch_of_a_coded_field_is_selected_by_name() -> None:
    con = c.Struct("k" / EnumField(c.Int8ul, _Colour),
                   "v" / c.Switch(c.this.k, {_Colour.RED: c.Int8ul, _Colour.GREEN: c.Int16ul}))
    assert con.build({"k": "green", "v": 0x0102}) == bytes([0x01, 0x02, 0x01])
    assert con.parse(bytes([0x01, 0x02, 0x01])).k is _Colour.GREEN
