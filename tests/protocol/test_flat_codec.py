"""The struct fast path agrees with the construct declarations it stands in for."""

from __future__ import annotations

import enum
import math
from typing import Any

import construct as c
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.catalogue import to_plain
from protocol.errors import PayloadError
from protocol.flat_codec import flat_codec, tail_codec
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import BootResult, ImageStatus
from protocol.messages.fmcb import ControlMode
from protocol.messages.palm import FingerEvent, FingerPower

FLAT = [(m, direction, decl) for m in CATALOGUE
        for direction, decl in (("request", m.request), ("reply", m.reply))
        if decl is not None and flat_codec(decl) is not None]


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(a == b) and type(a) is type(b)


def test_the_hot_messages_have_a_fast_path() -> None:
    names = {(m.name, d) for m, d, _ in FLAT}
    assert ("fmcb.status", "reply") in names
    assert ("f2.imu", "reply") in names and ("palm.finger_power", "request") in names


def test_declarations_with_checks_or_variable_parts_are_not_flat() -> None:
    assert flat_codec(CATALOGUE["fmcb.tunnel"].request) is None  # Rebuild + Check
    assert flat_codec(CATALOGUE["fmcb.control"].request) is None  # Switch
    assert flat_codec(c.Struct("a" / c.Int16ub)) is None  # big-endian
    assert flat_codec(c.Struct(c.Padding(2, pattern=b"\xff"))) is None


def test_fixed_bytes_and_arrays_of_structs_are_flat() -> None:
    names = {(m.name, d) for m, d, _ in FLAT}
    assert {("bl.read_page", "reply"), ("fmcb.param_get", "reply"), ("bl.hash", "reply"),
            ("palm.hand_status", "reply")} <= names
    codec = flat_codec(CATALOGUE["fmcb.param_set"].request)
    assert codec is not None and codec.size == 6
    assert codec.parse(b"\x01\x00" + b"\x00\x00\x80\x3f") == {"index": 1, "value": b"\x00\x00\x80\x3f"}
    assert codec.build({"index": 1, "value": b"\x01\x02\x03\x04"}) == b"\x01\x00\x01\x02\x03\x04"
    # struct would pad a short value or cut a long one; the fast path declines instead
    assert codec.build({"index": 1, "value": b"\x01\x02"}) is None
    assert codec.build({"index": 1, "value": b"\x01\x02\x03\x04\x05"}) is None
    assert codec.build({"index": 1, "value": 7}) is None
    status = flat_codec(CATALOGUE["palm.hand_status"].reply)
    assert status is not None and not status.buildable
    parsed = status.parse(bytes(range(status.size)))
    assert parsed is not None and len(parsed["fingers"]) == 4
    assert parsed["fingers"][0]["present"] == 8 and parsed["fingers"][1]["present"] == 8 + 24


def test_status_field_offsets_by_hand() -> None:
    """fmcb.status: pb_current at bytes 108-109, padding 110-111, pp_strain from 112."""
    codec = flat_codec(CATALOGUE["fmcb.status"].reply)
    assert codec is not None and codec.size == 148
    raw = bytearray(148)
    raw[108:110] = b"\x34\x12"
    raw[110:112] = b"\xee\xee"  # padding: ignored on parse, zero on build
    raw[112:116] = b"\xfe\xff\xff\xff"
    parsed = codec.parse(bytes(raw))
    assert parsed is not None and parsed["pb_current"] == 0x1234 and parsed["pp_strain"] == -2
    rebuilt = codec.build(parsed)
    assert rebuilt is not None and rebuilt[110:112] == b"\x00\x00"


