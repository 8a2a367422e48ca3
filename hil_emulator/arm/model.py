"""The 7-DOF compliant arm's MuJoCo model, built procedurally with :class:`mujoco.MjSpec`.

After the arm of the dissertation's chapter 5 (table 5.1): about 1.0 m from the shoulder-lift
axis to the wrist flange, 11.4 kg in all, 2.0 kg *flying mass* below the shoulder-lift joint
J2.  The stepper motors (two NEMA-34 for J1/J2, grounded in the base; two NEMA-23 for J3/J4,
riding on link 1) and their belts are not bodies of their own: their mass is lumped into
``base`` and ``link1``; what they drive (through the series-elastic couplings) is modelled by
:class:`hil_emulator.arm.plant.ArmPlant`.

Frames (right-handed; m, kg, rad).  The **base frame** is the ``parent`` body's frame moved
by ``pos``/``quat``: ``z`` up, ``x`` forward (the direction the arm reaches when J2 lifts it).
The **kinematic zero** (every joint angle 0) is the arm *hanging straight down* from the
shoulder, elbow straight, wrist aligned; each link body's frame is then parallel to the base
frame, with the link extending along its ``−z``.

=====  ===================  =============  ===========================================
joint  name                 axis (body)    positive direction at the kinematic zero
=====  ===================  =============  ===========================================
J1     shoulder pan (yaw)   ``+z``         counter-clockwise seen from above
J2     shoulder lift        ``−y``         swings the arm forward (``+x``) and up
J3     upper-arm roll       ``+z``         along the upper arm (counter-clockwise from below)
J4     elbow                ``−y``         bends the forearm forward/up
J5     forearm roll (RX-64) ``+z``         along the forearm
J6     wrist pitch (RX-64)  ``−y``         tips the flange forward
J7     wrist yaw (RX-64)    ``+x``         tips the flange sideways (towards ``−y``)
=====  ===================  =============  ===========================================

Bodies (``prefix`` + name): ``base`` (welded to ``parent``), ``link1`` (J1), ``shoulder``
(J2), ``upper_arm`` (J3), ``forearm`` (J4, carries the J5 servo), ``forearm_roll`` (J5,
carries the J6 servo), ``wrist`` (J6, carries the J7 servo), ``wrist_yaw`` (J7) and
``flange`` (no joint; site ``flange``): attach the hand there (its ``−z`` points away from
the arm).  Distances: base plate → J2 axis 0.36 m, J2 → elbow 0.55 m, elbow → wrist pitch
0.40 m, wrist pitch → flange 0.09 m.  Inertias are explicit (uniform cylinders along each
link); the forearm's inertia about the elbow axis is the dissertation's 0.083 kg·m² (so the
elbow's 86 N·m/rad coupling gives f0 ≈ 5.1 Hz).

**Start pose.**  ``start_pose`` (7 angles, rad; default :data:`DEFAULT_START_POSE`, the
kinematic zero) becomes each joint's ``ref``, i.e. ``model.qpos0``: a fresh ``MjData`` is in
the start pose, and :class:`~hil_emulator.arm.plant.ArmPlant` takes it as the power-up pose
(encoder counts 0 there).  The hanging default is gravity-neutral, so the arm holds still
there even before the firmware energises the steppers (they power up with torque off).  The
flange hangs 1.04 m below the J2 axis, 0.68 m below the base plate, and the hand below it:
mount the base plate :data:`MOUNT_HEIGHT_M` (1.0 m) or more above the floor (a pedestal or
table-edge mount), or pass another start pose and enable the steppers' torque promptly
(with torque off the arm falls).

Contacts: arm geoms have ``contype = 0, conaffinity = 1``: they touch the floor and objects
(``contype = 1``) but neither each other nor the hand (hand geoms have ``contype = 2``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import mujoco
import numpy as np

from hil_emulator.errors import EmulatorConfigError
from protocol.robot import (
    ARM_FLANGE_OFFSET_M,
    ARM_JOINT_AXES,
    ARM_JOINT_LIMITS,
    ARM_JOINT_NAMES,
    ARM_JOINT_OFFSETS_M,
    ARM_LINK_INERTIAS_KGM2,
    STEPPER_HUB_ARMATURE_KGM2,
)

Vec3 = tuple[float, float, float]

#: Joint names (without prefix), proximal first (:data:`protocol.robot.ARM_JOINT_NAMES`).
#: J1–J4 are stepper-driven series-elastic joints, J5–J7 RX-64 servos.
ARM_JOINTS: Final = ARM_JOINT_NAMES
#: The kinematic zero: hanging straight down (rad).
DEFAULT_START_POSE: Final = (0.0,) * 7
#: Height of the base plate above the floor (m) at which the hanging arm with a hand of
#: ~0.2 m clears the floor by ~10 cm.
MOUNT_HEIGHT_M: Final = 1.0

#: Joint axes in each joint's body frame (:data:`protocol.robot.ARM_JOINT_AXES`).
JOINT_AXES: Final = ARM_JOINT_AXES
#: Joint ranges (rad): the mechanical stops (:data:`protocol.robot.ARM_JOINT_LIMITS`).
JOINT_RANGES: Final = ARM_JOINT_LIMITS

# --- geometry (m): protocol.robot.ARM_JOINT_OFFSETS_M; the two lengths the geoms need ------
J3_TO_ELBOW: Final = -ARM_JOINT_OFFSETS_M[3][2]     # roll bearing → elbow axis
J5_TO_WRIST: Final = -ARM_JOINT_OFFSETS_M[5][2]     # forearm tube → wrist pitch axis

# --- masses (kg): 5.5 + 3.9 grounded/link 1, 2.0 flying below J2; 11.4 in all ---------------
BASE_MASS: Final = 5.5          # plywood base + the two NEMA-34 steppers and their belts
LINK1_MASS: Final = 3.9         # shoulder housing + the two NEMA-23 steppers, pulleys
SHOULDER_MASS: Final = 0.325    # J2 capstan hub and bracket
UPPER_ARM_TUBE_MASS: Final = 0.50
ELBOW_CAPSTAN_MASS: Final = 0.30
RX64_MASS: Final = 0.125        # one RX-64 servo
SERVO_BRACKET_MASS: Final = 0.025
FOREARM_BRACKET_MASS: Final = 0.125
FOREARM_TUBE_MASS: Final = 0.25
FLANGE_PLATE_MASS: Final = 0.05
FLANGE_MASS: Final = 0.025

#: RX-64 rotor inertia reflected through its 200:1 gearing (kg·m²): ~9e-8 × 200².
RX64_ARMATURE: Final = 0.0036
#: RX-64 gear train: viscous (N·m·s/rad) and Coulomb (N·m) friction at the output.
RX64_GEAR_DAMPING: Final = 0.05
RX64_GEAR_FRICTION_NM: Final = 0.3
#: Impedance of the friction constraints: close to hard, so the geared servo holds at rest.
FRICTION_SOLIMP: Final = (0.998, 0.9995, 0.001, 0.5, 2.0)
#: Output hub of the series-elastic joints J1–J4 (capstan bearing, cable pulleys riding
#: along), as armature (kg·m²; :data:`protocol.robot.STEPPER_HUB_ARMATURE_KGM2`); the
#: capstans themselves are on the motor side of the spring.
SEA_HUB_ARMATURE: Final = STEPPER_HUB_ARMATURE_KGM2

#: Contact bits of arm geoms (see the module docstring).
ARM_CONTYPE: Final = 0
ARM_CONAFFINITY: Final = 1

_LINK_RGBA: Final = (0.75, 0.62, 0.45, 1.0)   # plywood
_METAL_RGBA: Final = (0.6, 0.6, 0.65, 1.0)
_SERVO_RGBA: Final = (0.15, 0.15, 0.15, 1.0)


@dataclass(frozen=True)
class Cylinder:
    """A uniform solid cylinder on a body's ``z`` axis (centre ``z_m``), for inertia sums."""

    mass_kg: float
    z_m: float
    length_m: float
    radius_m: float


