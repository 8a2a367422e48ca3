"""``Hand.bring_up`` when boards are slow or stuck: a robot whose clock runs slower than the
link's (the emulator on a busy machine) is waited for by the boards' own clocks, and a board
that stays in its bootloader is asked why.  In process, on the simulation clock; the link's
clock is made to run faster than the robot's by a transport that scales it."""

from __future__ import annotations

from firmware_py.flash_layout import BOOT_CONTROL_PAGE, PAGE_SIZE, page_address
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport
from host.hand.bring_up import BOOT_TIMEOUT_S, BOOT_WAIT_LIMIT
from host.hand.facade import Hand
from host.hand.session import HandSession, Target
from host.transports.base import Transport
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from tests.host.slow_link import FastLinkClock

#: Simulation time for the palm to leave its bootloader after power-on (µs).
PALM_BOOT_US = AUTOBOOT_WINDOW_US + 500_000
AUTOBOOT_S = AUTOBOOT_WINDOW_US / 1e6


def _hand(factor: float = 1.0) -> tuple[Emulator, Hand]:
    emulator = Emulator("hand", physics=False, can="none")
    emulator.step(PALM_BOOT_US)
    link: Transport = EmulatorTransport(emulator, "palm")
    if factor != 1.0:
        link = FastLinkClock(link, factor)
    return emulator, Hand(HandSession(link))


def test_a_robot_slower_than_the_link_is_waited_for_by_its_boards_own_clocks() -> None:
    # At half speed a board's 4.5 s autoboot window lasts 9 s on the link's clock, past
    # the default timeout (8 s) a board used to be given up after ("flash it").
    _emulator, hand = _hand(factor=2.0)
    assert 2 * AUTOBOOT_S > BOOT_TIMEOUT_S
    [finger] = hand.bring_up(1)
    assert finger.up, [n.problem for n in finger.nodes]
    fmcb, f2, f3 = finger.nodes
    assert fmcb.after_s is not None and fmcb.after_s >= 2 * AUTOBOOT_S
    assert f2.after_s is not None and f2.after_s - fmcb.after_s >= 2 * AUTOBOOT_S


def test_a_robot_far_slower_than_the_link_is_reported_as_slow_not_as_unflashed() -> None:
    lines: list[str] = []
    _emulator, hand = _hand(factor=4.0)
    [finger] = hand.bring_up(1, timeout=2.0, on_progress=lines.append)
    fmcb = finger.nodes[0]
    assert not fmcb.up and fmcb.problem is not None
    # Given up after BOOT_WAIT_LIMIT x timeout on the link's clock: 1.5 s of the robot's.
    assert "1.5 s after its power-up by its own clock" in fmcb.problem
    assert f"when {BOOT_WAIT_LIMIT * 2.0:.1f} s had passed on this link" in fmcb.problem
    assert "runs slower than the link's clock" in fmcb.problem
    assert "flash" not in fmcb.problem
    assert f"finger 1 fmcb: NOT UP: {fmcb.problem}" in lines


def test_a_phalange_without_a_bootable_image_says_so_from_its_bootloader() -> None:
    emulator, hand = _hand()
    assert emulator.hand is not None
    f3 = emulator.hand.fingers[1].f3
    assert isinstance(f3.hal, VirtualHal)
    f3.hal.flash.load(page_address(BOOT_CONTROL_PAGE), b"\xff" * PAGE_SIZE)  # not activated
    start = hand.session.now()
    [finger] = hand.bring_up(1)
    _fmcb, f2, f3_up = finger.nodes
    assert f2.up and not f3_up.up and f3_up.running == "bootloader"
    assert f3_up.problem is not None
    assert "stayed in its bootloader after its 4.5 s autoboot window: no bootable image" \
        in f3_up.problem
    assert "flash it: flash-all-fingers" in f3_up.problem
    # Given up once its own clock says it has been powered for the timeout, not later.
    assert hand.session.now() - start < AUTOBOOT_S + 2 * BOOT_TIMEOUT_S


def test_a_halted_bootloader_is_named_with_the_way_out() -> None:
    _emulator, hand = _hand()
    hand.power(1, "full")
    hand.session.sleep(AUTOBOOT_S + 0.5)
    hand.fingers[1].motor.request("fmcb.phalange_power", {"on": 1})
    hand.session.request("bl.halt", to=Target(1, 1))  # a flashing tool stopped f2's autoboot
    [finger] = hand.bring_up(1)
    f2 = finger.nodes[1]
    assert not f2.up and f2.problem is not None
    assert "its bootloader was halted" in f2.problem
    assert "switch the finger off and run `handctl up` again" in f2.problem
    assert finger.nodes[2].up  # f3 booted as usual
