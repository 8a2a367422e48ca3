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
#: Lengths of the finger's links along their ``x`` axes (m): J0 → J1 (the abduction link,
#: F1), J1 → J2 (the proximal phalange, F2) and J2 → the fingertip (the distal phalange,
#: F3).  J0's axis passes through the module frame's origin.
FINGER_LINK_LENGTHS_M: Final[Vec3] = (0.018, 0.045, 0.040)
#: Default joint limits of J0, J1, J2 (rad, lower, upper): the fmcb's parameter defaults.
FINGER_JOINT_LIMITS: Final[tuple[Range, Range, Range]] = (
    (-1.57, 1.57), (-1.57, 1.57), (-1.57, 1.57))
#: Mechanical stops of J0, J1, J2 (rad), a little beyond :data:`FINGER_JOINT_LIMITS`.
FINGER_JOINT_STOPS: Final[tuple[Range, Range, Range]] = ((-1.6, 1.6), (-1.6, 1.6), (-1.6, 1.8))
#: How long (ms) joint limits a host widened in the fmcb's RAM hold without a request from
#: the host: then the fmcb puts back the limits it had before (a host killed while it
#: pushed a finger onto its stops).  Over the hand calibration's 4 s push onto a stop.
FINGER_LIMIT_LEASE_MS: Final = 5_000


#: The finger's accelerometers (LSM303 on each board): board → the segment (MuJoCo body)
#: it rides on.  F0 carries the fmcb, F2 the proximal phalange board (f2), F3 the distal (f3).
FINGER_ACCEL_SEGMENTS: Final = {"fmcb": "F0", "f2": "F2", "f3": "F3"}
#: Each accelerometer's axes in its segment's frame (rows: the board's x, y, z axes): the
#: nominal mounting, every board's axes along its segment's (x distal, z palmar).  A real
#: board is off by a few degrees; :mod:`host.estimation.accel_calibration` measures that.
FINGER_ACCEL_AXES: Final[dict[str, tuple[Vec3, Vec3, Vec3]]] = {
    board: ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    for board in FINGER_ACCEL_SEGMENTS}
#: Accelerometer scale (counts per g of proper acceleration; the wire's mg): a board at rest
#: reads +1000 on its upward axis.
ACCEL_COUNTS_PER_G: Final = 1000.0


def accel_mount_rotation(board: str) -> np.ndarray:
    """``R`` (3×3) with ``v_segment = R · v_board`` for accelerometer ``board`` (``"fmcb"``,
    ``"f2"``, ``"f3"``): its axes as columns in its segment's frame."""
    return np.asarray(FINGER_ACCEL_AXES[board], dtype=float).T


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
#: Soft travel of the series-elastic elements each way (rad): the polyurethane tubes give
#: "around 4 degrees of compliance in each direction" (§5.4), then they are compressed solid.
SERIES_ELASTIC_TRAVEL_RAD: Final = math.radians(4.0)
#: Stiffness of the elements beyond their soft travel, as a multiple of the soft stiffness.
SERIES_ELASTIC_SOLID_STIFFNESS_FACTOR: Final = 10.0


def series_elastic_deflection(torque: float, stiffness: float,
                              travel: float = SERIES_ELASTIC_TRAVEL_RAD,
                              solid_factor: float = SERIES_ELASTIC_SOLID_STIFFNESS_FACTOR
                              ) -> float:
    """The deflection (rad) at which an element of soft ``stiffness`` (N·m/rad) carries
    ``torque`` (N·m) still: ``torque/stiffness`` within ``±travel`` (rad), ``solid_factor``
    times stiffer beyond (the tubes compressed solid)."""
    edge = stiffness * travel
    if torque > edge:
        return travel + (torque - edge) / (stiffness * solid_factor)
    if torque < -edge:
        return -travel + (torque + edge) / (stiffness * solid_factor)
    return torque / stiffness


