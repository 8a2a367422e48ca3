"""Messages of the bootloader that runs on every hand microcontroller.

The original commands keep their ids and meaning: ping 0x01 and hardware version 0xFA
(common), boot 0x08, read page 0x0A, write page 0x0B with its status codes, halt autoboot
0x0C.  New: status 0x07, info 0x0D, hash of a flash range 0x0E, and activation 0x0F of a
staged image (an image written page by page never boots until it is verified and
activated).  Every bootloader command halts the autoboot countdown.
"""

from __future__ import annotations

import construct as c

from protocol.catalogue import Message
from protocol.image import HEADER_SIZE
from protocol.messages.fields import EMPTY, VERSION

PAGE_SIZE = 256

#: Page-write status codes.  0x80 + i: word i of the page did not program (original).
WRITE_STATUS = {
    0x00: "ok",
    0x01: "page_out_of_range",
    0x02: "page_protected",
    0x03: "flash_busy",
}
WRITE_STATUS_WORD_FAILED = 0x80

#: Bootloader states.
BL_STATE = {0: "autoboot_countdown", 1: "halted", 2: "booting", 3: "no_valid_image"}

#: Why the installed image is not bootable (0 = it is).
IMAGE_STATUS = {
    0: "valid",
    1: "empty",
    2: "bad_header",
    3: "wrong_board",
    4: "hash_mismatch",
    5: "not_activated",
    6: "too_large",
}

#: Generic bootloader result codes (activate, hash, boot).
BL_RESULT = {
    0: "ok",
    1: "out_of_range",
    2: "bad_image",
    3: "hash_mismatch",
    4: "wrong_board",
    5: "not_activated",
    6: "protected",
}

PAGE_DATA = c.Bytes(PAGE_SIZE)

BL_INFO = c.Struct(
    "board" / c.Int8ul * "[-] board type (protocol.image.BoardType)",
    "bl_version" / VERSION * "[-] bootloader version",
    "state" / c.Int8ul * "[-] 0 autoboot countdown, 1 halted, 2 booting, 3 no valid image",
    "image_status" / c.Int8ul * "[-] 0 valid, 1 empty, 2 bad header, 3 wrong board, "
    "4 hash mismatch, 5 not activated, 6 too large",
    "autoboot_ms_left" / c.Int16ul * "[ms] time left in the autoboot window (0 when halted)",
    "page_size" / c.Int16ul * "[bytes] flash page size",
    "page_count" / c.Int16ul * "[pages] flash pages in all",
    "app_start_page" / c.Int16ul * "[page] first page of the application area",
    "app_end_page" / c.Int16ul * "[page] first page after the application area",
    "param_page" / c.Int16ul * "[page] the parameter page (kept across updates)",
    "header" / c.Bytes(HEADER_SIZE) * "[-] the installed image header as stored in flash",
)

MESSAGES = [
    Message(
        "bl.status",
        "bootloader",
        0x07,
        EMPTY,
        c.Struct(
            "state" / c.Int8ul * "[-] see bl.info state",
            "image_status" / c.Int8ul * "[-] see bl.info image_status",
            "last_error" / c.Int8ul * "[-] result code of the last failed command (0 none)",
            "last_page" / c.Int32ul * "[page] page of the last write (0xFFFFFFFF none)",
            "text" / c.PascalString(c.Int8ul, "ascii") * "[-] why, in words",
        ),
        "Bootloader state and the reason the application does not boot.",
        original=False,
    ),
    Message(
        "bl.boot",
        "bootloader",
        0x08,
        EMPTY,
        EMPTY,
        "Acknowledge, then start the application (only a verified, activated image).",
    ),
    Message(
        "bl.read_page",
        "bootloader",
        0x0A,
        c.Struct("page" / c.Int32ul * "[page] page number 0..1023"),
        c.Struct("data" / PAGE_DATA * "[-] the page's 256 bytes"),
        "Read one flash page.",
    ),
    Message(
        "bl.write_page",
        "bootloader",
        0x0B,
        c.Struct(
            "page" / c.Int32ul * "[page] page number (application area only)",
            "data" / PAGE_DATA * "[-] the page's 256 bytes",
        ),
        c.Struct(
            "page" / c.Int32ul * "[page] the page written (echo)",
            "status" / c.Int8ul * "[-] 0 ok, 1 out of range, 2 protected, 3 busy, "
            "0x80+i word i failed",
        ),
        "Erase and program one page; staging an image clears its activation.",
    ),
    Message("bl.halt", "bootloader", 0x0C, EMPTY, EMPTY, "Halt the autoboot countdown."),
    Message("bl.info", "bootloader", 0x0D, EMPTY, BL_INFO, "Board, versions, flash geometry "
            "and the installed image header.", original=False),
    Message(
        "bl.hash",
        "bootloader",
        0x0E,
        c.Struct(
            "start_page" / c.Int32ul * "[page] first page",
            "pages" / c.Int32ul * "[pages] how many pages",
        ),
        c.Struct(
            "status" / c.Int8ul * "[-] 0 ok, 1 out of range",
            "sha256" / c.Bytes(32) * "[-] SHA-256 of the pages' bytes",
        ),
        "SHA-256 of a flash range, for verification without reading it back.",
        original=False,
    ),
    Message(
        "bl.activate",
        "bootloader",
        0x0F,
        c.Struct("sha256" / c.Bytes(32) * "[-] expected SHA-256 of the staged image payload"),
        c.Struct(
            "status" / c.Int8ul * "[-] 0 ok, 2 bad image, 3 hash mismatch, 4 wrong board",
            "image_status" / c.Int8ul * "[-] see bl.info image_status",
        ),
        "Verify the staged image and mark it bootable.",
        original=False,
    ),
]
