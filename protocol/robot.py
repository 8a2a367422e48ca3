"""The robot's mechanical facts: what both ends of the wire must agree on to read its numbers.

Firmware, the emulated plant and host programs learn the robot here, and only here.  Pure:
the standard library and numpy.

**Finger module** (four identical modules, three motors each).  Joint order J0, J1, J2 (base
abduction, proximal flexion, distal flexion; the MuJoCo model names them J1..J3); motor ``i``
is the motor whose tendon mainly drives joint ``i``.  Joint angles in rad, motor shaft angles
in rad, motor positions in hall counts (transitions of the three 120° hall sensors,
:data:`HALL_STATES_PER_MOTOR_REV` per motor revolution).  With ``K`` hall states per rad of
motor shaft, gear ratios ``g`` and the distal tendon's coupling ``c`` into the proximal
motors (the original hand's tendon routing)::

    m2 = K·g2·q2
    m1 = K·(g1·q1 − c·g2·q2)
    m0 = K·(g0·q0 + g1·q1 + c·g2·q2)

A positive joint angle flexes the finger towards its pads (J1, J2) or turns it about the
module's ``+z`` (J0); a positive motor turn counts hall states forward along
:data:`HALL_SEQUENCE`.

**Hand layouts** place the four modules on the palm (figure 6.4 of the hand's design):
:data:`HAND_LAYOUTS` gives each module's frame in the palm frame, and from it the joint axes
(the signs of each finger's joints as the palm sees them).

**Arm** (7 DOF): J1–J4 series-elastic joints driven by steppers through a reduction, with an
indexed joint encoder; J5–J7 ROBOTIS RX-64 servos.  Joint angles in rad, joint encoder counts
(:data:`ARM_ENCODER_COUNTS_PER_REV` per joint revolution), stepper microsteps, RX-64 position
units (:data:`RX64_RANGE_DEG` over :data:`RX64_POSITION_UNITS`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

Vec3 = tuple[float, float, float]
Range = tuple[float, float]

# ============================================================================ finger module

#: Names of the finger module's joints J0, J1, J2, in firmware order.
FINGER_JOINT_NAMES: Final = ("abduction", "proximal", "distal")
#: Hall states (transitions of the three hall sensors) per motor shaft revolution.
HALL_STATES_PER_MOTOR_REV: Final = 36
#: Hall states per radian of motor shaft (hall counts/rad).
HALL_STATES_PER_RAD: Final = HALL_STATES_PER_MOTOR_REV / (2.0 * math.pi)
#: The six valid hall states in forward order (120° sensors); 0 and 7 never occur.
HALL_SEQUENCE: Final = (1, 3, 2, 6, 4, 5)
#: Gear ratios of motors 0, 1, 2 (motor revs per capstan rev, dimensionless).
FINGER_GEAR_RATIOS: Final = (173.4, 196.7, 231.0)
#: Coupling of the distal joint's tendon into the proximal motors (dimensionless).
TENDON_COUPLING: Final = 0.89
#: Joint axes of J0, J1, J2 in the finger module's frame (``x`` along the extended finger,
#: ``z`` the pads' side): a positive angle turns about ``+z`` (J0) or flexes towards ``+z``.
FINGER_JOINT_AXES: Final[tuple[Vec3, Vec3, Vec3]] = (
    (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.0, -1.0, 0.0))
#: Default joint limits of J0, J1, J2 (rad, lower, upper): the fmcb's parameter defaults.
FINGER_JOINT_LIMITS: Final[tuple[Range, Range, Range]] = (
    (-1.57, 1.57), (-1.57, 1.57), (-1.57, 1.57))
#: Mechanical stops of J0, J1, J2 (rad), a little beyond :data:`FINGER_JOINT_LIMITS`.
FINGER_JOINT_STOPS: Final[tuple[Range, Range, Range]] = ((-1.6, 1.6), (-1.6, 1.6), (-1.6, 1.8))


def finger_coupling_matrix() -> np.ndarray:
    """``M`` (3×3) with ``m = M·q``: joint angles (rad) → motor positions (hall counts)."""
    g0, g1, g2 = FINGER_GEAR_RATIOS
    c = TENDON_COUPLING
    return HALL_STATES_PER_RAD * np.array(
        [[g0, g1, c * g2],
         [0.0, g1, -c * g2],
         [0.0, 0.0, g2]]
    )


def finger_coupling_matrix_rad() -> np.ndarray:
    """``M_rad`` (3×3) with ``θ_m = M_rad·q``: joint angles (rad) → motor shaft angles (rad)."""
    return finger_coupling_matrix() / HALL_STATES_PER_RAD


def finger_decoupling_matrix() -> np.ndarray:
    """``M⁻¹`` (3×3) with ``q = M⁻¹·m``: motor positions (hall counts) → joint angles (rad)."""
    return np.linalg.inv(finger_coupling_matrix())


def joint_to_motor(q: Sequence[float]) -> Vec3:
    """Motor positions (hall counts) for joint angles ``q`` (rad, J0..J2)."""
    g0, g1, g2 = FINGER_GEAR_RATIOS
    c = TENDON_COUPLING
    k = HALL_STATES_PER_RAD
    q0, q1, q2 = (float(v) for v in q)
    return (k * (g0 * q0 + g1 * q1 + c * g2 * q2),
            k * (g1 * q1 - c * g2 * q2),
            k * g2 * q2)


def motor_to_joint(m: Sequence[float]) -> Vec3:
    """Joint angles (rad) for motor positions ``m`` (hall counts): the inverse coupling."""
    g0, g1, g2 = FINGER_GEAR_RATIOS
    c = TENDON_COUPLING
    k = HALL_STATES_PER_RAD
    m0, m1, m2 = (float(v) / k for v in m)
    q2 = m2 / g2
    q1 = (m1 + c * g2 * q2) / g1
    q0 = (m0 - g1 * q1 - c * g2 * q2) / g0
    return (q0, q1, q2)


def joint_to_motor_rad(q: Sequence[float]) -> Vec3:
    """Motor shaft angles (rad) for joint angles ``q`` (rad)."""
    m0, m1, m2 = joint_to_motor(q)
    k = HALL_STATES_PER_RAD
    return (m0 / k, m1 / k, m2 / k)


def motor_rad_to_joint(theta: Sequence[float]) -> Vec3:
    """Joint angles (rad) for motor shaft angles ``theta`` (rad)."""
    k = HALL_STATES_PER_RAD
    return motor_to_joint([float(v) * k for v in theta])


# ============================================================================ hand layouts

#: Half extents of the palm (m, palm frame x, y, z): 90 × 100 × 25 mm.  The palm frame's
#: origin is the palm's centre, ``y`` points towards the fingers' edge, ``z`` out of the
#: palmar face.
PALM_HALF_EXTENTS_M: Final = (0.045, 0.050, 0.0125)


def _unit(v: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return a / np.linalg.norm(a)


@dataclass(frozen=True)
class FingerMount:
    """Where one finger module's frame (its F0 body, origin on the J0 axis) sits on the palm.

    ``position_m`` in the palm frame (m); ``x_axis`` the direction of the extended finger and
    ``z_axis`` the side its pads face, both in the palm frame (any length; ``z_axis`` is
    re-orthogonalised against ``x_axis``).
    """

    position_m: Vec3
    x_axis: Vec3
    z_axis: Vec3

    def rotation(self) -> np.ndarray:
        """The module frame's orientation (3×3, columns x, y, z in the palm frame)."""
        x = _unit(self.x_axis)
        z = np.asarray(self.z_axis, dtype=float)
        z = _unit(z - x * float(x @ z))
        return np.column_stack((x, np.cross(z, x), z))

    def joint_axes(self) -> np.ndarray:
        """Axes of J0, J1, J2 in the palm frame (3×3, one unit vector per row): a positive
        joint angle turns the finger counter-clockwise about that axis."""
        return (self.rotation() @ np.asarray(FINGER_JOINT_AXES, dtype=float).T).T