def series_elastic_torque(deflection: float, stiffness: float,
                          travel: float = SERIES_ELASTIC_TRAVEL_RAD,
                          solid_factor: float = SERIES_ELASTIC_SOLID_STIFFNESS_FACTOR
                          ) -> float:
    """The torque (N·m) an element of soft ``stiffness`` (N·m/rad) carries still at
    ``deflection`` (rad): the inverse of :func:`series_elastic_deflection`."""
    beyond = max(0.0, deflection - travel) + min(0.0, deflection + travel)
    return stiffness * deflection + stiffness * (solid_factor - 1.0) * beyond

#: Stepper full steps per motor revolution (1.8° motors).
STEPPER_FULL_STEPS_PER_REV: Final = 200
#: Microsteps per full step of the stepper drivers (1/10 stepping): the base stepper then
#: commands 2π/(200·10·6) = 0.030° at J1, 0.54 mm at the outstretched flange (1.04 m), the
#: dissertation's "0.52 mm at the end effector" (§5.6; 16 gave 0.34 mm, 8 would give 0.68).
STEPPER_MICROSTEPPING: Final = 10
#: The stepper controllers' maximum step rate (microsteps/s): the step generator never runs
#: faster, and ``velocity_limit`` is capped to it.  The dissertation gives the end-effector
#: speed it allows (1.5 m/s, J2 lifting the outstretched arm, §5.6), not the rate: 4600
#: microsteps/s is 460 full steps/s, J2 at 1.445 rad/s, the flange at 1.04 m at 1.50 m/s.
STEPPER_MAX_STEP_RATE: Final = 4600
#: Torque constants of the steppers of J1..J4 at the motor shaft (N·m/A): holding torque at
#: standstill is ``k_T · I`` (NEMA-34 for J1/J2, NEMA-23 for J3/J4).  At the default run
#: and holding current (:data:`STEPPER_DEFAULT_CURRENT_MA`) the shoulder (J2) holds
#: 2.62·2·10 = 52.4 N·m and moves at most 52.4/1.6 = 32.75 N·m: the outstretched arm
#: (10.15 N·m), the elbow cables' reaction through the routes (0.18 × the elbow's torque)
#: and 2.0 kg at the flange (20.4 + 0.18·9.6 N·m), the dissertation's payload (§5.6); the
#: elbow (0.86·2·13/1.6 = 14.0 N·m moving) carries 2.0 kg outstretched (11.9 N·m) with a
#: margin, so the shoulder slips first.
STEPPER_TORQUE_CONSTANT_NM_PER_A: Final = (2.62, 2.62, 0.86, 0.86)
#: Holding torque over the maximum moving (pull-out) torque at the same current: "the
#: holding torque is approximately 60 % more than the maximum moving torque" (§5.3.2).
STEPPER_HOLDING_MARGIN: Final = 1.6
#: Corner of the steppers' pull-out curve (full steps/s): the maximum moving torque holds up
#: to it and then falls as ``corner / rate`` (constant power: the drivers' voltage can no
#: longer force the current into the windings).  At the controllers' maximum rate (J2: 460
#: full steps/s) the shoulder still moves 32.75·300/460 = 21.4 N·m, enough to lift the
#: unloaded outstretched arm; at twice that rate it could not.
STEPPER_PULL_OUT_CORNER_FULL_STEPS_PER_S: Final = 300.0
#: The stepper nodes' run and holding current at power-up (mA): equal, so the steppers hold
#: 1.6× their maximum moving torque at standstill, as the dissertation's controllers did.
STEPPER_DEFAULT_CURRENT_MA: Final = 2000
#: Joint encoder counts per joint revolution (0.036° per count).
ARM_ENCODER_COUNTS_PER_REV: Final = 10_000

# --- the stepper nodes' settling after a watchdog stop (firmware_py/stepper_settle.py) ------

