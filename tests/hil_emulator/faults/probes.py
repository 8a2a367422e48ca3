"""What the fault tests ask of an emulator to see a fault's effect: a host on the hand's palm
link, whether a node answers, whether an arm servo answers a ping."""

from __future__ import annotations

from typing import Any

from hil_emulator.emulator import Emulator
from hil_emulator.faults import FaultInjector
from hil_emulator.faults.control import ControlChannel
from hil_emulator.inprocess import EmulatorTransport
from host.errors import HostError
from host.hand.facade import Hand
from host.hand.session import HandSession
from protocol.dynamixel import make_ping

#: One millisecond of simulated time (µs).
MS = 1_000


class FaultyEmulator(Emulator):
    """An emulator and the fault injector that whoever runs a plan owns (here: the test)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.faults = FaultInjector(self)

    def open_control(self, path: str) -> str:
        """Serve the control channel at ``path`` on this emulator's injector."""
        self.add_port(ControlChannel(self, path, self.faults))
        return path


def host_of(emu: Emulator) -> Hand:
    """A host on ``emu``'s palm link that never retries (a lost frame is seen at once)."""
    return Hand(HandSession(EmulatorTransport(emu, "palm"), retries=0))


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
