"""The 7-DOF arm's kinematics: flange pose, geometric Jacobian, inverse kinematics.

Geometry from :mod:`protocol.robot` (``ARM_JOINT_OFFSETS_M``, ``ARM_JOINT_AXES``,
``ARM_FLANGE_OFFSET_M``, ``ARM_JOINT_LIMITS``).  Units: m, rad.  Poses are in the arm's
**base frame** (the base plate: ``z`` up, ``x`` forward); at the kinematic zero (all joints 0)
the arm hangs straight down and the flange is at ``(0, 0, −0.68)`` with its frame parallel to
the base frame.

Each joint ``i`` sits at ``ARM_JOINT_OFFSETS_M[i]`` in its parent's frame and turns its body
about ``ARM_JOINT_AXES[i]`` (in that body's frame), so the flange pose is the product
``Π_i Trans(offset_i)·Rot(axis_i, q_i)`` times ``Trans(flange offset)``.  Every function that
computes a pose takes ``geometry`` (an :class:`~host.arm.geometry.ArmGeometry`, e.g. the
arm's calibration, ``Arm.geometry``): its offsets, and its zero offsets added to the joint
readings ``q``; None is the CAD model above.  Angles in and out are always the host's joint
readings.

Orientation targets are roll-pitch-yaw (rad) about the base frame's fixed axes:
``R = Rz(yaw)·Ry(pitch)·Rx(roll)`` (the KDL/ROS convention).

**Inverse kinematics** (:func:`solve_ik`): damped least squares from a start configuration,

    Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ e  +  (I − J⁺ J) · z

with ``e`` the position error (and, given an orientation, the rotation error as an axis-angle
vector), ``λ`` growing near singularities (λ² = λ₀²·(1 − (σ_min/ε)²) for σ_min < ε), and a
null-space term ``z = −k_lim ∇H_lim + k_sing ∇ log w`` that keeps the joints away from their
limits (``H_lim = Σ ((q − mid)/span)²``) and from singular configurations (``w``, the
manipulability ``sqrt(det J Jᵀ)``, gradient by finite differences, near singularities
only: σ_min < 2ε); each step is limited in
size and every joint clamped into its limits less a margin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.arm.geometry import ArmGeometry
from protocol.robot import (
    ARM_FLANGE_OFFSET_M,
    ARM_JOINT_AXES,
    ARM_JOINT_LIMITS,
    ARM_JOINT_OFFSETS_M,
)

#: Joint angles or a vector: a sequence of floats or a numpy array.
Vector = Sequence[float] | np.ndarray

N_JOINTS: Final = len(ARM_JOINT_AXES)
#: Joint limits (rad), lower and upper rows, J1..J7.
LOWER: Final = np.array([lo for lo, _ in ARM_JOINT_LIMITS])
UPPER: Final = np.array([hi for _, hi in ARM_JOINT_LIMITS])
#: How far inside the mechanical stops IK keeps every joint (rad).
LIMIT_MARGIN_RAD: Final = 0.02


def axis_rotation(axis: Vector, angle: float) -> np.ndarray:
    """Rotation matrix (3×3) turning ``angle`` (rad) counter-clockwise about unit ``axis``."""
    return np.array(_axis_rotation_rows([float(v) for v in axis], float(angle)))


def rpy_to_matrix(rpy: Vector) -> np.ndarray:
    """``Rz(yaw)·Ry(pitch)·Rx(roll)`` for ``rpy = (roll, pitch, yaw)`` (rad)."""
    r, p, y = (float(v) for v in rpy)
    return (axis_rotation((0, 0, 1), y) @ axis_rotation((0, 1, 0), p)
            @ axis_rotation((1, 0, 0), r))


def matrix_to_rpy(rotation: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad) of a rotation matrix (inverse of :func:`rpy_to_matrix`;
    pitch in [−π/2, π/2])."""
    m = np.asarray(rotation, dtype=float)
    pitch = math.asin(max(-1.0, min(1.0, -m[2, 0])))
    if abs(m[2, 0]) < 1.0 - 1e-9:
        roll = math.atan2(m[2, 1], m[2, 2])
        yaw = math.atan2(m[1, 0], m[0, 0])
    else:  # gimbal lock: put it all in yaw
        roll = 0.0
        yaw = math.atan2(-m[0, 1], m[1, 1])
    return roll, pitch, yaw


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis-angle vector (rad, base frame) turning ``current`` onto ``target``."""
    r = np.asarray(target) @ np.asarray(current).T
    cos = max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cos)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return 0.5 * v
    if math.pi - angle < 1e-6:  # half a turn: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(r) + 1.0) / 2.0, 0.0))
        signs = np.sign(np.array([r[0, 1] + r[1, 0], r[1, 2] + r[2, 1], r[0, 2] + r[2, 0]]))
        i = int(np.argmax(axis))
        if i == 0:
            axis[1] *= signs[0] or 1.0
            axis[2] *= signs[2] or 1.0
        elif i == 1:
            axis[0] *= signs[0] or 1.0
            axis[2] *= signs[1] or 1.0
        else:
            axis[0] *= signs[2] or 1.0
            axis[1] *= signs[1] or 1.0
        return angle * axis / np.linalg.norm(axis)
    return angle / (2.0 * math.sin(angle)) * v


@dataclass(frozen=True)
class Pose:
    """The flange's pose in the base frame: ``position`` (m, 3) and ``rotation`` (3×3)."""

    position: np.ndarray
    rotation: np.ndarray

    @property
    def rpy(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw (rad) of :attr:`rotation`."""
        return matrix_to_rpy(self.rotation)


def _mat_mul(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [[a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c] for c in range(3)]
            for r in range(3)]


def _mat_vec(a: list[list[float]], v: Vector) -> list[float]:
    return [a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2] for r in range(3)]


_OFFSET_ROWS: Final = [list(map(float, o)) for o in ARM_JOINT_OFFSETS_M]
_AXIS_ROWS: Final = [list(map(float, a)) for a in ARM_JOINT_AXES]
_FLANGE_ROW: Final = list(map(float, ARM_FLANGE_OFFSET_M))


def _geometry_rows(geometry: ArmGeometry | None
                   ) -> tuple[list[list[float]], list[float], list[float] | None]:
    """The offsets' rows, the flange's row and the zero offsets (None: none) of
    ``geometry`` (None: the CAD model)."""
    if geometry is None:
        return _OFFSET_ROWS, _FLANGE_ROW, None
    return (geometry.joint_offsets_m.tolist(), geometry.flange_offset_m.tolist(),
            geometry.zero_offsets_rad.tolist())


def joint_frames(q: Vector, geometry: ArmGeometry | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For joint readings ``q`` (rad, 7): each joint's origin (7×3, m) and axis (7×3, unit)
    in the base frame, and the flange's position (3) and rotation (3×3), of ``geometry``
    (None: the CAD model).  (Plain floats inside: a 7-link chain is far cheaper so than as
    numpy calls, and IK calls it thousands of times.)"""
    qs = [float(v) for v in q]
    if len(qs) != N_JOINTS:
        raise ValueError(f"need {N_JOINTS} joint angles, got {len(qs)}")
    offset_rows, flange_row, zeros = _geometry_rows(geometry)
    if zeros is not None:
        qs = [a + z for a, z in zip(qs, zeros, strict=True)]
    rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    pos = [0.0, 0.0, 0.0]
    origins = []
    axes = []
    for i in range(N_JOINTS):
        d = _mat_vec(rot, offset_rows[i])
        pos = [pos[0] + d[0], pos[1] + d[1], pos[2] + d[2]]
        origins.append(pos)
        axes.append(_mat_vec(rot, _AXIS_ROWS[i]))
        rot = _mat_mul(rot, _axis_rotation_rows(_AXIS_ROWS[i], qs[i]))
    d = _mat_vec(rot, flange_row)
    tip = [pos[0] + d[0], pos[1] + d[1], pos[2] + d[2]]
    return np.array(origins), np.array(axes), np.array(tip), np.array(rot)


def _axis_rotation_rows(axis: Vector, angle: float) -> list[list[float]]:
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]


