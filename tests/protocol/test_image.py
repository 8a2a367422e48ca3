"""Tests of protocol.image: golden header bytes, every rejection path, and property tests."""

from __future__ import annotations

import hashlib
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import ImageError, ProtocolError
from protocol.image import (
    APP_START_ADDRESS,
    FLASH,
    HEADER_SIZE,
    MAGIC,
    MAX_PAYLOAD,
    BoardType,
    FirmwareImage,
    ImageFlags,
    ImageHeader,
    Version,
    header_crc,
    make_image,
    pages_needed,
    parse_header,
    parse_image,
    signing_bytes,
    split_pages,
    verify_payload,
)

ABC_SHA256 = bytes.fromhex("ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad")

# Header of make_image(b"abc", BoardType.FMCB, "1.2.3", "fmcb", timestamp=0x01020304),
# written by hand from the layout in protocol/image.py:
GOLDEN_HEADER = (
    b"HAND"  # 0   magic 0x444E4148 LE
    + bytes([1, 2])  # 4   header version 1, board FMCB = 2
    + bytes([0, 0])  # 6   flags: unsigned
    + bytes([1, 2, 3, 0])  # 8   version 1.2.3 (u8, u8, u16 LE)
    + bytes([3, 0, 0, 0])  # 12  payload size 3
    + bytes([0x00, 0x20, 0x40, 0x00])  # 16  load address 0x00402000 (page 32)
    + bytes([4, 3, 2, 1])  # 20  timestamp 0x01020304
    + b"fmcb" + bytes(12)  # 24  app name, NUL-padded to 16
    + ABC_SHA256  # 40  SHA-256(b"abc")
    + bytes(64)  # 72  signature slot, zero when unsigned
    + bytes(116)  # 136 reserved
    + bytes([0x76, 0x0E, 0x07, 0x5A])  # 252 CRC-32 of bytes 0..251 = 0x5A070E76
)  # fmt: skip


def golden_image() -> bytes:
    return make_image(b"abc", BoardType.FMCB, "1.2.3", "fmcb", timestamp=0x01020304)


def recrc(header: bytes | bytearray) -> bytes:
    """Return ``header`` (256 B, maybe followed by payload) with a fresh, valid CRC-32."""
    raw = bytearray(header)
    raw[252:256] = zlib.crc32(bytes(raw[:252])).to_bytes(4, "little")
    return bytes(raw)


def patched(offset: int, value: bytes, image: bytes | None = None) -> bytes:
    """A valid-CRC image with ``value`` written at header ``offset``."""
    raw = bytearray(golden_image() if image is None else image)
    raw[offset : offset + len(value)] = value
    return recrc(raw)


# --- golden bytes and known constants ------------------------------------------------------


def test_known_constants() -> None:
    assert hashlib.sha256(b"abc").digest() == ABC_SHA256
    assert header_crc(b"123456789") == 0xCBF43926  # CRC-32 check value
    assert MAGIC.to_bytes(4, "little") == b"HAND"
    assert HEADER_SIZE == FLASH.page_size == 256
    assert APP_START_ADDRESS == 0x402000 == FLASH.page_address(32)
    assert MAX_PAYLOAD == (1020 - 32) * 256 - 256 == 252672


def test_golden_header_bytes() -> None:
    assert len(GOLDEN_HEADER) == 256
    assert zlib.crc32(GOLDEN_HEADER[:252]) == 0x5A070E76
    assert golden_image() == GOLDEN_HEADER + b"abc"


def test_golden_parse() -> None:
    image = parse_image(GOLDEN_HEADER + b"abc", expected_board=BoardType.FMCB)
    h = image.header
    assert image.payload == b"abc"
    assert (h.board, h.version, h.payload_size, h.app_name) == (
        BoardType.FMCB, Version(1, 2, 3), 3, "fmcb"
    )  # fmt: skip
    assert (h.load_address, h.timestamp, h.flags, h.signed) == (0x402000, 0x01020304, 0, False)
    assert h.sha256 == ABC_SHA256 and h.crc == 0x5A070E76
    assert h.payload_address == 0x402100 and h.start_page() == 32 and h.image_size == 259
    assert parse_header(GOLDEN_HEADER) == h
    assert image.to_bytes() == GOLDEN_HEADER + b"abc"


