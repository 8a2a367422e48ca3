"""Firmware image format: a 256-byte header followed by the application payload.

An image is what the host flashes into a node's application area and what a node's bootloader
checks before it boots.  It is pure data: callers pass bytes in and get bytes out.

Header layout (all integers little-endian; offsets and sizes in bytes)::

    off size field
      0    4 magic           0x444E4148, i.e. the bytes b"HAND" in flash / a hex dump
      4    1 header_version  1 (any layout change bumps it)
      5    1 board           BoardType (1..6)
      6    2 flags           ImageFlags; bit 0 SIGNED; every other bit must be 0
      8    1 version.major
      9    1 version.minor
     10    2 version.patch
     12    4 payload_size    bytes of payload following the header
     16    4 load_address    flash address of the header (default 0x402000 = page 32)
     20    4 timestamp       build time, unix seconds (0 = unknown / reproducible build)
     24   16 app_name        printable ASCII (0x21..0x7E), NUL-padded, 1..16 characters
     40   32 sha256          SHA-256 of the payload
     72   64 signature       ED25519 signature of signing_bytes(); all zero when unsigned
    136  116 reserved        must be zero
    252    4 header_crc      CRC-32 (zlib / IEEE 802.3) of bytes 0..251

Why 256 bytes: it is exactly one SAM3S flash page.  The header fills page 32 on its own, so

* the payload starts page-aligned at ``load_address + 256`` (0x402100, page 33), which is also
  an address the Cortex-M3 VTOR accepts for the SAM3S vector table (< 64 entries, so 256-byte
  alignment): real firmware is linked at the payload address, not at the header;
* the header is read or written with a single bootloader page command (0x0a / 0x0b);
* a flasher that writes the header page *last* gets a commit marker for free: an interrupted
  flash leaves page 32 erased (no magic), so the node stays in its bootloader instead of
  booting half an image (the failure Katapult users report).

Why CRC-32 for the header: a bootloader reads page 32 and must decide whether the size, address
and hash fields are trustworthy before using them.  CRC-32 detects every error of up to three
bits and every burst up to 32 bits in 252 bytes, and random bytes pass it 1 time in 2**32
instead of 1 in 65536 for CRC-16; the SAM3S CRCCU computes it in hardware.  The CRC covers the
reserved bytes and the signature.  The magic and header version are checked *before* the CRC,
because the version decides where the CRC is.

Trailing bytes: data after ``header + payload_size`` is accepted only if every byte is 0xFF
(erased flash, or the fill of :func:`split_pages`), so an image read back page by page parses
like the image that was written.  Anything else after the payload is rejected.

Signing: an ED25519 signature of :func:`signing_bytes` sits in the 64-byte slot with the SIGNED
flag set.  A node provisioned with a public key (its key page, inside the locked bootloader
region) refuses images signed with another key, and unsigned images when it requires a
signature.
"""

from __future__ import annotations

import enum
import hashlib
import re
import zlib
from dataclasses import dataclass, field, replace

import construct as cs

from protocol.errors import ImageError, wrap_construct
from protocol.topology import BoardType

__all__ = [
    "APP_START_ADDRESS", "FLASH", "HEADER_SIZE", "HEADER_VERSION", "MAGIC", "MAX_PAYLOAD",
    "SLOT_MAX_PAYLOAD",
    "BoardType", "FirmwareImage", "FlashGeometry", "ImageFlags", "ImageHeader", "Version",
    "header_crc", "make_image", "pages_needed", "parse_header", "parse_image", "signing_bytes",
    "split_pages", "verify_payload",
]  # fmt: skip


