"""The bootloader that runs on every hand microcontroller after power-up and reset.

One program, configured by the board type in the node's identity page: it listens on the
board's upstream UART (``pogo`` on an fmcb, ``tendon`` on f2/f3, ``host`` on the palm),
locks its own pages 0–31 (bootloader and identity), holds the phalange bus unpowered on an
fmcb, and opens an autoboot window of :attr:`Bootloader.autoboot_us` µs on the node clock.
Any bootloader command addressed to the node (its address or broadcast) closes the window
for good, as read, write and halt did on the original hand.  The common messages (ping,
identify, hw_version) are answered without closing it: a host that polls ``identify`` to
learn when a node has booted must not be what keeps it in its bootloader.

When the window ends the application starts only if the installed image verifies
(:func:`inspect_image`): the header on page 32 parses and names this board and load
address, the payload pages hash to the header's SHA-256, and the activation record on
:data:`~firmware_py.flash_layout.BOOT_CONTROL_PAGE` names that SHA-256.  Otherwise the node
stays here and ``bl.status`` / ``bl.info`` say why.

Flashing is staged: the first write to the image area in a session first erases the
activation record (and waits for that), so an interrupted update never boots half an image;
``bl.activate`` verifies the staged image and writes the record.  An explicit ``bl.boot``
is the host's consent: a verified but not activated image is activated, then booted (so the
original write-then-boot flow still works); an image that does not verify never boots, and
its ``bl.boot`` gets no reply (the original host's sign of a failed boot).

Choices beyond the original:

* ``bl.read_page`` of a page outside 0..1023 gets no reply (its reply has no status
  field); the node counts it in :attr:`Bootloader.refused_reads` and ``bl.status``
  reports ``last_error`` 1.
* ``bl.write_page`` replies only once the page is programmed and read back; a word that
  reads back wrong gives status ``0x80 + i`` (word ``i``), a write the flash reports as
  failed gives ``0x80``.  Status 1: page < 32 or ≥ 1024 (as the original, so the identity
  page 31 is covered); 2: the boot-control page (activation only through ``bl.activate``);
  3: a write is already in progress.
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
from dataclasses import dataclass
from typing import Any, Final

from firmware_py import ed25519
from firmware_py.errors import ConfigError
from firmware_py.flash_layout import (
    APP_PAGES,
    BOOT_CONTROL_PAGE,
    BOOTLOADER_PAGES,
    HEADER_PAGE,
    KEY_PAGE,
    PAGE_SIZE,
    PARAM_PAGE,
    PAYLOAD_FIRST_PAGE,
    ActivationRecord,
    KeyRecord,
    page_address,
)
from firmware_py.hal import Flash, Hal, Timer, Uart
from firmware_py.hand_node import DEFERRED, HandNode, Request
from firmware_py.mcu import Mcu
from protocol.errors import ImageError
from protocol.framing import Frame
from protocol.image import (
    FLASH,
    MAX_PAYLOAD,
    BoardType,
    ImageHeader,
    parse_header,
    signing_bytes,
)
from protocol.messages import CATALOGUE
from protocol.messages.bootloader import (
    AUTOBOOT_WINDOW_US,
    WRITE_STATUS_WORD_FAILED,
    BootResult,
    BootState,
    ImageStatus,
    WriteStatus,
)
from protocol.messages.common import Running

#: Default autoboot window (µs): the protocol's window, long enough for the original host
#: tools' reset, wait 1 s + 2 s, halt (see :data:`AUTOBOOT_WINDOW_US`).
AUTOBOOT_US: Final = AUTOBOOT_WINDOW_US
#: Delay between an acknowledgement and the jump to the application (µs).
BOOT_DELAY_US: Final = 200
#: Poll period while waiting for a flash write this program did not start (µs).
BUSY_POLL_US: Final = 500

#: Upstream UART of each hand board: where the host (or the board above) talks to it.
UPSTREAM_UART: Final = {
    BoardType.PALM: "host",
    BoardType.FMCB: "pogo",
    BoardType.F2: "tendon",
    BoardType.F3: "tendon",
}

#: What a failed image check means as a command result.
_RESULT_OF_IMAGE_STATUS: Final = {
    ImageStatus.EMPTY: BootResult.BAD_IMAGE,
    ImageStatus.BAD_HEADER: BootResult.BAD_IMAGE,
    ImageStatus.TOO_LARGE: BootResult.BAD_IMAGE,
    ImageStatus.WRONG_BOARD: BootResult.WRONG_BOARD,
    ImageStatus.HASH_MISMATCH: BootResult.HASH_MISMATCH,
    ImageStatus.NOT_ACTIVATED: BootResult.NOT_ACTIVATED,
    ImageStatus.BAD_SIGNATURE: BootResult.BAD_SIGNATURE,
    ImageStatus.UNSIGNED: BootResult.BAD_SIGNATURE,
}
_ERASED_PAGE: Final = b"\xff" * PAGE_SIZE
_NO_PAGE: Final = 0xFFFFFFFF


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


def inspect_image(flash: Flash, board: BoardType | None) -> ImageCheck:
    """Check the image installed in ``flash`` for a board of type ``board``.

    In order: header page erased → empty; header does not parse or names another load
    address → bad header; another board → wrong board; payload larger than the
    application area → too large; SHA-256 of the payload pages differs → hash mismatch
    (a truncated image lands here); the node is provisioned with a key (key page) and the
    image is signed by another key → bad signature, or unsigned while the key record
    requires a signature → unsigned; activation record missing or naming another hash →
    not activated; else valid.
    """
    raw = flash.read_page(HEADER_PAGE)
    if raw == _ERASED_PAGE:
        return ImageCheck(ImageStatus.EMPTY, None, "no image: header page is erased")
    checked = check_header(raw, board)
    if isinstance(checked, ImageCheck):
        return checked
    header = checked
    payload = flash.read(page_address(PAYLOAD_FIRST_PAGE), header.payload_size)
    if hashlib.sha256(payload).digest() != header.sha256:
        return ImageCheck(ImageStatus.HASH_MISMATCH, header,
                          f"hash mismatch: payload pages do not hash to "
                          f"{header.sha256.hex()[:16]}... (truncated or corrupt)")
    refused = check_signature(header, flash)
    if refused is not None:
        return refused
    record = ActivationRecord.from_page(flash.read_page(BOOT_CONTROL_PAGE))
    if record is None or record.sha256 != header.sha256:
        return ImageCheck(ImageStatus.NOT_ACTIVATED, header,
                          f"not activated: {header.app_name} {header.version} verifies but "
                          "has no activation record")
    return ImageCheck(ImageStatus.VALID, header,
                      f"valid: {header.app_name} {header.version} ({header.payload_size} B)")


def check_header(raw: bytes, board: BoardType | None) -> ImageHeader | ImageCheck:
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
    if header.payload_size > MAX_PAYLOAD:
        return ImageCheck(ImageStatus.TOO_LARGE, header,
                          f"too large: payload {header.payload_size} B > {MAX_PAYLOAD} B")
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


def _first_bad_word(expected: bytes, actual: bytes) -> int | None:
    """Index of the first 32-bit word that differs, or None if the pages are equal."""
    for i in range(0, len(expected), 4):
        if expected[i : i + 4] != actual[i : i + 4]:
            return i // 4
    return None


class Bootloader(HandNode):
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
        self.state = BootState.AUTOBOOT_COUNTDOWN
        self._deadline_us = self.hal.clock.now_us() + self.autoboot_us
        self._timer = self.hal.clock.call_later(self.autoboot_us, self._autoboot)

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
        try:
            self.mcu.boot(check.header.app_name, check.header.version)
        except ConfigError as exc:
            self.state = BootState.NO_VALID_IMAGE
            self._fail(BootResult.BAD_IMAGE, f"boot failed: {exc}")

    def _fail(self, code: int, note: str) -> None:
        self.last_error = code
        self.note = note

    # --- flash writes, one at a time --------------------------------------------------------
    @property
    def flash_busy(self) -> bool:
        """A page write (ours, or one left over from before a reset) is in progress."""
        return self._busy or self.hal.flash.busy

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
        elif page in APP_PAGES and self.hal.flash.read_page(BOOT_CONTROL_PAGE) != _ERASED_PAGE:
            # Staging begins: forget the activation before the image changes.
            def cleared(status: int) -> None:
                if status == WriteStatus.OK:
                    self._program(page, data, reply)
                else:
                    reply(status)

            self._program(BOOT_CONTROL_PAGE, _ERASED_PAGE, cleared)
        else:
            self._program(page, data, reply)
        return DEFERRED

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
                code = _RESULT_OF_IMAGE_STATUS[check.status]
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
            self._fail(_RESULT_OF_IMAGE_STATUS[check.status], f"boot refused: {check.reason}")
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
