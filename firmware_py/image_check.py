"""The verdict on an image in a hand node's flash: the checks a bootloader makes before it
boots or swaps in an image (header, board, size, payload hash, signature, activation).

Shared by the bootloader and by the slot service an application runs, so that an image is
judged the same way wherever it is written.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Final

from firmware_py import ed25519
from firmware_py.flash_layout import (
    BOOT_CONTROL_PAGE,
    HEADER_PAGE,
    KEY_PAGE,
    PAGE_SIZE,
    ActivationRecord,
    KeyRecord,
    page_address,
)
from firmware_py.hal import Flash
from protocol.errors import ImageError
from protocol.image import MAX_PAYLOAD, BoardType, ImageHeader, parse_header, signing_bytes
from protocol.messages.boot_program import BootResult, ImageStatus

#: What a failed image check means as a command result.
RESULT_OF_IMAGE_STATUS: Final = {
    ImageStatus.EMPTY: BootResult.BAD_IMAGE,
    ImageStatus.BAD_HEADER: BootResult.BAD_IMAGE,
    ImageStatus.TOO_LARGE: BootResult.BAD_IMAGE,
    ImageStatus.WRONG_BOARD: BootResult.WRONG_BOARD,
    ImageStatus.HASH_MISMATCH: BootResult.HASH_MISMATCH,
    ImageStatus.NOT_ACTIVATED: BootResult.NOT_ACTIVATED,
    ImageStatus.BAD_SIGNATURE: BootResult.BAD_SIGNATURE,
    ImageStatus.UNSIGNED: BootResult.BAD_SIGNATURE,
}
ERASED_PAGE: Final = b"\xff" * PAGE_SIZE


@dataclass(frozen=True)
class ImageCheck:
    """The verdict on the installed image: its status, the header, and why."""

    status: ImageStatus
    header: ImageHeader | None
    reason: str

    @property
    def staged_ok(self) -> bool:
        """Header and payload verify (the image may still lack its activation)."""
        return self.status in (ImageStatus.VALID, ImageStatus.NOT_ACTIVATED)


def inspect_image(flash: Flash, board: BoardType | None, header_page: int = HEADER_PAGE,
                  max_payload: int = MAX_PAYLOAD, activated: bool = True) -> ImageCheck:
    """Check the image whose header is on ``header_page`` (default: the installed image)
    for a board of type ``board``; ``max_payload`` (bytes) is the room after the header,
    and ``activated`` False skips the activation check (a secondary-slot image has none:
    it is verified before it is swapped in and activated there).

    In order: header page erased → empty; header does not parse or names another load
    address → bad header; another board → wrong board; payload larger than the
    application area → too large; SHA-256 of the payload pages differs → hash mismatch
    (a truncated image lands here); the node is provisioned with a key (key page) and the
    image is signed by another key → bad signature, or unsigned while the key record
    requires a signature → unsigned; activation record missing or naming another hash →
    not activated; else valid.
    """
    raw = flash.read_page(header_page)
    if raw == ERASED_PAGE:
        return ImageCheck(ImageStatus.EMPTY, None, "no image: header page is erased")
    checked = check_header(raw, board, max_payload)
    if isinstance(checked, ImageCheck):
        return checked
    header = checked
    payload = flash.read(page_address(header_page + 1), header.payload_size)
    if hashlib.sha256(payload).digest() != header.sha256:
        return ImageCheck(ImageStatus.HASH_MISMATCH, header,
                          f"hash mismatch: payload pages do not hash to "
                          f"{header.sha256.hex()[:16]}... (truncated or corrupt)")
    refused = check_signature(header, flash)
    if refused is not None:
        return refused
    if not activated:
        return ImageCheck(ImageStatus.VALID, header,
                          f"valid: {header.app_name} {header.version} ({header.payload_size} B)")
    record = ActivationRecord.from_page(flash.read_page(BOOT_CONTROL_PAGE))
    if record is None or record.sha256 != header.sha256:
        return ImageCheck(ImageStatus.NOT_ACTIVATED, header,
                          f"not activated: {header.app_name} {header.version} verifies but "
                          "has no activation record")
    return ImageCheck(ImageStatus.VALID, header,
                      f"valid: {header.app_name} {header.version} ({header.payload_size} B)")


def check_header(raw: bytes, board: BoardType | None,
                 max_payload: int = MAX_PAYLOAD) -> ImageHeader | ImageCheck:
    """The header in ``raw`` (a header page) if it parses, names the header page as its load
    address and ``board``, and its payload fits; else the :class:`ImageCheck` saying why
    (bad header, wrong board, too large)."""
    try:
        header = parse_header(raw, max_payload=0xFFFFFFFF)
    except ImageError as exc:
        return ImageCheck(ImageStatus.BAD_HEADER, None, f"bad header: {exc}")
    if header.load_address != page_address(HEADER_PAGE):
        return ImageCheck(ImageStatus.BAD_HEADER, header,
                          f"bad header: load address 0x{header.load_address:x} is not "
                          f"0x{page_address(HEADER_PAGE):x}")
    if board is None or header.board != board:
        mine = board.name if board is not None else "unknown"
        return ImageCheck(ImageStatus.WRONG_BOARD, header,
                          f"wrong board: image is for {header.board.name}, this is {mine}")
    if header.payload_size > max_payload:
        return ImageCheck(ImageStatus.TOO_LARGE, header,
                          f"too large: payload {header.payload_size} B > {max_payload} B")
    return header


def check_signature(header: ImageHeader, flash: Flash) -> ImageCheck | None:
    """None if the node's key record (key page) accepts ``header``'s signature (or the node
    has no key); else the :class:`ImageCheck` (bad signature, or unsigned where the record
    requires a signature)."""
    key = KeyRecord.from_page(flash.read_page(KEY_PAGE))
    if key is None:
        return None
    if not header.signed:
        if key.required:
            return ImageCheck(ImageStatus.UNSIGNED, header,
                              "unsigned: this node requires a signed image")
        return None
    if not ed25519.verify(key.public_key, header.signature, signing_bytes(header)):
        return ImageCheck(ImageStatus.BAD_SIGNATURE, header,
                          "bad signature: not signed by this node's key")
    return None
