"""Tests of the message catalogue: round trips of every declaration, layouts, errors, lookup.

Field values are generated from the construct declarations themselves by the shared
strategies of :mod:`protocol.strategies` (``values_for``, extremes first), so a message added
to the catalogue is covered without touching this file.
"""

from __future__ import annotations

import enum
import struct
from typing import Any

import construct as c
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.catalogue import (
    REPLY,
    REQUEST,
    Catalogue,
    Message,
    describe_layout,
    iter_fields,
    static_size,
)
from protocol.errors import MessageError, PayloadError, ProtocolError, UnknownMessageError
from protocol.framing import Frame, encode_frame
from protocol.interpret import candidate_nodes, interpret, unwrap_envelopes
from protocol.messages import CATALOGUE, CATALOGUE_HASH
from protocol.messages.fields import EMPTY
from protocol.messages.fmcb import TUNNEL_MAX
from protocol.messages.palm import RouteStatus
from protocol.strategies import unwrap as _unwrap
from protocol.strategies import values_for
from protocol.topology import Hop

# Field values come from the shared strategies of protocol.strategies (``values_for``).


def rebuilt_names(con: c.Construct | None) -> set[str]:
    """Names of the Rebuild fields anywhere in ``con`` (computed, so absent from the values)."""
    names: set[str] = set()
    if con is None:
        return names
    inner = _unwrap(con)
    if isinstance(inner, c.Struct):
        for sub in inner.subcons:
            if isinstance(_unwrap(sub), c.Rebuild):
                names.add(sub.name)
            names |= rebuilt_names(sub)
    elif isinstance(inner, c.Array):
        names |= rebuilt_names(inner.subcon)
    elif isinstance(inner, c.Switch):
        for case in inner.cases.values():
            names |= rebuilt_names(case)
    return names


def assert_matches(values: Any, parsed: Any, computed: set[str]) -> None:
    """``parsed`` equals ``values`` except for extra computed (Rebuild) keys."""
    if isinstance(values, dict):
        assert isinstance(parsed, dict)
        extra = set(parsed) - set(values)
        assert extra <= computed, extra
        for key, value in values.items():
            assert_matches(value, parsed[key], computed)
    elif isinstance(values, list):
        assert isinstance(parsed, list)
        assert len(parsed) == len(values)
        for v, p in zip(values, parsed, strict=True):
            assert_matches(v, p, computed)
    elif isinstance(values, str) and isinstance(parsed, enum.IntEnum):
        assert parsed.name.lower() == values.lower()  # a code built from its name
    else:
        assert parsed == values


DIRECTIONS = [
    (msg, direction)
    for msg in CATALOGUE
    for direction in (REQUEST, REPLY)
    if (msg.request if direction == REQUEST else msg.reply) is not None
]
DIRECTION_IDS = [f"{m.name}-{d}" for m, d in DIRECTIONS]


@pytest.mark.parametrize(("msg", "direction"), DIRECTIONS, ids=DIRECTION_IDS)
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_every_message_round_trips(msg: Message, direction: str, data: st.DataObject) -> None:
    con = msg.declaration(direction)
    values = data.draw(values_for(con), label="fields")
    payload = msg.build(direction, values)
    assert isinstance(payload, bytes)
    size = static_size(con)
    if size is not None:
        assert len(payload) == size
    parsed = msg.parse(direction, payload)
    assert_matches(values, parsed, rebuilt_names(con))
    # parse → build is the identity on bytes as well
    assert msg.build(direction, parsed) == payload


def test_every_message_has_a_direction() -> None:
    for msg in CATALOGUE:
        assert msg.request is not None or msg.reply is not None
        assert msg.replies == (msg.reply is not None)


# --- layouts with hand-computed offsets -----------------------------------------------------

# (field, offset, struct format) of the 148-byte fmcb status, counted by hand from the facts.
STATUS_LAYOUT = [
    ("pp_time", 0, "<I"),
    ("dp_time", 4, "<I"),
    ("fmcb_time", 8, "<I"),
    ("pp_tactile", 12, "<6H"),
    ("dp_tactile", 24, "<12H"),
    ("pp_imu", 48, "<6h"),
    ("dp_imu", 60, "<6h"),
    ("fmcb_imu", 72, "<6h"),
    ("pp_temp", 84, "<4H"),
    ("dp_temp", 92, "<4H"),
    ("fmcb_temp", 100, "<3H"),
    ("voltage", 106, "<H"),
    ("pb_current", 108, "<H"),
    # 110..112 padding
    ("pp_strain", 112, "<i"),
    ("hall_tgt", 116, "<3i"),
    ("hall_pos", 128, "<3i"),
    ("effort", 140, "<3h"),
    # 146..148 padding
]