def forward(q: Vector, geometry: ArmGeometry | None = None) -> Pose:
    """The flange pose for joint readings ``q`` (rad, J1..J7) of ``geometry`` (None: the
    CAD model)."""
    _, _, position, rotation = joint_frames(q, geometry)
    return Pose(position, rotation)


def jacobian(q: Vector, geometry: ArmGeometry | None = None) -> np.ndarray:
    """Geometric Jacobian (6×7) of the flange at ``q`` (of ``geometry``, None: the CAD
    model): rows 0–2 linear velocity (m/s per rad/s), rows 3–5 angular velocity (rad/s per
    rad/s), both in the base frame."""
    origins, axes, tip, _ = joint_frames(q, geometry)
    j = np.empty((6, N_JOINTS))
    j[:3] = np.cross(axes, tip - origins).T
    j[3:] = axes.T
    return j


def manipulability(j: np.ndarray) -> float:
    """Yoshikawa's measure ``sqrt(det(J Jᵀ))`` of a Jacobian (0 at a singularity)."""
    return math.sqrt(max(float(np.linalg.det(j @ j.T)), 0.0))


def within_limits(q: Vector, margin: float = 0.0) -> bool:
    """True if every joint angle (rad) is within its limits less ``margin``."""
    qa = np.asarray(q, dtype=float)
    return bool(np.all(qa >= LOWER + margin) and np.all(qa <= UPPER - margin))


def clamp_to_limits(q: Vector, margin: float = LIMIT_MARGIN_RAD) -> np.ndarray:
    """``q`` (rad) with every joint clamped into its limits less ``margin``."""
    return np.clip(np.asarray(q, dtype=float), LOWER + margin, UPPER - margin)


@dataclass(frozen=True)
class IkResult:
    """What :func:`solve_ik` found: joint angles ``q`` (rad, within limits), the remaining
    ``position_error`` (m) and ``orientation_error`` (rad; 0 if no orientation was asked),
    ``iterations``, and ``converged`` (both errors under their tolerances)."""

    q: np.ndarray
    position_error: float
    orientation_error: float
    iterations: int
    converged: bool


