"""What the fault tests ask of an emulator to see a fault's effect: a host on the hand's palm
link, whether a node answers, whether an arm servo answers a ping."""

from __future__ import annotations

from hil_emulator.emulator import Emulator
from host.errors import HostError
from host.hand import Hand
from host.hand_session import HandSession
from protocol.dynamixel import make_ping

#: One millisecond of simulated time (µs).
MS = 1_000


def host_of(emu: Emulator) -> Hand:
    """A host on ``emu``'s palm link that never retries (a lost frame is seen at once)."""
    return Hand(HandSession(emu.transport("palm"), retries=0))


def answers(node: object) -> bool:
    """Whether the host-side node (a palm, a motor, a phalange) answers ``identify``."""
    try:
        node.identify()  # type: ignore[attr-defined]
    except HostError:
        return False
    return True


def arm_ping_answered(emu: Emulator, dxl_id: int = 5) -> bool:
    """Whether servo ``dxl_id`` answers a ping on the arm bus within 2 ms (simulated)."""
    assert emu.arm is not None
    emu.arm.take_host_bytes()
    emu.arm.send_from_host(make_ping(dxl_id).encode())
    emu.step(2 * MS)
    return bytes(emu.arm.take_host_bytes()).startswith(b"\xff\xff" + bytes([dxl_id]))
