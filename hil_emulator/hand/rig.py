"""The hand's thirteen microcontrollers wired together, without physics.

Palm UART ``finger{k}`` ↔ fmcb ``pogo`` (point to point, breakable: a finger that breaks
away takes its pogo link and its power with it); each fmcb's ``tendon`` UART is the master
of a multidrop bus shared with its f2 and f3; the palm's finger power switches power the
fmcbs, each fmcb's phalange switch powers its phalanges.  The host talks to the palm's
``host`` UART (or its CAN controller).  The emulator adds the plant and the line models on
top of this topology; tests use it as it is to run real firmware end to end.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from firmware_py.mcu import Mcu
from firmware_py.phalange import HOLD_UP_US
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_node
from firmware_py.sim.virtual_hal import VirtualHal
from firmware_py.sim.virtual_ports import VirtualCan, VirtualUart
from hil_emulator.lines.rs485_bus import Rs485Bus
from hil_emulator.ports.host_side import HostSide
from protocol.image import BoardType
from protocol.topology import FINGERS, TENDON_BAUD, TENDON_MANCHESTER

#: Supply current of one running phalange board through the tendons (mA): MCU, IMU and
#: taxel LEDs; the fmcb's phalange switch reports the sum (its breaker trips at 200 mA).
PHALANGE_LOAD_MA = 35
#: Contact bounces when a finger is pushed back onto its pogo pins, and their length (µs).
POGO_BOUNCES = 3
POGO_BOUNCE_US = (200, 1_500)


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
    #: False while the pogo pins carry power but no data (a partial contact).
    data_contact: bool = True
    #: The tendon line (with the emulator's line model), or None when wired ideally.
    tendon_bus: Rs485Bus | None = None


class HandRig(HostSide):
    """Palm + four fingers on one scheduler, wired as on the real hand.

    ``uid_base`` numbers the nodes' unique ids; ``on_host_bytes`` (if given) receives what
    the palm sends on its host UART, with the arrival time (µs); without it the bytes
    collect in ``host_received``.  With ``line_model`` each finger's tendon bus is an
    :class:`~hil_emulator.lines.rs485_bus.Rs485Bus` carrying Manchester chips (seeded from
    ``seed``), and ``record=False`` stops the UARTs from keeping what they sent (long runs).
    """

    def __init__(self, scheduler: Scheduler | None = None, uid_base: int = 0x1000, *,
                 line_model: bool = False, seed: int = 0, record: bool = True) -> None:
        super().__init__(scheduler or Scheduler())
        self.line_model = line_model
        self._rng = np.random.default_rng(seed)
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
        if not record:
            for mcu in self.mcus:
                hal = _hal(mcu)
                for uart in hal.uarts.values():
                    uart.keep_sent = False
            _hal(self.palm).can().keep_sent = False
        self.host_uart.sink = self._to_host

    # --- wiring ---------------------------------------------------------------------------
    def _wire_finger(self, finger: Finger) -> None:
        palm_hal = _hal(self.palm)
        fmcb_hal = _hal(finger.fmcb)
        palm_side = palm_hal.uart(f"finger{finger.index}")
        pogo = fmcb_hal.uart("pogo")
        palm_side.sink = lambda data, t: self._pogo_down(finger, data)
        pogo.sink = lambda data, t: self._pogo_up(finger, data)
        wire_tendon_bus(finger, self.line_model,
                        int(self._rng.integers(2**31)) if self.line_model else 0)
        palm_hal.power(f"finger{finger.index}").on_change.append(
            lambda state: self._finger_power(finger, state))
        wire_phalange_power(finger)

    def _pogo_down(self, finger: Finger, data: bytes) -> None:
        if finger.attached and finger.data_contact and finger.fmcb.powered:
            _hal(finger.fmcb).uart("pogo").deliver(data)

    def _pogo_up(self, finger: Finger, data: bytes) -> None:
        if finger.attached and finger.data_contact:
            _hal(self.palm).uart(f"finger{finger.index}").deliver(data)

    def _finger_power(self, finger: Finger, state: int) -> None:
        if state and finger.attached:
            finger.fmcb.power_on()
        elif not state:
            finger.fmcb.power_off()

    # --- what a bench does --------------------------------------------------------------
    @property
    def mcus(self) -> list[Mcu]:
        """All thirteen microcontrollers: palm, then each finger's fmcb, f2, f3."""
        return [self.palm] + [m for f in self.fingers for m in (f.fmcb, f.f2, f.f3)]

    @property
    def host_uart(self) -> VirtualUart:
        """The palm's USB serial UART."""
        return _hal(self.palm).uart("host")

    @property
    def palm_can(self) -> VirtualCan:
        """The palm's CAN controller (the hand's second host link)."""
        return _hal(self.palm).can()

    def power_on(self) -> None:
        """Hand supply on: the palm boots (its fingers stay off until commanded)."""
        self.palm.power_on()

    def send_from_host(self, frame: bytes) -> None:
        """Bytes from the host arrive at the palm now."""
        self.host_uart.deliver(frame)

    def break_away(self, index: int) -> None:
        """Finger ``index`` leaves its pogo pins: link and power gone."""
        finger = self.fingers[index]
        finger.attached = False
        for node in (finger.f2, finger.f3, finger.fmcb):
            node.power_off()

    def reattach(self, index: int, bounce: bool = False) -> None:
        """Finger ``index`` is pushed back on: it gets the palm's power state again.

        With ``bounce`` the pogo contacts chatter first (:data:`POGO_BOUNCES` short
        contacts of random length in :data:`POGO_BOUNCE_US`, each carrying a burst of line
        noise to the palm's UART) and settle only after them."""
        finger = self.fingers[index]
        if not bounce:
            self.make_contact(finger)
            return
        t = self.chatter(finger, POGO_BOUNCES, POGO_BOUNCE_US, self._rng)
        self.scheduler.call_later(t, lambda: self.make_contact(finger))

    def chatter(self, finger: Finger, contacts: int, length_us: tuple[int, int],
                rng: np.random.Generator) -> int:
        """Schedule ``contacts`` short contacts of ``finger``'s pogo pins from now, each of a
        random length in ``length_us`` (µs) carrying a burst of line noise to the palm's UART
        and followed by as long without contact; returns when the last ends (µs from now),
        the pins open."""
        t = 0
        for _ in range(contacts):
            length = int(rng.integers(*length_us))
            noise = rng.integers(0, 256, size=int(rng.integers(1, 8)), dtype=np.uint8).tobytes()
            self.scheduler.call_later(t, functools.partial(self._bounce_contact, finger, noise))
            self.scheduler.call_later(t + length, lambda: self.lose_contact(finger))
            t += 2 * length
        return t

    def make_contact(self, finger: Finger) -> None:
        """The pogo pins of ``finger`` touch: it gets the palm's power state."""
        finger.attached = True
        if _hal(self.palm).power(f"finger{finger.index}").state:
            finger.fmcb.power_on()

    def _bounce_contact(self, finger: Finger, noise: bytes) -> None:
        self.make_contact(finger)
        _hal(self.palm).uart(f"finger{finger.index}").deliver(noise)

    def lose_contact(self, finger: Finger) -> None:
        """The pogo pins of ``finger`` open: link and power gone."""
        finger.attached = False
        for node in (finger.f2, finger.f3, finger.fmcb):
            node.power_off()

    def tendon_glitch(self, index: int, duration_us: int) -> None:
        """Finger ``index``'s tendon contact opens for ``duration_us``: the bus carries
        nothing meanwhile and the phalanges ride through on their hold-up or brown out."""
        tendon_glitch(self.fingers[index], self.scheduler, duration_us)