def axial_inertial(parts: Sequence[Cylinder]) -> tuple[float, float, Vec3]:
    """Mass (kg), centre of mass ``z`` (m) and principal inertia about it (kg·m², body axes)
    of cylinders stacked on the body's ``z`` axis."""
    mass = sum(p.mass_kg for p in parts)
    zc = sum(p.mass_kg * p.z_m for p in parts) / mass
    perp = sum(p.mass_kg * ((3 * p.radius_m ** 2 + p.length_m ** 2) / 12 + (p.z_m - zc) ** 2)
               for p in parts)
    axial = sum(p.mass_kg * p.radius_m ** 2 / 2 for p in parts)
    return mass, zc, (perp, perp, axial)


#: Each moving body's mass parts (in its own frame, z ≤ 0 along the link).
LINK_PARTS: Final[dict[str, tuple[Cylinder, ...]]] = {
    "shoulder": (Cylinder(SHOULDER_MASS, -0.03, 0.08, 0.05),),
    "upper_arm": (Cylinder(UPPER_ARM_TUBE_MASS, -0.22, 0.40, 0.03),
                  Cylinder(ELBOW_CAPSTAN_MASS, -J3_TO_ELBOW, 0.04, 0.05)),
    "forearm": (Cylinder(FOREARM_BRACKET_MASS + RX64_MASS, -0.05, 0.08, 0.025),),
    "forearm_roll": (Cylinder(FOREARM_TUBE_MASS, -0.16, 0.30, 0.02),
                     Cylinder(RX64_MASS + SERVO_BRACKET_MASS, -0.29, 0.06, 0.025)),
    "wrist": (Cylinder(RX64_MASS + SERVO_BRACKET_MASS, -0.03, 0.05, 0.025),),
    "wrist_yaw": (Cylinder(FLANGE_PLATE_MASS, -0.02, 0.03, 0.03),),
    "flange": (Cylinder(FLANGE_MASS, -0.002, 0.004, 0.04),),
}


