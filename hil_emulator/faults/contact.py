"""Faults of power and contact: pogo pins, tendon supply, a node's supply.

They act through :class:`~hil_emulator.emulator.Emulator` (``break_away``, ``reattach``), the
hand rig's contacts (:meth:`~hil_emulator.hand.rig.HandRig.chatter`, ``Finger.data_contact``),
the fmcb's phalange power switch (its load) and each node's :class:`~firmware_py.mcu.Mcu`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import hil_emulator.faults.targets as targets
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.faults.base import Fault

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator
    from hil_emulator.hand.rig import HandRig


@dataclass
class BreakAway(Fault):
    """Finger ``finger`` leaves its pogo pins (overload): no link, no power, motors coast.
    Cleared, it is pushed back on (with contact ``bounce``) and cold boots."""

    name = "break_away"
    entry_point = "node power"
    summary = "a finger pops off its pogo pins; cleared: pushed back on, cold boot"
    finger: int = 0  #: finger module 0..3
    bounce: bool = True  #: contact bounce when it is pushed back on

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        emulator.break_away(self.finger)

    def clear(self, emulator: Emulator) -> None:
        emulator.reattach(self.finger, bounce=self.bounce)


@dataclass
class Reattach(Fault):
    """Finger ``finger`` is pushed back on its pogo pins (with contact ``bounce``): it gets
    the palm's power state once the contacts settle and cold boots through its bootloader."""

    name = "reattach"
    entry_point = "node power"
    summary = "a finger pushed back on (contact bounce), cold boot"
    instantaneous = True
    finger: int = 0  #: finger module 0..3
    bounce: bool = True  #: contact bounce first

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        emulator.reattach(self.finger, bounce=self.bounce)


@dataclass
class PogoChatter(Fault):
    """Finger ``finger``'s pogo pins chatter: ``contacts`` short contacts of random length in
    [``min_us``, ``max_us``) µs, each with line noise, then they settle closed (the finger
    cold boots if it lost power)."""

    name = "pogo_chatter"
    entry_point = "node power"
    summary = "pogo pins chattering: short contacts with noise, then settled"
    instantaneous = True
    finger: int = 0  #: finger module 0..3
    contacts: int = 5  #: number of short contacts
    min_us: int = 100  #: shortest contact (µs)
    max_us: int = 2_000  #: longest contact (µs)

    def __post_init__(self) -> None:
        if self.contacts < 1 or not 0 < self.min_us < self.max_us:
            raise ValueError("contacts must be >= 1 and 0 < min_us < max_us")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        hand = _hand(emulator)
        finger = targets.finger(emulator, self.finger)
        hand.lose_contact(finger)
        end = hand.chatter(finger, self.contacts, (self.min_us, self.max_us), rng)
        emulator.scheduler.call_later(end, lambda: hand.make_contact(finger))


@dataclass
class PartialContact(Fault):
    """Finger ``finger``'s pogo pins carry power but no data: the fmcb runs, the palm
    hears nothing from it and it hears nothing from the palm."""

    name = "partial_contact"
    entry_point = "node power"
    summary = "pogo pins with power but no data"
    finger: int = 0  #: finger module 0..3

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        _hand(emulator)
        targets.finger(emulator, self.finger).data_contact = False

    def clear(self, emulator: Emulator) -> None:
        targets.finger(emulator, self.finger).data_contact = True


@dataclass
class ShortedTendon(Fault):
    """Finger ``finger``'s tendon supply shorted: the fmcb's phalange switch carries
    ``load_ma`` whenever it is on, so its breaker trips (and trips again when re-enabled)
    until cleared."""

    name = "shorted_tendon"
    entry_point = "node power"
    summary = "a shorted tendon supply: the phalange breaker trips"
    finger: int = 0  #: finger module 0..3
    load_ma: int = 600  #: current drawn through the short (mA)
    _hook: Any = field(default=None, init=False, repr=False)

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        switch = targets.node(emulator, f"finger{self.finger}.fmcb").hal.power("phalange")

        def short(state: int) -> None:  # after the rig's own handler has set the load
            switch.set_load_ma(self.load_ma)

        self._hook = short
        switch.on_change.append(short)
        switch.set_load_ma(self.load_ma)

    def clear(self, emulator: Emulator) -> None:
        from hil_emulator.hand.rig import PHALANGE_LOAD_MA

        finger = targets.finger(emulator, self.finger)
        switch = targets.node(emulator, f"finger{self.finger}.fmcb").hal.power("phalange")
        if self._hook in switch.on_change:
            switch.on_change.remove(self._hook)
        switch.set_load_ma(PHALANGE_LOAD_MA * sum(n.powered for n in (finger.f2, finger.f3)))


@dataclass
class NodePowerCut(Fault):
    """Node ``node``'s supply is cut (an unfinished flash write leaves its page half
    programmed); cleared, the supply returns and the node cold boots."""

    name = "node_power_cut"
    entry_point = "node power"
    summary = "a hand node's supply cut (at a chosen point of a flash write with a trigger)"
    node: str = "finger0.fmcb"  #: palm, finger<k>.fmcb|f2|f3

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        mcu = targets.node(emulator, self.node).mcu
        if mcu is None:
            raise EmulatorConfigError(f"node_power_cut: {self.node} has no hand supply")
        mcu.power_off()

    def clear(self, emulator: Emulator) -> None:
        mcu = targets.node(emulator, self.node).mcu
        assert mcu is not None
        mcu.power_on()


def _hand(emulator: Emulator) -> HandRig:
    if emulator.hand is None:
        raise EmulatorConfigError(f"the {emulator.config!r} configuration has no pogo pins")
    return emulator.hand