def wire_tendon_bus(finger: Finger, line_model: bool, seed: int = 0) -> None:
    """Wire ``finger``'s fmcb ``tendon`` UART and its phalanges' as one half-duplex bus.

    With ``line_model`` the bus is an :class:`Rs485Bus` carrying Manchester chips (wire time,
    collisions, chip errors); without it, frames go straight to the other nodes."""
    master = _hal(finger.fmcb).uart("tendon")
    phalanges = [_hal(finger.f2).uart("tendon"), _hal(finger.f3).uart("tendon")]
    if line_model:
        bus = Rs485Bus(master.scheduler, baud=TENDON_BAUD, seed=seed,
                       line_code="manchester" if TENDON_MANCHESTER else "nrz")
        bus.attach(master, "fmcb")
        bus.attach(phalanges[0], "f2")
        bus.attach(phalanges[1], "f3")
        finger.tendon_bus = bus
        return

    def down(data: bytes, t_us: int) -> None:
        for p in phalanges:
            p.deliver(data)

    def up(sender: VirtualUart, data: bytes) -> None:
        master.deliver(data)
        for p in phalanges:  # half duplex: the other slave hears it too
            if p is not sender:
                p.deliver(data)

    master.sink = down
    for p in phalanges:
        p.sink = lambda data, t, p=p: up(p, data)