def _rotate_quat(quat: Sequence[float], axis: Vec3, angle: float) -> list[float]:
    """``quat ⊗ rotation(axis, angle)``: a body frame turned about its own ``axis``."""
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.asarray(axis, dtype=float), float(angle))
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(quat, dtype=float), turn)
    return [float(v) for v in out]


def _add_inertial(body: mujoco.MjsBody, parts: Sequence[Cylinder]) -> None:
    mass, zc, inertia = axial_inertial(parts)
    body.mass = mass
    body.ipos = [0.0, 0.0, zc]
    body.inertia = list(inertia)
    body.explicitinertial = True


def _geom(body: mujoco.MjsBody, name: str, gtype: mujoco.mjtGeom, size: Sequence[float],
          rgba: Sequence[float], pos: Vec3 = (0.0, 0.0, 0.0),
          fromto: Sequence[float] | None = None, quat: Sequence[float] | None = None) -> None:
    g = body.add_geom(name=name, type=gtype, size=list(size), rgba=list(rgba))
    if fromto is not None:
        g.fromto = list(fromto)
    else:
        g.pos = list(pos)
    if quat is not None:
        g.quat = list(quat)
    g.contype = ARM_CONTYPE
    g.conaffinity = ARM_CONAFFINITY
    g.mass = 0.0  # inertia is explicit (see _add_inertial)


_Y_CYLINDER: Final = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # cylinder axis z → y
_X_CYLINDER: Final = (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)  # cylinder axis z → x


