"""Bring the hand up as a host would, on the simulation clock, before anyone connects.

``hil-emulator --ready`` (and benchmarks, tests) start from a robot whose thirteen hand
microcontrollers run their applications: the palm boots (its 3 s bootloader window), the
host powers the fingers (``palm.finger_power``), each fmcb boots, the host powers the
phalanges over the tendons (``fmcb.phalange_power``) and they boot, and every fmcb's 100 Hz
autopoll of its phalanges is switched on.  The frames are the ones a host sends, on the
palm's host UART (or the loose finger's cable); their replies are dropped.  The arm is left
as it powers up: torque off, hanging, until the host enables it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

from firmware_py.mcu import Mcu
from hil_emulator.errors import EmulatorError
from protocol.messages import CATALOGUE
from protocol.messages.palm import FingerPower
from protocol.topology import ADDR_PALM, HOP_ADDRESS, Hop

#: Time a hand node needs from power-up to its application (µs): the 3 s autoboot window.
BOOT_US: Final = 3_300_000
#: Stagger between fingers when the palm switches them all on (ms).
STAGGER_MS: Final = 5


def request(name: str, **fields: Any) -> bytes:
    """A hand frame carrying request ``name`` to the palm (or a loose finger's fmcb: the
    same address)."""
    return CATALOGUE[name].request_frame(ADDR_PALM, fields)


def routed(finger: int, name: str, **fields: Any) -> bytes:
    """``palm.route`` carrying request ``name`` to finger ``finger``'s fmcb."""
    return request("palm.route", finger=finger, hop=Hop.FMCB, timeout_ms=20,
                   frame=CATALOGUE[name].request_frame(HOP_ADDRESS[Hop.FMCB], fields))


def bring_up(hand: Any | None, loose: Any | None, step: Callable[[int], None],
             autopoll: bool = True) -> None:
    """Power and boot every hand node of ``hand`` (a HandRig) or ``loose`` (a LooseFinger),
    advancing simulation time with ``step(µs)``; raise :class:`EmulatorError` if a node is
    not running its application afterwards."""
    if hand is not None:
        step(BOOT_US)
        hand.send_from_host(request("palm.finger_power", finger=0xFF, state=FingerPower.FULL,
                                    stagger_ms=STAGGER_MS))
        step(BOOT_US + 4 * STAGGER_MS * 1000)
        for finger in range(len(hand.fingers)):
            hand.send_from_host(routed(finger, "fmcb.phalange_power", on=1))
            step(30_000)
        step(BOOT_US)
        if autopoll:
            for finger in range(len(hand.fingers)):
                hand.send_from_host(routed(finger, "fmcb.autopoll", on=1))
                step(30_000)
        hand.take_host_bytes()
        _check_running(hand.mcus)
    if loose is not None:
        step(BOOT_US)
        loose.send_from_host(request("fmcb.phalange_power", on=1))
        step(BOOT_US)
        if autopoll:
            loose.send_from_host(request("fmcb.autopoll", on=1))
            step(30_000)
        loose.take_host_bytes()
        finger = loose.finger
        _check_running([finger.fmcb, finger.f2, finger.f3])


def _check_running(mcus: list[Mcu]) -> None:
    stuck = [f"board {m.identity.board} uid {m.identity.uid:#x}" for m in mcus
             if not m.powered or m.program_name in (None, "bootloader")]
    if stuck:
        raise EmulatorError(f"bring-up: not running their application: {', '.join(stuck)}")
