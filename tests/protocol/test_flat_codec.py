"""The struct fast path agrees with the construct declarations it stands in for."""

from __future__ import annotations

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