def add_arm(spec: mujoco.MjSpec, parent: mujoco.MjsBody, prefix: str = "arm/",
            pos: Sequence[float] = (0.0, 0.0, 0.0),
            quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
            start_pose: Sequence[float] | None = None) -> mujoco.MjsBody:
    """Add the arm under ``parent`` (base frame at ``pos``/``quat`` in the parent's frame) and
    return the wrist flange body (where the ~1 kg hand attaches).  Joints are named
    ``f"{prefix}J1"`` … ``f"{prefix}J7"``; ``start_pose`` (rad, 7) becomes ``qpos0``.

    J1–J4 get no stiffness or damping here: the plant part
    (:class:`~hil_emulator.arm.plant.ArmPlant`) sets the series-elastic couplings' values in
    ``bind`` from its parameters.  J5–J7 carry the RX-64s' reflected rotor inertia
    (armature) and gear friction.
    """
    pose = tuple(float(a) for a in (DEFAULT_START_POSE if start_pose is None else start_pose))
    if len(pose) != len(ARM_JOINTS):
        raise EmulatorConfigError(f"the arm's start pose needs {len(ARM_JOINTS)} joint angles, "
                                  f"got {len(pose)}")
    for name, angle, (lo, hi) in zip(ARM_JOINTS, pose, JOINT_RANGES, strict=True):
        if not lo <= angle <= hi:
            raise EmulatorConfigError(f"start angle {angle:.3f} rad of {name} is outside its "
                                      f"range [{lo}, {hi}]")

    base = parent.add_body(name=f"{prefix}base", pos=list(pos), quat=list(quat))
    base.mass = BASE_MASS
    base.ipos = [-0.04, 0.0, 0.07]
    base.inertia = [0.035, 0.045, 0.062]
    base.explicitinertial = True
    _geom(base, f"{prefix}base_box", mujoco.mjtGeom.mjGEOM_BOX, (0.14, 0.12, 0.07),
          _LINK_RGBA, pos=(-0.03, 0.0, 0.07))

    joint_index = iter(range(len(ARM_JOINTS)))
    unit = math.degrees(1.0) if spec.compiler.degree else 1.0  # MjSpec defaults to degrees

    def link(holder: mujoco.MjsBody, name: str) -> mujoco.MjsBody:
        """A child body carrying the next joint at its offset
        (:data:`protocol.robot.ARM_JOINT_OFFSETS_M`), turned to its start angle."""
        i = next(joint_index)
        offset = ARM_JOINT_OFFSETS_M[i]
        axis = JOINT_AXES[i]
        body = holder.add_body(name=f"{prefix}{name}", pos=list(offset),
                               quat=_rotate_quat((1.0, 0.0, 0.0, 0.0), axis, pose[i]))
        joint = body.add_joint(name=f"{prefix}{ARM_JOINTS[i]}",
                               type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis))
        joint.ref = unit * pose[i]
        joint.springref = unit * pose[i]
        joint.range = [unit * a for a in JOINT_RANGES[i]]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        if i < 4:
            joint.armature = SEA_HUB_ARMATURE[i]
        else:
            joint.armature = RX64_ARMATURE
            joint.damping = [RX64_GEAR_DAMPING, 0.0, 0.0]
            joint.frictionloss = RX64_GEAR_FRICTION_NM
            joint.solimp_friction = list(FRICTION_SOLIMP)
        return body

    link1 = link(base, "link1")
    link1.mass = LINK1_MASS
    link1.ipos = [-0.06, 0.0, 0.09]
    link1.inertia = list(ARM_LINK_INERTIAS_KGM2[0])
    link1.explicitinertial = True
    _geom(link1, f"{prefix}link1_box", mujoco.mjtGeom.mjGEOM_BOX, (0.10, 0.09, 0.08),
          _LINK_RGBA, pos=(-0.04, 0.0, 0.09))

    shoulder = link(link1, "shoulder")
    _add_inertial(shoulder, LINK_PARTS["shoulder"])
    _geom(shoulder, f"{prefix}shoulder_capstan", mujoco.mjtGeom.mjGEOM_CYLINDER, (0.05, 0.05),
          _LINK_RGBA, quat=_Y_CYLINDER)

    upper = link(shoulder, "upper_arm")
    _add_inertial(upper, LINK_PARTS["upper_arm"])
    _geom(upper, f"{prefix}upper_arm_tube", mujoco.mjtGeom.mjGEOM_CAPSULE, (0.03,),
          _LINK_RGBA, fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -J3_TO_ELBOW + 0.05))
    _geom(upper, f"{prefix}elbow_capstan", mujoco.mjtGeom.mjGEOM_CYLINDER, (0.05, 0.03),
          _LINK_RGBA, pos=(0.0, 0.0, -J3_TO_ELBOW), quat=_Y_CYLINDER)

    forearm = link(upper, "forearm")
    _add_inertial(forearm, LINK_PARTS["forearm"])
    _geom(forearm, f"{prefix}J5_servo", mujoco.mjtGeom.mjGEOM_BOX, (0.02, 0.02, 0.035),
          _SERVO_RGBA, pos=(0.0, 0.0, -0.045))

    roll = link(forearm, "forearm_roll")
    _add_inertial(roll, LINK_PARTS["forearm_roll"])
    _geom(roll, f"{prefix}forearm_tube", mujoco.mjtGeom.mjGEOM_CAPSULE, (0.02,),
          _METAL_RGBA, fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -J5_TO_WRIST + 0.06))
    _geom(roll, f"{prefix}J6_servo", mujoco.mjtGeom.mjGEOM_BOX, (0.02, 0.035, 0.025),
          _SERVO_RGBA, pos=(0.0, 0.0, -0.29))

    wrist = link(roll, "wrist")
    _add_inertial(wrist, LINK_PARTS["wrist"])
    _geom(wrist, f"{prefix}J7_servo", mujoco.mjtGeom.mjGEOM_BOX, (0.035, 0.02, 0.025),
          _SERVO_RGBA, pos=(0.0, 0.0, -0.03))

    yaw = link(wrist, "wrist_yaw")
    _add_inertial(yaw, LINK_PARTS["wrist_yaw"])
    _geom(yaw, f"{prefix}flange_plate", mujoco.mjtGeom.mjGEOM_CYLINDER, (0.03, 0.015),
          _METAL_RGBA, pos=(0.0, 0.0, -0.02), quat=_X_CYLINDER)

    flange = yaw.add_body(name=f"{prefix}flange", pos=list(ARM_FLANGE_OFFSET_M))
    _add_inertial(flange, LINK_PARTS["flange"])
    flange.add_site(name=f"{prefix}flange", pos=[0.0, 0.0, 0.0], size=[0.01, 0.0, 0.0])
    return flange
