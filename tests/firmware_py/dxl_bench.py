"""Shared by the arm-node tests: one Dynamixel transaction against a node's virtual bus."""

from __future__ import annotations

from firmware_py.scheduler import Scheduler
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.dynamixel import DynamixelStreamDecoder, StatusPacket


def transact(sched: Scheduler, hal: VirtualHal, raw: bytes, run_us: int = 3_000
             ) -> list[StatusPacket]:
    """Deliver ``raw`` on the node's bus, run ``run_us`` µs, and decode the status packets
    the node sent."""
    bus = hal.uart("bus")
    bus.take_sent()
    bus.deliver(raw)
    sched.run_for(run_us)
    out = []
    for d in DynamixelStreamDecoder("status").feed(b"".join(bus.take_sent())):
        assert isinstance(d.packet, StatusPacket)
        out.append(d.packet)
    return out
