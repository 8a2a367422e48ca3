"""Messages of the two image slots: every hand node answers them, bootloader or application.

A node with the two-slot layout (:class:`protocol.image.FlashGeometry`) runs its image from
the primary slot and accepts a new one into the secondary slot while the application keeps
running: ``slot.write`` pages, ``slot.hash`` to verify them on the node, ``slot.swap`` to
exchange the slots at the next reset, then ``slot.confirm`` once the new image has proved
itself.  A node still on the one-slot layout (an older bootloader) does not know these
types: it answers none of them, which is how a host tells the layouts apart.

States (``SlotState``), kept in the swap-status pages:

* CONFIRMED: the primary image is the one that boots; nothing is pending.
* PENDING: ``slot.swap`` accepted a verified secondary image; the next reset swaps.
* SWAPPING: the bootloader is exchanging the slots, chunk by chunk through the scratch
  pages; a reset or power cut at any instant resumes the exchange where it stood.
* TRIAL: the swapped-in image is booted once on trial.  Unless confirmed before the next
  reset or before :data:`TRIAL_TIMEOUT_US` (the trial watchdog), the next boot swaps back.
* REVERTING: the exchange back to the previous image, resumable like SWAPPING.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

import construct as c

from protocol.catalogue import Message
from protocol.enum_field import EnumField
from protocol.messages.boot_program import IMAGE_STATUS, PAGE_DATA, WriteStatus
from protocol.messages.fields import EMPTY, VERSION

#: How long a trial image has to be confirmed (µs) before the trial watchdog resets the node
#: (and the next boot reverts it).  Enough for a host to identify, version-check and
#: self-test twelve fingers after a fleet swap, with margin.
TRIAL_TIMEOUT_US: Final = 10_000_000


class SlotState(IntEnum):
    """Where an update stands (see the module docstring)."""

    CONFIRMED = 0
    PENDING = 1
    SWAPPING = 2
    TRIAL = 3
    REVERTING = 4


class SlotEvent(IntEnum):
    """The last thing that happened to the slots, kept until the next update."""

    NONE = 0
    #: A swap finished: the new image runs on trial.
    INSTALLED = 1
    #: The trial image was confirmed (by the host or by the application).
    CONFIRMED = 2
    #: The trial image was not confirmed in time: the previous image was swapped back.
    REVERTED = 3
    #: The pending image no longer verified at boot: nothing was swapped.
    REFUSED = 4


class ConfirmBy(IntEnum):
    """Who confirms a trial image."""

    #: The host, with ``slot.confirm`` after its checks; the application does not.
    HOST = 0
    #: The application, after its own health check (the host may confirm too).
    APPLICATION = 1


class SlotResult(IntEnum):
    """Outcome of ``slot.hash``, ``slot.swap`` and ``slot.confirm``."""

    OK = 0
    OUT_OF_RANGE = 1
    #: The secondary image does not verify (header, board, size, hash or signature).
    BAD_IMAGE = 2
    #: The secondary image verifies but has another SHA-256 than the request names.
    HASH_MISMATCH = 3
    #: A page write or a swap is in progress.
    BUSY = 4
    #: ``slot.confirm`` while no trial runs.
    NOT_IN_TRIAL = 5
    #: The swap-status page did not program.
    FLASH_FAILED = 6


SLOT_STATE = EnumField(c.Int8ul, SlotState)
SLOT_EVENT = EnumField(c.Int8ul, SlotEvent)
CONFIRM_BY = EnumField(c.Int8ul, ConfirmBy)
SLOT_RESULT = EnumField(c.Int8ul, SlotResult)

SLOT_INFO = c.Struct(
    "primary_page" / c.Int16ul * "[page] first page of the primary slot",
    "secondary_page" / c.Int16ul * "[page] first page of the secondary slot",
    "slot_pages" / c.Int16ul * "[pages] pages in each slot",
    "state" / SLOT_STATE * "[-] where an update stands",
    "event" / SLOT_EVENT * "[-] the last thing that happened to the slots",
    "confirm_by" / CONFIRM_BY * "[-] who confirms the trial image",
    "swap_pages" / c.Int16ul * "[pages] pages the current or last swap exchanges",
    "swap_done" / c.Int16ul * "[pages] pages of it exchanged so far",
    "primary_status" / IMAGE_STATUS * "[-] verdict on the primary image",
    "primary_version" / VERSION * "[-] version in the primary header (0.0.0 none)",
    "primary_sha256" / c.Bytes(32) * "[-] payload SHA-256 in the primary header (zeros none)",
    "secondary_status" / IMAGE_STATUS * "[-] verdict on the secondary image",
    "secondary_version" / VERSION * "[-] version in the secondary header (0.0.0 none)",
    "secondary_sha256" / c.Bytes(32) * "[-] payload SHA-256 in the secondary header (zeros "
    "none)",
)

MESSAGES: list[Message] = [
    Message("slot.info", "common", 0x70, EMPTY, SLOT_INFO,
            "The two image slots: layout, update state, last event and both images.",
            original=False),
    Message(
        "slot.write",
        "common",
        0x71,
        c.Struct(
            "index" / c.Int16ul * "[page] page within the secondary slot (0: its header)",
            "data" / PAGE_DATA * "[-] the page's 256 bytes",
        ),
        c.Struct(
            "index" / c.Int16ul * "[page] the page written (echo)",
            "status" / EnumField(c.Int8ul, WriteStatus) * "[-] outcome; 0x80+i: word i did "
            "not program",
        ),
        "Erase and program one page of the secondary slot while the running image stays; a "
        "header for another board, too large for a slot or refused by the node's key is "
        "refused before anything is erased.",
        original=False,
    ),
    Message(
        "slot.hash",
        "common",
        0x72,
        c.Struct("pages" / c.Int16ul * "[pages] pages from the start of the secondary slot"),
        c.Struct(
            "status" / SLOT_RESULT * "[-] OK or OUT_OF_RANGE",
            "sha256" / c.Bytes(32) * "[-] SHA-256 of those pages' bytes",
            "image_status" / IMAGE_STATUS * "[-] verdict on the secondary image (header, "
            "board, size, payload hash, signature)",
        ),
        "Hash the secondary slot on the node, and say whether its image verifies.",
        original=False,
    ),
    Message(
        "slot.swap",
        "common",
        0x73,
        c.Struct(
            "sha256" / c.Bytes(32) * "[-] expected payload SHA-256 of the secondary image",
            "confirm_by" / CONFIRM_BY * "[-] who confirms the trial",
        ),
        c.Struct(
            "status" / SLOT_RESULT * "[-] outcome",
            "image_status" / IMAGE_STATUS * "[-] verdict on the secondary image",
        ),
        "Verify the secondary image, mark it pending, acknowledge, then reset: the bootloader "
        "swaps the slots and boots the new image on trial.",
        original=False,
    ),
    Message(
        "slot.confirm",
        "common",
        0x74,
        EMPTY,
        c.Struct(
            "status" / SLOT_RESULT * "[-] OK, NOT_IN_TRIAL or FLASH_FAILED",
            "state" / SLOT_STATE * "[-] the state after the request",
        ),
        "Keep the trial image: it becomes the confirmed one and the trial watchdog stops.",
        original=False,
    ),
]
