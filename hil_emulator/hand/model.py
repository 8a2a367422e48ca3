"""The hand's MuJoCo model, built procedurally with :class:`mujoco.MjSpec`.

Frames (all right-handed, SI units: m, kg, rad):

- **Palm frame**: origin at the centre of the palm box (100 × 90 × 25 mm, 300 g); ``x``
  across the palm (width), ``y`` along it towards the fingers' side, ``z`` out of the palmar
  face (the palmar face is at ``z = +12.5 mm``, where the palm's tactile pad lies).
- **Finger module frame** (body ``F0``, the motor module): origin on the J1 axis; ``x``
  along the extended finger (distal), ``z`` the palmar side of the phalanges (pads face
  ``+z``, flexion moves the tip towards ``+z``), ``y = z × x``.  The motor module box lies
  behind the origin (``x`` from −40 mm to 0).  F1, F2, F3 share that orientation at zero
  joint angles; each board's accelerometer site (fmcb on F0, f2 on F2, f3 on F3) is turned
  by :func:`protocol.robot.accel_mount_rotation` (nominally none: its body's frame).

Kinematics of a module: J1 (F0–F1) about ``+z`` (abduction / base rotation), J2 (F1–F2,
18 mm further) and J3 (F2–F3, at the end of the 45 mm F2) about ``−y``, so a positive angle
flexes the finger.  Joint order J1, J2, J3 is the firmware's J0, J1, J2.

Motors: each of the three motors is a *fixed tendon* whose length is the motor shaft angle
(rad) ``θ_m = M_rad · q`` with ``M_rad = M / K`` (the robot's coupling matrix,
:func:`protocol.robot.finger_coupling_matrix`, over K = 36/2π hall states per rad).  The
tendon carries the rotor inertia as tendon *armature* (so the reflected inertia is the full
``M_radᵀ J_rotor M_rad``) and the motor-side friction as tendon *frictionloss*; a general
actuator on the tendon (``ctrl`` = PWM duty, −1..1) produces the motor torque

    τ_m = k_t · i,   i = (duty·V − k_e·ω_m) / R   limited to I_max in the driven direction

(gain ``k_t·V/R``, affine velocity bias ``−k_t·k_e/R``, force range ``±k_t·I_max`` as
built; :class:`~hil_emulator.hand.finger_plant.FingerPlant` narrows it to the driven side each
tick, since the bridge's chopper does not limit braking current), which MuJoCo maps to the
joints by virtual work, ``τ_joint = M_radᵀ τ_m``.  The back-EMF term is a
stiff damping (mechanical time constant J_rotor·R/k² ≈ 0.16 ms), so :func:`add_hand` and
:func:`add_finger` switch the spec to the ``implicitfast`` integrator, which integrates
actuator velocity terms implicitly.

Contacts: hand geoms have ``contype = 2, conaffinity = 1``; objects from
:func:`add_grasp_object` have ``contype = 1, conaffinity = 3``.  So the hand touches objects
and the floor (``contype = conaffinity = 1``) but never itself: fingers pass through each
other and the palm (no self-collision; documented simplification).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import mujoco
import numpy as np

from hil_emulator.errors import EmulatorConfigError
from protocol.robot import (
    DEFAULT_HAND_LAYOUT,
    FINGER_JOINT_AXES,
    FINGER_JOINT_STOPS,
    FINGER_LINK_LENGTHS_M,
    HAND_LAYOUTS,
    PALM_HALF_EXTENTS_M,
    accel_mount_rotation,
    finger_coupling_matrix_rad,
)

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Mount = tuple[Vec3, Quat]

#: Contact bits of hand geoms and of graspable objects (see the module docstring).
HAND_CONTYPE: Final = 2
HAND_CONAFFINITY: Final = 1
OBJECT_CONTYPE: Final = 1
OBJECT_CONAFFINITY: Final = 3

# --- palm geometry (m, kg) ----------------------------------------------------------------------
PALM_HALF: Final = PALM_HALF_EXTENTS_M
PALM_MASS_KG: Final = 0.30
PAD_HALF_THICKNESS: Final = 0.0015
PALM_PAD_Z: Final = PALM_HALF[2] + PAD_HALF_THICKNESS

# --- finger geometry (m, kg), in each body's frame -----------------------------------------------
F0_HALF: Final = (0.020, 0.012, 0.012)   # motor module, centred at x = −20 mm
F0_MASS_KG: Final = 0.085
F1_LENGTH: Final = FINGER_LINK_LENGTHS_M[0]  # J1 → J2
F1_MASS_KG: Final = 0.010
F2_LENGTH: Final = FINGER_LINK_LENGTHS_M[1]  # J2 → J3
F2_HALF_WIDTH: Final = 0.010
F2_HALF_THICK: Final = 0.008
F2_MASS_KG: Final = 0.018
F3_LENGTH: Final = FINGER_LINK_LENGTHS_M[2]  # J3 → tip
F3_HALF_WIDTH: Final = 0.009
F3_HALF_THICK: Final = 0.007
F3_MASS_KG: Final = 0.012
PAD_MASS_KG: Final = 0.002
#: Height of the pad surfaces above each body's x axis (m, along +z).
F2_PAD_Z: Final = F2_HALF_THICK + PAD_HALF_THICKNESS
F3_PAD_Z: Final = F3_HALF_THICK + PAD_HALF_THICKNESS
#: The strain gauge sits at the middle of F2 (body frame, m).
GAUGE_POS: Final = (F2_LENGTH / 2, 0.0, 0.0)
#: Joint ranges of the model (rad): the mechanical stops, a little beyond the firmware's
#: default limits.
JOINT_RANGES: Final = FINGER_JOINT_STOPS
JOINT_DAMPING: Final = 0.002             # N·m·s/rad, bearing losses at each joint
PAD_FRICTION: Final = (1.0, 0.005, 0.0001)
#: Impedance of the motors' friction constraints: close to hard, so a gearbox at rest holds
#: the finger against gravity (creep < 1e-4 rad/s) instead of MuJoCo's default soft slip.
FRICTION_SOLIMP: Final = (0.998, 0.9995, 0.001, 0.5, 2.0)


def _grid(xs: tuple[float, ...], ys: tuple[float, ...]) -> tuple[tuple[float, float], ...]:
    """Taxel centres (x, y) row by row along x, ``len(ys)`` taxels across per row."""
    return tuple((x, y) for x in xs for y in ys)


#: Taxel centres on each pad (m, body frame x, y; the pad surface is at the segment's pad z).
#: Index = row (along the finger, proximal first) · taxels-across + column (−y first).
F2_TAXELS: Final = _grid((0.010, 0.0225, 0.035), (-0.0045, 0.0045))
F3_TAXELS: Final = _grid((0.006, 0.0145, 0.023, 0.0315), (-0.005, 0.0, 0.005))
#: Palm taxels: 8 rows along y (proximal first) × 4 across x.
PALM_TAXELS: Final = _grid(tuple(-0.04 + i * 0.08 / 7 for i in range(8)),
                           (-0.03, -0.01, 0.01, 0.03))


@dataclass(frozen=True)
class MotorConstants:
    """One finger motor behind its L6229-like bridge (SI units, motor side).

    ``supply_v`` across the bridge at duty 1; ``resistance_ohm`` winding + bridge;
    ``ke_v_s_per_rad`` back-EMF constant, equal to the torque constant in N·m/A;
    ``current_limit_a`` the bridge's current limit (sense-resistor chopping);
    ``rotor_inertia_kg_m2`` rotor + pinion; ``friction_nm`` motor-side Coulomb friction
    (gearbox and capstan losses referred to the shaft).

    The fmcb reads the halls once per millisecond and its
    :class:`~firmware_py.fmcb_control.HallCounter` only counts a step to a *neighbouring*
    state (a jump of two is rejected as invalid), so a shaft must turn less than one hall
    state (2π/36 rad) per millisecond: below 174.5 rad/s.  The defaults give a no-load speed
    of 12 V / 0.08 V·s/rad = 150 rad/s, i.e. 0.86 hall states per millisecond, which leaves
    margin for overshoot and back-driving.  Stall torque is set by the bridge's current limit:
    0.08 N·m/A × 0.15 A = 12 mN·m at the shaft, ≈ 2.8 N·m at J3 through the 231:1 reduction.
    """

    supply_v: float = 12.0
    resistance_ohm: float = 2.0
    ke_v_s_per_rad: float = 0.08
    current_limit_a: float = 0.15
    rotor_inertia_kg_m2: float = 5.0e-7
    friction_nm: float = 1.0e-3

    @property
    def no_load_speed_rad_s(self) -> float:
        """Motor shaft speed at duty 1 and no load (rad/s)."""
        return self.supply_v / self.ke_v_s_per_rad

    @property
    def gain_nm_per_duty(self) -> float:
        """Stall torque per unit duty before the current limit (N·m)."""
        return self.ke_v_s_per_rad * self.supply_v / self.resistance_ohm

    @property
    def emf_damping_nm_s(self) -> float:
        """Back-EMF damping with the winding shorted through the bridge (N·m·s/rad)."""
        return self.ke_v_s_per_rad ** 2 / self.resistance_ohm

    @property
    def torque_limit_nm(self) -> float:
        """Torque at the current limit (N·m)."""
        return self.ke_v_s_per_rad * self.current_limit_a


DEFAULT_MOTOR: Final = MotorConstants()


def motor_coupling_rad() -> np.ndarray:
    """``M_rad`` (3×3): motor shaft angles (rad) per joint angle (rad), ``θ_m = M_rad·q``."""
    return finger_coupling_matrix_rad()


@dataclass(frozen=True)
class FingerNames:
    """Names of one finger module's model elements, all starting with ``prefix``."""

    prefix: str

    def body(self, segment: str) -> str:
        """Body ``"F0"`` … ``"F3"``."""
        return f"{self.prefix}{segment}"

    def joint(self, j: int) -> str:
        """Joint J1..J3 by firmware index 0..2."""
        return f"{self.prefix}J{j + 1}"

    def motor(self, i: int) -> str:
        """Tendon and actuator of motor ``i`` (0..2)."""
        return f"{self.prefix}motor{i}"

    def pad(self, segment: str) -> str:
        """Tactile pad geom of ``"F1"``, ``"F2"`` or ``"F3"``."""
        return f"{self.prefix}{segment}_pad"

    def imu_site(self, board: str) -> str:
        """IMU site of board ``"fmcb"``, ``"f2"`` or ``"f3"``."""
        return f"{self.prefix}{board}_imu"

    def accel_sensor(self, board: str) -> str:
        """Accelerometer sensor of board ``"fmcb"``, ``"f2"`` or ``"f3"``."""
        return f"{self.prefix}{board}_accel"

    def mag_sensor(self, board: str) -> str:
        """Magnetometer sensor of board ``"fmcb"``, ``"f2"`` or ``"f3"``."""
        return f"{self.prefix}{board}_mag"

    @property
    def gauge_site(self) -> str:
        """The strain gauge's site on F2."""
        return f"{self.prefix}f2_gauge"