def test_board_type_values() -> None:
    assert [(b.name, b.value) for b in BoardType] == [
        ("PALM", 1), ("FMCB", 2), ("F2", 3), ("F3", 4), ("ARM_STEPPER", 5), ("RX64", 6)
    ]  # fmt: skip


def test_flash_geometry() -> None:
    assert FLASH.flash_base == 0x400000 and FLASH.page_count == 1024
    assert FLASH.bootloader_pages == range(0, 32)
    assert FLASH.app_pages == range(32, 1020) and FLASH.app_area_bytes == 988 * 256
    assert FLASH.page_address(FLASH.param_page) == 0x43FC00  # 0x400000 + 1020 * 256
    assert FLASH.page_of(FLASH.hw_version_address) == 31 == FLASH.page_of(0x401FFC)
    assert FLASH.node_address_address == 0x401FFC and FLASH.hw_version_address == 0x401FF8
    assert (FLASH.header_page, FLASH.payload_first_page) == (32, 33)
    assert FLASH.page_address(FLASH.payload_first_page) == 0x402100 == APP_START_ADDRESS + 256
    assert FLASH.boot_control_page == 1021 and FLASH.boot_control_page not in FLASH.app_pages
    assert FLASH.identity_address == 0x401FF0 and FLASH.page_of(FLASH.identity_address) == 31
    # the identity's 16 bytes end exactly at the end of the last bootloader page
    assert FLASH.identity_address + 16 == FLASH.page_address(FLASH.bootloader_pages.stop)


# --- Version ------------------------------------------------------------------------------


def test_version() -> None:
    assert str(Version(1, 2, 3)) == "1.2.3"
    assert Version.parse("1.2.3") == Version(1, 2, 3) == Version.coerce("1.2.3")
    assert Version(1, 2, 3) < Version(1, 10, 0) < Version(2, 0, 0)
    assert Version(0, 0, 65535) < Version(0, 1, 0)
    for bad in ("1.2", "1.2.3.4", "a.b.c", "", "1.2.-3"):
        with pytest.raises(ImageError, match="bad version string"):
            Version.parse(bad)
    with pytest.raises(ImageError, match="major"):
        Version(256, 0, 0)
    with pytest.raises(ImageError, match="patch"):
        Version(0, 0, 65536)


# --- every rejection path -----------------------------------------------------------------


def test_too_short_for_header() -> None:
    with pytest.raises(ImageError, match="too short for a header: 255 bytes, need 256"):
        parse_image(GOLDEN_HEADER[:255])
    with pytest.raises(ImageError, match="too short for a header: 0 bytes"):
        parse_header(b"")


def test_wrong_magic() -> None:
    with pytest.raises(ImageError, match="wrong magic 0x444e4149"):
        parse_image(patched(0, b"IAND"))
    with pytest.raises(ImageError, match="wrong magic 0xffffffff"):
        parse_header(b"\xff" * 256)  # erased flash


def test_unknown_header_version() -> None:
    with pytest.raises(ImageError, match=r"unknown header version 2 \(supported: 1\)"):
        parse_image(patched(4, b"\x02"))


def test_header_crc_mismatch() -> None:
    raw = bytearray(golden_image())
    raw[252] ^= 0x01
    with pytest.raises(ImageError, match="header CRC mismatch: stored 0x5a070e77"):
        parse_image(bytes(raw))
    raw = bytearray(golden_image())
    raw[12] = 4  # payload size changed without a new CRC
    with pytest.raises(ImageError, match="header CRC mismatch"):
        parse_image(bytes(raw))


@pytest.mark.parametrize("board", [0, 7, 255])
def test_unknown_board_type(board: int) -> None:
    with pytest.raises(ImageError, match=f"unknown board type {board}$"):
        parse_image(patched(5, bytes([board])))


def test_wrong_board() -> None:
    with pytest.raises(ImageError, match="wrong board: image is for FMCB, expected F2"):
        parse_image(golden_image(), expected_board=BoardType.F2)
    with pytest.raises(ImageError, match="wrong board"):
        parse_header(golden_image(), expected_board=BoardType.PALM)


def test_payload_larger_than_max() -> None:
    with pytest.raises(ImageError, match="payload size 3 bytes is larger than the maximum 2"):
        parse_image(golden_image(), max_payload=2)
    huge = patched(12, (MAX_PAYLOAD + 1).to_bytes(4, "little"))
    with pytest.raises(ImageError, match=f"larger than the maximum {MAX_PAYLOAD} bytes"):
        parse_image(huge)
    assert parse_image(make_image(bytes(MAX_PAYLOAD), BoardType.F3, "0.0.1", "f3"))
    with pytest.raises(ImageError, match="larger than the maximum"):
        make_image(bytes(MAX_PAYLOAD + 1), BoardType.F3, "0.0.1", "f3")