PALM_STATE_LAYOUT = [
    ("time", 0, "<I"),
    ("accel", 4, "<3h"),
    ("gyro", 10, "<3h"),
    ("mag", 16, "<3h"),
    ("temps", 22, "<7H"),
    ("tactile", 36, "<32H"),
]


def _distinct_values(layout: list[tuple[str, int, str]]) -> dict[str, Any]:
    """Distinct small values per field (1, 2, 3 … across all fields and elements)."""
    values: dict[str, Any] = {}
    counter = 1
    for name, _offset, fmt in layout:
        n = struct.calcsize(fmt) // struct.calcsize("<" + fmt[-1])
        items = list(range(counter, counter + n))
        counter += n
        values[name] = items if n > 1 or fmt[1:-1] else items[0]
    return values


def test_fmcb_status_reply_layout() -> None:
    msg = CATALOGUE["fmcb.status"]
    assert static_size(msg.reply) == 148
    values = _distinct_values(STATUS_LAYOUT)
    values["hall_pos"] = [0x11223344, -2, 0x7FFFFFFF]
    values["pb_current"] = 0xFFFF
    payload = msg.build_reply(values)
    assert len(payload) == 148
    assert payload[128:140] == bytes.fromhex("44332211" "feffffff" "ffffff7f")
    assert payload[108:110] == b"\xff\xff"
    assert payload[110:112] == b"\x00\x00"  # explicit padding at offset 110
    assert payload[146:148] == b"\x00\x00"  # and at the end
    for name, offset, fmt in STATUS_LAYOUT:
        value = values[name]
        packed = struct.pack(fmt, *(value if isinstance(value, list) else [value]))
        assert payload[offset : offset + len(packed)] == packed, name
    assert msg.parse_reply(payload) == values
    assert msg.build_request() == b""


def test_palm_state_reply_layout() -> None:
    msg = CATALOGUE["palm.state"]
    assert static_size(msg.reply) == 100
    values = _distinct_values(PALM_STATE_LAYOUT)
    payload = msg.build_reply(values)
    assert len(payload) == 100
    for name, offset, fmt in PALM_STATE_LAYOUT:
        value = values[name]
        packed = struct.pack(fmt, *(value if isinstance(value, list) else [value]))
        assert payload[offset : offset + len(packed)] == packed, name
    assert msg.parse_reply(payload) == values


def test_control_golden_payloads() -> None:
    msg = CATALOGUE["fmcb.control"]
    assert msg.build_request(mode=0, args={}) == b"\x00"
    # 0.5 = 0x3F000000, -1.0 = 0xBF800000, 2.0 = 0x40000000 (float32, LE)
    assert msg.build_request(mode=2, args={"target": [0.5, -1.0, 2.0]}) == bytes.fromhex(
        "02" "0000003f" "000080bf" "00000040"
    )
    assert msg.build_request(mode=1, args={"hall_target": [1, -1, 0x1234]}) == bytes.fromhex(
        "01" "0100" "ffff" "3412"
    )
    assert msg.build_request(
        mode=4, args={"target": [0.5, 0.5, 0.5], "max_effort": [1, 2, 255]}
    ) == bytes.fromhex("04" + "0000003f" * 3 + "0102ff")
    assert msg.parse_request(bytes.fromhex("03" "1027" "f0d8" "0000")) == {
        "mode": 3, "args": {"target": [10000, -10000, 0]},
    }


def test_control_mode_9_is_rejected() -> None:
    msg = CATALOGUE["fmcb.control"]
    with pytest.raises(PayloadError):
        msg.build_request(mode=9, args={})
    with pytest.raises(PayloadError):
        msg.parse_request(b"\x09")
    with pytest.raises(PayloadError):
        msg.parse_request(b"\x09" + bytes(12))