@dataclass(frozen=True)
class PalmNames:
    """Names of the palm's model elements (``prefix`` is the hand's prefix)."""

    prefix: str

    @property
    def body(self) -> str:
        return f"{self.prefix}palm"

    @property
    def pad(self) -> str:
        return f"{self.prefix}palm_pad"

    @property
    def imu_site(self) -> str:
        return f"{self.prefix}palm_imu"

    @property
    def accel_sensor(self) -> str:
        return f"{self.prefix}palm_accel"

    @property
    def gyro_sensor(self) -> str:
        return f"{self.prefix}palm_gyro"

    @property
    def mag_sensor(self) -> str:
        return f"{self.prefix}palm_mag"


# --- layouts ------------------------------------------------------------------------------------
def _quat_from_axes(x_axis: Vec3, z_axis: Vec3) -> Quat:
    """Quaternion (w, x, y, z) of the frame whose x and z axes are given (z re-orthogonalised)."""
    x = np.asarray(x_axis, dtype=float)
    x /= np.linalg.norm(x)
    z = np.asarray(z_axis, dtype=float)
    z = z - x * float(x @ z)
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    mat = np.column_stack((x, y, z)).ravel()
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat)
    w, qx, qy, qz = (round(float(v), 12) for v in quat)
    return (w, qx, qy, qz)