@dataclass(frozen=True)
class HandLayout:
    """A hand frame: the four finger modules' mounts, finger 0 first (the palm's ``finger{k}``
    port ``k`` drives ``mounts[k]``)."""

    name: str
    mounts: tuple[FingerMount, FingerMount, FingerMount, FingerMount]


_ALONG_Y: Final = ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))         # fingers along +y, pads up
_ALONG_MINUS_Y: Final = ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0))  # fingers along −y, pads up
_EDGE_Y: Final = PALM_HALF_EXTENTS_M[1]

#: The hand frames this project provides (figure 6.4; the finger modules are unchanged).
HAND_LAYOUTS: Final[dict[str, HandLayout]] = {
    # Three parallel fingers on the distal edge; the thumb module stands up from the palmar
    # face near the proximal corner, its pads facing the fingers (opposable).
    "four-finger-thumb": HandLayout("four-finger-thumb", (
        FingerMount((-0.030, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.000, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.030, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.030, -0.032, PALM_HALF_EXTENTS_M[2] + 0.006),
                    (0.0, 0.0, 1.0), (-0.35, 1.0, 0.0)),
    )),
    # Three parallel fingers; the fourth module on the proximal edge's centre line, directly
    # opposed to the middle finger (a three-against-one gripper).
    "three-plus-opposed": HandLayout("three-plus-opposed", (
        FingerMount((-0.030, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.000, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.030, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.000, -_EDGE_Y, 0.0), *_ALONG_MINUS_Y),
    )),
    # Two fingers on each end, facing each other across the palm (symmetric gripper).
    "two-by-two": HandLayout("two-by-two", (
        FingerMount((-0.022, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((0.022, _EDGE_Y, 0.0), *_ALONG_Y),
        FingerMount((-0.022, -_EDGE_Y, 0.0), *_ALONG_MINUS_Y),
        FingerMount((0.022, -_EDGE_Y, 0.0), *_ALONG_MINUS_Y),
    )),
}
DEFAULT_HAND_LAYOUT: Final = "four-finger-thumb"

# ============================================================================ arm

#: Joint names, proximal first: J1–J4 stepper-driven series-elastic joints, J5–J7 RX-64s.
ARM_JOINT_NAMES: Final = ("J1", "J2", "J3", "J4", "J5", "J6", "J7")
#: Number of stepper-driven joints (J1–J4); the rest are RX-64 servos.
ARM_STEPPER_JOINTS: Final = 4
#: Joint axes in each joint's body frame (the arm hanging straight down at all-zero angles;
#: a positive angle turns counter-clockwise about the axis).
ARM_JOINT_AXES: Final[tuple[Vec3, ...]] = (
    (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0))
#: Joint limits (rad): the mechanical stops.  J2 has about 180° of motion (hanging slightly
#: backwards to nearly straight up); the RX-64 joints stop just inside the pot's ±150°.
ARM_JOINT_LIMITS: Final[tuple[Range, ...]] = (
    (-2.97, 2.97), (-0.35, 2.80), (-2.62, 2.62), (-0.35, 2.60),
    (-2.60, 2.60), (-2.60, 2.60), (-2.60, 2.60))
#: Effective reductions of J1–J4 (motor revs per joint rev): timing belt × cable circuit.
STEPPER_REDUCTIONS: Final = (6.0, 10.0, 13.0, 13.0)
#: Stiffness of the series-elastic couplings of J1–J4 (N·m/rad): torque per rad of deflection
#: between the motor side (steps ÷ reduction) and the joint encoder.  The elbow's (J4) 86 is
#: the dissertation's; the shoulder's makes 15 g at the outstretched wrist move the J2
#: encoder by about a count.
SERIES_ELASTIC_STIFFNESS_NM_PER_RAD: Final = (160.0, 200.0, 110.0, 86.0)
#: Stepper full steps per motor revolution (1.8° motors).
STEPPER_FULL_STEPS_PER_REV: Final = 200
#: Microsteps per full step of the stepper drivers.
STEPPER_MICROSTEPPING: Final = 16
#: Joint encoder counts per joint revolution (0.036° per count).
ARM_ENCODER_COUNTS_PER_REV: Final = 10_000


def reduction_x100(reduction: float) -> int:
    """A reduction as the stepper node's ``gear_reduction_x100`` register holds it."""
    return round(reduction * 100)


def microsteps_per_rad(joint: int) -> float:
    """Stepper microsteps per rad of joint ``joint`` (0..3 for J1..J4)."""
    return (STEPPER_FULL_STEPS_PER_REV * STEPPER_MICROSTEPPING * STEPPER_REDUCTIONS[joint]
            / (2.0 * math.pi))


def microsteps_to_rad(joint: int, microsteps: float) -> float:
    """Joint angle (rad) the motor of ``joint`` (0..3) moves through in ``microsteps``."""
    return microsteps / microsteps_per_rad(joint)


def rad_to_microsteps(joint: int, angle: float) -> float:
    """Microsteps of the motor of ``joint`` (0..3) for a joint angle (rad)."""
    return angle * microsteps_per_rad(joint)


def microsteps_per_encoder_count(joint: int) -> float:
    """Microsteps per joint encoder count of ``joint`` (0..3)."""
    return (STEPPER_FULL_STEPS_PER_REV * STEPPER_MICROSTEPPING * STEPPER_REDUCTIONS[joint]
            / ARM_ENCODER_COUNTS_PER_REV)


def encoder_counts_to_rad(counts: float) -> float:
    """Joint angle (rad) of a joint encoder reading (counts)."""
    return counts * (2.0 * math.pi) / ARM_ENCODER_COUNTS_PER_REV


def rad_to_encoder_counts(angle: float) -> int:
    """Joint encoder counts (rounded) of a joint angle (rad)."""
    return round(angle * ARM_ENCODER_COUNTS_PER_REV / (2.0 * math.pi))


#: RX-64 potentiometer range (deg): position units 0..1023 span it, centred on joint angle 0.
RX64_RANGE_DEG: Final = 300.0
#: The RX-64 range (rad).
RX64_RANGE_RAD: Final = math.radians(RX64_RANGE_DEG)
#: Position units spread over :data:`RX64_RANGE_DEG` (the register holds 0..1023).
RX64_POSITION_UNITS: Final = 1024
#: Position register at the centre of travel (joint angle 0).
RX64_POSITION_CENTRE: Final = 512
#: Highest position register value.
RX64_POSITION_MAX: Final = RX64_POSITION_UNITS - 1
#: Radians per RX-64 position unit (0.293°).
RX64_RAD_PER_UNIT: Final = RX64_RANGE_RAD / RX64_POSITION_UNITS
#: RX-64 position units per radian.
RX64_UNITS_PER_RAD: Final = RX64_POSITION_UNITS / RX64_RANGE_RAD
