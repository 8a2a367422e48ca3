"""The arm's joints as the host sees them: what discovery learns, commands as data, state.

Joints are numbered 0..6 (J1..J7, proximal first) and sit at bus IDs 1..7: J1-J4 are
series-elastic stepper joints (this project's stepper node), J5-J7 ROBOTIS RX-64 servos.

Frames and units: joint angles in rad, 0 at

* a stepper joint's encoder count 0 - the node's power-up pose (on the emulator the
  kinematic zero, the arm hanging straight down); calibration against the index mark is left
  to the caller (``index_*`` registers);
* an RX-64's centre position (register 512), positive counter-clockwise.

A stepper joint's *motor angle* is the step count integrated by its node turned into a
joint angle: ``step_count / (steps_per_rev × microstepping) × 2π / reduction`` (rad), from
the numbers the node reports (``gear_reduction_x100 / 100``, ``steps_per_rev``,
``microstepping``), plus the joint angle at the node's power-up (where the step count
started), so it is in the joint's frame.  Its *deflection* (motor angle after
the reduction minus joint angle, what the elastic element is compressed by) times the
joint's stiffness is the series-elastic torque (N·m).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

from host.arm.bus import error_names
from protocol.control_tables import GOAL_FINE_PER_COUNT, StepperFlag
from protocol.dynamixel import ErrorBit
from protocol.robot import ARM_JOINT_NAMES, SERIES_ELASTIC_STIFFNESS_NM_PER_RAD
from protocol.topology import ARM_JOINTS

#: Number of joints and how many of them are stepper joints (J1..J4).
N_JOINTS: Final = 7
N_STEPPERS: Final = 4
#: Joint names, proximal first.
JOINT_NAMES: Final = ARM_JOINT_NAMES
#: Bus ID of each joint.
JOINT_IDS: Final = tuple(joint.dxl_id for joint in ARM_JOINTS)
#: Coupling stiffness of the stepper joints J1..J4 (N·m/rad): the series-elastic element's
#: torque per rad of deflection (the elbow's 86 N·m/rad as measured on the arm; the others
#: as the emulator's plant models them).
DEFAULT_STIFFNESS_NM_PER_RAD: Final = SERIES_ELASTIC_STIFFNESS_NM_PER_RAD

Kind = Literal["stepper", "servo"]


@dataclass(frozen=True)
class JointInfo:
    """One joint's node as discovery found it.

    ``model_number`` and ``firmware_version`` are the node's registers 0 and 2.  For a
    stepper joint: ``reduction`` (motor revs per joint rev, ``gear_reduction_x100 / 100``),
    ``steps_per_rev`` (full steps per motor rev), ``microstepping`` (microsteps per step),
    ``encoder_counts_per_rev`` (joint encoder), ``stiffness`` (N·m/rad) and ``arm_serial``
    (the arm's serial number its node holds; 0: never programmed); zero for a servo.
    """

    joint: int
    dxl_id: int
    kind: Kind
    model_number: int
    firmware_version: int
    reduction: float = 0.0
    steps_per_rev: int = 0
    microstepping: int = 0
    encoder_counts_per_rev: int = 0
    stiffness: float = 0.0
    arm_serial: int = 0

    @property
    def name(self) -> str:
        """``J1`` .. ``J7``."""
        return JOINT_NAMES[self.joint]

    @property
    def microsteps_per_count(self) -> float:
        """Motor microsteps per joint encoder count (the node's own ratio)."""
        return (self.reduction * self.steps_per_rev * self.microstepping
                / self.encoder_counts_per_rev)

    def counts_to_rad(self, counts: float) -> float:
        """Joint encoder counts -> rad."""
        return counts * 2.0 * math.pi / self.encoder_counts_per_rev

    def rad_to_counts(self, angle: float) -> int:
        """Rad -> the nearest joint encoder count."""
        return round(angle * self.encoder_counts_per_rev / (2.0 * math.pi))

    def rad_to_fine(self, angle: float) -> int:
        """Rad -> the nearest ``command_goal`` unit (1/16 joint encoder count)."""
        return round(angle * self.encoder_counts_per_rev * GOAL_FINE_PER_COUNT
                     / (2.0 * math.pi))

    def steps_to_rad(self, steps: int) -> float:
        """Integrated microsteps -> motor angle after the reduction (rad at the joint)."""
        return steps * 2.0 * math.pi / (self.steps_per_rev * self.microstepping
                                        * self.reduction)


# ----------------------------------------------------------------------------- commands


@dataclass(frozen=True)
class PositionCommand:
    """Move ``joint`` (0..6) to ``angle`` (rad); ``speed`` (rad/s, > 0) also sets its speed
    limit (stepper ``velocity_limit``, RX-64 ``moving_speed``); None leaves it as it is."""

    joint: int
    angle: float
    speed: float | None = None


@dataclass(frozen=True)
class TorqueCommand:
    """Enable (``on``) or disable a joint's torque (stepper coils, RX-64 output)."""

    joint: int
    on: bool


Command = PositionCommand | TorqueCommand


# ----------------------------------------------------------------------------- state


@dataclass(frozen=True)
class StepperState:
    """A stepper joint at one cycle.

    ``angle`` (rad, joint encoder), ``velocity`` (rad/s, encoder, resolution 1 count/s),
    ``motor_angle`` (rad at the joint, to the count: ``angle`` plus the deflection),
    ``goal`` (rad, the node's goal for the motor as the host last set it), ``step_count``
    (microsteps), ``deflection`` (joint encoder counts, as the node's register defines it:
    motor − joint) and ``deflection_rad``, ``torque`` (N·m: the series-elastic element's,
    from its own deflection, the node's plus the routes' coupling ``C·Δq``, which turns the
    capstans of J3 and J4 with the joints before them;
    :func:`protocol.robot.series_elastic_torque`), ``flags`` (:class:`StepperFlag`),
    ``errors`` (the status packet's alarm bits).
    """

    joint: int
    angle: float
    velocity: float
    motor_angle: float
    step_count: int
    deflection: int
    deflection_rad: float
    torque: float
    flags: StepperFlag
    errors: ErrorBit
    goal: float

    @property
    def slip(self) -> bool:
        """The node latched SLIP: steps were lost, the step count no longer gives the motor."""
        return bool(self.flags & StepperFlag.SLIP)

    @property
    def stalled(self) -> bool:
        """The node latched STALLED (over-deflection; reported as OVERLOAD)."""
        return bool(self.flags & StepperFlag.STALLED)

    @property
    def moving(self) -> bool:
        """A move towards the goal is in progress."""
        return bool(self.flags & StepperFlag.MOVING)

    @property
    def watchdog(self) -> bool:
        """The node's command watchdog stopped its move (no instruction from the host
        within ``watchdog_timeout``); it holds there until the next goal."""
        return bool(self.flags & StepperFlag.WATCHDOG)


@dataclass(frozen=True)
class ServoState:
    """An RX-64 joint at one cycle: ``angle`` (rad), ``velocity`` (rad/s), ``load``
    (signed fraction of maximum torque, counter-clockwise > 0), ``temperature`` (°C) and
    ``voltage`` (V) as last read (one cycle in :data:`host.arm.facade.SLOW_READ_EVERY`), ``errors``
    (alarm bits of its status packet, every cycle)."""

    joint: int
    angle: float
    velocity: float
    load: float
    temperature: float
    voltage: float
    errors: ErrorBit


@dataclass(frozen=True)
class ArmState:
    """The whole arm at one cycle; ``t`` is the transport's time (s) the replies were in."""

    t: float
    steppers: tuple[StepperState, ...]
    servos: tuple[ServoState, ...]
    raw: dict[int, bytes] = field(default_factory=dict, compare=False, repr=False)

    @property
    def joints(self) -> list[float]:
        """The seven joint angles (rad), J1..J7."""
        return [s.angle for s in self.steppers] + [s.angle for s in self.servos]

    @property
    def motor_joints(self) -> list[float]:
        """The four stepper joints' motor angles (rad at the joint, from the step counts)."""
        return [s.motor_angle for s in self.steppers]

    @property
    def torques(self) -> list[float]:
        """The four series-elastic torques (N·m)."""
        return [s.torque for s in self.steppers]

    @property
    def slip(self) -> list[bool]:
        """The four stepper joints' SLIP flags."""
        return [s.slip for s in self.steppers]

    @property
    def errors(self) -> dict[str, list[str]]:
        """Alarm bits by joint name, for the joints that report any (e.g.
        ``{"J6": ["OVERHEATING"]}``)."""
        out: dict[str, list[str]] = {}
        joints: tuple[StepperState | ServoState, ...] = (*self.steppers, *self.servos)
        for s in joints:
            if s.errors:
                out[JOINT_NAMES[s.joint]] = list(error_names(s.errors))
        return out

    def as_dict(self) -> dict[str, object]:
        """A JSON-ready summary (what ``armctl --json status`` prints)."""
        return {
            "t": self.t,
            "joints": self.joints,
            "motor_joints": self.motor_joints,
            "goals": [s.goal for s in self.steppers],
            "torques": self.torques,
            "slip": self.slip,
            "stalled": [s.stalled for s in self.steppers],
            "moving": [s.moving for s in self.steppers],
            "watchdog": [s.watchdog for s in self.steppers],
            "deflection_counts": [s.deflection for s in self.steppers],
            "step_counts": [s.step_count for s in self.steppers],
            "servo_load": [s.load for s in self.servos],
            "servo_temperature_c": [s.temperature for s in self.servos],
            "errors": self.errors,
        }


@dataclass(frozen=True)
class JointCalibration:
    """The arm's joint frames after homing.

    ``offsets`` (rad, 7): absolute joint angle = the node's angle + offset (0 for the
    servos); ``index_encoder_counts`` and ``index_step_counts`` (4): the stepper nodes'
    latches (joint encoder counts, microsteps)."""

    offsets: tuple[float, ...]
    index_encoder_counts: tuple[int, ...]
    index_step_counts: tuple[int, ...]

    def to_node(self, angles: Sequence[float]) -> list[float]:
        """Absolute joint angles (rad, 7) → the nodes' frame."""
        return [a - o for a, o in zip(angles, self.offsets, strict=True)]

    def from_node(self, angles: Sequence[float]) -> list[float]:
        """The nodes' joint angles (rad, 7) → absolute."""
        return [a + o for a, o in zip(angles, self.offsets, strict=True)]

    def commands_to_node(self, commands: Iterable[Command]) -> list[Command]:
        """Position commands with absolute angles → the nodes' frame (others unchanged)."""
        out: list[Command] = []
        for c in commands:
            if isinstance(c, PositionCommand) and self.offsets[c.joint]:
                c = dataclasses.replace(c, angle=c.angle - self.offsets[c.joint])
            out.append(c)
        return out

    def state_from_node(self, state: ArmState) -> ArmState:
        """A state read in the nodes' frame, in absolute angles (joint, motor and goal angles
        shifted alike, so deflections and torques are unchanged)."""
        steppers = tuple(dataclasses.replace(
            s, angle=s.angle + self.offsets[s.joint],
            motor_angle=s.motor_angle + self.offsets[s.joint],
            goal=s.goal + self.offsets[s.joint]) for s in state.steppers)
        servos = tuple(dataclasses.replace(s, angle=s.angle + self.offsets[s.joint])
                       if self.offsets[s.joint] else s for s in state.servos)
        return dataclasses.replace(state, steppers=steppers, servos=servos)
