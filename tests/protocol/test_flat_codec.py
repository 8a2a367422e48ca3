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
from protocol.flat_codec import flat_codec
from protocol.messages import CATALOGUE
from protocol.messages.bootloader import BootResult, ImageStatus
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
    assert codec.build(fast) == decl.build(reference)
    # The catalogue goes through the fast path and gives the same answer.
    assert _same(msg.parse(direction, payload), reference)
    # A wrong length is still construct's documented error.
    with pytest.raises(PayloadError):
        msg.parse(direction, payload + b"\x00")


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
