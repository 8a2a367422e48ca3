"""The boot program: the bootloader that runs on every hand microcontroller after power-up
and reset (named so beside the host's flashing package :mod:`bootloader`; its messages are
:mod:`protocol.messages.boot_program`, ``bl.*`` on the wire).

One program, configured by the board type in the node's identity page: it listens on the
board's upstream UART (``pogo`` on an fmcb, ``tendon`` on f2/f3, ``host`` on the palm),
locks its own pages 0–31 (bootloader and identity), holds the phalange bus unpowered on an
fmcb, and opens an autoboot window of :attr:`BootProgram.autoboot_us` µs on the node clock.
Any bootloader command addressed to the node (its address or broadcast) closes the window
for good, as read, write and halt did on the original hand.  The common messages (ping,
identify, hw_version) are answered without closing it: a host that polls ``identify`` to
learn when a node has booted must not be what keeps it in its bootloader.

When the window ends the application starts only if the installed image verifies
(:func:`inspect_image`): the header on page 32 parses and names this board and load
address, the payload pages hash to the header's SHA-256, and the activation record on
:data:`~firmware_py.flash_layout.BOOT_CONTROL_PAGE` names that SHA-256.  Otherwise the node
stays here and ``bl.status`` / ``bl.info`` say why.

Two image slots (:mod:`firmware_py.slot_swap`): at start, before any autoboot window, the
bootloader carries an update on from the swap-status record: it verifies a pending
secondary image and swaps it in, resumes a swap a reset or power cut interrupted, or swaps
the previous image back when a trial ended unconfirmed.  After a swap it boots at once (no
window; a ``bl.*`` command meanwhile makes it stay); a trial image is booted with the trial
watchdog armed (:data:`~protocol.messages.slots.TRIAL_TIMEOUT_US`), and one that does not
verify or has no program on this board is swapped back at once.  ``bl.status`` says what
happened.

Flashing is staged: the first write to the image area in a session first erases the
activation record (and waits for that), so an interrupted update never boots half an image;
``bl.activate`` verifies the staged image and writes the record.  An explicit ``bl.boot``
is the host's consent: a verified but not activated image is activated, then booted (so the
original write-then-boot flow still works); an image that does not verify never boots, and
its ``bl.boot`` gets no reply (the original host's sign of a failed boot).

Choices beyond the original:

* ``bl.read_page`` of a page outside 0..1023 gets no reply (its reply has no status
  field); the node counts it in :attr:`BootProgram.refused_reads` and ``bl.status``
  reports ``last_error`` 1.
* ``bl.write_page`` replies only once the page is programmed and read back; a word that
  reads back wrong gives status ``0x80 + i`` (word ``i``), a write the flash reports as
  failed gives ``0x80``.  Status 1: page < 32 or ≥ 1024 (as the original, so the identity
  page 31 is covered); 2: the boot-control page (activation only through ``bl.activate``);
  3: a write is already in progress (or a swap is running).  A write of the application
  area first forgets an update in progress (the record goes back to CONFIRMED), so that no
  swap later undoes the image being burnt the one-slot way.
* A write of the header page (page 32) holding an image header this node would never
  activate is refused before anything is erased, so the installed image keeps booting:
  status 4 for another board or load address or a payload too large, 5 for a signature
  this node's key refuses (or none where the key record requires one).  A page that is no
  image header at all is written as before (the write-then-boot check refuses it later).
* ``bl.activate`` and ``bl.boot`` arriving while a page write is in progress wait for it.
* ``last_error`` in ``bl.status`` is the code of the last failed command: a write-page
  status (``WriteStatus``) for ``bl.write_page``, a ``BootResult`` for the others.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Final

from mypy_extensions import mypyc_attr

from firmware_py.errors import ConfigError
from firmware_py.flash_layout import (
    APP_PAGES,
    BOOT_CONTROL_PAGE,
    BOOTLOADER_PAGES,
    HEADER_PAGE,
    PAGE_SIZE,
    PARAM_PAGE,
    ActivationRecord,
    page_address,
)
from firmware_py.hal import Hal, Timer, Uart
from firmware_py.hand_node import DEFERRED, HandNode, Request
from firmware_py.image_check import (
    ERASED_PAGE,
    RESULT_OF_IMAGE_STATUS,
    ImageCheck,
    check_header,
    check_signature,
    inspect_image,
)
from firmware_py.mcu import Mcu
from firmware_py.slot_swap import (
    PRIMARY,
    SECONDARY,
    SlotSwap,
    SwapRecord,
    image_pages,
    read_record,
    secondary_check,
    write_record,
)
from protocol.framing import Frame
from protocol.image import FLASH, BoardType
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import (
    AUTOBOOT_WINDOW_US,
    WRITE_STATUS_WORD_FAILED,
    BootResult,
    BootState,
    ImageStatus,
    WriteStatus,
)
from protocol.messages.common import Running
from protocol.messages.slots import TRIAL_TIMEOUT_US, SlotEvent, SlotState
from protocol.topology import HAND_BOARDS

__all__ = ["AUTOBOOT_US", "BootProgram", "ImageCheck", "check_header", "check_signature",
           "inspect_image"]

#: Default autoboot window (µs): the protocol's window, long enough for the original host
#: tools' reset, wait 1 s + 2 s, halt (see :data:`AUTOBOOT_WINDOW_US`).
AUTOBOOT_US: Final = AUTOBOOT_WINDOW_US
#: Delay between an acknowledgement and the jump to the application (µs).
BOOT_DELAY_US: Final = 200
#: Poll period while waiting for a flash write this program did not start (µs).
BUSY_POLL_US: Final = 500

#: Upstream UART of each hand board: where the host (or the board above) talks to it.
UPSTREAM_UART: Final = {b.board_type: b.upstream for b in HAND_BOARDS}

_NO_PAGE: Final = 0xFFFFFFFF


def _first_bad_word(expected: bytes, actual: bytes) -> int | None:
    """Index of the first 32-bit word that differs, or None if the pages are equal."""
    for i in range(0, len(expected), 4):
        if expected[i : i + 4] != actual[i : i + 4]:
            return i // 4
    return None


@mypyc_attr(allow_interpreted_subclasses=True)
class BootProgram(HandNode):
    """The bootloader program of a hand node (see the module docstring).

    ``autoboot_us`` overrides the class default window (µs).
    """

    node_kind = "bootloader"
    running = Running.BOOTLOADER
    FW_VERSION = (1, 0, 0)
    #: Autoboot window (µs) after power-up or reset.
    autoboot_us: int = AUTOBOOT_US

    def __init__(self, hal: Hal, mcu: Mcu, autoboot_us: int | None = None) -> None:
        super().__init__(hal)
        self.mcu = mcu
        if autoboot_us is not None:
            self.autoboot_us = int(autoboot_us)
        board = self.identity.board_type
        if board not in UPSTREAM_UART:
            raise ConfigError(f"no hand bootloader for board type {self.identity.board}")
        self.board: BoardType = board
        self.upstream = hal.uart(UPSTREAM_UART[board])
        self.state = BootState.AUTOBOOT_COUNTDOWN
        self.last_error = 0
        self.last_page = _NO_PAGE
        self.note = ""
        self.refused_reads = 0
        self._deadline_us = 0
        self._timer: Timer | None = None
        self._busy = False
        self._waiting: list[Callable[[], None]] = []
        #: The slot swap under way (None: none), and whether a host asked to stay here.
        self._swap: SlotSwap | None = None
        self._stay = False
        if self.slots is not None:
            self.slots.busy = lambda: self._busy or self._swap is not None
        self.handle("bl.halt", lambda req: {})
        self.handle("bl.status", self._on_status)
        self.handle("bl.info", self._on_info)
        self.handle("bl.read_page", self._on_read_page)
        self.handle("bl.write_page", self._on_write_page)
        self.handle("bl.hash", self._on_hash)
        self.handle("bl.activate", self._on_activate)
        self.handle("bl.boot", self._on_boot)

    # --- program life -----------------------------------------------------------------------
    def start(self) -> None:
        """Lock the bootloader pages, cut phalange power, listen, open the autoboot window."""
        self.hal.flash.lock(BOOTLOADER_PAGES.start, len(BOOTLOADER_PAGES))  # with the key page
        if self.board == BoardType.FMCB:
            self.hal.power("phalange").set(0)
        self.listen(self.upstream)
        record, _ = read_record(self.hal.flash)
        if self.slots is not None and record.state != SlotState.CONFIRMED:
            self._finish_update(record)
        else:
            self._open_window()

    def _open_window(self) -> None:
        """Start the autoboot countdown."""
        self.state = BootState.AUTOBOOT_COUNTDOWN
        self._deadline_us = self.hal.clock.now_us() + self.autoboot_us
        self._timer = self.hal.clock.call_later(self.autoboot_us, self._autoboot)

    # --- the two slots ------------------------------------------------------------------------
    def _finish_update(self, record: SwapRecord) -> None:
        """Carry an update on from ``record``: verify and start a pending swap, swap back an
        unconfirmed trial, or resume a swap a reset or power cut interrupted."""
        self.state = BootState.SWAPPING
        if record.state == SlotState.PENDING:
            check = secondary_check(self.hal.flash, self.board)
            if (check.status != ImageStatus.VALID or check.header is None
                    or check.header.sha256 != record.sha256):
                why = check.reason if check.status != ImageStatus.VALID else "another SHA-256"
                self.note = f"swap refused: secondary image: {why}"
                refused = replace(record, state=SlotState.CONFIRMED, event=SlotEvent.REFUSED)
                self._record_then(refused, lambda rec: self._open_window())
                return
            pages = max(image_pages(self.hal.flash, SECONDARY.start, self.board),
                        image_pages(self.hal.flash, PRIMARY.start, self.board))
            record = replace(record, state=SlotState.SWAPPING, event=SlotEvent.NONE,
                             pages=pages, index=0, step=0)
            self._record_then(record, self._run_swap)
        elif record.state == SlotState.TRIAL:
            self._revert(record, "trial image not confirmed: swapping the previous image back")
        else:
            self._run_swap(record)

    def _revert(self, record: SwapRecord, why: str) -> None:
        """Swap the previous image back (the trial image failed or was not confirmed)."""
        self.note = why
        self.state = BootState.SWAPPING
        self._record_then(replace(record, state=SlotState.REVERTING, index=0, step=0),
                          self._run_swap)

    def _record_then(self, record: SwapRecord, then: Callable[[SwapRecord], None]) -> None:
        """Write the swap-status ``record``, then call ``then`` with it (as written)."""
        self._busy = True
        box: list[SwapRecord] = []

        def done(ok: bool) -> None:
            if not self._running():
                return
            self._busy = False
            if ok:
                then(box[0])
            else:
                self._swap_failed("swap-status page did not program")

        box.append(write_record(self.hal.flash, record, done))

    def _run_swap(self, record: SwapRecord) -> None:
        self.state = BootState.SWAPPING
        self._swap = SlotSwap(self.hal.flash, self.board, self._running)
        self._swap.resume(record, self._swapped)

    def _swap_failed(self, why: str) -> None:
        self._swap = None
        self.state = BootState.NO_VALID_IMAGE
        self._fail(BootResult.PROTECTED, f"swap stopped: {why}")
        self._run_waiting()

    def _swapped(self, final: SwapRecord | None) -> None:
        """The exchange is over: boot what is now primary at once (no autoboot window),
        unless a host halted the countdown meanwhile."""
        if final is None:
            self._swap_failed("a page did not program")
            return
        self._swap = None
        check = self.inspect()
        name = f"{check.header.app_name} {check.header.version}" if check.header else "none"
        if final.state == SlotState.TRIAL:
            self.note = f"swapped: {name} boots on trial"
        else:
            self.note = f"reverted: the trial image was not confirmed; back to {name}"
        self._run_waiting()
        if final.state == SlotState.TRIAL and (
                check.status != ImageStatus.VALID or check.header is None
                or check.header.app_name not in self.mcu.apps):
            self._revert(final, f"swapped-in image cannot boot ({check.reason}): reverting")
        elif self._stay:
            self.state = BootState.HALTED
        elif check.status == ImageStatus.VALID:
            self._jump(check)
        else:
            self.state = BootState.NO_VALID_IMAGE

    def _running(self) -> bool:
        """True while this program is the one running on the MCU (not reset or replaced)."""
        return self.mcu.powered and self.mcu.program is self

    def inspect(self) -> ImageCheck:
        """The verdict on the image installed in this node's flash."""
        return inspect_image(self.hal.flash, self.board)

    @property
    def autoboot_ms_left(self) -> int:
        """Time left in the autoboot window (ms, rounded up; 0 once it is closed)."""
        if self.state != BootState.AUTOBOOT_COUNTDOWN:
            return 0
        left_us = max(0, self._deadline_us - self.hal.clock.now_us())
        return min(0xFFFF, -(-left_us // 1000))

    def halt_autoboot(self) -> None:
        """Close the autoboot window: the node stays here until told to boot."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.state == BootState.AUTOBOOT_COUNTDOWN:
            self.state = BootState.HALTED
        elif self.state == BootState.SWAPPING:
            self._stay = True  # finish the swap, then stay

    def dispatch(self, msg_type: int, payload: bytes, frame: Frame, uart: Uart,
                 send: Callable[[bytes | None, int], None]) -> None:
        """A bootloader command (``bl.*``) for this node halts the autoboot countdown, sent
        plain or inside a ``txn`` envelope (the envelope's inner request is dispatched here
        too).

        The common messages (ping, identify) and application traffic that a bootloader does
        not understand (the palm polling ``fmcb.status`` while a finger boots, say) do not:
        otherwise a polled or pinged finger would never leave its bootloader after a power
        cycle.
        """
        message = CATALOGUE.lookup(self.node_kind, msg_type)
        if message is not None and message.node == "bootloader":
            self.halt_autoboot()
        super().dispatch(msg_type, payload, frame, uart, send)

    def _autoboot(self) -> None:
        self._timer = None
        if not self._running() or self.state != BootState.AUTOBOOT_COUNTDOWN:
            return
        check = self.inspect()
        if check.status == ImageStatus.VALID:
            self._jump(check)
        else:
            self.state = BootState.NO_VALID_IMAGE
            self.note = "autoboot: stayed in bootloader"

    def _jump(self, check: ImageCheck) -> None:
        """Start the application the verified header names."""
        assert check.header is not None
        self.state = BootState.BOOTING
        trial = read_record(self.hal.flash)[0].state == SlotState.TRIAL
        try:
            self.mcu.boot(check.header.app_name, check.header.version)
        except ConfigError as exc:
            self.state = BootState.NO_VALID_IMAGE
            self._fail(BootResult.BAD_IMAGE, f"boot failed: {exc}")
            return
        if trial:
            # The trial watchdog: unless the image confirms itself (or the host confirms
            # it) in time, the node resets and the next boot swaps the previous image back.
            self.hal.watchdog.start(TRIAL_TIMEOUT_US)

    def _fail(self, code: int, note: str) -> None:
        self.last_error = code
        self.note = note

    # --- flash writes, one at a time --------------------------------------------------------
    @property
    def flash_busy(self) -> bool:
        """A page write (ours, or one left over from before a reset) is in progress."""
        return self._busy or self._swap is not None or self.hal.flash.busy

    def _program(self, page: int, data: bytes, then: Callable[[int], None]) -> None:
        """Erase and program ``page``, read it back, then call ``then`` with a write status."""
        self._busy = True

        def done(ok: bool) -> None:
            if not self._running():
                return  # reset or power cut: the CPU that asked is gone
            self._busy = False
            status = WRITE_STATUS_WORD_FAILED
            if ok:
                bad = _first_bad_word(data, self.hal.flash.read_page(page))
                status = WriteStatus.OK if bad is None else WRITE_STATUS_WORD_FAILED + bad
            then(status)
            self._run_waiting()

        self.hal.flash.write_page(page, data, done)

    def _when_idle(self, action: Callable[[], None]) -> None:
        """Run ``action`` now, or once the page write in progress has finished."""
        self._waiting.append(action)
        self._run_waiting()

    def _run_waiting(self) -> None:
        if not self._running():
            return
        while self._waiting and not self.flash_busy and self._running():
            self._waiting.pop(0)()
        if self._waiting and not self._busy and self._running():
            # Someone else's write (started before a reset): nobody will call us back.
            self.hal.clock.call_later(BUSY_POLL_US, self._run_waiting)

    # --- handlers ---------------------------------------------------------------------------
    def _on_status(self, req: Request) -> dict[str, Any]:
        check = self.inspect()
        text = f"{self.note}; {check.reason}" if self.note else check.reason
        return {
            "state": self.state,
            "image_status": check.status,
            "last_error": self.last_error,
            "last_page": self.last_page,
            "text": text.encode("ascii", "replace").decode("ascii")[:255],
        }

    def _on_info(self, req: Request) -> dict[str, Any]:
        major, minor, patch = self.fw_version
        return {
            "board": int(self.board),
            "bl_version": {"major": major, "minor": minor, "patch": patch},
            "state": self.state,
            "image_status": self.inspect().status,
            "autoboot_ms_left": self.autoboot_ms_left,
            "page_size": FLASH.page_size,
            "page_count": FLASH.page_count,
            "app_start_page": APP_PAGES.start,
            "app_end_page": APP_PAGES.stop,
            "param_page": PARAM_PAGE,
            "header": self.hal.flash.read_page(HEADER_PAGE),
        }

    def _on_read_page(self, req: Request) -> dict[str, Any] | None:
        page = req.fields["page"]
        if not 0 <= page < FLASH.page_count:
            self.refused_reads += 1
            self._fail(BootResult.OUT_OF_RANGE, f"read of page {page}: out of range")
            return None
        return {"data": self.hal.flash.read_page(page)}

    def _on_write_page(self, req: Request) -> Any:
        page, data = req.fields["page"], req.fields["data"]
        self.last_page = page

        def reply(status: int) -> None:
            if status != WriteStatus.OK:
                self._fail(status, f"write of page {page}: status 0x{status:02x}")
            req.respond({"page": page, "status": status})

        if not FLASH.app_start_page <= page < FLASH.page_count:
            reply(WriteStatus.PAGE_OUT_OF_RANGE)
        elif page == BOOT_CONTROL_PAGE:
            reply(WriteStatus.PAGE_PROTECTED)
        elif self.flash_busy:
            reply(WriteStatus.FLASH_BUSY)
        elif page == HEADER_PAGE and (refused := self._header_refusal(data)) is not None:
            status, why = refused
            self._fail(status, f"write of page {page}: header refused: {why}")
            req.respond({"page": page, "status": status})
        elif page in APP_PAGES:
            self._stage(page, data, reply)
        else:
            self._program(page, data, reply)
        return DEFERRED

    def _stage(self, page: int, data: bytes, reply: Callable[[int], None]) -> None:
        """Write a page of the application area the one-slot way: first forget an update
        in progress (so that no swap later undoes the image being burnt) and the activation
        (so that an interrupted write never boots), then the page."""
        def program(status: int = WriteStatus.OK) -> None:
            if status == WriteStatus.OK:
                self._program(page, data, reply)
            else:
                reply(status)

        def deactivate(status: int = WriteStatus.OK) -> None:
            if status != WriteStatus.OK:
                reply(status)
            elif self.hal.flash.read_page(BOOT_CONTROL_PAGE) != ERASED_PAGE:
                self._program(BOOT_CONTROL_PAGE, ERASED_PAGE, program)
            else:
                program()

        if read_record(self.hal.flash)[0].state != SlotState.CONFIRMED:
            self._busy = True

            def forgotten(ok: bool) -> None:
                if self._running():
                    self._busy = False
                    deactivate(WriteStatus.OK if ok else WRITE_STATUS_WORD_FAILED)

            write_record(self.hal.flash, SwapRecord(), forgotten)
        else:
            deactivate()

    def _header_refusal(self, data: bytes) -> tuple[WriteStatus, str] | None:
        """Why a header page must not be written: its status and reason (None: write it).  An image header for
        another board or load address, too large, or refused by this node's key would only
        be found out at activation, after the installed image was overwritten: it is refused
        before anything is erased.  A page that is no image header at all (erased, or what
        an older tool writes) is written as before."""
        checked = check_header(data, self.board)
        if isinstance(checked, ImageCheck):
            if checked.header is None:
                return None
            return WriteStatus.NOT_FOR_THIS_NODE, checked.reason
        refused = check_signature(checked, self.hal.flash)
        if refused is not None:
            return WriteStatus.BAD_SIGNATURE, refused.reason
        return None

    def _on_hash(self, req: Request) -> dict[str, Any]:
        start, count = req.fields["start_page"], req.fields["pages"]
        if start >= FLASH.page_count or count > FLASH.page_count - start:
            self._fail(BootResult.OUT_OF_RANGE, f"hash of pages {start}+{count}: out of range")
            return {"status": BootResult.OUT_OF_RANGE, "sha256": bytes(32)}
        data = self.hal.flash.read(page_address(start), count * PAGE_SIZE)
        return {"status": BootResult.OK, "sha256": hashlib.sha256(data).digest()}

    def _on_activate(self, req: Request) -> Any:
        wanted = req.fields["sha256"]

        def activate() -> None:
            check = self.inspect()
            if not check.staged_ok:
                code = RESULT_OF_IMAGE_STATUS[check.status]
                self._fail(code, f"activate refused: {check.reason}")
                req.respond({"status": code, "image_status": check.status})
            elif check.header is None or check.header.sha256 != wanted:
                self._fail(BootResult.HASH_MISMATCH,
                           "activate refused: staged image has another SHA-256")
                req.respond({"status": BootResult.HASH_MISMATCH, "image_status": check.status})
            else:
                self._activate(check, lambda code, after: req.respond(
                    {"status": code, "image_status": after.status}))

        self._when_idle(activate)
        return DEFERRED

    def _activate(self, check: ImageCheck, then: Callable[[int, ImageCheck], None]) -> None:
        """Write the activation record for the verified ``check`` (no-op if present)."""
        assert check.header is not None
        if check.status == ImageStatus.VALID:
            then(BootResult.OK, check)
            return

        def written(status: int) -> None:
            after = self.inspect()
            if status != WriteStatus.OK or after.status != ImageStatus.VALID:
                self._fail(BootResult.PROTECTED, "activation record did not program")
                then(BootResult.PROTECTED, after)
            else:
                then(BootResult.OK, after)

        self._program(BOOT_CONTROL_PAGE, ActivationRecord(check.header.sha256).to_page(), written)

    def _on_boot(self, req: Request) -> Any:
        """Boot only what verifies, and say so truthfully.

        After any page write in progress, the image is checked (and, verified, activated);
        only then is the request acknowledged and the jump made :data:`BOOT_DELAY_US` later,
        once the acknowledgement has left the UART.  An image that does not verify (a
        header-less raw binary, a truncated or foreign image) gets no reply: the original
        host listens for a reply of this type and reports "failed to boot" without one.
        """
        self._when_idle(lambda: self._boot_requested(req))
        return DEFERRED

    def _boot_requested(self, req: Request) -> None:
        check = self.inspect()
        if not check.staged_ok:
            self.state = BootState.NO_VALID_IMAGE
            self._fail(RESULT_OF_IMAGE_STATUS[check.status], f"boot refused: {check.reason}")
            return
        assert check.header is not None
        if check.header.app_name not in self.mcu.apps:
            self.state = BootState.NO_VALID_IMAGE
            self._fail(BootResult.BAD_IMAGE,
                       f"boot refused: no application {check.header.app_name!r} on this board")
            return

        def activated(code: int, after: ImageCheck) -> None:
            if code != BootResult.OK:
                self.state = BootState.NO_VALID_IMAGE
                return
            req.respond({})
            self.hal.clock.call_later(BOOT_DELAY_US, lambda: self._jump_if_running(after))

        # An explicit boot is the host's consent to activate a verified image.
        self._activate(check, activated)

    def _jump_if_running(self, check: ImageCheck) -> None:
        if self._running():
            self._jump(check)
