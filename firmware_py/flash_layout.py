"""Where things live in a hand microcontroller's flash, as the firmware names it.

The geometry (bootloader pages 0–31, header page 32, payload from 33, parameters 1020,
activation record 1021, and the two-slot division: primary 32–523, secondary 524–1015,
scratch 1016–1019, swap status 1022–1023) is declared once, in
:class:`protocol.image.FlashGeometry`.

An image boots only if its header is valid for this board, its payload's SHA-256 matches,
and the activation record names that same SHA-256.  Writing any page of the image area
clears the activation record first, so an interrupted update never boots half an image.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Final

from protocol.image import FLASH

PAGE_SIZE: Final = FLASH.page_size
BOOTLOADER_PAGES: Final = FLASH.bootloader_pages
HEADER_PAGE: Final = FLASH.header_page
PAYLOAD_FIRST_PAGE: Final = FLASH.payload_first_page
APP_PAGES: Final = FLASH.app_pages
PARAM_PAGE: Final = FLASH.param_page
BOOT_CONTROL_PAGE: Final = FLASH.boot_control_page
KEY_PAGE: Final = FLASH.key_page

ACTIVATION_MAGIC: Final = 0x56544341  # b"ACTV" little-endian
_RECORD = struct.Struct("<I32sI")
KEY_MAGIC: Final = 0x3159454B  # b"KEY1" little-endian
#: Key record flag: unsigned images are refused.
KEY_REQUIRED: Final = 1
_KEY_RECORD = struct.Struct("<II32sI")


@dataclass(frozen=True)
class ActivationRecord:
    """The boot-control page's content: which image payload (by SHA-256) may boot."""

    sha256: bytes

    def to_page(self) -> bytes:
        """The record as a whole flash page (CRC-32 protected, 0xFF-filled)."""
        body = struct.pack("<I32s", ACTIVATION_MAGIC, self.sha256)
        rec = body + struct.pack("<I", zlib.crc32(body))
        return rec + b"\xff" * (PAGE_SIZE - len(rec))

    @staticmethod
    def from_page(page: bytes) -> ActivationRecord | None:
        """The record in ``page``, or None if the page holds none (erased or corrupt)."""
        magic, sha, crc = _RECORD.unpack_from(page)
        if magic != ACTIVATION_MAGIC or zlib.crc32(page[: _RECORD.size - 4]) != crc:
            return None
        return ActivationRecord(sha)


def page_address(page: int) -> int:
    """Absolute address of a page."""
    return FLASH.flash_base + page * PAGE_SIZE


@dataclass(frozen=True)
class KeyRecord:
    """The key page's content (written at provisioning, like the identity; the bootloader
    locks it): the ED25519 public key images must be signed with, and whether an unsigned
    image is refused (``required``).  Layout: magic u32, flags u32 (bit 0 required),
    public key 32 B, CRC-32 of the 40 bytes before it; the rest of the page 0xFF."""

    public_key: bytes
    required: bool = True

    def to_page(self) -> bytes:
        """The record as a whole flash page."""
        body = struct.pack("<II32s", KEY_MAGIC, KEY_REQUIRED if self.required else 0,
                           self.public_key)
        rec = body + struct.pack("<I", zlib.crc32(body))
        return rec + b"\xff" * (PAGE_SIZE - len(rec))

    @staticmethod
    def from_page(page: bytes) -> KeyRecord | None:
        """The record in ``page``, or None if the node is not provisioned (erased/corrupt)."""
        magic, flags, key, crc = _KEY_RECORD.unpack_from(page)
        if magic != KEY_MAGIC or zlib.crc32(page[: _KEY_RECORD.size - 4]) != crc:
            return None
        return KeyRecord(key, bool(flags & KEY_REQUIRED))