def test_control_wrong_length_for_its_mode_is_rejected() -> None:
    msg = CATALOGUE["fmcb.control"]
    with pytest.raises(PayloadError):
        msg.parse_request(b"\x02" + bytes(11))
    with pytest.raises(PayloadError):
        msg.parse_request(b"\x02" + bytes(13))
    with pytest.raises(PayloadError):
        msg.parse_request(b"\x00\x00")


def test_tunnel_bound() -> None:
    msg = CATALOGUE["fmcb.tunnel"]
    ok = msg.build_request(max_ms=5, data=bytes(TUNNEL_MAX))
    assert ok[:4] == bytes.fromhex("0002" "0500")
    assert msg.parse_request(ok)["length"] == TUNNEL_MAX
    with pytest.raises(PayloadError):
        msg.build_request(max_ms=5, data=bytes(TUNNEL_MAX + 1))
    with pytest.raises(PayloadError):
        msg.parse_request((TUNNEL_MAX + 1).to_bytes(2, "little") + b"\x05\x00"
                          + bytes(TUNNEL_MAX + 1))
    assert msg.build_reply(data=b"\xab\xcd") == bytes.fromhex("0200abcd")
    with pytest.raises(PayloadError):
        msg.build_reply(data=bytes(TUNNEL_MAX + 1))
    with pytest.raises(PayloadError):
        msg.parse_reply(bytes.fromhex("0300abcd"))  # length says 3, 2 bytes follow


def test_identify_reply_size_and_fingerprint_field() -> None:
    msg = CATALOGUE["identify"]
    assert static_size(msg.reply) == 27
    payload = msg.build_reply(
        board=2, address=10, running=1, hw_version=0xBEEF0041,
        fw_version={"major": 1, "minor": 2, "patch": 3}, catalogue=CATALOGUE_HASH,
        uid=0xDEADBEEF, uptime_us=5,
    )
    assert payload[:7] == bytes.fromhex("020a01" "4100efbe")
    assert payload[7:11] == bytes.fromhex("01020300")
    assert payload[11:19] == CATALOGUE_HASH


# --- errors ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["nope", "", "fmcb.statu", "PING", "fmcb"])
def test_unknown_names(name: str) -> None:
    with pytest.raises(UnknownMessageError) as info:
        CATALOGUE.by_name(name)
    assert isinstance(info.value, MessageError)
    assert isinstance(info.value, ProtocolError)
    assert isinstance(info.value, ValueError)
    with pytest.raises(UnknownMessageError):
        CATALOGUE[name]


@pytest.mark.parametrize(("msg", "direction"), DIRECTIONS, ids=DIRECTION_IDS)
@settings(max_examples=5, deadline=None)
@given(data=st.data())
def test_wrong_length_payloads(msg: Message, direction: str, data: st.DataObject) -> None:
    con = msg.declaration(direction)
    payload = msg.build(direction, data.draw(values_for(con), label="fields"))
    size = static_size(con)
    if size is not None:
        with pytest.raises(PayloadError) as info:
            msg.parse(direction, payload + b"\x00")
        assert isinstance(info.value, MessageError)
        assert isinstance(info.value, ProtocolError)
        assert isinstance(info.value, ValueError)
    if payload and _unwrap(list(iter_fields(con))[-1][1]) is not c.GreedyBytes:
        with pytest.raises(PayloadError):
            msg.parse(direction, payload[:-1])


def test_missing_direction_and_fields() -> None:
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.control"].build_reply()
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.control"].parse_reply(b"")
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.control"].declaration(REPLY)
    with pytest.raises(PayloadError):
        CATALOGUE["palm.finger_event"].build_request()
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.phalange_power"].build_request()  # field missing
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.phalange_power"].build_request(on=256)
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.phalange_power"].build_request(on="x")
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.param_name"].build_reply(name="é")
    with pytest.raises(PayloadError):
        CATALOGUE["fmcb.param_name"].parse_reply(b"\x01\xff")


ALL_PARSERS = st.sampled_from(DIRECTIONS)


@settings(max_examples=300)
@given(ALL_PARSERS, st.binary(max_size=200))
def test_arbitrary_bytes_raise_only_payload_error(
    msg_direction: tuple[Message, str], payload: bytes
) -> None:
    msg, direction = msg_direction
    try:
        parsed = msg.parse(direction, payload)
    except PayloadError:
        return
    assert isinstance(parsed, dict)
    assert msg.build(direction, parsed) == payload


