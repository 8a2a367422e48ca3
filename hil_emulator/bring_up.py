"""Bring the hand up as a host would, on the simulation clock, before anyone connects.

``hil-emulator --ready`` (and benchmarks, tests) start from a robot whose thirteen hand
microcontrollers run their applications.  The host library does it, through the emulator's
in-process transport (:class:`~hil_emulator.inprocess.EmulatorTransport`): a
:class:`~host.hand.Hand` on the palm's link waits out the palm's bootloader window (4.5 s),
powers the fingers (``palm.finger_power``), waits for each fmcb to boot, powers the
phalanges over the tendons (``fmcb.phalange_power``) and, after their boot, switches on
every fmcb's 100 Hz autopoll of its phalanges; a :class:`~host.hand_session.HandSession` on
a loose finger's cable does the same for its one module.  Every reply is checked (route
statuses), then the emulator checks that each node runs its application.  The
arm is left as it powers up: torque off, hanging, until the host enables it.

The requests go without the ``txn`` envelope (``txn=False``) and each starts a fixed slot
of simulation time, so the frames and their times are those of the original hand's host
and a recorded run (``tools/traffic_record.py``) does not depend on the envelope's format.
Bytes a listener already had on the link (a recorder) keep reaching it (``tee``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Final

from firmware_py.mcu import Mcu
from hil_emulator.errors import EmulatorError
from hil_emulator.inprocess import EmulatorTransport
from host.errors import HostError
from host.hand import Hand, Node
from host.hand_session import LINK_NODE, HandSession, Timeouts
from protocol.messages.bootloader import AUTOBOOT_WINDOW_US
from protocol.messages.palm import ALL_FINGERS, FingerPower
from protocol.topology import FINGERS

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

#: Time a hand node needs from power-up to its application (µs): the autoboot window and
#: 0.3 s for the application to start.
BOOT_US: Final = AUTOBOOT_WINDOW_US + 300_000
#: Stagger between fingers when the palm switches them all on (ms).
STAGGER_MS: Final = 5
#: How long the palm waits for an fmcb's reply to a routed bring-up request (ms).
ROUTE_MS: Final = 20
#: Simulation time each routed request is given before the next is sent (µs).
ROUTED_SLOT_US: Final = 30_000


def bring_up(emulator: Emulator, autopoll: bool = True) -> None:
    """Power and boot every hand node of ``emulator`` (its hand, or its loose finger) with
    the host library; raise :class:`EmulatorError` if a request fails or a node is not
    running its application afterwards."""
    try:
        if emulator.hand is not None:
            with _session(emulator, "palm") as session:
                _bring_up_hand(emulator, Hand(session), autopoll)
            _check_running(emulator.hand.mcus)
        if emulator.loose is not None:
            with _session(emulator, "finger0") as session:
                fmcb = Node(session, LINK_NODE, "fmcb")
                _bring_up_finger(emulator, fmcb, BOOT_US, autopoll)
            finger = emulator.loose.finger
            _check_running([finger.fmcb, finger.f2, finger.f3])
    except HostError as exc:
        raise EmulatorError(f"bring-up: {exc}") from exc


def _session(emulator: Emulator, link: str) -> HandSession:
    transport = EmulatorTransport(emulator, link, tee=True)
    return HandSession(transport, link="palm" if link == "palm" else "finger",
                       timeouts=Timeouts(fmcb_ms=ROUTE_MS), retries=0)


def _in_slot(emulator: Emulator, slot_us: int, node: Node, name: str,
             fields: dict[str, Any]) -> dict[str, Any]:
    """Request ``name`` of ``node`` un-enveloped, take its reply, and let the rest of
    ``slot_us`` (µs from the moment it was sent) pass."""
    sent_us = emulator.scheduler.now_us()
    reply = node.request(name, fields, txn=False)
    emulator.step(max(0, sent_us + slot_us - emulator.scheduler.now_us()))
    node.session.pump()
    return reply


def _bring_up_hand(emulator: Emulator, hand: Hand, autopoll: bool) -> None:
    emulator.step(BOOT_US)
    # The reply shows the first finger on; the others follow STAGGER_MS apart.
    _in_slot(emulator, BOOT_US + FINGERS * STAGGER_MS * 1000, hand.palm, "palm.finger_power",
             {"finger": ALL_FINGERS, "state": FingerPower.FULL, "stagger_ms": STAGGER_MS})
    for finger in hand.fingers:
        _in_slot(emulator, ROUTED_SLOT_US, finger.motor, "fmcb.phalange_power", {"on": 1})
    emulator.step(BOOT_US)
    if autopoll:
        for finger in hand.fingers:
            _in_slot(emulator, ROUTED_SLOT_US, finger.motor, "fmcb.autopoll", {"on": 1})


def _bring_up_finger(emulator: Emulator, fmcb: Node, boot_us: int, autopoll: bool) -> None:
    emulator.step(boot_us)
    _in_slot(emulator, boot_us, fmcb, "fmcb.phalange_power", {"on": 1})
    if autopoll:
        _in_slot(emulator, ROUTED_SLOT_US, fmcb, "fmcb.autopoll", {"on": 1})


def _check_running(mcus: list[Mcu]) -> None:
    stuck = [f"board {m.identity.board} uid {m.identity.uid:#x}" for m in mcus
             if not m.powered or m.program_name in (None, "bootloader")]
    if stuck:
        raise EmulatorError(f"bring-up: not running their application: {', '.join(stuck)}")
