"""Manchester coding of the tendon bus (half-duplex RS-485 over the two power tendons).

The tendons also carry DC power, so the MCU's USART runs in Manchester mode: every UART
character goes on the wire as 10 bits -- a start bit (0), 8 data bits LSB first, a stop bit
(1) -- and every bit becomes two *chips* (half-bit line levels, 0 or 1).  A stream of valid
chip pairs has exactly as many 1 chips as 0 chips (no DC).

Conventions (chips listed in wire order, first half-bit first):

* :attr:`Convention.IEEE_802_3` (the default): bit 0 -> ``(1, 0)`` (high-to-low),
  bit 1 -> ``(0, 1)`` (low-to-high);
* :attr:`Convention.G_E_THOMAS`: the inverse, bit 0 -> ``(0, 1)``, bit 1 -> ``(1, 0)``.

A pair ``(0, 0)`` or ``(1, 1)`` is invalid.  With ``uart_framing=False`` a byte is just its
8 data bits, LSB first (16 chips); with ``uart_framing=True`` (the default) it is 20 chips.

Vocabulary and indices used throughout:

* *chip index*: position of a chip in the stream, from 0.
* *bit cell*: one chip pair; its index is ``chip_index // 2`` counted over the whole stream
  (so with UART framing character ``k`` owns bit cells ``10*k .. 10*k + 9``, its start bit
  being cell ``10*k`` and its stop bit cell ``10*k + 9``).
* *character index*: position of a (10- or 8-bit) character in the stream, from 0.

Two representations of a chip stream are supported:

* **unpacked**: a 1-D ``numpy.uint8`` array with one chip (0 or 1) per element
  (:func:`encode`, :func:`decode`, :func:`decode_report`);
* **packed**: ``bytes`` with 8 chips per byte, *little bit order*: chip ``i`` is bit
  ``i % 8`` (value ``1 << (i % 8)``) of byte ``i // 8``, exactly
  ``numpy.packbits(chips, bitorder="little")``.  The last byte is padded with 0 bits when the
  chip count is not a multiple of 8 (an odd number of UART-framed characters leaves 4 padding
  bits); decoders ignore padding bits.  (:func:`encode_packed`, :func:`decode_packed`,
  :func:`decode_report_packed`; :func:`pack_chips` / :func:`unpack_chips` convert.)

Everything is vectorised with lookup tables built at import (a 256 x 20 chip table per
convention, 40-bit chip words for pairs of characters, and a 2**20-entry table mapping every
20-chip character word to its byte or to "not a valid character"; about 5 MB in all), so
megabytes go through in milliseconds.  No I/O.  Problems with a chip stream (bad chips,
framing, length) raise :class:`protocol.errors.ManchesterError`; other bad arguments (an
unknown convention, a negative byte count) raise :class:`protocol.errors.ProtocolError`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.errors import ManchesterError, ProtocolError
from protocol.topology import BITS_PER_CHAR

__all__ = [
    "CHIPS_PER_BIT",
    "Convention",
    "DecodeReport",
    "chips_per_character",
    "dc_balance",
    "decode",
    "decode_packed",
    "decode_report",
    "decode_report_packed",
    "encode",
    "encode_packed",
    "pack_chips",
    "packed_size",
    "unpack_chips",
    "wire_time_s",
]

#: Byte-like inputs accepted wherever a byte string is expected (a ``uint8`` array works too).
BytesLike = bytes | bytearray | memoryview | npt.NDArray[np.uint8]

#: Chips per bit cell.
CHIPS_PER_BIT: Final = 2
_UART_BITS: Final = BITS_PER_CHAR  # start + 8 data + stop
_RAW_BITS: Final = 8
_MAX_LISTED: Final = 10  # positions spelled out in an error message


class Convention(enum.Enum):
    """Which chip pair stands for which bit (see the module docstring)."""

    #: IEEE 802.3: bit 0 -> chips (1, 0) (high-to-low), bit 1 -> chips (0, 1) (low-to-high).
    IEEE_802_3 = "ieee_802_3"
    #: G. E. Thomas: bit 0 -> chips (0, 1), bit 1 -> chips (1, 0).
    G_E_THOMAS = "g_e_thomas"


def chips_per_character(uart_framing: bool = True) -> int:
    """Chips one byte occupies on the wire: 20 with UART framing, 16 without."""
    return CHIPS_PER_BIT * (_UART_BITS if uart_framing else _RAW_BITS)


def packed_size(n_bytes: int, uart_framing: bool = True) -> int:
    """Length in bytes of the packed chip stream of ``n_bytes`` payload bytes (8 chips/byte)."""
    if n_bytes < 0:
        raise ProtocolError(f"n_bytes must be >= 0, got {n_bytes}")
    return -(-n_bytes * chips_per_character(uart_framing) // 8)


# --------------------------------------------------------------------------------------------
# Lookup tables (built once at import, all vectorised).
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Tables:
    """Everything needed to encode/decode one (convention, framing) combination."""

    cells: int  # bit cells per character (10 or 8)
    chips: npt.NDArray[np.uint8]  # (256, 2*cells) chips in wire order
    chips_void: npt.NDArray[np.void]  # the same rows as one opaque 2*cells-byte item each
    packed: npt.NDArray[np.void]  # UART: (65536,) 5-byte chip words of byte pairs; raw: (256,) 2
    word: npt.NDArray[np.uint32]  # (256,) chip word: chip i at bit i
    dec: npt.NDArray[np.int16]  # (2**(2*cells),) chip word -> byte, or -1 if not a valid char


def _build_tables(convention: Convention, uart_framing: bool) -> _Tables:
    values = np.arange(256, dtype=np.uint16)
    bits = ((values[:, None] >> np.arange(8, dtype=np.uint16)) & 1).astype(np.uint8)  # LSB first
    if uart_framing:
        start = np.zeros((256, 1), dtype=np.uint8)
        stop = np.ones((256, 1), dtype=np.uint8)
        bits = np.concatenate([start, bits, stop], axis=1)
    cells = bits.shape[1]
    n_chips = CHIPS_PER_BIT * cells
    # IEEE 802.3: bit b -> (1 - b, b); G. E. Thomas is the complement: (b, 1 - b).
    chips = np.stack([1 - bits, bits], axis=2).reshape(256, n_chips)
    if convention is Convention.G_E_THOMAS:
        chips = 1 - chips
    chips = np.ascontiguousarray(chips, dtype=np.uint8)
    word = (chips.astype(np.uint32) << np.arange(n_chips, dtype=np.uint32)).sum(
        axis=1, dtype=np.uint32
    )
    dec = np.full(1 << n_chips, -1, dtype=np.int16)
    dec[word] = np.arange(256, dtype=np.int16)
    if uart_framing:
        # Index i = first byte | second byte << 8 (a little-endian uint16 of two payload bytes);
        # entry = the 40 chips of both characters as 5 little-endian bytes.
        pair = np.arange(65536, dtype=np.uint32)
        w40 = word[pair & 0xFF].astype(np.uint64) | (word[pair >> 8].astype(np.uint64) << 20)
        packed = w40.astype("<u8").view(np.uint8).reshape(65536, 8)[:, :5].copy()
        packed_void = packed.view("V5").reshape(65536)
    else:
        packed_void = word.astype("<u2").view("V2").reshape(256)
    return _Tables(
        cells=cells,
        chips=chips,
        chips_void=chips.view(f"V{n_chips}").reshape(256),
        packed=packed_void,
        word=word,
        dec=dec,
    )


_TABLES: Final[dict[tuple[Convention, bool], _Tables]] = {
    (convention, framing): _build_tables(convention, framing)
    for convention in Convention
    for framing in (True, False)
}


def _tables(convention: Convention, uart_framing: bool) -> _Tables:
    try:
        return _TABLES[(convention, bool(uart_framing))]
    except (KeyError, TypeError):
        raise ProtocolError(f"unknown Manchester convention {convention!r}") from None


def _as_u8(data: BytesLike) -> npt.NDArray[np.uint8]:
    """A 1-D ``uint8`` view (no copy when possible) of a bytes-like object."""
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise ProtocolError(f"expected a uint8 array, got dtype {data.dtype}")
        return data.reshape(-1)
    return np.frombuffer(data, dtype=np.uint8)


# --------------------------------------------------------------------------------------------
# Encoding.
# --------------------------------------------------------------------------------------------


def encode(
    data: BytesLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
) -> npt.NDArray[np.uint8]:
    """Manchester-encode ``data`` into unpacked chips.

    Returns a new 1-D ``uint8`` array of ``len(data) * chips_per_character(uart_framing)``
    chips, each 0 or 1, in wire order.
    """
    tables = _tables(convention, uart_framing)
    index = _as_u8(data)
    chars = np.take(tables.chips_void, index, mode="clip")  # one opaque 20/16-chip row per byte
    return chars.view(np.uint8).reshape(-1)


def encode_packed(
    data: BytesLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
) -> bytes:
    """Manchester-encode ``data`` into packed chips (8 per byte, little bit order).

    The result is ``packed_size(len(data), uart_framing)`` bytes and equals
    ``pack_chips(encode(data, convention, uart_framing))``; padding bits are 0.
    """
    tables = _tables(convention, uart_framing)
    index = _as_u8(data)
    if not uart_framing:
        return np.take(tables.packed, index, mode="clip").tobytes()
    n_even = index.size - index.size % 2
    pairs = np.ascontiguousarray(index[:n_even]).view("<u2")
    out = np.take(tables.packed, pairs, mode="clip").tobytes()
    if n_even != index.size:
        # The odd last character starts on a byte boundary (20 * even chips); its 20-bit word
        # fills 2.5 bytes and the top 4 bits are padding.
        out += int(tables.word[index[-1]]).to_bytes(3, "little")
    return out


# --------------------------------------------------------------------------------------------
# Packing helpers.
# --------------------------------------------------------------------------------------------


def _check_chips(chips: npt.ArrayLike) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.intp]]:
    """Validate an unpacked chip array.

    Returns it as 0/1 ``uint8`` and the sorted chip indices whose value was neither 0 nor 1
    (those chips are taken as 0 in the returned array).
    """
    array = np.asarray(chips)
    if array.ndim != 1:
        raise ManchesterError(f"chips must be a 1-D array, got shape {array.shape}")
    if array.size == 0:  # whatever its dtype ([] comes as float64)
        return np.zeros(0, dtype=np.uint8), np.empty(0, dtype=np.intp)
    if array.dtype == np.bool_:
        return array.view(np.uint8), np.empty(0, dtype=np.intp)
    if array.dtype.kind not in "iu":
        raise ManchesterError(f"chips must be integers 0/1, got dtype {array.dtype}")
    if array.dtype == np.uint8:
        if array.size == 0 or int(array.max()) <= 1:
            return array, np.empty(0, dtype=np.intp)
    not_binary = (array != 0) & (array != 1)
    bad = np.flatnonzero(not_binary)
    return (array == 1).view(np.uint8), bad


def pack_chips(chips: npt.ArrayLike) -> bytes:
    """Pack unpacked chips (0/1) 8 per byte, little bit order, zero padding bits.

    Raises :class:`ManchesterError` if a chip is not 0 or 1 (``positions`` = the bit cells
    holding such chips).
    """
    array, not_binary = _check_chips(chips)
    if not_binary.size:
        cells = np.unique(not_binary // CHIPS_PER_BIT)
        raise ManchesterError(
            f"{not_binary.size} chip(s) are neither 0 nor 1", tuple(cells.tolist())
        )
    return np.packbits(array, bitorder="little").tobytes()


def unpack_chips(packed: BytesLike, n_chips: int | None = None) -> npt.NDArray[np.uint8]:
    """Unpack packed chips (little bit order) into a 1-D ``uint8`` array of 0/1.

    ``n_chips`` (default ``8 * len(packed)``) is how many chips to return; it must satisfy
    ``ceil(n_chips / 8) == len(packed)``, otherwise :class:`ManchesterError`.
    """
    array = _as_u8(packed)
    if n_chips is None:
        n_chips = 8 * array.size
    if n_chips < 0 or -(-n_chips // 8) != array.size:
        raise ManchesterError(f"{array.size} packed bytes cannot hold exactly {n_chips} chips")
    return np.unpackbits(array, count=n_chips, bitorder="little")


# --------------------------------------------------------------------------------------------
# Decoding.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DecodeReport:
    """What a lenient decode found in a chip stream.

    ``data``
        The bytes of the *good* characters, in stream order: every bit cell a valid chip pair
        and (with UART framing) start bit 0 and stop bit 1.  **Bad characters are omitted**
        (not replaced), so ``len(data) == n_characters - len(bad_characters)``; the stream
        index of ``data[i]`` is the ``i``-th index not in ``bad_characters``.
    ``invalid_bit_cells``
        Sorted stream bit-cell indices (``chip_index // 2``) whose chip pair is ``(0, 0)`` or
        ``(1, 1)`` (or holds a chip that is neither 0 nor 1).
    ``framing_errors``
        Sorted character indices whose start bit decoded as 1 or whose stop bit decoded as 0
        from a *valid* chip pair (an invalid start/stop pair is reported in
        ``invalid_bit_cells`` only).  Always empty without UART framing.
    ``bad_characters``
        Sorted character indices left out of ``data``: those with an invalid bit cell or a
        framing error.
    ``n_characters``
        Whole characters in the stream (good and bad).
    ``trailing_chips``
        Chips after the last whole character; not examined and not decoded.

    A pair flipped into the other valid pair (both chips flipped) changes a bit without any
    chip-level trace: in a data bit it silently yields a different byte; in a start/stop bit
    it is a framing error.
    """

    data: bytes
    invalid_bit_cells: tuple[int, ...]
    framing_errors: tuple[int, ...]
    bad_characters: tuple[int, ...]
    n_characters: int
    trailing_chips: int = 0

    @property
    def ok(self) -> bool:
        """True if every character was good and no chips were left over."""
        return not self.bad_characters and self.trailing_chips == 0


def _lookup(
    packed: npt.NDArray[np.uint8], n_chars: int, tables: _Tables
) -> tuple[npt.NDArray[np.unsignedinteger], npt.NDArray[np.int16]]:
    """Chip words of the first ``n_chars`` characters of ``packed`` and their table values.

    With UART framing both arrays are *planar*, shape ``(2, ceil(n_chars / 2))``: row 0 holds
    the even characters, row 1 the odd ones, and an odd ``n_chars`` gets a dummy valid last
    character in row 1.  Without UART framing they are flat, shape ``(n_chars,)``.  A word
    has chip ``j`` of its character at bit ``j``; a value is the byte, or -1 if the word is not
    a valid, well-framed character.  Bits of ``packed`` after ``n_chars`` are ignored.
    """
    if tables.cells == _RAW_BITS:
        raw = np.ascontiguousarray(packed[: 2 * n_chars])
        words_16 = np.frombuffer(raw, dtype="<u2")
        return words_16, np.take(tables.dec, words_16, mode="clip")
    n_pairs = -(-n_chars // 2)
    words = np.empty((2, n_pairs), dtype=np.uint32)
    if n_pairs > 1:
        # Two characters = 40 chips = 5 bytes.  Read the first character of each 5-byte group
        # as an unaligned little-endian uint32 at byte 5*i (chips 0..19 = bits 0..19) and the
        # second at byte 5*i + 2 (chips 20..39 = bits 4..23); the last group is done apart so
        # no read goes past the end of ``packed`` (the last group has at least 3 bytes).
        body = np.ascontiguousarray(packed[: 5 * (n_pairs - 1) + 1])
        strides = (5,)
        first = np.ndarray((n_pairs - 1,), dtype="<u4", buffer=body, strides=strides)
        second = np.ndarray((n_pairs - 1,), dtype="<u4", buffer=body, offset=2, strides=strides)
        np.bitwise_and(first, 0xFFFFF, out=words[0, :-1])
        np.right_shift(second, 4, out=words[1, :-1])
        words[1, :-1] &= 0xFFFFF
    if n_pairs:
        last = int.from_bytes(packed[5 * (n_pairs - 1) : 5 * n_pairs].tobytes(), "little")
        words[0, -1] = last & 0xFFFFF
        words[1, -1] = (last >> 20) & 0xFFFFF if n_chars % 2 == 0 else tables.word[0]
    return words, np.take(tables.dec, words, mode="clip")


def _values_to_bytes(values: npt.NDArray[np.int16], n_chars: int) -> bytes:
    """The bytes of all-valid table values as laid out by :func:`_lookup`."""
    if values.ndim == 1:
        return values.astype(np.uint8).tobytes()
    # Planar even/odd characters -> little-endian uint16 (even | odd << 8) -> bytes in order.
    even = values[0].view(np.uint16)
    odd = values[1].view(np.uint16)
    odd <<= 8
    odd |= even
    return odd.astype("<u2", copy=False).view(np.uint8)[:n_chars].tobytes()


def _decode_chars(
    packed: npt.NDArray[np.uint8],
    n_chars: int,
    tables: _Tables,
    convention: Convention,
    trailing_chips: int,
    not_binary_cells: npt.NDArray[np.intp],
) -> tuple[DecodeReport, tuple[int, ...]]:
    """Decode ``n_chars`` characters of packed chips; return the report and error positions.

    Error positions are the sorted bit cells that are invalid pairs or wrong start/stop bits.
    ``not_binary_cells`` are bit cells to be taken as invalid whatever their chips.
    """
    empty: tuple[int, ...] = ()
    words, values = _lookup(packed, n_chars, tables)
    if not not_binary_cells.size and (values.size == 0 or int(values.min()) >= 0):
        data = _values_to_bytes(values, n_chars)
        return DecodeReport(data, empty, empty, empty, n_chars, trailing_chips), empty
    # Slow path: back to stream order, then look closely at the bad characters only.
    cells = tables.cells
    words_c = words.T.reshape(-1)[:n_chars].astype(np.uint32)
    values_c = values.T.reshape(-1)[:n_chars]
    bad = values_c < 0
    if not_binary_cells.size:
        bad[not_binary_cells // cells] = True
    bad_chars = np.flatnonzero(bad)
    w = words_c[bad_chars]
    if convention is Convention.G_E_THOMAS:
        w = w ^ np.uint32((1 << (CHIPS_PER_BIT * cells)) - 1)  # Thomas = complemented IEEE
    shifts = (CHIPS_PER_BIT * np.arange(cells, dtype=np.uint32))[None, :]
    first = (w[:, None] >> shifts) & 1
    second = (w[:, None] >> (shifts + 1)) & 1
    invalid = first == second  # (n_bad, cells)
    if not_binary_cells.size:
        rows = np.searchsorted(bad_chars, not_binary_cells // cells)
        invalid[rows, not_binary_cells % cells] = True
    bit = second  # IEEE: the bit is the second chip
    if cells == _UART_BITS:
        start_bad = ~invalid[:, 0] & (bit[:, 0] == 1)
        stop_bad = ~invalid[:, -1] & (bit[:, -1] == 0)
    else:
        start_bad = stop_bad = np.zeros(bad_chars.size, dtype=bool)
    # The table holds exactly the valid, well-framed words, so every bad character has an
    # invalid bit cell or a framing error (or a non-binary chip, which is an invalid cell).
    rows, cols = np.nonzero(invalid)
    invalid_cells = bad_chars[rows] * cells + cols
    framing_cells = np.concatenate(
        [bad_chars[start_bad] * cells, bad_chars[stop_bad] * cells + (cells - 1)]
    )
    report = DecodeReport(
        data=values_c[~bad].astype(np.uint8).tobytes(),
        invalid_bit_cells=tuple(invalid_cells.tolist()),
        framing_errors=tuple(bad_chars[start_bad | stop_bad].tolist()),
        bad_characters=tuple(bad_chars.tolist()),
        n_characters=n_chars,
        trailing_chips=trailing_chips,
    )
    return report, tuple(np.union1d(invalid_cells, framing_cells).tolist())


def _unpacked_report(
    chips: npt.ArrayLike, convention: Convention, uart_framing: bool
) -> tuple[DecodeReport, tuple[int, ...]]:
    tables = _tables(convention, uart_framing)
    array, not_binary = _check_chips(chips)
    per_char = chips_per_character(uart_framing)
    n_chars, trailing = divmod(array.size, per_char)
    used = n_chars * per_char
    if trailing:
        array = array[:used]
        not_binary = not_binary[not_binary < used]
    packed = np.packbits(array, bitorder="little")
    not_binary_cells = np.unique(not_binary // CHIPS_PER_BIT)
    return _decode_chars(packed, n_chars, tables, convention, trailing, not_binary_cells)


def _packed_report(
    packed: BytesLike, convention: Convention, uart_framing: bool, n_chips: int | None
) -> tuple[DecodeReport, tuple[int, ...]]:
    tables = _tables(convention, uart_framing)
    array = _as_u8(packed)
    per_char = chips_per_character(uart_framing)
    if n_chips is None:
        n_chars = 8 * array.size // per_char
        if 8 * array.size - n_chars * per_char >= 8:
            raise ManchesterError(
                f"{array.size} packed bytes are not a whole number of {per_char}-chip "
                "characters plus padding; pass n_chips"
            )
        n_chips = n_chars * per_char
    elif n_chips < 0 or -(-n_chips // 8) != array.size:
        raise ManchesterError(f"{array.size} packed bytes cannot hold exactly {n_chips} chips")
    n_chars, trailing = divmod(n_chips, per_char)
    no_cells = np.empty(0, dtype=np.intp)
    return _decode_chars(array, n_chars, tables, convention, trailing, no_cells)


def _raise_if_bad(report: DecodeReport, positions: tuple[int, ...], per_char: int) -> bytes:
    if report.trailing_chips:
        n_chips = report.n_characters * per_char + report.trailing_chips
        raise ManchesterError(
            f"{n_chips} chips is not a whole number of {per_char}-chip characters"
        )
    if not report.bad_characters:
        return report.data
    parts = []
    if report.invalid_bit_cells:
        parts.append(
            f"{len(report.invalid_bit_cells)} invalid chip pair(s) at bit cell(s) "
            f"{_listing(report.invalid_bit_cells)}"
        )
    if report.framing_errors:
        parts.append(
            f"{len(report.framing_errors)} framing error(s) (bad start/stop bit) in "
            f"character(s) {_listing(report.framing_errors)}"
        )
    raise ManchesterError("Manchester decode failed: " + "; ".join(parts), positions)


def _listing(items: tuple[int, ...]) -> str:
    shown = ", ".join(str(i) for i in items[:_MAX_LISTED])
    return f"[{shown}{', ...' if len(items) > _MAX_LISTED else ''}]"


def decode(
    chips: npt.ArrayLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
) -> bytes:
    """Decode unpacked chips (a 1-D integer array of 0/1) back into bytes, strictly.

    Raises :class:`ManchesterError` if the chip count is not a multiple of 20 (16 without UART
    framing; ``positions`` empty), or if any chip pair is invalid or any start bit is 1 or stop
    bit 0.  Then ``positions`` holds the sorted bit-cell indices (``chip_index // 2``) of the
    invalid pairs and of the wrong start/stop bits -- nothing else is guessed.  A chip that is
    neither 0 nor 1 makes its pair invalid.
    """
    report, positions = _unpacked_report(chips, convention, uart_framing)
    return _raise_if_bad(report, positions, chips_per_character(uart_framing))


def decode_packed(
    packed: BytesLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
    n_chips: int | None = None,
) -> bytes:
    """Decode packed chips (8 per byte, little bit order) back into bytes, strictly.

    ``n_chips`` is the number of chips in the stream; by default it is the largest whole number
    of characters that fits in ``8 * len(packed)`` bits, which must then leave fewer than 8
    padding bits (so ``decode_packed(encode_packed(x)) == x``).  Padding bits are ignored.
    Errors as for :func:`decode`.
    """
    report, positions = _packed_report(packed, convention, uart_framing, n_chips)
    return _raise_if_bad(report, positions, chips_per_character(uart_framing))


def decode_report(
    chips: npt.ArrayLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
) -> DecodeReport:
    """Decode unpacked chips leniently: never raises for bad chips, framing or length.

    See :class:`DecodeReport` for what is kept and what is reported.  Raises
    :class:`ManchesterError` only if ``chips`` is not a 1-D integer (or bool) array.
    """
    return _unpacked_report(chips, convention, uart_framing)[0]


def decode_report_packed(
    packed: BytesLike,
    convention: Convention = Convention.IEEE_802_3,
    uart_framing: bool = True,
    n_chips: int | None = None,
) -> DecodeReport:
    """Lenient decode of packed chips; ``n_chips`` as for :func:`decode_packed`.

    Raises :class:`ManchesterError` only when ``len(packed)`` does not match ``n_chips`` (or,
    with ``n_chips=None``, leaves 8 or more bits that are not whole characters).
    """
    return _packed_report(packed, convention, uart_framing, n_chips)[0]


# --------------------------------------------------------------------------------------------
# Line properties.
# --------------------------------------------------------------------------------------------


def dc_balance(chips: npt.ArrayLike) -> int:
    """``count(1) - count(0)`` over unpacked chips (elements that are neither are not counted).

    0 for any valid Manchester encoding: every bit cell holds one 1 chip and one 0 chip.
    """
    array = np.asarray(chips).reshape(-1)
    return int(np.count_nonzero(array == 1)) - int(np.count_nonzero(array == 0))


def wire_time_s(n_bytes: int, baud_chips_per_s: float, uart_framing: bool = True) -> float:
    """Seconds on the wire for ``n_bytes`` payload bytes, sent back to back.

    ``baud_chips_per_s`` is the *chip* rate in chips per second, i.e. twice the UART bit rate
    (a 1 Mbit/s Manchester USART puts 2,000,000 chips/s on the tendons).  Each byte takes 20
    chips with UART framing, 16 without; inter-character idle time is not included.
    """
    if n_bytes < 0:
        raise ProtocolError(f"n_bytes must be >= 0, got {n_bytes}")
    if not baud_chips_per_s > 0:
        raise ProtocolError(f"chip rate must be > 0 chips/s, got {baud_chips_per_s}")
    return n_bytes * chips_per_character(uart_framing) / baud_chips_per_s