def test_truncated_payload() -> None:
    with pytest.raises(ImageError, match="truncated payload: 2 of 3 declared bytes"):
        parse_image(golden_image()[:-1])


def test_trailing_bytes() -> None:
    # 0xFF padding (erased flash, split_pages fill) is accepted ...
    assert parse_image(golden_image() + b"\xff" * 300).payload == b"abc"
    assert parse_image(b"".join(split_pages(golden_image()))).payload == b"abc"
    # ... anything else is rejected.
    with pytest.raises(ImageError, match="trailing garbage: 2 bytes .* 0x00 at payload offset 4"):
        parse_image(golden_image() + b"\xff\x00")
    with pytest.raises(ImageError, match="trailing garbage"):
        parse_image(b"".join(split_pages(golden_image(), fill=0x00)))


def test_sha256_mismatch() -> None:
    with pytest.raises(ImageError, match="SHA-256 mismatch: header ba7816bf8f01cfea"):
        parse_image(GOLDEN_HEADER + b"abd")


def test_flags_signature_reserved_and_name() -> None:
    with pytest.raises(ImageError, match="unknown flag bits set: 0x0002"):
        parse_image(patched(6, b"\x02\x00"))
    with pytest.raises(ImageError, match="SIGNED flag set but the signature is all zero"):
        parse_image(patched(6, b"\x01\x00"))
    with pytest.raises(ImageError, match="signature present but the SIGNED flag is clear"):
        parse_image(patched(72, b"\x01"))
    with pytest.raises(ImageError, match="reserved header bytes 136..251 are not zero"):
        parse_image(patched(200, b"\x01"))
    for name in (bytes(16), b"fm cb", b"fm\x00cb", b"f\xe9", b"f\x01"):
        with pytest.raises(ImageError, match="bad app name"):
            parse_image(patched(24, name.ljust(16, b"\0")))


def test_build_rejections() -> None:
    for name in ("", "x" * 17, "two words", "caf\u00e9"):
        with pytest.raises(ImageError, match="bad app name"):
            make_image(b"", BoardType.F2, "1.0.0", name)
    with pytest.raises(ImageError, match="unknown board type 9"):
        make_image(b"", 9, "1.0.0", "f2")  # type: ignore[arg-type]
    with pytest.raises(ImageError, match="timestamp must be a u32"):
        make_image(b"", BoardType.F2, "1.0.0", "f2", timestamp=1 << 32)
    with pytest.raises(ImageError, match="signature must be 64 bytes"):
        make_image(b"", BoardType.F2, "1.0.0", "f2", signature=b"\x01" * 63)
    with pytest.raises(ImageError, match="unknown header version 2"):
        ImageHeader(BoardType.F2, Version(1, 0, 0), 0, bytes(32), "f2", header_version=2)
    assert issubclass(ImageError, ProtocolError) and issubclass(ImageError, ValueError)


# --- signing, pages, helpers --------------------------------------------------------------


def test_signed_image_and_signing_bytes() -> None:
    image = FirmwareImage.build(b"abc", BoardType.FMCB, "1.2.3", "fmcb", 0x01020304)
    message = signing_bytes(image.header)
    signed = image.with_signature(b"\x5a" * 64)
    raw = signed.to_bytes()
    parsed = parse_image(raw)
    assert parsed.header.signed and parsed.header.signature == b"\x5a" * 64
    assert raw[6:8] == b"\x01\x00" and raw[72:136] == b"\x5a" * 64
    # The message: the header with signature and CRC zeroed, flags as signed (SIGNED set).
    assert signing_bytes(parsed.header) == message[:6] + b"\x01\x00" + message[8:]
    assert message[72:136] == bytes(64) and message[252:] == bytes(4)
    assert message[40:72] == ABC_SHA256  # the payload hash is part of what is signed
    assert make_image(b"abc", BoardType.FMCB, "1.2.3", "fmcb", 0x01020304,
                      signature=b"\x5a" * 64) == raw  # fmt: skip