@settings(max_examples=200)
@given(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=160), st.sampled_from(
    [None, "fmcb", "palm", "f2", "f3", "bootloader"]))
def test_interpret_never_raises(address: int, msg_type: int, payload: bytes,
                                hint: str | None) -> None:
    meaning = interpret(Frame(address, msg_type, payload), hint)
    assert meaning.direction == (REPLY if address == 0 else REQUEST)
    if meaning.fields is not None:
        assert meaning.message is not None
        assert meaning.error is None
    assert len(unwrap_envelopes(meaning, Frame(address, msg_type, payload))) <= 4


@settings(max_examples=200)
@given(st.binary(max_size=80), st.sampled_from([0x61, 0x62]))
def test_unwrapping_any_envelope_never_raises(inner: bytes, inner_type: int) -> None:
    # a txn reply from the palm (status OK) around arbitrary bytes, read as palm.route or not
    payload = bytes([1, 1, 10, inner_type, 0]) + inner
    for layer in unwrap_envelopes(interpret(Frame(0, 0x61, payload)), Frame(0, 0x61, payload)):
        assert (layer.fields is None) == (layer.message is None or layer.error is not None)


def test_a_palm_poll_reply_unwraps_to_the_finger_nodes_message() -> None:
    """txn (palm) ⊃ palm.route (finger 2, f2) ⊃ the f2's hw_version reply, bytes by hand."""
    # hw_version reply of the f2 to the host: 0xBEEF0041, little-endian
    routed = encode_frame(0, 0xFA, bytes.fromhex("4100efbe"))
    route = bytes([2, Hop.F2, RouteStatus.OK]) + routed  # finger, hop, status, frame
    txn = bytes([7, 1, 10, 0x62, 0]) + route  # seq, board PALM, address, palm.route, OK
    outer = interpret(Frame(0, 0x61, txn))
    assert outer.name == "txn"
    layers = unwrap_envelopes(outer, Frame(0, 0x61, txn))
    assert [layer.name for layer in layers] == ["palm.route", "hw_version"]
    assert layers[0].fields is not None and layers[0].fields["finger"] == 2
    assert layers[1].fields == {"version": 0xBEEF0041}
    # a refused txn carries nothing; a routed frame that is no frame says why
    refused = bytes([7, 1, 10, 0x62, 4])  # status NO_REPLY, no inner
    assert unwrap_envelopes(interpret(Frame(0, 0x61, refused)), Frame(0, 0x61, refused)) == []
    broken = bytes([7, 1, 10, 0x62, 0, 2, Hop.F2, RouteStatus.OK]) + routed[:-1]
    layers = unwrap_envelopes(interpret(Frame(0, 0x61, broken)), Frame(0, 0x61, broken))
    assert [layer.name for layer in layers] == ["palm.route", None]
    assert layers[1].error is not None and layers[1].error.startswith("routed frame:")


# --- lookup ---------------------------------------------------------------------------------


def test_lookup_falls_back_to_common_messages() -> None:
    for node in ("fmcb", "palm", "f2", "f3", "bootloader"):
        assert CATALOGUE.lookup(node, 0x01) is CATALOGUE["ping"]
        assert CATALOGUE.lookup(node, 0xFA) is CATALOGUE["hw_version"]
        assert CATALOGUE.lookup(node, 0x60) is CATALOGUE["identify"]
    assert CATALOGUE.lookup("common", 0x01) is CATALOGUE["ping"]
    assert CATALOGUE.lookup("common", 0x21) is None
    assert CATALOGUE.lookup("fmcb", 0x21) is CATALOGUE["fmcb.status"]
    assert CATALOGUE.lookup("palm", 0x21) is CATALOGUE["palm.state"]
    assert CATALOGUE.lookup("fmcb", 0x0B) is None
    assert CATALOGUE.lookup("nonsense", 0x01) is None


def test_bootloader_ids() -> None:
    expected = {
        0x07: "bl.status", 0x08: "bl.boot", 0x0A: "bl.read_page", 0x0B: "bl.write_page",
        0x0C: "bl.halt", 0x0D: "bl.info", 0x0E: "bl.hash", 0x0F: "bl.activate",
        0x01: "ping", 0xFA: "hw_version",
    }
    for type_id, name in expected.items():
        assert CATALOGUE.require("bootloader", type_id).name == name
    assert static_size(CATALOGUE["bl.read_page"].reply) == 256
    assert static_size(CATALOGUE["bl.write_page"].request) == 260


