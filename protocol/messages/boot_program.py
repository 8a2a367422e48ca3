"""Messages (``bl.*``) of the boot program that runs on every hand microcontroller
(:mod:`firmware_py.boot_program`; the host's flashing package is :mod:`bootloader`).

The original commands keep their ids and meaning: ping 0x01 and hardware version 0xFA
(common), boot 0x08, read page 0x0A, write page 0x0B with its status codes, halt autoboot
0x0C.  New: status 0x07, info 0x0D, hash of a flash range 0x0E, and activation 0x0F of a
staged image (an image written page by page never boots until it is verified and
activated).  Every bootloader command halts the autoboot countdown.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

import construct as c

from protocol.catalogue import Message
from protocol.enum_field import EnumField
from protocol.image import HEADER_SIZE
from protocol.messages.common import BOARD
from protocol.messages.fields import EMPTY, VERSION

PAGE_SIZE = 256

#: The autoboot window (µs): how long a hand bootloader waits after power-up or reset for a
#: bootloader command before it starts a verified image.  The original bootloader had no
#: timer: it counted down 3 000 000 busy-loop iterations after about 1 000 000 of start-up
#: loops, "several seconds" on its 64 MHz Cortex-M3.  Its host tools were written against
#: that: the reset-based ``burn`` of a motor module or palm sends reset, listens 1 s then
#: 2 s, and only then sends halt, about 3.02 s after the reset (3.5 s when the reset's
#: acknowledgement is lost and its 0.5 s wait runs out), with 0.5 s more for the reply; the
#: phalange burns halt about 2 s after power-on.  4.5 s lets the slowest of these in with
#: 1 s to spare, and costs a power-up only 1.5 s over the 3 s a shorter window would.
AUTOBOOT_WINDOW_US: Final = 4_500_000


class WriteStatus(IntEnum):
    """Status of ``bl.write_page``; 0x80 + i (:data:`WRITE_STATUS_WORD_FAILED`) means word
    i of the page did not program, and decodes as a plain int."""

    OK = 0x00
    PAGE_OUT_OF_RANGE = 0x01
    PAGE_PROTECTED = 0x02
    FLASH_BUSY = 0x03
    #: New: a header page (page 32) whose image header names another board or load address,
    #: or a payload larger than the application area; nothing is written, the installed
    #: image and its activation stay.
    NOT_FOR_THIS_NODE = 0x04
    #: New: a header page whose image is not signed with this node's key (or is unsigned
    #: where the node requires a signature); nothing is written.
    BAD_SIGNATURE = 0x05


#: Base of the page-write codes "word i did not program" (0x80 + i), as on the original.
WRITE_STATUS_WORD_FAILED = 0x80


class BootState(IntEnum):
    """What the bootloader is doing."""

    AUTOBOOT_COUNTDOWN = 0
    HALTED = 1
    BOOTING = 2
    NO_VALID_IMAGE = 3
    #: New: exchanging the image slots (an update or a revert; see the slot messages).
    SWAPPING = 4


class ImageStatus(IntEnum):
    """Why the installed image is not bootable (VALID: it is)."""

    VALID = 0
    EMPTY = 1
    BAD_HEADER = 2
    WRONG_BOARD = 3
    HASH_MISMATCH = 4
    NOT_ACTIVATED = 5
    TOO_LARGE = 6
    BAD_SIGNATURE = 7
    UNSIGNED = 8


class BootResult(IntEnum):
    """Result of a bootloader command other than a page write (activate, hash, boot)."""

    OK = 0
    OUT_OF_RANGE = 1
    BAD_IMAGE = 2
    HASH_MISMATCH = 3
    WRONG_BOARD = 4
    NOT_ACTIVATED = 5
    PROTECTED = 6
    BAD_SIGNATURE = 7


STATE = EnumField(c.Int8ul, BootState)
IMAGE_STATUS = EnumField(c.Int8ul, ImageStatus)
RESULT = EnumField(c.Int8ul, BootResult)

PAGE_DATA = c.Bytes(PAGE_SIZE)

BL_INFO = c.Struct(
    "board" / BOARD * "[-] board type",
    "bl_version" / VERSION * "[-] bootloader version",
    "state" / STATE * "[-] bootloader state",
    "image_status" / IMAGE_STATUS * "[-] verdict on the installed image",
    "autoboot_ms_left" / c.Int16ul * "[ms] time left in the autoboot window (0 when halted)",
    "page_size" / c.Int16ul * "[bytes] flash page size",
    "page_count" / c.Int16ul * "[pages] flash pages in all",
    "app_start_page" / c.Int16ul * "[page] first page of the application area",
    "app_end_page" / c.Int16ul * "[page] first page after the application area",
    "param_page" / c.Int16ul * "[page] the parameter page (kept across updates)",
    "header" / c.Bytes(HEADER_SIZE) * "[-] the installed image header as stored in flash",
)

MESSAGES: list[Message] = [
    Message(
        "bl.status",
        "bootloader",
        0x07,
        EMPTY,
        c.Struct(
            "state" / STATE * "[-] bootloader state",
            "image_status" / IMAGE_STATUS * "[-] verdict on the installed image",
            "last_error" / c.Int8ul * "[-] code of the last failed command (0 none): a "
            "WriteStatus for bl.write_page, a BootResult for the others",
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
        "Start the application: acknowledged only when the image verifies (a verified image "
        "is activated first), then the node jumps to it.  An image that does not verify gets "
        "no reply, the original host's sign of a failed boot (it listens for this type only); "
        "the node stays in its bootloader and bl.status says why.",
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
            "status" / EnumField(c.Int8ul, WriteStatus) * "[-] outcome; 0x80+i: word i "
            "did not program",
        ),
        "Erase and program one page; staging an image clears its activation.",
    ),
    Message("bl.halt", "bootloader", 0x0C, EMPTY, EMPTY,
            f"Halt the autoboot countdown (the window: {AUTOBOOT_WINDOW_US / 1e6:g} s after "
            "power-up or reset, long enough for the original host tools' reset, listen "
            "1 s + 2 s, halt)."),
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
            "status" / RESULT * "[-] outcome (OK or OUT_OF_RANGE)",
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
            "status" / RESULT * "[-] outcome (OK, BAD_IMAGE, HASH_MISMATCH, WRONG_BOARD or "
            "PROTECTED)",
            "image_status" / IMAGE_STATUS * "[-] verdict on the staged image",
        ),
        "Verify the staged image and mark it bootable.",
        original=False,
    ),
]