#: Corrections a node makes at the turns of its link's swing after one watchdog stop.
STEPPER_SETTLE_CORRECTIONS: Final = 3
#: Encoder readings (1 ms ticks) in each least-squares fit of the link's motion.
STEPPER_SETTLE_WINDOW_TICKS: Final = 40
#: A predicted swing smaller than this (joint encoder counts) is left alone.
STEPPER_SETTLE_MIN_SWING_COUNTS: Final = 2.0
#: The most a correction moves the motor's goal from the watchdog's hold (joint counts; 40 = 1.44°).
STEPPER_SETTLE_MAX_CHANGE_COUNTS: Final = 40
#: ... and against the way the joint was going when the watchdog fired (joint counts; 0.36°):
#: a correction must not let a joint fall back.
STEPPER_SETTLE_MAX_BACK_COUNTS: Final = 10
#: Acceleration of a correcting move (joint encoder counts/s²); its speed is the node's
#: maximum step rate.
STEPPER_SETTLE_ACCEL_COUNTS_S2: Final = 20_000


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


def max_velocity_counts_per_s(joint: int) -> float:
    """Joint ``joint``'s (0..3) speed at the controllers' maximum step rate (encoder
    counts/s)."""
    return STEPPER_MAX_STEP_RATE / microsteps_per_encoder_count(joint)


def pull_out_fraction(full_steps_per_s: float) -> float:
    """The maximum moving torque available at a step rate (full steps/s, either sign), as a
    fraction of the low-speed maximum (:data:`STEPPER_PULL_OUT_CORNER_FULL_STEPS_PER_S`)."""
    rate = abs(full_steps_per_s)
    corner = STEPPER_PULL_OUT_CORNER_FULL_STEPS_PER_S
    return 1.0 if rate <= corner else corner / rate


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

# --- arm motion limits (every host-planned motion is checked against them) -----------------

#: The stepper nodes' ``acceleration_limit`` at power-up (joint encoder counts/s²; π rad/s²):
#: their motion profile brakes towards every goal at this rate.
STEPPER_DEFAULT_ACCEL_COUNTS_S2: Final = 5000
#: RX-64 speed at no load and 18 V (rad/s): 0.157 s per 60° on the datasheet.
RX64_NO_LOAD_SPEED_RAD_S: Final = math.radians(60.0) / 0.157
#: Each joint's speed limit (rad/s), J1..J7: a path needing more is refused, not clamped.
#: J1–J4 at the controllers' maximum step rate (:data:`STEPPER_MAX_STEP_RATE` through each
#: reduction: 2.41, 1.45, 1.11, 1.11), J5–J7 the RX-64's no-load speed.
ARM_JOINT_SPEED_LIMITS: Final[tuple[float, ...]] = tuple(
    [encoder_counts_to_rad(max_velocity_counts_per_s(j)) for j in range(ARM_STEPPER_JOINTS)]
    + [RX64_NO_LOAD_SPEED_RAD_S] * 3)
#: Each joint's acceleration limit (rad/s²), J1..J7.  J1–J4: what their nodes' motion profile
#: does (:data:`STEPPER_DEFAULT_ACCEL_COUNTS_S2`); a path asking more leaves the joint
#: trailing it, and the elastic joint ringing.  J5–J7: the RX-64 has no acceleration limit of
#: its own (it drives at full torque towards its setpoint); 10 rad/s² takes the wrist from
#: rest to 1 rad/s in 0.1 s, well within what its 6.3 N·m stall torque gives the 1 kg hand;
#: a step needing more is a jump, not a motion.
ARM_JOINT_ACCEL_LIMITS: Final[tuple[float, ...]] = (
    (encoder_counts_to_rad(STEPPER_DEFAULT_ACCEL_COUNTS_S2),) * ARM_STEPPER_JOINTS
    + (10.0,) * 3)

# --- arm geometry and routing (the emulator's model and the host's kinematics share them) --