@dataclass(frozen=True)
class FlashGeometry:
    """Flash layout of an MCU (addresses in bytes, pages in flash-page units).

    On the SAM3S (1024 pages × 256 B from 0x400000)::

        pages 0–31      bootloader; page 30 the signing-key record (trust anchor), page 31
                        ends with the node identity (16 B at 0x401FF0)
        page 32         image header (``app_start_page``; one page, :data:`HEADER_SIZE`)
        pages 33–1019   image payload (one-slot layout: an image may fill the whole area)
        page 1020       parameters (kept across updates)
        page 1021       boot control: the activation record
        pages 1022–1023 swap status (two alternating records)

    The two-slot layout divides the same application area::

        pages 32–523    primary slot (492 pages): the image that runs, header on page 32
        pages 524–1015  secondary slot (492 pages): where a new image is written
        pages 1016–1019 scratch (4 pages): one chunk of the primary during a swap

    An image of at most :data:`SLOT_MAX_PAYLOAD` bytes fits a slot and can be installed by
    a swap; a larger one (up to :data:`MAX_PAYLOAD`) is burnt into the application area
    the one-slot way and leaves no room for a second image.
    """

    flash_base: int = 0x400000
    page_size: int = 256
    page_count: int = 1024
    app_start_page: int = 32
    param_page: int = 1020
    boot_control_page: int = 1021
    #: The trust anchor: which ED25519 public key images must be signed with (if any).
    key_page: int = 30
    #: The node identity: board type, unique id, hardware version, bus address (u32 each).
    identity_address: int = 0x401FF0
    #: Pages in each image slot (header included).
    slot_pages: int = 492
    #: First page of the secondary slot (its header page).
    secondary_slot_page: int = 524
    #: First scratch page and how many (a swap moves this many pages at a time).
    scratch_page: int = 1016
    scratch_pages: int = 4
    #: The two swap-status pages, written alternately so that one always holds a whole record.
    swap_status_pages: tuple[int, int] = (1022, 1023)

    @property
    def bootloader_pages(self) -> range:
        """Pages of the bootloader (and the identity): everything below the application."""
        return range(0, self.app_start_page)

    @property
    def header_page(self) -> int:
        """Page holding an image's header (the first page of the application area)."""
        return self.app_start_page

    @property
    def payload_first_page(self) -> int:
        """First page of an image's payload, right after its one-page header."""
        return self.header_page + HEADER_SIZE // self.page_size

    @property
    def hw_version_address(self) -> int:
        """Address of the identity's hardware-version word (bytes)."""
        return self.identity_address + 8

    @property
    def node_address_address(self) -> int:
        """Address of the identity's bus-address word (bytes)."""
        return self.identity_address + 12

    def page_address(self, page: int) -> int:
        """Flash address (bytes) of the first byte of ``page``."""
        return self.flash_base + page * self.page_size

    def page_of(self, address: int) -> int:
        """Page number holding flash ``address`` (bytes)."""
        return (address - self.flash_base) // self.page_size

    @property
    def app_start_address(self) -> int:
        """Address where an image (its header) is written by default: 0x402000 on the SAM3S."""
        return self.page_address(self.app_start_page)

    @property
    def app_pages(self) -> range:
        """Pages an image may occupy: from the application start up to the parameter page."""
        return range(self.app_start_page, self.param_page)

    @property
    def primary_slot(self) -> range:
        """Pages of the primary slot: where the running image lives (header first)."""
        return range(self.app_start_page, self.app_start_page + self.slot_pages)

    @property
    def secondary_slot(self) -> range:
        """Pages of the secondary slot: where a new image is written while the old one runs."""
        return range(self.secondary_slot_page, self.secondary_slot_page + self.slot_pages)

    @property
    def scratch(self) -> range:
        """Pages a swap parks one chunk of the primary slot in."""
        return range(self.scratch_page, self.scratch_page + self.scratch_pages)

    @property
    def slot_max_payload(self) -> int:
        """Largest payload (bytes) an image in one slot can carry: 491 pages, 125696 B."""
        return (self.slot_pages - HEADER_SIZE // self.page_size) * self.page_size

    @property
    def app_area_bytes(self) -> int:
        """Size of the application area in bytes (988 pages = 252928 B on the SAM3S)."""
        return len(self.app_pages) * self.page_size


#: The SAM3S of every finger board (fmcb, f2, f3): shared by firmware models and bootloader.
FLASH = FlashGeometry()

MAGIC = 0x444E4148  # b"HAND" little-endian
HEADER_VERSION = 1
HEADER_SIZE = 256
SIGNATURE_SIZE = 64
APP_NAME_SIZE = 16
APP_START_ADDRESS = FLASH.app_start_address
#: Largest payload (bytes) that fits the SAM3S application area after the header: 252672.
MAX_PAYLOAD = FLASH.app_area_bytes - HEADER_SIZE
#: Largest payload (bytes) of an image that fits one slot of the two-slot layout: 125696.
SLOT_MAX_PAYLOAD = FLASH.slot_max_payload
_CRC_OFFSET = HEADER_SIZE - 4
_APP_NAME_RE = re.compile(r"[\x21-\x7e]{1,16}")


class ImageFlags(enum.IntFlag):
    """Header flag bits (u16); bits not named here must be zero."""

    NONE = 0
    SIGNED = 1


@dataclass(frozen=True, order=True)
class Version:
    """Image version major.minor.patch (u8, u8, u16); orders numerically, prints "1.2.3"."""

    major: int
    minor: int
    patch: int

    def __post_init__(self) -> None:
        for name, limit in (("major", 0xFF), ("minor", 0xFF), ("patch", 0xFFFF)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= limit:
                raise ImageError(f"version {name} must be an int in 0..{limit}, got {value!r}")

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}.{self.patch}"

    @classmethod
    def parse(cls, text: str) -> Version:
        """Parse ``"major.minor.patch"`` (decimal)."""
        match = re.fullmatch(r"(\d{1,3})\.(\d{1,3})\.(\d{1,5})", text.strip())
        if match is None:
            raise ImageError(f"bad version string {text!r}: expected major.minor.patch")
        return cls(*(int(part) for part in match.groups()))

    @classmethod
    def coerce(cls, value: Version | str) -> Version:
        """Return ``value`` as a :class:`Version`, parsing it if it is a string."""
        return value if isinstance(value, Version) else cls.parse(value)


_VERSION = cs.Struct("major" / cs.Int8ul, "minor" / cs.Int8ul, "patch" / cs.Int16ul)
_BODY_FIELDS = (
    "magic" / cs.Int32ul,
    "header_version" / cs.Int8ul,
    "board" / cs.Int8ul,
    "flags" / cs.Int16ul,
    "version" / _VERSION,
    "payload_size" / cs.Int32ul,
    "load_address" / cs.Int32ul,
    "timestamp" / cs.Int32ul,
    "app_name" / cs.Bytes(APP_NAME_SIZE),
    "sha256" / cs.Bytes(32),
    "signature" / cs.Bytes(SIGNATURE_SIZE),
    "reserved" / cs.Default(cs.Bytes(_CRC_OFFSET - 136), bytes(_CRC_OFFSET - 136)),
)
#: Header bytes 0..251, the part the CRC covers.
HEADER_BODY = cs.Struct(*_BODY_FIELDS)
#: The whole 256-byte header (body + CRC-32).
HEADER = cs.Struct(*_BODY_FIELDS, "header_crc" / cs.Int32ul)
assert HEADER_BODY.sizeof() == _CRC_OFFSET and HEADER.sizeof() == HEADER_SIZE
_SIGNATURE_OFFSET = 72


def header_crc(body: bytes) -> int:
    """CRC-32 (zlib / IEEE 802.3, check value 0xCBF43926) of the 252 header bytes before it."""
    return zlib.crc32(body) & 0xFFFFFFFF


def _decode_app_name(raw: bytes) -> str:
    name, _, rest = raw.partition(b"\0")
    if rest.strip(b"\0") or not _APP_NAME_RE.fullmatch(name.decode("latin-1")):
        raise ImageError(
            f"bad app name {raw!r}: expected 1..16 printable ASCII characters, NUL-padded"
        )
    return name.decode("ascii")


@dataclass(frozen=True)
class ImageHeader:
    """A decoded, consistent image header (the CRC is recomputed by :meth:`to_bytes`).

    ``payload_size`` is in bytes; ``load_address`` is the flash address (bytes) of the header.
    Construction validates every field and raises :class:`ImageError` on any inconsistency.
    """

    board: BoardType
    version: Version
    payload_size: int
    sha256: bytes
    app_name: str
    load_address: int = APP_START_ADDRESS
    timestamp: int = 0
    flags: ImageFlags = ImageFlags.NONE
    signature: bytes = field(default=bytes(SIGNATURE_SIZE), repr=False)
    header_version: int = HEADER_VERSION

    def __post_init__(self) -> None:
        if self.header_version != HEADER_VERSION:
            raise ImageError(
                f"unknown header version {self.header_version} (supported: {HEADER_VERSION})"
            )
        if not isinstance(self.board, BoardType):
            raise ImageError(f"board must be a BoardType, got {self.board!r}")
        if not isinstance(self.version, Version):
            raise ImageError(f"version must be a Version, got {self.version!r}")
        for name in ("payload_size", "load_address", "timestamp"):
            value = getattr(self, name)
            if not isinstance(value, int) or not 0 <= value <= 0xFFFFFFFF:
                raise ImageError(f"{name} must be a u32, got {value!r}")
        if not isinstance(self.app_name, str) or not _APP_NAME_RE.fullmatch(self.app_name):
            raise ImageError(
                f"bad app name {self.app_name!r}: expected 1..16 printable ASCII characters"
            )
        if len(self.sha256) != 32:
            raise ImageError(f"sha256 must be 32 bytes, got {len(self.sha256)}")
        if len(self.signature) != SIGNATURE_SIZE:
            raise ImageError(f"signature must be 64 bytes, got {len(self.signature)}")
        flags = int(self.flags)
        if not 0 <= flags <= 0xFFFF or flags & ~int(ImageFlags.SIGNED):
            raise ImageError(f"unknown flag bits set: 0x{flags:04x} (known: SIGNED=0x0001)")
        object.__setattr__(self, "flags", ImageFlags(flags))
        unsigned = not any(self.signature)
        if self.signed and unsigned:
            raise ImageError("SIGNED flag set but the signature is all zero")
        if not self.signed and not unsigned:
            raise ImageError("signature present but the SIGNED flag is clear")

    @property
    def signed(self) -> bool:
        """True if the SIGNED flag is set (the signature is not verified here)."""
        return bool(self.flags & ImageFlags.SIGNED)

    @property
    def payload_address(self) -> int:
        """Flash address (bytes) of the first payload byte: ``load_address + 256``."""
        return self.load_address + HEADER_SIZE

    @property
    def image_size(self) -> int:
        """Header plus payload, in bytes."""
        return HEADER_SIZE + self.payload_size

    def start_page(self, flash: FlashGeometry = FLASH) -> int:
        """Flash page (page units) where the header is written."""
        return flash.page_of(self.load_address)

    def to_bytes(self) -> bytes:
        """The 256-byte header, CRC included."""
        body = wrap_construct(
            lambda: HEADER_BODY.build(
                {
                    "magic": MAGIC,
                    "header_version": self.header_version,
                    "board": int(self.board),
                    "flags": int(self.flags),
                    "version": vars(self.version),
                    "payload_size": self.payload_size,
                    "load_address": self.load_address,
                    "timestamp": self.timestamp,
                    "app_name": self.app_name.encode("ascii").ljust(APP_NAME_SIZE, b"\0"),
                    "sha256": bytes(self.sha256),
                    "signature": bytes(self.signature),
                }
            ),
            "image header",
            ImageError,
        )
        return body + header_crc(body).to_bytes(4, "little")

    @property
    def crc(self) -> int:
        """The header CRC-32 as stored at offset 252."""
        return int.from_bytes(self.to_bytes()[_CRC_OFFSET:], "little")


def parse_header(
    data: bytes, expected_board: BoardType | None = None, max_payload: int | None = None
) -> ImageHeader:
    """Decode and check the header in the first 256 bytes of ``data`` (more bytes are ignored).

    Checks, in order: length, magic, header version, CRC, board type, flags, signature slot,
    reserved bytes, app name, ``expected_board``, and ``payload_size <= max_payload`` (bytes;
    default :data:`MAX_PAYLOAD`, the SAM3S application area minus the header).
    Raises :class:`ImageError` with a specific message on the first failure.
    """
    data = bytes(data)
    if len(data) < HEADER_SIZE:
        raise ImageError(f"too short for a header: {len(data)} bytes, need {HEADER_SIZE}")
    magic = int.from_bytes(data[:4], "little")
    if magic != MAGIC:
        raise ImageError(f"wrong magic 0x{magic:08x} {data[:4]!r} (expected 0x{MAGIC:08x} b'HAND')")
    if data[4] != HEADER_VERSION:
        raise ImageError(f"unknown header version {data[4]} (supported: {HEADER_VERSION})")
    raw = wrap_construct(lambda: HEADER.parse(data[:HEADER_SIZE]), "image header", ImageError)
    computed = header_crc(data[:_CRC_OFFSET])
    if raw.header_crc != computed:
        raise ImageError(
            f"header CRC mismatch: stored 0x{raw.header_crc:08x}, computed 0x{computed:08x}"
        )
    try:
        board = BoardType(raw.board)
    except ValueError:
        raise ImageError(f"unknown board type {raw.board}") from None
    if any(raw.reserved):
        raise ImageError("reserved header bytes 136..251 are not zero")
    header = ImageHeader(
        board=board,
        version=Version(raw.version.major, raw.version.minor, raw.version.patch),
        payload_size=raw.payload_size,
        sha256=raw.sha256,
        app_name=_decode_app_name(raw.app_name),
        load_address=raw.load_address,
        timestamp=raw.timestamp,
        flags=ImageFlags(raw.flags),
        signature=raw.signature,
        header_version=raw.header_version,
    )
    if expected_board is not None and board != expected_board:
        raise ImageError(f"wrong board: image is for {board.name}, expected {expected_board.name}")
    limit = MAX_PAYLOAD if max_payload is None else max_payload
    if header.payload_size > limit:
        raise ImageError(
            f"payload size {header.payload_size} bytes is larger than the maximum {limit} bytes"
        )
    return header


def verify_payload(header: ImageHeader, payload: bytes) -> bytes:
    """Check ``payload`` (bytes after the header) against ``header``; return the exact payload.

    ``payload`` may carry trailing 0xFF fill (erased flash / page padding); any other trailing
    byte is rejected.  Raises :class:`ImageError` if it is shorter than ``payload_size`` bytes,
    has non-0xFF trailing bytes, or its SHA-256 differs from the header's.
    """
    payload = bytes(payload)
    size = header.payload_size
    if len(payload) < size:
        raise ImageError(f"truncated payload: {len(payload)} of {size} declared bytes")
    tail = payload[size:]
    if tail.strip(b"\xff"):
        first = next(i for i, b in enumerate(tail) if b != 0xFF)
        raise ImageError(
            f"trailing garbage: {len(tail)} bytes after the declared payload, "
            f"non-0xFF byte 0x{tail[first]:02x} at payload offset {size + first}"
        )
    payload = payload[:size]
    digest = hashlib.sha256(payload).digest()
    if digest != header.sha256:
        raise ImageError(
            f"SHA-256 mismatch: header {header.sha256.hex()[:16]}..., "
            f"payload {digest.hex()[:16]}..."
        )
    return payload


@dataclass(frozen=True)
class FirmwareImage:
    """A checked header and its exact payload (bytes)."""

    header: ImageHeader
    payload: bytes

    @classmethod
    def build(
        cls, payload: bytes, board: BoardType, version: Version | str, app_name: str,
        timestamp: int = 0, *, load_address: int = APP_START_ADDRESS,
        signature: bytes | None = None, max_payload: int | None = None,
    ) -> FirmwareImage:  # fmt: skip
        """Make an image: size and SHA-256 come from ``payload``; a ``signature`` sets SIGNED.

        Raises :class:`ImageError` if the payload exceeds ``max_payload`` bytes (default
        :data:`MAX_PAYLOAD`) or any field is out of range.
        """
        payload = bytes(payload)
        limit = MAX_PAYLOAD if max_payload is None else max_payload
        if len(payload) > limit:
            raise ImageError(
                f"payload size {len(payload)} bytes is larger than the maximum {limit} bytes"
            )
        try:
            board = BoardType(board)
        except ValueError:
            raise ImageError(f"unknown board type {board!r}") from None
        header = ImageHeader(
            board=board,
            version=Version.coerce(version),
            payload_size=len(payload),
            sha256=hashlib.sha256(payload).digest(),
            app_name=app_name,
            load_address=load_address,
            timestamp=timestamp,
            flags=ImageFlags.SIGNED if signature is not None else ImageFlags.NONE,
            signature=bytes(SIGNATURE_SIZE) if signature is None else bytes(signature),
        )
        return cls(header, payload)

    def to_bytes(self) -> bytes:
        """Header (256 bytes) followed by the payload."""
        return self.header.to_bytes() + self.payload

    def with_signature(self, signature: bytes) -> FirmwareImage:
        """A copy with ``signature`` (64 bytes) in the slot and the SIGNED flag set."""
        header = replace(
            self.header, flags=self.header.flags | ImageFlags.SIGNED, signature=bytes(signature)
        )
        return FirmwareImage(header, self.payload)

    def pages(self, fill: int = 0xFF) -> list[bytes]:
        """The image split into flash pages (the unit the bootloader writes)."""
        return split_pages(self.to_bytes(), FLASH.page_size, fill)


def parse_image(
    data: bytes, expected_board: BoardType | None = None, max_payload: int | None = None
) -> FirmwareImage:
    """Decode and fully check an image: header (see :func:`parse_header`), then payload.

    Trailing bytes after the declared payload are accepted only if all 0xFF.
    Raises :class:`ImageError` (only) on any failure.
    """
    data = bytes(data)
    header = parse_header(data, expected_board, max_payload)
    return FirmwareImage(header, verify_payload(header, data[HEADER_SIZE:]))


def make_image(
    payload: bytes, board: BoardType, version: Version | str, app_name: str,
    timestamp: int = 0, *, load_address: int = APP_START_ADDRESS,
    signature: bytes | None = None, max_payload: int | None = None,
) -> bytes:  # fmt: skip
    """Image bytes (256-byte header + payload) for ``payload``; see :meth:`FirmwareImage.build`."""
    return FirmwareImage.build(
        payload, board, version, app_name, timestamp,
        load_address=load_address, signature=signature, max_payload=max_payload,
    ).to_bytes()  # fmt: skip


def signing_bytes(header: ImageHeader) -> bytes:
    """The message an ED25519 signature covers: the 256-byte header with signature and CRC zeroed.

    The header already holds the payload's SHA-256 (offset 40), so the signature binds the
    payload without hashing it twice; the SIGNED flag is part of the message.  A verifier needs
    only the header and the hash it computes while streaming the payload.
    """
    raw = bytearray(header.to_bytes())
    raw[_SIGNATURE_OFFSET : _SIGNATURE_OFFSET + SIGNATURE_SIZE] = bytes(SIGNATURE_SIZE)
    raw[_CRC_OFFSET:] = bytes(4)
    return bytes(raw)


def pages_needed(image_bytes_len: int, page_size: int = 256) -> int:
    """Number of flash pages (page units) that ``image_bytes_len`` bytes occupy."""
    if page_size <= 0 or image_bytes_len < 0:
        raise ImageError(f"bad sizes: {image_bytes_len} bytes, page size {page_size} bytes")
    return -(-image_bytes_len // page_size)


def split_pages(image_bytes: bytes, page_size: int = 256, fill: int = 0xFF) -> list[bytes]:
    """Split image bytes into ``page_size``-byte pages, padding the last one with ``fill``."""
    if not 0 <= fill <= 0xFF:
        raise ImageError(f"fill must be a byte value, got {fill}")
    data = bytes(image_bytes)
    count = pages_needed(len(data), page_size)
    padded = data.ljust(count * page_size, bytes([fill]))
    return [padded[i * page_size : (i + 1) * page_size] for i in range(count)]


assert (
    FLASH.primary_slot.stop == FLASH.secondary_slot.start
    and FLASH.secondary_slot.stop == FLASH.scratch.start
    and FLASH.scratch.stop == FLASH.param_page
    and min(FLASH.swap_status_pages) > FLASH.boot_control_page
), "the two-slot layout must tile the application area"
