"""The arm as its helpers see it: small protocols of what each uses of :class:`host.arm.facade.Arm`.

The facade (:mod:`host.arm.facade`) imports its helpers (homing, the hold, the gate, the joint
loop, Cartesian moves, waypoints, the recorder, the view); they never import it back.  Each
helper types its ``arm`` argument with the protocol here that names what it calls, so a
helper's reader sees what it may touch, and a test can hand it anything that has those
members.  :class:`~host.arm.facade.Arm` satisfies every one of them (mypy checks it where the
facade calls a helper).

* :class:`ArmReader` - read the joints and their torque (the gate);
* :class:`CyclingArm` - cycle commands and states (a hold);
* :class:`DrivenArm` - drive the arm through moves (homing, the joint loop, Cartesian moves,
  waypoints);
* :class:`WatchedArm` - the bus and state taps a recorder or a view attaches to.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Protocol

from host.arm.bus import DynamixelBus
from host.arm.rest import RestWatch
from host.arm.state import (
    ArmState,
    Command,
    JointCalibration,
    JointInfo,
    PositionCommand,
    TorqueCommand,
)
from host.transports.base import Transport


class ArmReader(Protocol):
    """Reads the arm: its state and which joints have their torque on."""

    def state(self) -> ArmState:
        """The seven joints' state now (a cycle without commands)."""
        ...

    def torque_enabled(self) -> tuple[bool, ...]:
        """Each joint's ``torque_enable`` register (J1..J7)."""
        ...


class WatchedArm(Protocol):
    """What a recorder or a view attaches to: the bus (its bytes, its statistics) and the
    taps every cycle's state goes to."""

    @property
    def bus(self) -> DynamixelBus:
        """The arm's Dynamixel bus."""
        ...

    @property
    def state_taps(self) -> list[Callable[[ArmState], None]]:
        """Called with every cycle's state."""
        ...

    @property
    def transport(self) -> Transport:
        """The bus's transport (its clock: ``now``, ``sleep``)."""
        ...

    def cycle(self, commands: Iterable[Command] = ()) -> ArmState:
        """Send ``commands`` and read the state of all seven joints in one exchange."""
        ...


class CyclingArm(ArmReader, WatchedArm, Protocol):
    """Cycles the arm: commands as data, sent with a cycle or on their own (a hold)."""

    @property
    def last_state(self) -> ArmState | None:
        """The last state a cycle read (None before any)."""
        ...

    @property
    def previous_state(self) -> ArmState | None:
        """The state the cycle before the last read (None before two): with
        :attr:`last_state`, how fast each motor was turning."""
        ...

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        """J1..J7 as discovered."""
        ...

    @property
    def unpowered_steppers(self) -> frozenset[int]:
        """The stepper joints whose torque the arm turned off, or found off."""
        ...

    @property
    def stepper_speed_limits(self) -> list[float | None]:
        """Each stepper's speed limit (rad/s) as the arm last wrote it (None: not written)."""
        ...

    def send(self, commands: Iterable[Command]) -> None:
        """Send position ``commands`` without reading anything back."""
        ...

    def make_position(self, joint: int | str, angle: float,
                      speed: float | None = None) -> PositionCommand:
        """A command moving ``joint`` to ``angle`` (rad), at most ``speed`` (rad/s)."""
        ...


class DrivenArm(CyclingArm, Protocol):
    """Drives the arm through moves: torque, alarms, frames (homing sets ``calibration``)."""

    #: Absolute joint frames after homing; None: the nodes' frames.
    calibration: JointCalibration | None
    #: The hand is on the flange (its weight counts in the arm's model at rest).
    hand: bool

    @property
    def steppers(self) -> tuple[JointInfo, ...]:
        """J1..J4 as discovered."""
        ...

    @property
    def homed(self) -> bool:
        """True once the joints' absolute angles are known."""
        ...

    @property
    def encoder_at_power_up(self) -> Sequence[int]:
        """Each stepper node's encoder count at its power-up."""
        ...

    def deflection_offsets(self) -> list[int]:
        """What each stepper node's deflection differs from its elastic element's by, now
        (counts: the routes' coupling)."""
        ...

    def torque(self, on: bool, joints: Iterable[int | str] | None = None, *,
               hold: bool = False) -> ArmState:
        """Enable or disable the torque of ``joints`` (default: all)."""
        ...

    def make_torque(self, joint: int | str, on: bool) -> TorqueCommand:
        """A command enabling or disabling ``joint``'s torque."""
        ...

    def clear_errors(self) -> None:
        """Clear the nodes' latched alarms."""
        ...

    def move(self, angles: Sequence[float], *, duration: float | None = None,
             speed: float | None = None, tolerance: float = ...,
             settle_speed: float = ..., timeout: float = ..., period: float = ...,
             rest: RestWatch | None = None,
             unhomed_speed: float | None = ..., motors: bool = ...) -> tuple[ArmState, bool]:
        """Move all seven joints to ``angles`` (rad) and wait until they settle (a stepper
        joint no faster than ``unhomed_speed``, rad/s, while the arm is not homed)."""
        ...