@dataclass(frozen=True)
class HandLayout:
    """A hand frame: where each of the four finger modules' F0 frame sits in the palm frame.

    ``mounts[k]`` = (position m, quaternion w x y z) of finger ``k``'s F0 frame.
    """

    name: str
    mounts: tuple[Mount, ...]

    def __post_init__(self) -> None:
        if len(self.mounts) != 4:
            raise EmulatorConfigError(f"layout {self.name!r} has {len(self.mounts)} mounts, "
                                      "not 4")


#: The hand frames of :data:`protocol.robot.HAND_LAYOUTS`, as MuJoCo mounts.
LAYOUTS: Final[dict[str, HandLayout]] = {
    name: HandLayout(name, tuple((m.position_m, _quat_from_axes(m.x_axis, m.z_axis))
                                 for m in layout.mounts))
    for name, layout in HAND_LAYOUTS.items()
}
DEFAULT_LAYOUT: Final = DEFAULT_HAND_LAYOUT


# --- builders -----------------------------------------------------------------------------------
def use_implicit_integrator(spec: mujoco.MjSpec) -> None:
    """Switch an explicit-Euler or RK4 spec to ``implicitfast`` (motor back-EMF is stiff)."""
    if spec.option.integrator in (mujoco.mjtIntegrator.mjINT_EULER,
                                  mujoco.mjtIntegrator.mjINT_RK4):
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST


