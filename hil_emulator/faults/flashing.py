"""Faults of flashing: a flash page that fails to write.  (A node's power cut at a chosen
point of a flash write is :class:`~hil_emulator.faults.contact.NodePowerCut` with the
``after_flash_bytes`` trigger of its schedule.)

They act through the node's :class:`~firmware_py.sim.virtual_hal.VirtualFlash`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import hil_emulator.faults.targets as targets
from hil_emulator.faults.base import Fault

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator


@dataclass
class FlashPageFail(Fault):
    """The next ``count`` page writes of node ``node`` (to ``page``, or any page when -1)
    fail: the flash reports an error and the page is left erased."""

    name = "flash_page_fail"
    entry_point = "flash"
    summary = "a flash page that fails to write"
    node: str = "finger0.fmcb"  #: palm, finger<k>.fmcb|f2|f3
    page: int = -1  #: page number, -1: any
    count: int = 1  #: failing writes
    failed: int = field(default=0, init=False, repr=False)
    _flash: Any = field(default=None, init=False, repr=False)

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        flash = targets.node(emulator, self.node).hal.flash
        self._flash = flash
        self.failed = 0
        original = type(flash).write_page

        def write_page(page: int, data: bytes, done: Callable[[bool], None]) -> None:
            if self.failed < self.count and self.page in (-1, page):
                self.failed += 1
                off = page * flash.page_size
                flash.memory[off: off + flash.page_size] = b"\xff" * flash.page_size
                flash.scheduler.call_later(flash.page_write_us, lambda: done(False))
                return
            original(flash, page, data, done)

        flash.write_page = write_page  # type: ignore[method-assign]

    def clear(self, emulator: Emulator) -> None:
        if self._flash is not None and "write_page" in vars(self._flash):
            del self._flash.write_page