def test_require_raises_for_unknown_ids() -> None:
    with pytest.raises(UnknownMessageError):
        CATALOGUE.require("fmcb", 0xEE)
    with pytest.raises(UnknownMessageError):
        CATALOGUE.require("common", 0x21)


def test_new_message_ids() -> None:
    assert (CATALOGUE["identify"].type_id, CATALOGUE["identify"].node) == (0x60, "common")
    assert (CATALOGUE["txn"].type_id, CATALOGUE["txn"].node) == (0x61, "common")
    assert (CATALOGUE["palm.route"].type_id, CATALOGUE["palm.route"].node) == (0x62, "palm")
    assert not CATALOGUE["identify"].original
    assert CATALOGUE["ping"].original


def test_original_ids() -> None:
    expected = {
        "ping": 0x01, "reset": 0x09, "hw_version": 0xFA, "fmcb.imu": 0x10, "fmcb.halls": 0x12,
        "fmcb.motor_raw": 0x13, "fmcb.hall_counts": 0x14, "fmcb.param_count": 0x16,
        "fmcb.param_name": 0x17, "fmcb.param_get": 0x18, "fmcb.param_set": 0x19,
        "fmcb.param_commit": 0x1A, "fmcb.param_reload": 0x1B, "fmcb.param_defaults": 0x1C,
        "fmcb.control": 0x1D, "fmcb.phalange_power": 0x1E, "fmcb.tunnel": 0x1F,
        "fmcb.autopoll": 0x20, "fmcb.status": 0x21, "fmcb.temperatures": 0x22,
        "fmcb.effort_cap": 0x23, "palm.tactile": 0x10, "palm.state": 0x21,
    }
    for name, type_id in expected.items():
        assert CATALOGUE[name].type_id == type_id, name
    assert CATALOGUE["fmcb.control"].reply is None
    assert CATALOGUE["fmcb.effort_cap"].reply is None


def test_catalogue_iteration_and_names() -> None:
    names = CATALOGUE.names()
    assert len(names) == len(CATALOGUE) == len(set(names))
    assert names[0] == "ping"
    assert [m.name for m in CATALOGUE] == names


# --- fingerprint ----------------------------------------------------------------------------


def test_fingerprint_is_8_stable_bytes() -> None:
    fp = CATALOGUE.fingerprint()
    assert isinstance(fp, bytes)
    assert len(fp) == 8
    assert fp == CATALOGUE.fingerprint() == CATALOGUE_HASH
    assert Catalogue(list(CATALOGUE)).fingerprint() == fp
    assert Catalogue(reversed(list(CATALOGUE))).fingerprint() == fp  # order-independent


def test_fingerprint_changes_with_the_catalogue() -> None:
    copy = Catalogue(list(CATALOGUE))
    copy.add(Message("test.extra", "fmcb", 0xEE, EMPTY, EMPTY, "An extra message."))
    assert copy.fingerprint() != CATALOGUE_HASH
    assert len(CATALOGUE) == len(copy) - 1  # the original is untouched
    # a changed layout changes it too
    changed = Catalogue(
        [m for m in CATALOGUE if m.name != "fmcb.halls"]
        + [Message("fmcb.halls", "fmcb", 0x12, EMPTY,
                   c.Struct("bits" / c.Array(4, c.Int8ul)), "changed")]
    )
    assert changed.fingerprint() != CATALOGUE_HASH


def test_describe_layout() -> None:
    assert describe_layout(None) == "-"
    assert describe_layout(EMPTY) == ""
    status = describe_layout(CATALOGUE["fmcb.status"].reply)
    assert "hall_pos:Array(count=3;<l):12" in status
    assert "pp_time:<L:4" in status
    assert status.count("<pad>:Padded(") == 2


def test_iter_fields_yields_the_field_declarations() -> None:
    fields = list(iter_fields(CATALOGUE["fmcb.status"].reply))
    by_name = {name: sub for name, sub, _ in fields}
    assert by_name["pp_time"] is c.Int32ul
    assert isinstance(by_name["hall_pos"], c.Array)
    docs = {name: doc for name, _, doc in fields}
    assert docs["pp_time"].startswith("[µs]")
    assert [name for name, _, _ in fields].count("<pad>") == 2


