"""The hand's thirteen microcontrollers wired together, without physics.

Palm UART ``finger{k}`` ↔ fmcb ``pogo`` (point to point, breakable: a finger that breaks
away takes its pogo link and its power with it); each fmcb's ``tendon`` UART is the master
of a multidrop bus shared with its f2 and f3; the palm's finger power switches power the
fmcbs, each fmcb's phalange switch powers its phalanges.  The host talks to the palm's
``host`` UART (or its CAN controller).  The emulator adds the plant and the line models on
top of this topology; tests use it as it is to run real firmware end to end.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from firmware_py.boards import make_node
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.virtual_hal import VirtualHal, VirtualUart
from protocol.image import BoardType

FINGERS = 4


def _hal(mcu: Mcu) -> VirtualHal:
    hal = mcu.hal
    assert isinstance(hal, VirtualHal)
    return hal


@dataclass
class Finger:
    """One finger module: its fmcb and phalanges, and whether it is attached to the palm."""

    index: int
    fmcb: Mcu
    f2: Mcu
    f3: Mcu
    attached: bool = True


class HandRig:
    """Palm + four fingers on one scheduler, wired as on the real hand.

    ``uid_base`` numbers the nodes' unique ids; ``on_host_bytes`` (if given) receives what
    the palm sends on its host UART, with the arrival time (µs).
    """

    def __init__(self, scheduler: Scheduler | None = None, uid_base: int = 0x1000) -> None:
        self.scheduler = scheduler or Scheduler()
        self.palm = make_node(self.scheduler, BoardType.PALM, uid=uid_base)
        self.fingers: list[Finger] = []
        for k in range(FINGERS):
            uid = uid_base + 0x10 * (k + 1)
            finger = Finger(
                k,
                make_node(self.scheduler, BoardType.FMCB, uid=uid),
                make_node(self.scheduler, BoardType.F2, uid=uid + 1),
                make_node(self.scheduler, BoardType.F3, uid=uid + 2),
            )
            self.fingers.append(finger)
            self._wire_finger(finger)
        self.host_received: list[tuple[bytes, int]] = []
        self.host_uart.sink = self._host_sink
        self.on_host_bytes: Callable[[bytes, int], None] | None = None

    # --- wiring ---------------------------------------------------------------------------
    def _wire_finger(self, finger: Finger) -> None:
        palm_hal = _hal(self.palm)
        fmcb_hal = _hal(finger.fmcb)
        palm_side = palm_hal.uart(f"finger{finger.index}")
        pogo = fmcb_hal.uart("pogo")
        palm_side.sink = lambda data, t: self._pogo_down(finger, data)
        pogo.sink = lambda data, t: self._pogo_up(finger, data)
        tendon = fmcb_hal.uart("tendon")
        phalanges = [_hal(finger.f2).uart("tendon"), _hal(finger.f3).uart("tendon")]
        tendon.sink = lambda data, t: self._tendon_down(phalanges, data)
        for p in phalanges:
            p.sink = lambda data, t, p=p: self._tendon_up(tendon, phalanges, p, data)
        palm_hal.power(f"finger{finger.index}").on_change.append(
            lambda state: self._finger_power(finger, state))
        fmcb_hal.power("phalange").on_change.append(
            lambda state: self._phalange_power(finger, state))

    def _pogo_down(self, finger: Finger, data: bytes) -> None:
        if finger.attached and finger.fmcb.powered:
            _hal(finger.fmcb).uart("pogo").deliver(data)

    def _pogo_up(self, finger: Finger, data: bytes) -> None:
        if finger.attached:
            _hal(self.palm).uart(f"finger{finger.index}").deliver(data)

    @staticmethod
    def _tendon_down(phalanges: list[VirtualUart], data: bytes) -> None:
        for p in phalanges:
            p.deliver(data)

    @staticmethod
    def _tendon_up(master: VirtualUart, phalanges: list[VirtualUart], sender: VirtualUart,
                   data: bytes) -> None:
        master.deliver(data)
        for p in phalanges:  # half duplex: the other slave hears it too
            if p is not sender:
                p.deliver(data)

    def _finger_power(self, finger: Finger, state: int) -> None:
        if state and finger.attached:
            finger.fmcb.power_on()
        elif not state:
            finger.fmcb.power_off()

    def _phalange_power(self, finger: Finger, state: int) -> None:
        for node in (finger.f2, finger.f3):
            if state and finger.fmcb.powered:
                node.power_on()
            else:
                node.power_off()

    def _host_sink(self, data: bytes, t_us: int) -> None:
        self.host_received.append((data, t_us))
        if self.on_host_bytes is not None:
            self.on_host_bytes(data, t_us)

    # --- what a bench does --------------------------------------------------------------
    @property
    def host_uart(self) -> VirtualUart:
        """The palm's USB serial UART."""
        return _hal(self.palm).uart("host")

    def power_on(self) -> None:
        """Hand supply on: the palm boots (its fingers stay off until commanded)."""
        self.palm.power_on()

    def send_from_host(self, frame: bytes) -> None:
        """Bytes from the host arrive at the palm now."""
        self.host_uart.deliver(frame)

    def take_host_bytes(self) -> bytes:
        """Everything the palm sent to the host since the last call."""
        out = b"".join(d for d, _ in self.host_received)
        self.host_received.clear()
        return out

    def break_away(self, index: int) -> None:
        """Finger ``index`` leaves its pogo pins: link and power gone."""
        finger = self.fingers[index]
        finger.attached = False
        for node in (finger.f2, finger.f3, finger.fmcb):
            node.power_off()

    def reattach(self, index: int) -> None:
        """Finger ``index`` is pushed back on: it gets the palm's power state again."""
        finger = self.fingers[index]
        finger.attached = True
        if _hal(self.palm).power(f"finger{index}").state:
            finger.fmcb.power_on()

    def run_for(self, duration_us: int) -> None:
        """Advance simulation time."""
        self.scheduler.run_for(duration_us)
