"""Names a fault uses for the parts of the emulated robot: nodes, buses, host links.

* nodes: ``"palm"``, ``"finger<k>.fmcb"``, ``"finger<k>.f2"``, ``"finger<k>.f3"`` (k = 0..3;
  the loose finger is ``finger0``), ``"arm.<id>"`` (Dynamixel id 1..7);
* buses: ``"arm"`` (the arm's RS-485 line), ``"tendon<k>"`` (finger k's tendon bus);
* host links: ``"palm"``, ``"arm"``, ``"finger0"`` (the loose finger's cable);
* finger physics: :func:`finger_plant` by the finger's index.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.mcu import Mcu
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.rig import Finger
from hil_emulator.lines.rs485_bus import Rs485Bus
from protocol.topology import FINGER_BOARDS

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator
    from hil_emulator.hand.finger_plant import FingerPlant

_FINGER_BOARDS = "|".join(b.app for b in FINGER_BOARDS)
_FINGER_NODE = re.compile(rf"finger(\d)\.({_FINGER_BOARDS})$")
_ARM_NODE = re.compile(r"arm\.(\d)$")


@dataclass
class NodeRef:
    """A node: its HAL, and its :class:`Mcu` (hand nodes) or Dynamixel application (arm)."""

    name: str
    hal: VirtualHal
    mcu: Mcu | None = None
    app: DynamixelSlave | None = None

    def reset(self) -> None:
        """The node's reset line (watchdog, reset button): its program starts again."""
        self.hal.reset()


def finger(emulator: Emulator, index: int) -> Finger:
    """Finger module ``index`` of the hand, or the loose finger (index 0)."""
    if emulator.hand is not None:
        if not 0 <= index < len(emulator.hand.fingers):
            raise EmulatorConfigError(f"finger {index}: the hand has fingers 0..3")
        return emulator.hand.fingers[index]
    if emulator.loose is not None and index == 0:
        return emulator.loose.finger
    raise EmulatorConfigError(f"the {emulator.config!r} configuration has no finger {index}")


def finger_plant(emulator: Emulator, index: int) -> FingerPlant:
    """The physics of finger module ``index`` (or the loose finger, index 0)."""
    finger(emulator, index)  # the same errors for a finger the configuration lacks
    if not emulator.finger_plants:
        raise EmulatorConfigError(f"finger {index} has no physics (the emulator runs with "
                                  "physics off)")
    plant: FingerPlant = emulator.finger_plants[index]
    return plant


def node(emulator: Emulator, name: str) -> NodeRef:
    """The node called ``name`` (see the module's docstring)."""
    if name == "palm":
        if emulator.hand is None:
            raise EmulatorConfigError(f"the {emulator.config!r} configuration has no palm")
        mcu = emulator.hand.palm
        return NodeRef(name, _hal(mcu), mcu)
    m = _FINGER_NODE.match(name)
    if m:
        mcu = getattr(finger(emulator, int(m.group(1))), m.group(2))
        return NodeRef(name, _hal(mcu), mcu)
    m = _ARM_NODE.match(name)
    if m:
        if emulator.arm is None:
            raise EmulatorConfigError(f"the {emulator.config!r} configuration has no arm")
        dxl_id = int(m.group(1))
        if dxl_id not in emulator.arm.nodes:
            raise EmulatorConfigError(f"node {name!r}: the arm has ids 1..7")
        hal, app = emulator.arm.nodes[dxl_id]
        return NodeRef(name, hal, None, app)
    raise EmulatorConfigError(
        f"unknown node {name!r}: palm, finger<k>.{_FINGER_BOARDS} or arm.<id>")


def bus(emulator: Emulator, name: str) -> Rs485Bus:
    """The bus called ``name``: ``arm`` or ``tendon<k>``."""
    if name == "arm":
        if emulator.arm is None:
            raise EmulatorConfigError(f"the {emulator.config!r} configuration has no arm bus")
        return emulator.arm.bus
    m = re.fullmatch(r"tendon(\d)", name)
    if m:
        line = finger(emulator, int(m.group(1))).tendon_bus
        if line is None:
            raise EmulatorConfigError(f"bus {name!r} has no line model")
        return line
    raise EmulatorConfigError(f"unknown bus {name!r}: arm or tendon<k>")


def _hal(mcu: Mcu) -> VirtualHal:
    hal = mcu.hal
    assert isinstance(hal, VirtualHal)
    return hal
