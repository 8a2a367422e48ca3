"""A stateful property test of the bootloader: random command sequences, resets and power cuts.

Invariants, checked after every step:

* pages 0–31 (bootloader and identity) are byte-identical to their factory content;
* a node that runs its application runs an image that verifies, checked here independently
  of the bootloader: header valid for the board, payload hash ok, activation record matches;
* after a power cycle and the autoboot window, the node runs its application exactly when
  the installed image verifies (otherwise it stays in its bootloader).
"""

from __future__ import annotations

import hashlib
from typing import Any

from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from firmware_py.boot_program import AUTOBOOT_US
from firmware_py.flash_layout import BOOT_CONTROL_PAGE, HEADER_PAGE, ActivationRecord, page_address
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import install_image, make_node
from firmware_py.sim.virtual_hal import VirtualFlash, VirtualHal
from protocol.errors import ImageError
from protocol.image import BoardType, make_image, parse_header, split_pages
from protocol.messages import CATALOGUE
from protocol.stream import decode_all
from tests.firmware_py.stand_ins import TinyApp

BOARD = BoardType.FMCB
ADDRESS = 10
OLD = make_image(b"old firmware " * 100, BOARD, "1.0.0", "fmcb")
NEW = make_image(bytes(range(256)) * 6 + b"new", BOARD, "2.0.0", "fmcb")
NEW_PAGES = split_pages(NEW)
NEW_SHA = NEW[40:72]
PROTECTED_BYTES = 32 * 256



def image_verifies(flash: VirtualFlash) -> bool:
    """The bootability rule, re-derived from the flash layout (not from the bootloader)."""
    try:
        header = parse_header(flash.read_page(HEADER_PAGE), expected_board=BOARD)
    except ImageError:
        return False
    if header.load_address != page_address(HEADER_PAGE):
        return False
    payload = flash.read(page_address(HEADER_PAGE + 1), header.payload_size)
    if hashlib.sha256(payload).digest() != header.sha256:
        return False
    record = ActivationRecord.from_page(flash.read_page(BOOT_CONTROL_PAGE))
    return record is not None and record.sha256 == header.sha256


class BootloaderMachine(RuleBasedStateMachine):
    """Drives one fmcb node with random bootloader traffic, resets and power cuts."""

    mcu: Mcu
    hal: VirtualHal
    flash: VirtualFlash
    factory: bytes

    @initialize(start=st.sampled_from(["activated", "empty", "not_activated"]))
    def make(self, start: str) -> None:
        self.mcu = make_node(Scheduler(), BOARD, installed=False, apps={"fmcb": TinyApp})
        assert isinstance(self.mcu.hal, VirtualHal)
        self.hal = self.mcu.hal
        assert isinstance(self.hal.flash, VirtualFlash)
        self.flash = self.hal.flash
        if start != "empty":
            install_image(self.hal, OLD, activate=start == "activated")
        self.factory = bytes(self.flash.memory[:PROTECTED_BYTES])
        self.mcu.power_on()

    # --- helpers ------------------------------------------------------------------------------
    def send(self, name: str, run_us: int = 10_000, **fields: Any) -> list[dict[str, Any]]:
        msg = CATALOGUE[name]
        uart = self.hal.uart("pogo")
        uart.take_sent()
        uart.deliver(msg.request_frame(ADDRESS, fields))
        self.hal.scheduler.run_for(run_us)
        frames = decode_all(b"".join(uart.take_sent()))
        return [msg.parse_reply(f.payload) for f in frames if f.type == msg.type_id]

    # --- rules --------------------------------------------------------------------------------
    @rule(index=st.integers(0, len(NEW_PAGES) - 1))
    def write_new_page(self, index: int) -> None:
        self.send("bl.write_page", page=HEADER_PAGE + index, data=NEW_PAGES[index])

    @rule()
    def write_whole_new_image(self) -> None:
        for i, data in enumerate(NEW_PAGES):
            self.send("bl.write_page", page=HEADER_PAGE + i, data=data)

    @rule(page=st.one_of(st.integers(0, 1023), st.sampled_from([31, 32, 33, BOOT_CONTROL_PAGE])),
          data=st.binary(min_size=256, max_size=256))
    def write_random_page(self, page: int, data: bytes) -> None:
        in_bootloader = self.mcu.in_bootloader
        got = self.send("bl.write_page", page=page, data=data)
        if in_bootloader and page < 32:
            assert got == [{"page": page, "status": 1}]
        if in_bootloader and page == BOOT_CONTROL_PAGE:
            assert got == [{"page": page, "status": 2}]

    @rule(byte=st.integers(0, 255))
    def write_corrupt_header(self, byte: int) -> None:
        header = bytearray(NEW_PAGES[0])
        header[byte] ^= 0x40
        self.send("bl.write_page", page=HEADER_PAGE, data=bytes(header))

    @rule(right=st.booleans(), other=st.binary(min_size=32, max_size=32))
    def activate(self, right: bool, other: bytes) -> None:
        in_bootloader = self.mcu.in_bootloader
        got = self.send("bl.activate", sha256=NEW_SHA if right else other)
        if in_bootloader and got and got[0]["status"] == 0:
            assert image_verifies(self.flash)

    @rule()
    def boot(self) -> None:
        self.send("bl.boot")

    @rule()
    def halt(self) -> None:
        self.send("bl.halt", run_us=1_000)

    @rule()
    def reset(self) -> None:
        self.mcu.reset()
        self.hal.scheduler.run_for(1_000)

    @rule(page=st.integers(32, 1023), delay=st.integers(0, 5_000))
    def power_cut_mid_write(self, page: int, delay: int) -> None:
        self.send("bl.write_page", run_us=delay, page=page, data=b"\x5a" * 256)
        self.mcu.power_off()
        self.mcu.power_on()

    @rule(us=st.integers(0, 4_000_000))
    def run_time(self, us: int) -> None:
        self.hal.scheduler.run_for(us)

    @rule()
    def power_cycle_and_wait(self) -> None:
        self.mcu.power_off()
        self.mcu.power_on()
        self.hal.scheduler.run_for(AUTOBOOT_US + 1_000)
        assert (self.mcu.program_name == "fmcb") == image_verifies(self.flash)

    # --- invariants ---------------------------------------------------------------------------
    @invariant()
    def bootloader_and_identity_untouched(self) -> None:
        assert bytes(self.flash.memory[:PROTECTED_BYTES]) == self.factory

    @invariant()
    def runs_only_verified_images(self) -> None:
        assert self.mcu.program_name in ("bootloader", "fmcb")
        if self.mcu.program_name == "fmcb":
            assert image_verifies(self.flash)


BootloaderMachine.TestCase.settings = settings(
    max_examples=30, stateful_step_count=25, deadline=None)
TestBootloaderMachine = BootloaderMachine.TestCase
