"""The ``slot.*`` messages, answered by every hand program (bootloader or application).

The application keeps running while the host writes the secondary slot page by page
(``slot.write``), hashes it on the node (``slot.hash``) and asks for the swap
(``slot.swap``): the node verifies the image (header, board, size, payload hash, signature
where provisioned), records it as pending, acknowledges and resets; its bootloader swaps the
slots and boots the new image on trial (:mod:`firmware_py.slot_swap`).  ``slot.confirm`` from
the host, or the application's own health check when the swap asked for it, keeps the trial
image; otherwise the trial watchdog or the next reset brings the previous image back.

Refusals of ``slot.write`` (``WriteStatus``): PAGE_OUT_OF_RANGE for an index past the slot;
FLASH_BUSY while a page write or a swap is under way; PAGE_PROTECTED while a trial runs (the
secondary slot holds the previous image, the one a revert brings back) or when the running
image was burnt the one-slot way and runs on into the secondary slot; NOT_FOR_THIS_NODE or
BAD_SIGNATURE for a header the swap would refuse, before anything is erased.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any, Final, Protocol

from firmware_py.flash_layout import PAGE_SIZE, page_address
from firmware_py.hal import Hal
from firmware_py.image_check import ImageCheck, check_header, check_signature, inspect_image
from firmware_py.node_request import DEFERRED, Handler, Request
from firmware_py.slot_swap import (
    PRIMARY,
    SECONDARY,
    SwapRecord,
    read_record,
    secondary_check,
    write_record,
)
from protocol.image import SLOT_MAX_PAYLOAD, BoardType, pages_needed
from protocol.messages.boot_program import WRITE_STATUS_WORD_FAILED, ImageStatus, WriteStatus
from protocol.messages.slots import ConfirmBy, SlotEvent, SlotResult, SlotState

#: After this long on trial (µs) without a reset, an application that was asked to confirm
#: itself runs its health check and, if it passes, confirms.
SELF_CHECK_US: Final = 500_000
#: Delay between the acknowledgement of ``slot.swap`` and the reset (µs): the reply leaves
#: the UART first.
SWAP_RESET_DELAY_US: Final = 200
_NO_HASH: Final = bytes(32)


def _version(check: ImageCheck) -> dict[str, int]:
    if check.header is None:
        return {"major": 0, "minor": 0, "patch": 0}
    return vars(check.header.version)


class Handlers(Protocol):
    """Where the service registers its handlers (a :class:`~firmware_py.hand_node.HandNode`)."""

    def handle(self, name: str, handler: Handler) -> None:
        """Answer message ``name`` with ``handler``."""
        ...


class SlotService:
    """Registers the ``slot.*`` handlers on ``node`` and answers them from ``hal.flash``.

    ``application`` says whether ``node`` is the image running from the primary slot (it
    may then confirm a trial); ``busy()`` adds the program's own reasons not to touch the
    flash (the bootloader's page write or swap in progress); ``health()`` is the
    application's own check before it confirms itself.
    """

    def __init__(self, node: Handlers, hal: Hal, board: BoardType, application: bool,
                 busy: Callable[[], bool] = lambda: False,
                 health: Callable[[], bool] = lambda: True) -> None:
        self.node = node
        self.hal = hal
        self.board = board
        self.application = application
        self.busy = busy
        self.health = health
        self._writing = False
        node.handle("slot.info", self._on_info)
        node.handle("slot.write", self._on_write)
        node.handle("slot.hash", self._on_hash)
        node.handle("slot.swap", self._on_swap)
        node.handle("slot.confirm", self._on_confirm)

    @property
    def flash_busy(self) -> bool:
        """A page write (this service's, the program's, or the flash's own) is under way."""
        return self._writing or self.hal.flash.busy or self.busy()

    def start_self_check(self) -> None:
        """On trial with ``confirm_by`` APPLICATION: confirm after :data:`SELF_CHECK_US` if
        the health check passes (call once, when the application starts)."""
        record, _ = read_record(self.hal.flash)
        if record.state == SlotState.TRIAL and record.confirm_by == ConfirmBy.APPLICATION:
            self.hal.clock.call_later(SELF_CHECK_US, self._self_check)

    def _self_check(self) -> None:
        if self.health() and not self.flash_busy:
            self.confirm(lambda result: None)
        elif not self.flash_busy:
            return  # unhealthy: stay unconfirmed, the trial watchdog reverts
        else:
            self.hal.clock.call_later(SELF_CHECK_US // 10, self._self_check)

    # --- handlers ---------------------------------------------------------------------------
    def _on_info(self, req: Request) -> dict[str, Any]:
        record, _ = read_record(self.hal.flash)
        primary = inspect_image(self.hal.flash, self.board)
        secondary = secondary_check(self.hal.flash, self.board)
        return {
            "primary_page": PRIMARY.start, "secondary_page": SECONDARY.start,
            "slot_pages": len(PRIMARY), "state": record.state, "event": record.event,
            "confirm_by": record.confirm_by, "swap_pages": record.pages,
            "swap_done": record.index if record.in_swap else record.pages,
            "primary_status": primary.status, "primary_version": _version(primary),
            "primary_sha256": primary.header.sha256 if primary.header else _NO_HASH,
            "secondary_status": secondary.status, "secondary_version": _version(secondary),
            "secondary_sha256": secondary.header.sha256 if secondary.header else _NO_HASH,
        }

    def _write_refusal(self, index: int, data: bytes) -> int | None:
        """Why page ``index`` of the secondary slot must not be written (None: write it)."""
        if not 0 <= index < len(SECONDARY):
            return WriteStatus.PAGE_OUT_OF_RANGE
        if self.flash_busy:
            return WriteStatus.FLASH_BUSY
        record, _ = read_record(self.hal.flash)
        if record.in_swap:
            return WriteStatus.FLASH_BUSY
        if record.state == SlotState.TRIAL:
            return WriteStatus.PAGE_PROTECTED
        running = check_header(self.hal.flash.read_page(PRIMARY.start), self.board,
                               0xFFFFFFFF)
        if (not isinstance(running, ImageCheck)
                and pages_needed(running.image_size, PAGE_SIZE) > len(PRIMARY)):
            return WriteStatus.PAGE_PROTECTED
        if index == 0:
            checked = check_header(data, self.board, SLOT_MAX_PAYLOAD)
            if isinstance(checked, ImageCheck):
                return None if checked.header is None else WriteStatus.NOT_FOR_THIS_NODE
            if check_signature(checked, self.hal.flash) is not None:
                return WriteStatus.BAD_SIGNATURE
        return None

    def _on_write(self, req: Request) -> Any:
        index, data = req.fields["index"], req.fields["data"]
        refused = self._write_refusal(index, data)
        if refused is not None:
            return {"index": index, "status": refused}
        page = SECONDARY[index]
        self._writing = True

        def done(ok: bool) -> None:
            self._writing = False
            status = WRITE_STATUS_WORD_FAILED
            if ok:
                got = self.hal.flash.read_page(page)
                bad = next((i // 4 for i in range(0, PAGE_SIZE, 4)
                            if got[i : i + 4] != data[i : i + 4]), None)
                status = WriteStatus.OK if bad is None else WRITE_STATUS_WORD_FAILED + bad
            req.respond({"index": index, "status": status})

        self.hal.flash.write_page(page, data, done)
        return DEFERRED

    def _on_hash(self, req: Request) -> dict[str, Any]:
        pages = req.fields["pages"]
        status = secondary_check(self.hal.flash, self.board).status
        if pages > len(SECONDARY):
            return {"status": SlotResult.OUT_OF_RANGE, "sha256": _NO_HASH,
                    "image_status": status}
        data = self.hal.flash.read(page_address(SECONDARY.start), pages * PAGE_SIZE)
        return {"status": SlotResult.OK, "sha256": hashlib.sha256(data).digest(),
                "image_status": status}

    def _on_swap(self, req: Request) -> Any:
        record, _ = read_record(self.hal.flash)
        check = secondary_check(self.hal.flash, self.board)
        if self.flash_busy or record.in_swap or record.state == SlotState.TRIAL:
            return {"status": SlotResult.BUSY, "image_status": check.status}
        if check.status != ImageStatus.VALID or check.header is None:
            return {"status": SlotResult.BAD_IMAGE, "image_status": check.status}
        if check.header.sha256 != req.fields["sha256"]:
            return {"status": SlotResult.HASH_MISMATCH, "image_status": check.status}
        pending = SwapRecord(SlotState.PENDING, SlotEvent.NONE, ConfirmBy(req.fields["confirm_by"]),
                             sha256=check.header.sha256)
        self._writing = True

        def written(ok: bool) -> None:
            self._writing = False
            if not ok:
                req.respond({"status": SlotResult.FLASH_FAILED, "image_status": check.status})
                return
            req.respond({"status": SlotResult.OK, "image_status": check.status})
            self.hal.clock.call_later(SWAP_RESET_DELAY_US, self.hal.reset)

        write_record(self.hal.flash, pending, written)
        return DEFERRED

    def _on_confirm(self, req: Request) -> Any:
        record, _ = read_record(self.hal.flash)
        if record.state == SlotState.CONFIRMED and record.event == SlotEvent.CONFIRMED:
            return {"status": SlotResult.OK, "state": record.state}
        if not self.application or record.state != SlotState.TRIAL:
            return {"status": SlotResult.NOT_IN_TRIAL, "state": record.state}
        if self.flash_busy:
            return {"status": SlotResult.BUSY, "state": record.state}
        self.confirm(lambda result: req.respond(
            {"status": result, "state": read_record(self.hal.flash)[0].state}))
        return DEFERRED

    def confirm(self, then: Callable[[SlotResult], None]) -> None:
        """Make the trial image the confirmed one and stop the trial watchdog."""
        record, _ = read_record(self.hal.flash)
        confirmed = SwapRecord(SlotState.CONFIRMED, SlotEvent.CONFIRMED, record.confirm_by,
                               record.pages, record.pages, 0, record.sha256)
        self._writing = True

        def written(ok: bool) -> None:
            self._writing = False
            if ok:
                self.hal.watchdog.start(0)
            then(SlotResult.OK if ok else SlotResult.FLASH_FAILED)

        write_record(self.hal.flash, confirmed, written)

