"""Tests of protocol.manchester: golden chips from the definition, round trips, corruption.

The reference model below (``_ref_report``) is a deliberately naive per-chip decoder written
straight from the definition; the vectorised decoder must agree with it on every input.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from protocol.errors import ManchesterError, ProtocolError
from protocol.manchester import (
    Convention,
    DecodeReport,
    chips_per_character,
    dc_balance,
    decode,
    decode_packed,
    decode_report,
    decode_report_packed,
    encode,
    encode_packed,
    pack_chips,
    packed_size,
    unpack_chips,
    wire_time_s,
)

IEEE = Convention.IEEE_802_3
THOMAS = Convention.G_E_THOMAS

conventions = st.sampled_from(list(Convention))
framings = st.booleans()
payloads = st.binary(max_size=64)


def chips_of(text: str) -> list[int]:
    """Chips written as a string of 0/1 (spaces ignored)."""
    return [int(c) for c in text.replace(" ", "")]


# --------------------------------------------------------------------------------------------
# Reference model, from the definition (no tables, no numpy).
# --------------------------------------------------------------------------------------------

_PAIRS = {
    IEEE: {(1, 0): 0, (0, 1): 1},
    THOMAS: {(0, 1): 0, (1, 0): 1},
}


def _ref_report(
    chips: list[int], convention: Convention, uart: bool
) -> tuple[DecodeReport, tuple[int, ...]]:
    cells = 10 if uart else 8
    per_char = 2 * cells
    n_chars, trailing = divmod(len(chips), per_char)
    data = bytearray()
    invalid: list[int] = []
    framing: list[int] = []
    bad: list[int] = []
    positions: list[int] = []
    for k in range(n_chars):
        bits: list[int | None] = []
        for j in range(cells):
            pair = (chips[k * per_char + 2 * j], chips[k * per_char + 2 * j + 1])
            bit = _PAIRS[convention].get(pair)
            bits.append(bit)
            if bit is None:
                invalid.append(k * cells + j)
                positions.append(k * cells + j)
        frame_bad = False
        if uart:
            if bits[0] == 1:
                frame_bad = True
                positions.append(k * cells)
            if bits[-1] == 0:
                frame_bad = True
                positions.append(k * cells + cells - 1)
            payload_bits = bits[1:9]
        else:
            payload_bits = bits
        if frame_bad:
            framing.append(k)
        if frame_bad or None in bits:
            bad.append(k)
            continue
        data.append(sum(b << i for i, b in enumerate(payload_bits) if b))
    report = DecodeReport(
        data=bytes(data),
        invalid_bit_cells=tuple(invalid),
        framing_errors=tuple(framing),
        bad_characters=tuple(bad),
        n_characters=n_chars,
        trailing_chips=trailing,
    )
    return report, tuple(sorted(positions))


# --------------------------------------------------------------------------------------------
# Golden chips, written by hand from the definition.
# --------------------------------------------------------------------------------------------

# IEEE 802.3: 0 -> 10, 1 -> 01.  UART: start 0, data LSB first, stop 1.
GOLDEN = [
    # byte, convention, uart framing, chips
    (0x00, IEEE, True, "10" + "10 10 10 10 10 10 10 10" + "01"),
    (0x01, IEEE, True, "10" + "01 10 10 10 10 10 10 10" + "01"),
    (0x80, IEEE, True, "10" + "10 10 10 10 10 10 10 01" + "01"),
    (0xFF, IEEE, True, "10" + "01 01 01 01 01 01 01 01" + "01"),
    # 0xA5 = 1010_0101: LSB first 1,0,1,0,0,1,0,1
    (0xA5, IEEE, True, "10" + "01 10 01 10 10 01 10 01" + "01"),
    (0xA5, IEEE, False, "01 10 01 10 10 01 10 01"),
    # G. E. Thomas: 0 -> 01, 1 -> 10.
    (0xA5, THOMAS, True, "01" + "10 01 10 01 01 10 01 10" + "10"),
    (0x01, THOMAS, True, "01" + "10 01 01 01 01 01 01 01" + "10"),
    (0x01, THOMAS, False, "10 01 01 01 01 01 01 01"),
]


@pytest.mark.parametrize(("byte", "convention", "uart", "text"), GOLDEN)
def test_golden_chips(byte: int, convention: Convention, uart: bool, text: str) -> None:
    expected = chips_of(text)
    assert len(expected) == (20 if uart else 16)
    chips = encode(bytes([byte]), convention, uart)
    assert chips.dtype == np.uint8
    assert chips.tolist() == expected
    assert decode(np.array(expected, dtype=np.uint8), convention, uart) == bytes([byte])
    assert decode(expected, convention, uart) == bytes([byte])  # plain lists work too


def test_golden_two_bytes_concatenate() -> None:
    expected = chips_of(GOLDEN[0][3]) + chips_of(GOLDEN[4][3])  # 0x00 then 0xA5
    assert encode(b"\x00\xa5").tolist() == expected


def test_golden_packed() -> None:
    # 0x00, IEEE, UART: chips 1010 1010 | 1010 1010 | 1001 (+4 padding); chip i = bit i % 8.
    assert encode_packed(b"\x00") == bytes([0x55, 0x55, 0x09])
    # A second 0x00 starts at chip 20 = bit 4 of byte 2: byte 2 = 1001 1010 -> 0x59,
    # byte 3 = 1010 1010 -> 0x55, byte 4 = 1010 1001 -> 0x95.
    assert encode_packed(b"\x00\x00") == bytes([0x55, 0x55, 0x59, 0x55, 0x95])
    # Without framing 0x00 is 16 chips "10" * 8 = two bytes 0x55.
    assert encode_packed(b"\x00", uart_framing=False) == bytes([0x55, 0x55])
    assert decode_packed(bytes([0x55, 0x55, 0x59, 0x55, 0x95])) == b"\x00\x00"


def test_empty() -> None:
    for convention in Convention:
        for uart in (True, False):
            assert encode(b"", convention, uart).size == 0
            assert encode_packed(b"", convention, uart) == b""
            assert decode(np.zeros(0, dtype=np.uint8), convention, uart) == b""
            assert decode_packed(b"", convention, uart) == b""
            assert decode_report([], convention, uart).ok


def test_thomas_is_complement_of_ieee() -> None:
    data = bytes(range(256))
    for uart in (True, False):
        assert np.array_equal(encode(data, THOMAS, uart), 1 - encode(data, IEEE, uart))


def test_all_bytes_match_reference() -> None:
    data = bytes(range(256))
    for convention in Convention:
        for uart in (True, False):
            chips = encode(data, convention, uart)
            per_char = chips_per_character(uart)
            for value in range(256):
                char = chips[value * per_char : (value + 1) * per_char].tolist()
                report, _ = _ref_report(char, convention, uart)
                assert report.data == bytes([value])


def test_chips_per_character_and_packed_size() -> None:
    assert chips_per_character(True) == 20
    assert chips_per_character(False) == 16
    assert [packed_size(n) for n in range(5)] == [0, 3, 5, 8, 10]
    assert [packed_size(n, uart_framing=False) for n in range(3)] == [0, 2, 4]
    for n in range(7):
        assert len(encode_packed(bytes(n))) == packed_size(n)
    with pytest.raises(ProtocolError):
        packed_size(-1)


# --------------------------------------------------------------------------------------------
# Round trips.
# --------------------------------------------------------------------------------------------


@given(payloads, conventions, framings)
def test_roundtrip(data: bytes, convention: Convention, uart: bool) -> None:
    chips = encode(data, convention, uart)
    assert chips.shape == (len(data) * chips_per_character(uart),)
    assert set(np.unique(chips).tolist()) <= {0, 1}
    assert decode(chips, convention, uart) == data
    packed = encode_packed(data, convention, uart)
    assert isinstance(packed, bytes)
    assert packed == pack_chips(chips)
    assert len(packed) == packed_size(len(data), uart)
    assert np.array_equal(unpack_chips(packed, chips.size), chips)
    assert decode_packed(packed, convention, uart) == data
    assert decode_packed(packed, convention, uart, n_chips=chips.size) == data
    report = decode_report_packed(packed, convention, uart)
    assert report.ok and report.data == data and report.n_characters == len(data)


@given(payloads, conventions, framings)
def test_dc_balance_is_zero(data: bytes, convention: Convention, uart: bool) -> None:
    assert dc_balance(encode(data, convention, uart)) == 0


def test_dc_balance_counts() -> None:
    assert dc_balance([1, 1, 1, 0]) == 2
    assert dc_balance(np.array([0, 0, 1], dtype=np.uint8)) == -1
    assert dc_balance([]) == 0


@given(st.binary(min_size=1, max_size=32), conventions)
def test_inputs_as_bytearray_memoryview_and_array(data: bytes, convention: Convention) -> None:
    expected = encode(data, convention)
    for form in (bytearray(data), memoryview(data), np.frombuffer(data, dtype=np.uint8)):
        assert np.array_equal(encode(form, convention), expected)
        assert encode_packed(form, convention) == encode_packed(data, convention)
    assert decode(expected.astype(np.int64), convention) == data
    assert decode(expected.astype(bool), convention) == data
    assert decode_packed(bytearray(encode_packed(data, convention)), convention) == data


def test_large_roundtrip() -> None:
    data = np.random.default_rng(1).integers(0, 256, 1 << 20, dtype=np.uint8).tobytes()
    for convention in Convention:
        assert decode(encode(data, convention), convention) == data
        assert decode_packed(encode_packed(data, convention), convention) == data
        raw = encode_packed(data, convention, uart_framing=False)
        assert decode_packed(raw, convention, uart_framing=False) == data


# --------------------------------------------------------------------------------------------
# Corruption.
# --------------------------------------------------------------------------------------------


@given(st.binary(min_size=1, max_size=32), conventions, framings, st.data())
def test_single_chip_flip_is_located(
    data: bytes, convention: Convention, uart: bool, draw: st.DataObject
) -> None:
    chips = encode(data, convention, uart)
    index = draw.draw(st.integers(0, chips.size - 1), label="chip index")
    chips[index] ^= 1
    cell = index // 2
    cells = chips_per_character(uart) // 2
    with pytest.raises(ManchesterError) as info:
        decode(chips, convention, uart)
    assert info.value.positions == (cell,)
    with pytest.raises(ManchesterError) as info:
        decode_packed(pack_chips(chips), convention, uart)
    assert info.value.positions == (cell,)
    report = decode_report(chips, convention, uart)
    char = cell // cells
    assert report.invalid_bit_cells == (cell,)
    assert report.framing_errors == ()
    assert report.bad_characters == (char,)
    assert report.data == data[:char] + data[char + 1 :]
    assert not report.ok
    assert decode_report_packed(pack_chips(chips), convention, uart) == report


@given(st.binary(min_size=1, max_size=32), conventions, framings, st.data())
def test_pair_flip_changes_the_bit(
    data: bytes, convention: Convention, uart: bool, draw: st.DataObject
) -> None:
    chips = encode(data, convention, uart)
    cell = draw.draw(st.integers(0, chips.size // 2 - 1), label="bit cell")
    chips[2 * cell] ^= 1
    chips[2 * cell + 1] ^= 1
    assert dc_balance(chips) == 0  # still a valid pair
    cells = chips_per_character(uart) // 2
    char, offset = divmod(cell, cells)
    report = decode_report(chips, convention, uart)
    assert report.invalid_bit_cells == ()
    if uart and offset in (0, cells - 1):
        # Start bit became 1 or stop bit became 0: a framing error, located.
        with pytest.raises(ManchesterError) as info:
            decode(chips, convention, uart)
        assert info.value.positions == (cell,)
        assert report.framing_errors == (char,)
        assert report.bad_characters == (char,)
        assert report.data == data[:char] + data[char + 1 :]
    else:
        # A data bit flipped: nothing at chip level betrays it.
        bit = offset - 1 if uart else offset
        expected = bytearray(data)
        expected[char] ^= 1 << bit
        assert decode(chips, convention, uart) == bytes(expected)
        assert report.ok and report.data == bytes(expected)


@st.composite
def corrupted_streams(draw: st.DrawFn) -> tuple[bytes, Convention, bool, np.ndarray, dict]:
    data = draw(st.binary(min_size=1, max_size=40))
    convention = draw(conventions)
    uart = draw(framings)
    chips = encode(data, convention, uart)
    per_char = chips_per_character(uart)
    cells = per_char // 2
    chosen = draw(st.sets(st.integers(0, len(data) - 1), max_size=len(data)))
    expected: dict = {"invalid": [], "framing": [], "bad": sorted(chosen)}
    for char in sorted(chosen):
        kinds = ["chip", "pair00or11"] + (["start", "stop"] if uart else [])
        kind = draw(st.sampled_from(kinds))
        base = char * per_char
        if kind == "chip":
            offset = draw(st.integers(0, per_char - 1))
            chips[base + offset] ^= 1
            expected["invalid"].append(char * cells + offset // 2)
        elif kind == "pair00or11":
            cell = draw(st.integers(0, cells - 1))
            level = draw(st.integers(0, 1))
            chips[base + 2 * cell : base + 2 * cell + 2] = level
            expected["invalid"].append(char * cells + cell)
        else:
            cell = 0 if kind == "start" else cells - 1
            chips[base + 2 * cell : base + 2 * cell + 2] ^= 1
            expected["framing"].append(char)
    good = bytes(b for i, b in enumerate(data) if i not in chosen)
    expected["data"] = good
    return data, convention, uart, chips, expected


@given(corrupted_streams())
def test_report_names_the_bad_characters(stream: tuple) -> None:
    data, convention, uart, chips, expected = stream
    report = decode_report(chips, convention, uart)
    assert report.data == expected["data"]
    assert report.invalid_bit_cells == tuple(sorted(expected["invalid"]))
    assert report.framing_errors == tuple(sorted(expected["framing"]))
    assert report.bad_characters == tuple(expected["bad"])
    assert report.n_characters == len(data)
    assert report.ok == (not expected["bad"])
    assert decode_report_packed(pack_chips(chips), convention, uart) == report
    if expected["bad"]:
        with pytest.raises(ManchesterError) as info:
            decode(chips, convention, uart)
        _, ref_positions = _ref_report(chips.tolist(), convention, uart)
        assert info.value.positions == ref_positions
    else:
        assert decode(chips, convention, uart) == data


@settings(max_examples=300)
@given(st.lists(st.integers(0, 1), max_size=130), conventions, framings)
def test_arbitrary_chips_agree_with_reference(
    chips: list[int], convention: Convention, uart: bool
) -> None:
    ref, ref_positions = _ref_report(chips, convention, uart)
    report = decode_report(chips, convention, uart)
    assert report == ref
    n_chips = len(chips)
    packed = pack_chips(chips)
    assert decode_report_packed(packed, convention, uart, n_chips=n_chips) == ref
    try:
        result = decode(np.array(chips, dtype=np.uint8), convention, uart)
    except ManchesterError as exc:
        assert not ref.ok
        assert exc.positions == (ref_positions if not ref.trailing_chips else ())
    else:
        assert ref.ok and result == ref.data
    try:
        result = decode_packed(packed, convention, uart, n_chips=n_chips)
    except ManchesterError:
        assert not ref.ok
    else:
        assert ref.ok and result == ref.data


@settings(max_examples=200)
@given(st.binary(max_size=40), conventions, framings)
def test_arbitrary_packed_bytes_only_raise_manchester_error(
    packed: bytes, convention: Convention, uart: bool
) -> None:
    try:
        result = decode_packed(packed, convention, uart)
    except ManchesterError:
        return
    assert len(result) <= 8 * len(packed) // chips_per_character(uart)


def test_padding_bits_are_ignored() -> None:
    packed = bytearray(encode_packed(b"\x5a"))
    packed[-1] |= 0xF0
    assert decode_packed(bytes(packed)) == b"\x5a"


def test_non_binary_chips_are_invalid_cells() -> None:
    chips = encode(b"ab").astype(np.int16)
    chips[5] = 2
    chips[30] = -1
    with pytest.raises(ManchesterError) as info:
        decode(chips)
    assert info.value.positions == (2, 15)
    report = decode_report(chips)
    assert report.invalid_bit_cells == (2, 15)
    assert report.bad_characters == (0, 1)
    assert report.data == b""
    with pytest.raises(ManchesterError) as info:
        pack_chips(chips)
    assert info.value.positions == (2, 15)
    chips8 = encode(b"ab")
    chips8[39] = 7
    assert decode_report(chips8).invalid_bit_cells == (19,)


# --------------------------------------------------------------------------------------------
# Lengths and bad arguments.
# --------------------------------------------------------------------------------------------


@given(st.binary(max_size=16), conventions, framings, st.integers(1, 19))
def test_wrong_length_raises(data: bytes, convention: Convention, uart: bool, extra: int) -> None:
    per_char = chips_per_character(uart)
    assume(extra < per_char)
    chips = np.concatenate([encode(data, convention, uart), np.ones(extra, dtype=np.uint8)])
    with pytest.raises(ManchesterError) as info:
        decode(chips, convention, uart)
    assert info.value.positions == ()
    report = decode_report(chips, convention, uart)
    assert report.data == data
    assert report.trailing_chips == extra
    assert report.bad_characters == ()
    assert not report.ok
    with pytest.raises(ManchesterError):
        decode_packed(pack_chips(chips), convention, uart, n_chips=chips.size)


def test_truncated_chip_stream_raises() -> None:
    chips = encode(b"xyz")
    with pytest.raises(ManchesterError):
        decode(chips[:-1])
    with pytest.raises(ManchesterError):
        decode(chips[:19])


def test_packed_length_checks() -> None:
    packed = encode_packed(b"abcd")  # 10 bytes
    with pytest.raises(ManchesterError):
        decode_packed(packed[:-1])  # 72 bits: 3 characters + 12 spare bits
    with pytest.raises(ManchesterError):
        decode_packed(packed, n_chips=60)  # 60 chips need 8 bytes, not 10
    with pytest.raises(ManchesterError):
        decode_packed(packed + b"\x00")
    assert decode_packed(packed[:8], n_chips=60) == b"abc"
    with pytest.raises(ManchesterError):
        decode_packed(b"\x55", uart_framing=False)
    with pytest.raises(ManchesterError):
        unpack_chips(b"\x00\x00", n_chips=17)
    assert unpack_chips(b"\x01\x80").tolist() == [1] + [0] * 14 + [1]


def test_bad_arguments() -> None:
    with pytest.raises(ManchesterError):
        decode(np.zeros((2, 20), dtype=np.uint8))
    with pytest.raises(ManchesterError):
        decode(np.zeros(20, dtype=np.float64))
    with pytest.raises(ProtocolError):
        encode(b"x", "ieee")  # type: ignore[arg-type]
    assert issubclass(ManchesterError, ValueError)


# --------------------------------------------------------------------------------------------
# Wire time.
# --------------------------------------------------------------------------------------------


def test_wire_time() -> None:
    # 1 Mbit/s UART -> 2 Mchips/s: a framed byte is 20 chips = 10 us, unframed 16 chips = 8 us.
    assert math.isclose(wire_time_s(1, 2_000_000), 10e-6)
    assert math.isclose(wire_time_s(1, 2_000_000, uart_framing=False), 8e-6)
    assert math.isclose(wire_time_s(1000, 2_000_000), 0.01)
    assert wire_time_s(0, 1.0) == 0.0
    data = b"hello"
    rate = 115_200 * 2
    assert math.isclose(wire_time_s(len(data), rate), encode(data).size / rate)
    with pytest.raises(ProtocolError):
        wire_time_s(1, 0)
    with pytest.raises(ProtocolError):
        wire_time_s(-1, 1e6)
