"""The swap of the two image slots: a status record and a copy that survives a cut anywhere.

The swap-status record lives on two pages (:attr:`FlashGeometry.swap_status_pages`) written
alternately with an increasing sequence number, so that a cut while one is being written
leaves the other holding the previous record; a torn page fails its CRC-32 and is ignored.
No valid record on either page (a node flashed the one-slot way) reads as CONFIRMED.

The exchange moves :attr:`SwapRecord.pages` pages (the larger of the two images) in chunks of
as many pages as there are scratch pages.  Each chunk takes three copies, and the record is
rewritten after each copy has finished, naming the copy to do next:

* step 0: scratch ← primary chunk (primary and secondary untouched);
* step 1: primary chunk ← secondary chunk (the scratch holds the old primary chunk);
* step 2: secondary chunk ← scratch (the primary chunk holds the new one).

Every step reads only pages the step itself does not write, and its sources are unchanged
until the record names the next step, so redoing the step the record names after a cut (in a
copy, or in the record write itself, when the older record names the step before) always
produces the same pages.  A page that already holds what it should is not written again
(quicker, and less wear).  When all chunks are done, the activation record is written for the
new primary image, then the record moves to TRIAL (an install) or CONFIRMED with the event
REVERTED (a swap back).

Wear: a swap of ``n`` pages writes each of them twice, the scratch pages ``n/4`` times each
and the two status pages ``3n/8`` times each; a 4 KiB image (17 pages) costs the status pages
7 erase cycles a swap, of the SAM3S's 10 000 guaranteed.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Final

from firmware_py.flash_layout import BOOT_CONTROL_PAGE, PAGE_SIZE, ActivationRecord
from firmware_py.hal import Flash
from firmware_py.image_check import ERASED_PAGE, ImageCheck, inspect_image
from protocol.image import FLASH, SLOT_MAX_PAYLOAD, BoardType, pages_needed
from protocol.messages.slots import ConfirmBy, SlotEvent, SlotState

SWAP_MAGIC: Final = 0x31544C53  # b"SLT1" little-endian
_RECORD = struct.Struct("<IIBBBBHH32s")
#: How many times a page write that reports failure is tried before the swap gives up.
WRITE_TRIES: Final = 3
PRIMARY: Final = FLASH.primary_slot
SECONDARY: Final = FLASH.secondary_slot
SCRATCH: Final = FLASH.scratch
STATUS_PAGES: Final = FLASH.swap_status_pages


@dataclass(frozen=True)
class SwapRecord:
    """One swap-status record: where an update stands.

    ``pages`` is the number of slot pages the swap exchanges, ``index`` the first page of the
    chunk being moved and ``step`` its next copy (0..2, see the module docstring); ``sha256``
    is the payload hash of the image being installed; ``seq`` orders the two pages' records.
    """

    state: SlotState = SlotState.CONFIRMED
    event: SlotEvent = SlotEvent.NONE
    confirm_by: ConfirmBy = ConfirmBy.HOST
    pages: int = 0
    index: int = 0
    step: int = 0
    sha256: bytes = bytes(32)
    seq: int = 0

    def to_page(self) -> bytes:
        """The record as a whole flash page (CRC-32 protected, 0xFF-filled)."""
        body = _RECORD.pack(SWAP_MAGIC, self.seq, int(self.state), int(self.event),
                            int(self.confirm_by), self.step, self.pages, self.index,
                            self.sha256)
        rec = body + struct.pack("<I", zlib.crc32(body))
        return rec + b"\xff" * (PAGE_SIZE - len(rec))

    @staticmethod
    def from_page(page: bytes) -> SwapRecord | None:
        """The record in ``page``, or None (erased, torn or corrupt)."""
        size = _RECORD.size
        magic, seq, state, event, confirm_by, step, pages, index, sha = _RECORD.unpack_from(page)
        (crc,) = struct.unpack_from("<I", page, size)
        if magic != SWAP_MAGIC or zlib.crc32(page[:size]) != crc:
            return None
        try:
            return SwapRecord(SlotState(state), SlotEvent(event), ConfirmBy(confirm_by),
                              pages, index, step, sha, seq)
        except ValueError:
            return None

    @property
    def in_swap(self) -> bool:
        """The slots are being exchanged (either way)."""
        return self.state in (SlotState.SWAPPING, SlotState.REVERTING)


def read_record(flash: Flash) -> tuple[SwapRecord, int | None]:
    """The newest valid record and the page it is on (None: no record, reads as CONFIRMED)."""
    best: tuple[SwapRecord, int | None] = (SwapRecord(), None)
    for page in STATUS_PAGES:
        rec = SwapRecord.from_page(flash.read_page(page))
        if rec is not None and (best[1] is None or rec.seq > best[0].seq):
            best = (rec, page)
    return best


def write_record(flash: Flash, record: SwapRecord, done: Callable[[bool], None]) -> SwapRecord:
    """Write ``record`` (with the next sequence number) onto the status page not holding the
    newest record; ``done(ok)`` once programmed and read back.  Returns what is written."""
    current, page = read_record(flash)
    target = STATUS_PAGES[1] if page == STATUS_PAGES[0] else STATUS_PAGES[0]
    new = replace(record, seq=current.seq + 1)
    data = new.to_page()

    def finished(ok: bool) -> None:
        done(ok and flash.read_page(target) == data)

    flash.write_page(target, data, finished)
    return new


def image_pages(flash: Flash, header_page: int, board: BoardType) -> int:
    """Slot pages the image on ``header_page`` occupies (0: no image header there; at most a
    slot: an image burnt the one-slot way may run past it)."""
    check = inspect_image(flash, board, header_page, max_payload=0xFFFFFFFF, activated=False)
    if check.header is None:
        return 0
    return min(len(PRIMARY), pages_needed(check.header.image_size, PAGE_SIZE))


def secondary_check(flash: Flash, board: BoardType) -> ImageCheck:
    """The verdict on the secondary slot's image (it must fit a slot; no activation)."""
    return inspect_image(flash, board, SECONDARY.start, SLOT_MAX_PAYLOAD, activated=False)


