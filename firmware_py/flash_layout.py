"""Where things live in a hand microcontroller's flash (SAM3S: 1024 pages × 256 B).

    pages 0–31      bootloader (page 31 ends with the node identity); locked at boot
    page 32         image header (protocol.image, 256 B)
    pages 33–1019   image payload (application code)
    page 1020       fmcb parameters (kept across updates)
    page 1021       boot control: the activation record
    pages 1022–1023 unused

An image boots only if its header is valid for this board, its payload's SHA-256 matches,
and the activation record names that same SHA-256.  Writing any page of the image area
clears the activation record first, so an interrupted update never boots half an image.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Final

from protocol.image import FLASH, HEADER_SIZE

PAGE_SIZE: Final = FLASH.page_size
BOOTLOADER_PAGES: Final = range(0, FLASH.app_start_page)
HEADER_PAGE: Final = FLASH.app_start_page
PAYLOAD_FIRST_PAGE: Final = HEADER_PAGE + HEADER_SIZE // PAGE_SIZE
APP_PAGES: Final = FLASH.app_pages
PARAM_PAGE: Final = FLASH.param_page
BOOT_CONTROL_PAGE: Final = 1021

ACTIVATION_MAGIC: Final = 0x56544341  # b"ACTV" little-endian
_RECORD = struct.Struct("<I32sI")


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