#: Each arm joint's body origin in its parent body's frame at the kinematic zero (m), J1..J7:
#: base plate → J1 (link 1 frame, on the J1 axis) 0.16; link 1 → J2 axis 0.20; J2 → upper-arm
#: roll bearing 0.08; roll bearing → elbow axis 0.47 (J2 → elbow 0.55); elbow → forearm roll
#: bearing 0.08; forearm → wrist pitch axis 0.32 (elbow → wrist 0.40); wrist pitch → wrist
#: yaw 0.05.  At the kinematic zero every body frame is parallel to the base frame (``z`` up,
#: ``x`` forward) and the links hang along ``−z``.
ARM_JOINT_OFFSETS_M: Final[tuple[Vec3, ...]] = (
    (0.0, 0.0, 0.16), (0.0, 0.0, 0.20), (0.0, 0.0, -0.08), (0.0, 0.0, -0.47),
    (0.0, 0.0, -0.08), (0.0, 0.0, -0.32), (0.0, 0.0, -0.05))
#: The wrist flange's origin in the J7 body's frame (m): the flange face, 0.04 m past the
#: wrist yaw axis (the hand attaches there, its ``−z`` pointing away from the arm).
ARM_FLANGE_OFFSET_M: Final[Vec3] = (0.0, 0.0, -0.04)
#: The calibration probe (a rod bolted to the wrist flange instead of the hand, its tip a
#: hardened ball): the ball's centre in the flange frame (m), on the flange's axis, and the
#: ball's radius (m).  The touch calibration moves this point (``armctl calibrate``); the
#: emulator's ``calibration`` scene builds the probe from the same figures.
ARM_PROBE_TIP_M: Final[Vec3] = (0.0, 0.0, -0.06)
ARM_PROBE_BALL_RADIUS_M: Final = 0.003
#: How the hand sits on the wrist flange (the ``full`` robot): the palm frame's origin in the
#: flange frame (m), the palm's back face on the flange face, and the palm frame's
#: orientation there (quaternion w, x, y, z): half a turn about the flange's ``y``, so the
#: palmar face (palm ``+z``) looks away from the arm (flange ``−z``) and the fingers close
#: round an object in front of it; the fingers extend along the flange's ``+y``, the palm's
#: width (palm ``x``) runs along the flange's ``−x``.
HAND_ON_FLANGE_POSITION_M: Final[Vec3] = (0.0, 0.0, -PALM_HALF_EXTENTS_M[2])
HAND_ON_FLANGE_QUAT: Final[tuple[float, float, float, float]] = (0.0, 0.0, 1.0, 0.0)
#: Wrist tilts (J6, J7; rad, the other arm joints at 0) of the hanging ``full`` robot in which
#: the hand's fingers can be homed from their accelerometers, each with the fingers it serves:
#: hanging straight, every finger's J0 axis (and the thumb's) is near vertical, where gravity
#: says nothing about the joint's angle.
HOMING_WRIST_TILTS: Final[tuple[tuple[tuple[float, float], tuple[int, ...]], ...]] = (
    ((0.4, 0.9), (0, 1, 2)), ((0.6, 0.5), (3,)))


def hand_on_flange_rotation() -> np.ndarray:
    """The palm frame's axes in the flange frame (3×3, columns x, y, z;
    :data:`HAND_ON_FLANGE_QUAT`)."""
    w, x, y, z = HAND_ON_FLANGE_QUAT
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
#: Joint angle (rad) of each joint encoder's index mark, J1..J4, in the kinematic frame: the
#: homing search latches the encoder count there, which fixes the joint's absolute angle.
ARM_INDEX_ANGLES: Final[tuple[float, float, float, float]] = (0.06, 0.07, -0.05, 0.08)
#: The belt and cable routes' linear coupling of J1..J4 (rows: capstan J1..J4; columns:
#: joint J1..J4; rad of capstan per rad of joint, zero diagonal): the capstan of joint ``i``
#: turns by ``Σ_j C[i][j]·Δq_j`` besides its motor.  J2 shifts the J3 capstan by −0.12·Δq2
#: and the J4 capstan by +0.18·Δq2 (belts turning about the J2 axis); J3 shifts the J4
#: capstan by +0.08·Δq3 (elbow cables twisting in the roll shaft).  Representative values
#: (the dissertation calls the coupling purely linear and gives none); the host cancels it
#: with a feed-forward on the motor goals.
ARM_ROUTE_COUPLING: Final[tuple[tuple[float, float, float, float], ...]] = (
    (0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0),
    (0.0, -0.12, 0.0, 0.0),
    (0.0, 0.18, 0.08, 0.0))