def _replaced(name: str, msg: Message) -> Catalogue:
    return Catalogue([m for m in CATALOGUE if m.name != name] + [msg])


def test_fingerprint_sees_same_size_type_changes() -> None:
    # i32 → f32 keeps every size, but it is another wire format.
    strain = _replaced("f2.strain", Message(
        "f2.strain", "f2", 0x13, EMPTY, c.Struct("strain" / c.Float32l), "changed"))
    assert strain.fingerprint() != CATALOGUE_HASH
    # a change inside a switch arm (control mode 2 as integers)
    from protocol.messages import fmcb

    arms = dict(_unwrap(fmcb.CONTROL.subcons[1]).cases)
    arms[2] = c.Struct("target" / c.Array(3, c.Int32sl))
    control = c.Struct("mode" / c.Int8ul, "args" / c.Switch(c.this.mode, arms, c.Error))
    changed = _replaced("fmcb.control", Message(
        "fmcb.control", "fmcb", 0x1D, control, None, "changed"))
    assert changed.fingerprint() != CATALOGUE_HASH
    # while an identical redeclaration (other docs) does not change it
    same = _replaced("fmcb.control", Message(
        "fmcb.control", "fmcb", 0x1D,
        c.Struct("mode" / c.Int8ul, "args" / c.Switch(c.this.mode, dict(
            _unwrap(fmcb.CONTROL.subcons[1]).cases), c.Error)), None, "other summary"))
    assert same.fingerprint() == CATALOGUE_HASH


def test_catalogue_rejects_duplicates_and_shadowing() -> None:
    cat = Catalogue([Message("a", "fmcb", 0x30, EMPTY, EMPTY, "a")])
    with pytest.raises(ValueError):
        cat.add(Message("a", "fmcb", 0x31, EMPTY, EMPTY, "dup name"))
    with pytest.raises(ValueError):
        cat.add(Message("b", "fmcb", 0x30, EMPTY, EMPTY, "dup key"))
    with pytest.raises(ValueError):
        cat.add(Message("c", "common", 0x30, EMPTY, EMPTY, "common shadowed by fmcb"))
    cat.add(Message("d", "common", 0x40, EMPTY, EMPTY, "common"))
    with pytest.raises(ValueError):
        cat.add(Message("e", "palm", 0x40, EMPTY, EMPTY, "shadows common"))


def test_message_validation() -> None:
    with pytest.raises(ValueError):
        Message("x", "gripper", 0x01, EMPTY, EMPTY, "bad node")
    with pytest.raises(ValueError):
        Message("x", "fmcb", 0x100, EMPTY, EMPTY, "bad id")


# --- interpret --------------------------------------------------------------------------------


def test_interpret_status_by_size() -> None:
    status = interpret(Frame(0, 0x21, bytes(148)))
    assert status.name == "fmcb.status"
    assert status.direction == REPLY
    assert status.fields is not None and status.fields["hall_pos"] == [0, 0, 0]
    state = interpret(Frame(0, 0x21, bytes(100)))
    assert state.name == "palm.state"
    assert state.fields is not None and len(state.fields["tactile"]) == 32
    neither = interpret(Frame(0, 0x21, bytes(99)))
    assert neither.fields is None
    assert neither.name == "fmcb.status"  # the first candidate, with the reason
    assert neither.error


def test_interpret_requests_and_hints() -> None:
    req = interpret(Frame(10, 0x21, b""))
    assert (req.name, req.direction, req.fields) == ("fmcb.status", REQUEST, {})
    assert interpret(Frame(10, 0x21, b""), hint="palm").name == "palm.state"
    assert interpret(Frame(1, 0x10, b"")).name == "f2.tactile"
    assert interpret(Frame(2, 0x10, b"")).name == "f3.tactile"
    assert interpret(Frame(10, 0x0B, bytes(260))).name == "bl.write_page"
    assert interpret(Frame(0, 0x10, bytes(24))).name == "f2.tactile"
    assert interpret(Frame(0, 0x10, bytes(36))).name == "f3.tactile"
    unknown = interpret(Frame(10, 0xEE, b"\x01"))
    assert unknown.message is None and unknown.name is None and unknown.fields is None
    assert candidate_nodes(10, "palm")[0] == "palm"
    assert set(candidate_nodes(0)) == {"fmcb", "palm", "f2", "f3", "bootloader"}
