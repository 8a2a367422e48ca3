"""A power cut at every page write of a swap (and of the swap back), and at random points of
several in a row: after each, with nothing re-run, the node runs its previous or its new
image, both images stay whole, and a trial image never outlives its trial."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.flash_layout import page_address
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_node
from firmware_py.sim.virtual_hal import PAGE_WRITE_US, VirtualFlash, VirtualHal
from firmware_py.slot_swap import SwapRecord, read_record, secondary_check
from protocol.image import FLASH, BoardType, make_image
from protocol.messages.slots import SlotState
from tests.firmware_py.stand_ins import TinyApp

#: Long enough for any swap of the test images plus the jump (µs), far less than the window.
SETTLE_US = 400_000
#: Time after which a node without a swap to do has booted: the autoboot window (µs).
WINDOW_US = 4_600_000



def _image(version: str, pages: int) -> bytes:
    size = (pages - 1) * 256 - 11
    payload = b"".join(hashlib.sha256(version.encode() + i.to_bytes(2, "little")).digest()
                       for i in range(size // 32 + 1))[:size]
    return make_image(payload, BoardType.FMCB, version, "fmcb")


OLD = _image("1.0.0", 6)
NEW = _image("2.0.0", 11)  # larger than OLD: the swap covers OLD's erased tail as well
VERSIONS = {OLD[40:72]: "1.0.0", NEW[40:72]: "2.0.0"}


def _flash(mcu: Mcu) -> VirtualFlash:
    assert isinstance(mcu.hal, VirtualHal)
    return mcu.hal.flash


def pending_node() -> Mcu:
    """A node running OLD with NEW downloaded and a swap pending (powered off)."""
    mcu = make_node(Scheduler(), BoardType.FMCB, image=OLD, apps={"fmcb": TinyApp})
    flash = _flash(mcu)
    flash.load(page_address(FLASH.secondary_slot.start), NEW)
    record = SwapRecord(SlotState.PENDING, sha256=NEW[40:72], seq=1)
    flash.load(page_address(FLASH.swap_status_pages[0]), record.to_page())
    return mcu


def run(mcu: Mcu, us: int) -> None:
    assert isinstance(mcu.hal, VirtualHal)
    mcu.hal.scheduler.run_for(us)


def cut_at(mcu: Mcu, writes: list[int], offset_us: int,
           erased: bool = False) -> Callable[[], None]:
    """Arrange a power cut ``offset_us`` µs into each write whose 0-based number (counted
    from now) is in ``writes``; the page being written is left half programmed (the virtual
    flash's model) or, with ``erased``, erased (a cut during the erase).  Returns a function
    that removes the hook."""
    flash = _flash(mcu)
    original = flash.write_page
    count = [0]

    def write_page(page: int, data: bytes, done: Callable[[bool], None]) -> None:
        n = count[0]
        count[0] += 1
        original(page, data, done)
        if n in writes:
            def cut() -> None:
                mcu.power_off()
                if erased:
                    flash.load(page_address(page), b"\xff" * flash.page_size)

            flash.scheduler.call_later(offset_us, cut)

    flash.write_page = write_page  # type: ignore[method-assign]
    return lambda: setattr(flash, "write_page", original)


def images(mcu: Mcu) -> tuple[str, str]:
    """(primary, secondary) versions; both must be whole images."""
    flash = _flash(mcu)
    primary = flash.read(page_address(FLASH.primary_slot.start) + 40, 32)
    check = secondary_check(flash, BoardType.FMCB)
    assert check.header is not None, check.reason
    assert primary in VERSIONS, "the primary slot holds no whole image"
    return VERSIONS[primary], VERSIONS[check.header.sha256]


def running(mcu: Mcu) -> str:
    """The version the node runs; it must run an application."""
    assert mcu.powered and mcu.program_name == "fmcb", "the node runs no application"
    program: Any = mcu.program
    return ".".join(str(p) for p in program.fw_version)


def check_after(mcu: Mcu) -> str:
    """Power back on if cut, let the node settle, and check the invariants."""
    mcu.power_on()
    run(mcu, SETTLE_US)
    if not mcu.program_name == "fmcb":
        run(mcu, WINDOW_US)  # nothing to swap: it boots after its window
    version = running(mcu)
    primary, secondary = images(mcu)
    assert {primary, secondary} == {"1.0.0", "2.0.0"}
    assert primary == version
    state = read_record(_flash(mcu))[0].state
    assert state == (SlotState.TRIAL if version == "2.0.0" else SlotState.CONFIRMED)
    return version


def writes_of_one_swap(prepare: Callable[[], Mcu]) -> int:
    mcu = prepare()
    before = len(_flash(mcu).writes)
    mcu.power_on()
    run(mcu, SETTLE_US)
    assert mcu.program_name == "fmcb"
    return len(_flash(mcu).writes) - before


def on_trial() -> Mcu:
    """A node that swapped to NEW and runs it on trial, about to be reset (powered)."""
    mcu = pending_node()
    mcu.power_on()
    run(mcu, SETTLE_US)
    assert running(mcu) == "2.0.0"
    return mcu


INSTALL_WRITES = writes_of_one_swap(pending_node)


def test_the_swap_writes_what_the_design_says() -> None:
    # 11 pages in chunks of 4 (3 chunks): 3 copies of up to 4 pages each, a record after
    # each copy, the activation record and the TRIAL record; equal pages are not rewritten.
    assert 3 * 11 + 3 * 3 + 2 - 6 <= INSTALL_WRITES <= 3 * 11 + 3 * 3 + 2 + 1


@pytest.mark.parametrize("erased", [False, True], ids=["half-programmed", "erased"])
@pytest.mark.parametrize("k", range(INSTALL_WRITES))
def test_a_power_cut_at_any_page_write_of_the_swap(k: int, erased: bool) -> None:
    mcu = pending_node()
    cut_at(mcu, [k], PAGE_WRITE_US // 2, erased)
    mcu.power_on()
    run(mcu, SETTLE_US)
    assert not mcu.powered
    version = check_after(mcu)
    # The trial is spent at the next reset: never an unconfirmed image after it.
    mcu.reset()
    run(mcu, SETTLE_US)
    if mcu.program_name != "fmcb":
        run(mcu, WINDOW_US)
    assert running(mcu) == "1.0.0" and images(mcu) == ("1.0.0", "2.0.0")
    assert version in ("1.0.0", "2.0.0")


@pytest.mark.parametrize("erased", [False, True], ids=["half-programmed", "erased"])
@pytest.mark.parametrize("k", range(INSTALL_WRITES))
def test_a_power_cut_at_any_page_write_of_the_swap_back(k: int, erased: bool) -> None:
    mcu = on_trial()
    cut_at(mcu, [k], PAGE_WRITE_US // 2, erased)
    mcu.reset()  # the trial is over, unconfirmed
    run(mcu, SETTLE_US)
    assert not mcu.powered
    assert check_after(mcu) == "1.0.0"
    assert images(mcu) == ("1.0.0", "2.0.0")


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(0, INSTALL_WRITES), min_size=1, max_size=4),
       offset=st.integers(1, PAGE_WRITE_US - 1), revert=st.booleans(), erased=st.booleans())
def test_several_power_cuts_at_random_instants(cuts: list[int], offset: int, revert: bool,
                                               erased: bool) -> None:
    """Cuts one after the other, each at a random write after the restart before it."""
    mcu = on_trial() if revert else pending_node()
    for k in cuts:
        unhook = cut_at(mcu, [k], offset, erased)
        if mcu.powered:
            mcu.reset()
        else:
            mcu.power_on()
        run(mcu, SETTLE_US)
        unhook()
    version = check_after(mcu)
    if revert:
        assert version == "1.0.0"