def tendon_glitch(finger: Finger, scheduler: Scheduler, duration_us: int) -> None:
    """The tendon contact of ``finger`` opens for ``duration_us`` µs starting now."""
    if duration_us <= 0:
        raise ValueError("a glitch lasts a positive time")
    bus = finger.tendon_bus
    if bus is not None:
        bus.set_line_cut(True)
        scheduler.call_later(duration_us, lambda: bus.set_line_cut(False))

    if duration_us <= HOLD_UP_US:
        return  # the phalanges ride through on their bulk capacitance

    def brown_out() -> None:
        for node in (finger.f2, finger.f3):
            node.power_off()

    def restored() -> None:
        if finger.fmcb.powered and _hal(finger.fmcb).power("phalange").state:
            for node in (finger.f2, finger.f3):
                node.power_on()

    scheduler.call_later(HOLD_UP_US, brown_out)
    scheduler.call_later(duration_us, restored)


def wire_phalange_power(finger: Finger) -> None:
    """The fmcb's ``phalange`` switch powers f2 and f3 (through the tendons)."""

    switch = _hal(finger.fmcb).power("phalange")

    def switched(state: int) -> None:
        for node in (finger.f2, finger.f3):
            if state and finger.fmcb.powered:
                node.power_on()
            else:
                node.power_off()
        switch.set_load_ma(PHALANGE_LOAD_MA * sum(n.powered for n in (finger.f2, finger.f3)))

    switch.on_change.append(switched)


class LooseFinger(HostSide):
    """One finger module on a bench, on the original's 'loose finger' cable.

    The cable carries the fmcb's pogo bus (2 Mbaud) to the host and its supply; the tendon
    bus to f2/f3 is wired as on the hand (:func:`wire_tendon_bus`).  What the fmcb sends on
    its pogo UART reaches ``on_host_bytes`` (or collects in ``host_received``).
    """

    def __init__(self, scheduler: Scheduler | None = None, uid: int = 0x2010, *,
                 line_model: bool = False, seed: int = 0, record: bool = True) -> None:
        super().__init__(scheduler or Scheduler())
        self.finger = Finger(0, make_node(self.scheduler, BoardType.FMCB, uid=uid),
                             make_node(self.scheduler, BoardType.F2, uid=uid + 1),
                             make_node(self.scheduler, BoardType.F3, uid=uid + 2))
        wire_tendon_bus(self.finger, line_model, seed)
        wire_phalange_power(self.finger)
        if not record:
            for mcu in (self.finger.fmcb, self.finger.f2, self.finger.f3):
                for uart in _hal(mcu).uarts.values():
                    uart.keep_sent = False
        self.host_uart.sink = self._to_host

    @property
    def host_uart(self) -> VirtualUart:
        """The fmcb's pogo UART, which the cable brings to the host."""
        return _hal(self.finger.fmcb).uart("pogo")

    def power_on(self) -> None:
        """Cable supply on: the fmcb's bootloader starts its autoboot window."""
        self.finger.fmcb.power_on()

    def send_from_host(self, data: bytes) -> None:
        """Bytes from the host arrive at the fmcb now."""
        self.host_uart.deliver(data)