def arm_route_coupling_matrix() -> np.ndarray:
    """``C`` (4×4, :data:`ARM_ROUTE_COUPLING`): capstan angles of J1..J4 move by ``C·Δq``."""
    return np.array(ARM_ROUTE_COUPLING, dtype=float)

# --- arm mass properties (the emulator's model and the host's gravity model share them) ----

#: Mass (kg) and centre of mass (m, in the body's own frame: the frame of the joint that
#: moves it, see :data:`ARM_JOINT_OFFSETS_M`) of what each joint J1..J7 turns, besides the
#: joints after it: link 1 (the shoulder housing with the two NEMA-23 steppers), the J2
#: capstan hub, the upper arm (tube and elbow capstan), the forearm's J5 bracket, the forearm
#: tube with the J6 servo, the J7 servo, the flange plate.  The emulator's MuJoCo model
#: (:mod:`hil_emulator.arm.model`) builds the same bodies from its parts; a test keeps the two
#: equal.  The base (5.5 kg with the NEMA-34 steppers) turns with no joint.
ARM_LINK_MASS_PROPERTIES: Final[tuple[tuple[float, Vec3], ...]] = (
    (3.9, (-0.06, 0.0, 0.09)),
    (0.325, (0.0, 0.0, -0.03)),
    (0.80, (0.0, 0.0, -0.31375)),
    (0.25, (0.0, 0.0, -0.05)),
    (0.40, (0.0, 0.0, -0.20875)),
    (0.15, (0.0, 0.0, -0.03)),
    (0.05, (0.0, 0.0, -0.02)))
#: The flange disc's mass (kg) and centre of mass in the flange frame (m).
ARM_FLANGE_MASS_PROPERTIES: Final[tuple[float, Vec3]] = (0.025, (0.0, 0.0, -0.002))
#: Principal moments of inertia (kg·m², about the centre of mass, along the body's own axes)
#: of the same bodies (:data:`ARM_LINK_MASS_PROPERTIES`): link 1 as measured, the others
#: uniform cylinders along each link (the emulator's model builds them from their parts; a
#: test keeps the two equal): the host's mass matrix of the arm (:mod:`host.arm.dynamics`).
ARM_LINK_INERTIAS_KGM2: Final[tuple[Vec3, ...]] = (
    (0.019, 0.021, 0.024),
    (0.000376458333, 0.000376458333, 0.00040625),
    (0.0187254167, 0.0187254167, 0.0006),
    (0.000172395833, 0.000172395833, 7.8125e-05),
    (0.0035528125, 0.0035528125, 9.6875e-05),
    (5.46875e-05, 5.46875e-05, 4.6875e-05),
    (1.5e-05, 1.5e-05, 2.25e-05))
#: The flange disc's principal moments of inertia (kg·m², flange axes).
ARM_FLANGE_INERTIA_KGM2: Final[Vec3] = (1.00333333e-05, 1.00333333e-05, 2e-05)
#: The output hub of each series-elastic joint J1..J4 (capstan bearing, cable pulleys riding
#: along) as an inertia about the joint's axis (kg·m², MuJoCo's armature): the capstans
#: themselves are on the motor side of the spring.
STEPPER_HUB_ARMATURE_KGM2: Final[tuple[float, float, float, float]] = (0.004, 0.004, 0.004,
                                                                        0.002)
#: The hand's mass (kg: palm, four finger modules and their boards) and its centre of mass
#: in the flange frame (m) when mounted as :data:`HAND_ON_FLANGE_POSITION_M` /
#: :data:`HAND_ON_FLANGE_QUAT` say, the fingers extended (every finger joint at 0; curling
#: them moves it by a few millimetres).
HAND_MASS_KG: Final = 0.83
HAND_COM_ON_FLANGE_M: Final[Vec3] = (-0.00468, 0.01988, -0.01618)