def test_pages() -> None:
    assert pages_needed(0) == 0 and pages_needed(1) == 1
    assert pages_needed(256) == 1 and pages_needed(257) == 2 and pages_needed(10, 4) == 3
    assert split_pages(b"") == []
    pages = split_pages(golden_image())
    assert len(pages) == 2 and pages[0] == GOLDEN_HEADER
    assert pages[1] == b"abc" + b"\xff" * 253
    assert split_pages(b"abcde", page_size=2, fill=0) == [b"ab", b"cd", b"e\x00"]
    assert FirmwareImage(parse_header(GOLDEN_HEADER), b"abc").pages() == pages
    with pytest.raises(ImageError):
        pages_needed(1, 0)
    with pytest.raises(ImageError):
        split_pages(b"a", fill=256)


def test_verify_payload() -> None:
    header = parse_header(GOLDEN_HEADER)
    assert verify_payload(header, b"abc\xff\xff") == b"abc"
    with pytest.raises(ImageError, match="SHA-256 mismatch"):
        verify_payload(header, b"abx")


# --- properties ---------------------------------------------------------------------------

versions = st.builds(
    Version, st.integers(0, 255), st.integers(0, 255), st.integers(0, 65535)
)  # fmt: skip
names = st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1, max_size=16)
load_addresses = st.integers(32, 1019).map(FLASH.page_address)


@given(
    payload=st.binary(max_size=2048), board=st.sampled_from(BoardType), version=versions,
    name=names, timestamp=st.integers(0, 2**32 - 1), load=load_addresses,
    signature=st.none() | st.binary(min_size=64, max_size=64).filter(any),
)  # fmt: skip
def test_round_trip(
    payload: bytes, board: BoardType, version: Version, name: str, timestamp: int,
    load: int, signature: bytes | None,
) -> None:  # fmt: skip
    raw = make_image(payload, board, version, name, timestamp,
                     load_address=load, signature=signature)  # fmt: skip
    assert len(raw) == HEADER_SIZE + len(payload)
    image = parse_image(raw, expected_board=board)
    h = image.header
    assert image.payload == payload and image.to_bytes() == raw
    assert (h.board, h.version, h.app_name, h.timestamp, h.load_address) == (
        board, version, name, timestamp, load
    )  # fmt: skip
    assert h.signed == (signature is not None)
    assert h.flags == (ImageFlags.SIGNED if signature else ImageFlags.NONE)
    assert parse_image(b"".join(split_pages(raw))) == image
    assert parse_header(raw[:HEADER_SIZE]) == h
    assert str(version) == str(Version.parse(str(version)))


@given(payload=st.binary(max_size=600), data=st.data())
def test_any_truncation_raises_image_error(payload: bytes, data: st.DataObject) -> None:
    raw = make_image(payload, BoardType.F2, "1.0.0", "f2")
    cut = data.draw(st.integers(0, len(raw) - 1))
    with pytest.raises(ImageError):
        parse_image(raw[:cut])


def test_every_truncation_of_golden_image() -> None:
    raw = golden_image()
    for cut in range(len(raw)):
        with pytest.raises(ImageError):
            parse_image(raw[:cut])


@given(payload=st.binary(max_size=600), data=st.data())
def test_any_single_bit_flip_is_rejected(payload: bytes, data: st.DataObject) -> None:
    raw = bytearray(make_image(payload, BoardType.PALM, "3.1.4", "palm", 1_700_000_000))
    bit = data.draw(st.integers(0, len(raw) * 8 - 1))
    raw[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(ImageError):
        parse_image(bytes(raw))


def test_every_single_bit_flip_of_golden_image() -> None:
    raw = golden_image()
    for bit in range(len(raw) * 8):
        flipped = bytearray(raw)
        flipped[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(ImageError):
            parse_image(bytes(flipped))


@pytest.mark.slow
@settings(max_examples=300)
@given(st.binary(max_size=1024))
def test_arbitrary_bytes_raise_only_image_error(data: bytes) -> None:
    with pytest.raises(ImageError):
        parse_image(data)


@pytest.mark.slow
@given(body=st.binary(min_size=248, max_size=248), tail=st.binary(max_size=64))
def test_arbitrary_header_with_good_magic_and_crc(body: bytes, tail: bytes) -> None:
    """Past the magic, version and CRC checks, random fields still fail only with ImageError."""
    raw = recrc(b"HAND\x01" + body[1:] + bytes(4)) + tail
    try:
        parse_image(raw)
    except ImageError:
        pass