@pytest.mark.parametrize(("msg", "direction", "decl"), FLAT,
                         ids=[f"{m.name}-{d}" for m, d, _ in FLAT])
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_fast_path_parses_and_builds_what_construct_does(msg: Any, direction: str, decl: Any,
                                                          data: st.DataObject) -> None:
    codec = flat_codec(decl)
    assert codec is not None
    payload = data.draw(st.binary(min_size=codec.size, max_size=codec.size))
    fast = codec.parse(payload)
    reference = to_plain(decl.parse(payload))
    assert fast is not None and _same(fast, reference)
    if codec.buildable:
        assert codec.build(fast) == decl.build(reference)
    else:  # arrays of Structs: construct builds them
        assert codec.build(fast) is None
        assert msg.build(direction, fast) == decl.build(reference)
    # The catalogue goes through the fast path and gives the same answer.
    assert _same(msg.parse(direction, payload), reference)
    # A wrong length is still construct's documented error.
    with pytest.raises(PayloadError):
        msg.parse(direction, payload + b"\x00")


TAIL = [(m, direction, decl) for m in CATALOGUE
        for direction, decl in (("request", m.request), ("reply", m.reply))
        if decl is not None and flat_codec(decl) is None and tail_codec(decl) is not None]


def test_variable_last_fields_have_a_parse_fast_path() -> None:
    kinds = {(m.name, d): tail_codec(decl).kind for m, d, decl in TAIL}  # type: ignore[union-attr]
    assert kinds[("txn", "request")] == "greedy"
    assert kinds[("fmcb.param_name", "reply")] == "pascal"
    assert kinds[("fmcb.control", "request")] == "switch"
    assert ("fmcb.tunnel", "request") not in kinds  # Rebuild + Check: construct only
    control = tail_codec(CATALOGUE["fmcb.control"].request)
    assert control is not None
    assert control.parse(bytes.fromhex("02" "0000003f" "000080bf" "00000040")) == {
        "mode": 2, "args": {"target": [0.5, -1.0, 2.0]}}
    assert control.parse(b"\x00") == {"mode": 0, "args": {}}
    assert control.parse(b"\x09") is None  # no such mode: construct says why
    assert control.parse(b"\x02\x00") is None  # short for its mode
    name = tail_codec(CATALOGUE["fmcb.param_name"].reply)
    assert name is not None
    assert name.parse(b"\x03abc") == {"name": "abc"}
    assert name.parse(b"\x03ab") is None and name.parse(b"\x01\xff") is None


