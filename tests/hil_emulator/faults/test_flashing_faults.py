"""Faults of a node's flash (``hil_emulator/faults/flashing.py``)."""

from __future__ import annotations

from tests.ground_truth import hand_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator


def test_a_flash_page_that_fails_to_write(hand: FaultyEmulator) -> None:
    flash = hand_rig_of(hand).fingers[0].f3.hal.flash
    entry = hand.faults.inject("flash_page_fail", {"node": "finger0.f3", "page": 700})
    results: list[bool] = []
    page = b"\x55" * flash.page_size
    for p in (700, 701):
        flash.write_page(p, page, results.append)
        hand.step(10 * MS)
    assert results == [False, True]
    hand.faults.clear(entry)
    flash.write_page(700, page, results.append)
    hand.step(10 * MS)
    assert results[-1] is True and "write_page" not in vars(flash)
