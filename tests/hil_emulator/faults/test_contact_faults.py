"""Faults of a finger's contacts and power (``hil_emulator/faults/contact.py``): each effect
observable, and gone once cleared."""

from __future__ import annotations

from hil_emulator.inprocess import BOOT_US
from tests.ground_truth import hand_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, answers, host_of


def test_break_away_and_its_clear_a_cold_booting_reattach(hand: FaultyEmulator) -> None:
    finger = hand_rig_of(hand).fingers[3]
    boots = finger.fmcb.boots
    entry = hand.faults.inject("break_away", {"finger": 3})
    assert not finger.attached and not finger.fmcb.powered
    hand.faults.clear(entry)
    hand.step(BOOT_US)
    assert finger.attached and finger.fmcb.program_name == "fmcb"
    assert finger.fmcb.boots == boots + 1


def test_reattach_and_pogo_chatter_power_cycle_the_fmcb(hand: FaultyEmulator) -> None:
    finger = hand_rig_of(hand).fingers[1]
    hand.break_away(1)
    hand.faults.inject("reattach", {"finger": 1, "bounce": False})
    assert finger.attached and finger.fmcb.in_bootloader
    hand.step(BOOT_US)
    assert finger.fmcb.program_name == "fmcb"
    hand.faults.inject("pogo_chatter", {"finger": 1, "contacts": 4})
    assert not finger.fmcb.powered
    hand.step(50 * MS)
    assert finger.attached and finger.fmcb.in_bootloader


def test_partial_contact_powers_the_finger_but_carries_no_data(hand: FaultyEmulator) -> None:
    host = host_of(hand)
    finger = hand_rig_of(hand).fingers[0]
    entry = hand.faults.inject("partial_contact", {"finger": 0})
    assert not answers(host.fingers[0].motor)
    assert finger.fmcb.powered and finger.fmcb.program_name == "fmcb"
    hand.faults.clear(entry)
    assert answers(host.fingers[0].motor)


def test_a_shorted_tendon_trips_the_phalange_breaker_until_cleared(hand: FaultyEmulator) -> None:
    host = host_of(hand)
    finger = hand_rig_of(hand).fingers[2]
    entry = hand.faults.inject("shorted_tendon", {"finger": 2})
    hand.step(200 * MS)
    assert finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]
    assert not finger.f2.powered
    host.fingers[2].motor.request("fmcb.phalange_power", {"on": 1})
    hand.step(200 * MS)
    assert finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]  # trips again
    hand.faults.clear(entry)
    host.fingers[2].motor.request("fmcb.phalange_power", {"on": 1})
    hand.step(200 * MS)
    assert not finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]
    assert finger.f2.powered


def test_node_power_cut_triggered_in_the_middle_of_a_flash_write(hand: FaultyEmulator) -> None:
    from hil_emulator.faults import Schedule

    fmcb = hand_rig_of(hand).fingers[1].fmcb
    flash = fmcb.hal.flash
    hand.faults.inject("node_power_cut", {"node": "finger1.fmcb"},
                       schedule=Schedule(after_flash_bytes=2 * flash.page_size,
                                         flash_node="finger1.fmcb"))
    page = bytes(range(256)) * (flash.page_size // 256)
    results: list[bool] = []
    flash.write_page(600, page, results.append)
    hand.step(10 * MS)
    assert fmcb.powered and results == [True]
    flash.write_page(601, page, results.append)
    hand.step(10 * MS)
    assert not fmcb.powered and results == [True]  # cut before the write finished
    half = flash.page_size // 2
    written = flash.read(flash.base_address + 601 * flash.page_size, flash.page_size)
    assert written[:half] == page[:half] and written[half:] == b"\xff" * half
    assert [e.action for e in hand.faults.timeline] == ["apply"]