class SlotSwap:
    """Runs (or resumes) the exchange a record describes, page write by page write.

    ``running()`` is False once the program that started it is gone (a reset or power cut):
    the swap then stops where it stands and the next boot resumes it.  ``done(record)`` gets
    the final record, or None if a page write failed :data:`WRITE_TRIES` times.
    """

    def __init__(self, flash: Flash, board: BoardType, running: Callable[[], bool]) -> None:
        self.flash = flash
        self.board = board
        self.running = running
        #: Pages written by this swap (copies, records, activation), for tests and reports.
        self.writes = 0

    def resume(self, record: SwapRecord, done: Callable[[SwapRecord | None], None]) -> None:
        """Carry on from ``record`` (state SWAPPING or REVERTING) to the end."""
        self._done = done
        self._chunk(record)

    # --- the copy, chunk by chunk ---------------------------------------------------------
    def _chunk(self, rec: SwapRecord) -> None:
        if not self.running():
            return
        if rec.index >= rec.pages:
            self._finish(rec)
            return
        k = min(len(SCRATCH), rec.pages - rec.index)
        first = rec.index
        if rec.step == 0:
            copies = [(SCRATCH[j], PRIMARY[first + j]) for j in range(k)]
            after = replace(rec, step=1)
        elif rec.step == 1:
            copies = [(PRIMARY[first + j], SECONDARY[first + j]) for j in range(k)]
            after = replace(rec, step=2)
        else:
            copies = [(SECONDARY[first + j], SCRATCH[j]) for j in range(k)]
            after = replace(rec, index=first + k, step=0)
        self._copy(copies, lambda: self._record(after, lambda: self._chunk(after)))

    def _copy(self, copies: list[tuple[int, int]], then: Callable[[], None]) -> None:
        """Copy pages (destination, source) one after the other, then call ``then``."""
        if not self.running():
            return
        if not copies:
            then()
            return
        dst, src = copies[0]
        data = self.flash.read_page(src)
        if self.flash.read_page(dst) == data:
            self._copy(copies[1:], then)
            return
        self._write(dst, data, lambda: self._copy(copies[1:], then))

    def _write(self, page: int, data: bytes, then: Callable[[], None], tries: int = 1) -> None:
        self.writes += 1

        def finished(ok: bool) -> None:
            if not self.running():
                return
            if ok and self.flash.read_page(page) == data:
                then()
            elif tries < WRITE_TRIES:
                self._write(page, data, then, tries + 1)
            else:
                self._done(None)

        self.flash.write_page(page, data, finished)

    def _record(self, rec: SwapRecord, then: Callable[[], None], tries: int = 1) -> None:
        if not self.running():
            return
        self.writes += 1

        def finished(ok: bool) -> None:
            if not self.running():
                return
            if ok:
                then()
            elif tries < WRITE_TRIES:
                self._record(rec, then, tries + 1)
            else:
                self._done(None)

        write_record(self.flash, rec, finished)

    def _finish(self, rec: SwapRecord) -> None:
        """All pages exchanged: activate what is now primary, then move the record on."""
        check = inspect_image(self.flash, self.board, activated=False)
        activation = (ActivationRecord(check.header.sha256).to_page()
                      if check.staged_ok and check.header is not None else ERASED_PAGE)
        if rec.state == SlotState.SWAPPING:
            final = replace(rec, state=SlotState.TRIAL, event=SlotEvent.INSTALLED)
        else:
            final = replace(rec, state=SlotState.CONFIRMED, event=SlotEvent.REVERTED)

        def recorded() -> None:
            self._done(read_record(self.flash)[0])

        def activated() -> None:
            self._record(final, recorded)

        if self.flash.read_page(BOOT_CONTROL_PAGE) == activation:
            activated()
        else:
            self._write(BOOT_CONTROL_PAGE, activation, activated)
