"""Hardware-in-the-loop emulator: MuJoCo plant, bus fabric, virtual serial ports.

The core (``emulator``, ``robot``, ``pacing``, ``plant``, ``scene_model``, ``inprocess``,
``introspection``) sits at the top; the rooms beside it: ``hand/`` and ``arm/`` (their
MuJoCo models, plants and rigs), ``ports/`` (the host's ports), ``lines/`` (buses and what a
UART misreads), ``faults/`` (docs/ARCHITECTURE.md).  The flat module names of before the
rooms (``hil_emulator.hand_rig`` …) still import, with a :class:`DeprecationWarning`.
"""

from typing import Final

import protocol  # noqa: F401 - first: it decides compiled core or source
from host.old_module_names import install

#: Where each flat module of before the rooms went (old name → new, under ``hil_emulator``).
MOVED: Final = {
    "arm_actuators": "arm.actuators",
    "arm_model": "arm.model",
    "arm_plant": "arm.plant",
    "arm_rig": "arm.rig",
    "finger_plant": "hand.finger_plant",
    "hand_model": "hand.model",
    "hand_rig": "hand.rig",
    "hand_sensors": "hand.sensors",
    "host_links": "ports.host_links",
    "pty_port": "ports.pty_port",
    "port_reader": "ports.port_reader",
    "slcan_adapter": "ports.slcan_adapter",
    "link_dir": "ports.link_dir",
    "link_tap": "ports.link_tap",
    "host_side": "ports.host_side",
    "rs485_bus": "lines.rs485_bus",
    "uart_sampling": "lines.uart_sampling",
}
install("hil_emulator", MOVED)