@pytest.mark.parametrize(("msg", "direction", "decl"), TAIL,
                         ids=[f"{m.name}-{d}" for m, d, _ in TAIL])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_tail_fast_path_parses_what_construct_does(msg: Any, direction: str, decl: Any,
                                                   data: st.DataObject) -> None:
    codec = tail_codec(decl)
    assert codec is not None
    head = codec.head.size
    prefix = data.draw(st.binary(min_size=head, max_size=head))
    if codec.kind == "switch":
        key = data.draw(st.sampled_from(sorted(codec.cases)))
        prefix = bytes([key]) + prefix[1:]
        size = codec.cases[key].size
        rest = data.draw(st.binary(min_size=max(size - 1, 0), max_size=size + 1))
    elif codec.kind == "pascal":
        text = data.draw(st.binary(max_size=40))
        rest = bytes([data.draw(st.sampled_from([len(text), len(text) + 1, 255]))]) + text
    else:
        rest = data.draw(st.binary(max_size=40))
    payload = data.draw(st.sampled_from([prefix + rest, prefix[: head // 2], prefix + rest[:1]]))
    fast = codec.parse(payload)
    try:  # the payload must be consumed exactly, as the catalogue asks
        reference = to_plain(c.FocusedSeq("v", "v" / decl, c.Terminated).parse(payload))
    except c.ConstructError:
        reference = None
    if fast is not None:
        assert reference is not None and _same(fast, reference)
        assert _same(msg.parse(direction, payload), reference)
    elif reference is not None:  # declined: construct parses it (the catalogue still does)
        assert _same(msg.parse(direction, payload), reference)


# --- coded (EnumField) fields -----------------------------------------------------------------

def test_coded_messages_have_a_fast_path() -> None:
    names = {(m.name, d) for m, d, _ in FLAT}
    assert {("palm.finger_power", "reply"), ("palm.finger_event", "reply"),
            ("bl.activate", "reply")} <= names


@pytest.mark.parametrize(("name", "direction", "payload", "expected"), [
    ("palm.finger_power", "reply", bytes([2, 0, 7, 255]),
     {"states": [FingerPower.FULL, FingerPower.OFF, 7, 255]}),
    ("palm.finger_power", "request", bytes([0xFF, 1, 10, 0]),
     {"finger": 0xFF, "state": FingerPower.LOW, "stagger_ms": 10}),
    ("palm.finger_power", "request", bytes([0, 3, 0, 0]),
     {"finger": 0, "state": 3, "stagger_ms": 0}),
    ("palm.finger_event", "reply", bytes([1, 4, 1, 0, 0, 0]),
     {"finger": 1, "event": FingerEvent.UNPOWERED, "time": 1}),
    ("palm.finger_event", "reply", bytes([1, 0x80, 1, 0, 0, 0]),
     {"finger": 1, "event": 0x80, "time": 1}),
    ("bl.activate", "reply", bytes([4, 3]),
     {"status": BootResult.WRONG_BOARD, "image_status": ImageStatus.WRONG_BOARD}),
    ("bl.activate", "reply", bytes([200, 77]), {"status": 200, "image_status": 77}),
])
def test_fast_path_names_known_codes_and_keeps_unknown_ones(
        name: str, direction: str, payload: bytes, expected: dict[str, Any]) -> None:
    msg = CATALOGUE[name]
    decl = msg.declaration(direction)
    codec = flat_codec(decl)
    assert codec is not None
    fast = codec.parse(payload)
    assert fast is not None and _same(fast, expected)  # members, and plain ints otherwise
    assert _same(fast, to_plain(decl.parse(payload)))
    assert codec.build(fast) == payload
    # A name is not a number: the fast path declines and construct translates it.
    named = {k: (v.name.lower() if isinstance(v, enum.IntEnum) else v) for k, v in fast.items()}
    if named != fast:
        assert codec.build(named) is None
        assert msg.build(direction, named) == payload


def test_codes_inside_arrays_of_structs_and_tail_heads_are_named() -> None:
    # palm.hand_status reply: time u32, effort_cap u8, poll_hz u8, bus_voltage u16, then four
    # fingers of present u8, power u8 (FingerPower), current u16, last_seen_ms u16,
    # hall_pos 3×i32, effort 3×i16 (a 24-byte element).
    decl = CATALOGUE["palm.hand_status"].reply
    assert decl is not None
    codec = flat_codec(decl)
    assert codec is not None and codec.size == 8 + 4 * 24
    powers = [2, 0, 9, 1]  # 9 has no name
    payload = bytes(8) + b"".join(bytes([1, p]) + bytes(22) for p in powers)
    fast = codec.parse(payload)
    assert fast is not None
    assert [f["power"] for f in fast["fingers"]] == powers
    assert [type(f["power"]) for f in fast["fingers"]] == [FingerPower, FingerPower, int,
                                                         FingerPower]
    assert _same(fast, to_plain(decl.parse(payload)))
    # fmcb.control request: the Switch key in the head is a ControlMode member
    control = tail_codec(CATALOGUE["fmcb.control"].request)
    assert control is not None
    parsed = control.parse(bytes([3]) + bytes.fromhex("e803" "ffff" "0000"))
    assert parsed is not None and type(parsed["mode"]) is ControlMode
    assert parsed == {"mode": ControlMode.JOINT_FIXED, "args": {"target": [1000, -1, 0]}}


def test_plain_numbers_and_fixed_bytes_carry_no_members() -> None:
    codec = flat_codec(CATALOGUE["fmcb.param_set"].request)
    assert codec is not None
    assert [f[3] for f in codec.fields] == [None, None]
    assert type(codec.parse(bytes(6))["index"]) is int  # type: ignore[index]
