"""Host driver library: transports, hand and arm clients.

The public names are importable from here (``from host import Hand, Arm, open_transport``)
and from their rooms: ``host.hand``, ``host.arm``, ``host.view``, ``host.transports``,
``host.estimation``, ``host.recording`` (docs/ARCHITECTURE.md).  They load on first use, so
``import host.errors`` stays cheap.  The flat module names of before the rooms
(``host.arm_cycle`` …) still import, with a :class:`DeprecationWarning`
(:mod:`host.old_module_names`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any, Final

from host.old_module_names import install

if TYPE_CHECKING:
    from host.arm.facade import Arm as Arm
    from host.errors import HostError as HostError
    from host.hand.facade import Hand as Hand
    from host.hand.session import HandSession as HandSession
    from host.transports.base import Transport as Transport
    from host.transports.base import open_transport as open_transport
    from host.view.live import RobotView as RobotView

#: Public name → the module that defines it.
EXPORTS: Final = {
    "Hand": "host.hand.facade",
    "Arm": "host.arm.facade",
    "RobotView": "host.view.live",
    "HandSession": "host.hand.session",
    "Transport": "host.transports.base",
    "open_transport": "host.transports.base",
    "HostError": "host.errors",
}
__all__ = sorted(EXPORTS)

#: Where each flat module of before the rooms went (old name → new, under ``host``).
MOVED: Final = {
    "transport": "transports.base",
    "hand_interface": "hand.interface",
    "hand_node": "hand.node",
    "hand_finger": "hand.finger",
    "hand_bring_up": "hand.bring_up",
    "hand_homing": "hand.homing",
    "hand_state": "hand.state",
    "hand_session": "hand.session",
    "hand_recording": "hand.recording",
    "grasp": "hand.grasp",
    "grasp_synergies": "hand.synergies",
    "finger_params": "hand.params",
    "joint_limits": "hand.joint_limits",
    "inertial_closed_form": "estimation.closed_form",
    "finger_gravity_model": "estimation.finger_gravity",
    "joint_ekf": "estimation.ekf",
    "accel_calibration": "estimation.accel_calibration",
    "arm_interface": "arm.interface",
    "dynamixel_bus": "arm.bus",
    "arm_cycle": "arm.cycle",
    "arm_discovery": "arm.discovery",
    "arm_state": "arm.state",
    "arm_gate": "arm.gate",
    "arm_hold": "arm.hold",
    "arm_rest": "arm.rest",
    "arm_homing": "arm.homing",
    "arm_stop_model": "arm.stop_model",
    "arm_move": "arm.move",
    "arm_joint_loop": "arm.joint_loop",
    "arm_motor_goals": "arm.motor_goals",
    "arm_trajectory": "arm.trajectory",
    "arm_cartesian": "arm.cartesian",
    "arm_waypoints": "arm.waypoints",
    "arm_kinematics": "arm.kinematics",
    "arm_gravity": "arm.gravity",
    "arm_control": "arm.control",
    "arm_dynamics": "arm.dynamics",
    "arm_recording": "arm.recording",
    "topics": "recording.topics",
    "view_render": "view.render",
    "view_columns": "view.columns",
    "view_server": "view.server",
    "view_child": "view.child",
    "robot_geometry": "view.geometry",
}
install("host", MOVED)


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use."""
    module = EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'host' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