def _joint_range(spec: mujoco.MjSpec, j: int) -> list[float]:
    """Joint ``j``'s range in the spec's angle unit (MjSpec defaults to degrees)."""
    lo, hi = JOINT_RANGES[j]
    if spec.compiler.degree:
        return [math.degrees(lo), math.degrees(hi)]
    return [lo, hi]


def _hand_geom(body: mujoco.MjsBody, name: str, pos: Vec3, half: Vec3, mass: float,
               rgba: tuple[float, float, float, float]) -> mujoco.MjsGeom:
    return body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, pos=list(pos),
                         size=list(half), mass=mass, rgba=list(rgba),
                         contype=HAND_CONTYPE, conaffinity=HAND_CONAFFINITY,
                         friction=list(PAD_FRICTION))


_LINK_RGBA = (0.25, 0.25, 0.28, 1.0)
_PAD_RGBA = (0.05, 0.05, 0.05, 1.0)
_MOTOR_RGBA = (0.7, 0.7, 0.72, 1.0)


def _accel_quat(board: str) -> list[float]:
    """Site quaternion (w, x, y, z) of ``board``'s accelerometer in its segment's frame
    (:func:`protocol.robot.accel_mount_rotation`)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, accel_mount_rotation(board).ravel())
    return [float(v) for v in quat]


def add_finger(spec: mujoco.MjSpec, parent: mujoco.MjsBody, prefix: str,
               pos: Vec3 = (0.0, 0.0, 0.0), quat: Quat = (1.0, 0.0, 0.0, 0.0),
               motor: MotorConstants = DEFAULT_MOTOR) -> mujoco.MjsBody:
    """One finger module (F0 welded to ``parent`` at ``pos``/``quat``); returns its F0 body.

    Adds bodies F0..F3, joints J1..J3, tendons and actuators ``motor0..2``, pads on F2 and
    F3 (and a small one on F1), IMU sites with accelerometers and magnetometers for the
    fmcb/f2/f3 boards, and the strain gauge site; every name starts with ``prefix`` (e.g. ``"hand/finger0/"``).
    """
    names = FingerNames(prefix)
    use_implicit_integrator(spec)
    f0 = parent.add_body(name=names.body("F0"), pos=list(pos), quat=list(quat))
    _hand_geom(f0, f"{prefix}F0_motors", (-F0_HALF[0], 0.0, 0.0), F0_HALF, F0_MASS_KG,
               _MOTOR_RGBA)
    f0.add_site(name=names.imu_site("fmcb"), pos=[-F0_HALF[0], 0.0, 0.0],
                quat=_accel_quat("fmcb"))

    f1 = f0.add_body(name=names.body("F1"))
    f1.add_joint(name=names.joint(0), type=mujoco.mjtJoint.mjJNT_HINGE,
                 axis=list(FINGER_JOINT_AXES[0]), range=_joint_range(spec, 0),
                 limited=mujoco.mjtLimited.mjLIMITED_TRUE, damping=JOINT_DAMPING)
    _hand_geom(f1, f"{prefix}F1_link", (F1_LENGTH / 2, 0.0, 0.0),
               (F1_LENGTH / 2, 0.009, 0.009), F1_MASS_KG, _LINK_RGBA)
    _hand_geom(f1, names.pad("F1"), (F1_LENGTH / 2, 0.0, 0.009 + PAD_HALF_THICKNESS),
               (F1_LENGTH / 2 - 0.002, 0.008, PAD_HALF_THICKNESS), PAD_MASS_KG / 2, _PAD_RGBA)

    f2 = f1.add_body(name=names.body("F2"), pos=[F1_LENGTH, 0.0, 0.0])
    f2.add_joint(name=names.joint(1), type=mujoco.mjtJoint.mjJNT_HINGE,
                 axis=list(FINGER_JOINT_AXES[1]), range=_joint_range(spec, 1),
                 limited=mujoco.mjtLimited.mjLIMITED_TRUE, damping=JOINT_DAMPING)
    _hand_geom(f2, f"{prefix}F2_link", (F2_LENGTH / 2, 0.0, 0.0),
               (F2_LENGTH / 2, F2_HALF_WIDTH, F2_HALF_THICK), F2_MASS_KG, _LINK_RGBA)
    _hand_geom(f2, names.pad("F2"), (F2_LENGTH / 2, 0.0, F2_PAD_Z),
               (F2_LENGTH / 2 - 0.002, F2_HALF_WIDTH - 0.001, PAD_HALF_THICKNESS),
               PAD_MASS_KG, _PAD_RGBA)
    f2.add_site(name=names.imu_site("f2"), pos=[0.6 * F2_LENGTH, 0.0, 0.0],
                quat=_accel_quat("f2"))
    f2.add_site(name=names.gauge_site, pos=list(GAUGE_POS))

    f3 = f2.add_body(name=names.body("F3"), pos=[F2_LENGTH, 0.0, 0.0])
    f3.add_joint(name=names.joint(2), type=mujoco.mjtJoint.mjJNT_HINGE,
                 axis=list(FINGER_JOINT_AXES[2]), range=_joint_range(spec, 2),
                 limited=mujoco.mjtLimited.mjLIMITED_TRUE, damping=JOINT_DAMPING)
    _hand_geom(f3, f"{prefix}F3_link", (F3_LENGTH / 2, 0.0, 0.0),
               (F3_LENGTH / 2, F3_HALF_WIDTH, F3_HALF_THICK), F3_MASS_KG, _LINK_RGBA)
    _hand_geom(f3, names.pad("F3"), (F3_LENGTH / 2, 0.0, F3_PAD_Z),
               (F3_LENGTH / 2 - 0.002, F3_HALF_WIDTH - 0.0005, PAD_HALF_THICKNESS),
               PAD_MASS_KG, _PAD_RGBA)
    f3.add_site(name=names.imu_site("f3"), pos=[0.4 * F3_LENGTH, 0.0, 0.0],
                quat=_accel_quat("f3"))

    for board in ("fmcb", "f2", "f3"):
        spec.add_sensor(name=names.accel_sensor(board),
                        type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname=names.imu_site(board))
        spec.add_sensor(name=names.mag_sensor(board),
                        type=mujoco.mjtSensor.mjSENS_MAGNETOMETER,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname=names.imu_site(board))
    _add_motors(spec, names, motor)
    return f0


def _add_motors(spec: mujoco.MjSpec, names: FingerNames, motor: MotorConstants) -> None:
    """Motor tendons (θ_m = M_rad·q) and their DC-motor actuators (ctrl = duty)."""
    m_rad = motor_coupling_rad()
    for i in range(3):
        tendon = spec.add_tendon(name=names.motor(i), armature=motor.rotor_inertia_kg_m2,
                                 frictionloss=motor.friction_nm,
                                 solimp_friction=list(FRICTION_SOLIMP))
        for j in range(3):
            if m_rad[i, j] != 0.0:
                tendon.wrap_joint(names.joint(j), float(m_rad[i, j]))
        limit = motor.torque_limit_nm
        spec.add_actuator(
            name=names.motor(i), trntype=mujoco.mjtTrn.mjTRN_TENDON, target=names.motor(i),
            gaintype=mujoco.mjtGain.mjGAIN_FIXED,
            gainprm=[motor.gain_nm_per_duty] + [0.0] * 9,
            biastype=mujoco.mjtBias.mjBIAS_AFFINE,
            biasprm=[0.0, 0.0, -motor.emf_damping_nm_s] + [0.0] * 7,
            ctrlrange=[-1.0, 1.0], ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            forcerange=[-limit, limit], forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
        )


def add_palm(spec: mujoco.MjSpec, parent: mujoco.MjsBody, prefix: str = "hand/",
             pos: Vec3 = (0.0, 0.0, 0.0), quat: Quat = (1.0, 0.0, 0.0, 0.0)) -> mujoco.MjsBody:
    """The palm body (welded to ``parent``) with its tactile pad and IMU (accel, gyro, mag)."""
    names = PalmNames(prefix)
    palm = parent.add_body(name=names.body, pos=list(pos), quat=list(quat))
    _hand_geom(palm, f"{prefix}palm_frame", (0.0, 0.0, 0.0), PALM_HALF, PALM_MASS_KG,
               (0.55, 0.55, 0.6, 1.0))
    _hand_geom(palm, names.pad, (0.0, 0.0, PALM_PAD_Z),
               (PALM_HALF[0] - 0.003, PALM_HALF[1] - 0.003, PAD_HALF_THICKNESS), 0.01, _PAD_RGBA)
    palm.add_site(name=names.imu_site, pos=[0.0, 0.0, 0.0])
    spec.add_sensor(name=names.accel_sensor, type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname=names.imu_site)
    spec.add_sensor(name=names.gyro_sensor, type=mujoco.mjtSensor.mjSENS_GYRO,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname=names.imu_site)
    spec.add_sensor(name=names.mag_sensor, type=mujoco.mjtSensor.mjSENS_MAGNETOMETER,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname=names.imu_site)
    return palm


def add_hand(spec: mujoco.MjSpec, parent: mujoco.MjsBody, layout: str = DEFAULT_LAYOUT,
             prefix: str = "hand/", pos: Vec3 = (0.0, 0.0, 0.0),
             quat: Quat = (1.0, 0.0, 0.0, 0.0)) -> mujoco.MjsBody:
    """Palm welded to ``parent`` + four finger modules ``f"{prefix}finger{k}/"``; returns the palm.

    ``layout`` names a :data:`LAYOUTS` entry (:class:`EmulatorConfigError` otherwise).
    """
    try:
        hand_layout = LAYOUTS[layout]
    except KeyError:
        raise EmulatorConfigError(f"unknown hand layout {layout!r}; "
                                  f"known: {', '.join(sorted(LAYOUTS))}") from None
    use_implicit_integrator(spec)
    palm = add_palm(spec, parent, prefix, pos, quat)
    for k, (mount_pos, mount_quat) in enumerate(hand_layout.mounts):
        add_finger(spec, palm, f"{prefix}finger{k}/", mount_pos, mount_quat)
    return palm


def add_grasp_object(spec: mujoco.MjSpec, parent: mujoco.MjsBody, name: str = "object",
                     pos: Vec3 = (0.0, 0.0, 0.3), size: tuple[float, float] = (0.02, 0.04),
                     mass_kg: float = 0.08) -> mujoco.MjsBody:
    """A free capsule (radius, half-length of its cylindrical part, m) lying along world x.

    A capsule rather than a cylinder: MuJoCo's capsule–box collision yields a contact
    *pair* along a lying capsule, where a cylinder gets a single general-convex contact and
    rocks.  ``parent`` must be the world body (MuJoCo allows free joints only there);
    ``pos`` is in the world frame.
    """
    if parent.name != "world":
        raise EmulatorConfigError("a free object must be a child of the world body")
    radius, half_length = size
    if radius <= 0 or half_length <= 0 or mass_kg <= 0:
        raise EmulatorConfigError(f"object size {size} and mass {mass_kg} must be positive")
    body = parent.add_body(name=name, pos=list(pos),
                           quat=[math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
    body.add_freejoint(name=f"{name}/free")
    body.add_geom(name=f"{name}/geom", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                  size=[radius, half_length, 0.0], mass=mass_kg, rgba=[0.8, 0.4, 0.1, 1.0],
                  contype=OBJECT_CONTYPE, conaffinity=OBJECT_CONAFFINITY,
                  friction=list(PAD_FRICTION), condim=4)
    return body