def _limit_gradient(q: np.ndarray) -> np.ndarray:
    """∇ Σ ((q − mid)/span)² (per rad)."""
    mid = (LOWER + UPPER) / 2.0
    span = UPPER - LOWER
    return 2.0 * (q - mid) / span ** 2


def _log_manipulability_gradient(q: np.ndarray, rows: slice, step: float = 1e-4,
                                 geometry: ArmGeometry | None = None) -> np.ndarray:
    """∇ log(w + ε) by central differences of the Jacobian's ``rows``."""
    grad = np.empty(N_JOINTS)
    for i in range(N_JOINTS):
        d = np.zeros(N_JOINTS)
        d[i] = step
        hi = manipulability(jacobian(q + d, geometry)[rows])
        lo = manipulability(jacobian(q - d, geometry)[rows])
        grad[i] = (math.log(hi + 1e-6) - math.log(lo + 1e-6)) / (2.0 * step)
    return grad


def solve_ik(xyz: Vector, rpy: Vector | None = None, *,
             q0: Vector | None = None, tolerance_m: float = 1e-4,
             tolerance_rad: float = 1e-3, max_iterations: int = 300, damping: float = 0.05,
             singular_threshold: float = 0.05, max_step_rad: float = 0.2,
             k_limits: float = 0.2, k_singular: float = 0.02,
             geometry: ArmGeometry | None = None) -> IkResult:
    """Joint angles (rad) putting the flange at ``xyz`` (m, base frame) and, if given,
    orientation ``rpy`` (rad), starting from ``q0`` (default the kinematic zero nudged off
    its singularity).  Damped least squares with a null-space term (see the module docs):
    ``damping`` λ₀, ``singular_threshold`` ε (smallest singular value below which damping
    sets in), ``max_step_rad`` per iteration, ``k_limits`` / ``k_singular`` the null-space
    gains; ``geometry`` the arm's (None: the CAD model).  Never raises for an unreachable
    target: see :attr:`IkResult.converged`."""
    target = np.asarray(xyz, dtype=float)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target position must be 3 finite numbers, got {xyz!r}")
    target_rot = None if rpy is None else rpy_to_matrix(rpy)
    rows = slice(0, 6) if target_rot is not None else slice(0, 3)
    if q0 is None:
        q = clamp_to_limits(np.array([0.0, 0.3, 0.0, 0.6, 0.0, 0.3, 0.0]))
    else:
        q = clamp_to_limits(q0)
    pos_err = rot_err = math.inf
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        _, _, tip, rot = joint_frames(q, geometry)
        e_pos = target - tip
        pos_err = float(np.linalg.norm(e_pos))
        if target_rot is not None:
            e_rot = rotation_error(target_rot, rot)
            rot_err = float(np.linalg.norm(e_rot))
            e = np.concatenate((e_pos, e_rot))
        else:
            rot_err = 0.0
            e = e_pos
        if pos_err <= tolerance_m and rot_err <= tolerance_rad:
            return IkResult(q, pos_err, rot_err, iterations - 1, True)
        full = jacobian(q, geometry)[rows]
        z = -k_limits * _limit_gradient(q)
        sigma_min = float(np.linalg.svd(full, compute_uv=False)[-1])
        if k_singular and sigma_min < 2.0 * singular_threshold:
            z += k_singular * _log_manipulability_gradient(q, rows, geometry=geometry)
        # A joint held at its limit that the step would push further is left out and the
        # step recomputed with the others (else the clamp undoes part of every step and the
        # solver stalls short of a target whose answer lies on that limit).
        free = np.ones(N_JOINTS, dtype=bool)
        for _ in range(N_JOINTS):
            j = full * free
            sigma_min = float(np.linalg.svd(j, compute_uv=False)[-1])
            lam2 = damping ** 2 * (1.0 - (sigma_min / singular_threshold) ** 2) \
                if sigma_min < singular_threshold else 0.0
            jjt = j @ j.T
            dq = j.T @ np.linalg.solve(jjt + (lam2 + 1e-9) * np.eye(jjt.shape[0]), e)
            null = np.eye(N_JOINTS) - np.linalg.pinv(j, rcond=1e-6) @ j
            dq = dq + null @ (z * free)
            pushed = free & (((q <= LOWER + LIMIT_MARGIN_RAD + 1e-9) & (dq < 0))
                             | ((q >= UPPER - LIMIT_MARGIN_RAD - 1e-9) & (dq > 0)))
            if not pushed.any():
                break
            free &= ~pushed
        biggest = float(np.max(np.abs(dq)))
        if biggest > max_step_rad:
            dq *= max_step_rad / biggest
        q = clamp_to_limits(q + dq)
    _, _, tip, rot = joint_frames(q, geometry)
    pos_err = float(np.linalg.norm(target - tip))
    rot_err = 0.0 if target_rot is None else float(np.linalg.norm(
        rotation_error(target_rot, rot)))
    return IkResult(q, pos_err, rot_err, iterations,
                    pos_err <= tolerance_m and rot_err <= tolerance_rad)
