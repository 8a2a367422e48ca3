"""The arm's linear model about a pose: the stepper joints' mass matrix, the springs, the
routes' coupling and gravity's stiffness.

Mass properties from :mod:`protocol.robot` (:data:`~protocol.robot.ARM_LINK_MASS_PROPERTIES`,
:data:`~protocol.robot.ARM_LINK_INERTIAS_KGM2`, the flange's, the joints' hubs
:data:`~protocol.robot.STEPPER_HUB_ARMATURE_KGM2`; the hand as a point mass at its centre of
mass, :data:`~protocol.robot.HAND_MASS_KG`), frames from
:func:`host.arm.kinematics.joint_frames`.  Units: rad, m, kg, N·m, s.

The series-elastic joints J1..J4 with the wrist's servos held (J5..J7 rigid), small motions
``δq`` about a pose and the motors' angles ``m`` (rad at the joint):

    M·δq̈ = Aᵀ·(τ₀ + K·(δm − A·δq) + D·(ṁ − A·q̇)) − g(q₀) − G·δq,     A = I − C

``M`` the mass matrix (:func:`mass_matrix`), ``K``/``D`` the springs' stiffness and damping,
``C`` the routes' coupling (:func:`protocol.robot.arm_route_coupling_matrix`: a spring's
torque ``τ`` acts on the joint as ``Aᵀ·τ``), ``g`` the holding torques
(:func:`host.arm.gravity.holding_torques`) and ``G = ∂g/∂q`` (:func:`gravity_stiffness`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

import host.arm.kinematics as arm_kinematics
from host.arm.gravity import holding_torques
from protocol.robot import (
    ARM_FLANGE_INERTIA_KGM2,
    ARM_FLANGE_MASS_PROPERTIES,
    ARM_JOINT_AXES,
    ARM_LINK_INERTIAS_KGM2,
    ARM_LINK_MASS_PROPERTIES,
    ARM_STEPPER_JOINTS,
    HAND_COM_ON_FLANGE_M,
    HAND_MASS_KG,
    STEPPER_HUB_ARMATURE_KGM2,
)

Vector = Sequence[float] | np.ndarray

#: The step (rad) of the finite differences giving gravity's stiffness.
GRAVITY_STEP_RAD: Final = 1e-4


def _bodies(q: Vector, hand: bool) -> list[tuple[int, float, np.ndarray, np.ndarray]]:
    """Every moving body at ``q``: (the last joint that moves it, mass (kg), centre of mass
    (m, base frame), inertia about it (kg·m², base axes))."""
    origins, _, tip, flange_rot = arm_kinematics.joint_frames(q)
    qs = [float(v) for v in q]
    rot = np.eye(3)
    bodies = []
    for i, ((mass, com), inertia) in enumerate(zip(ARM_LINK_MASS_PROPERTIES,
                                                   ARM_LINK_INERTIAS_KGM2, strict=True)):
        rot = rot @ arm_kinematics.axis_rotation(ARM_JOINT_AXES[i], qs[i])
        bodies.append((i, mass, origins[i] + rot @ np.asarray(com, dtype=float),
                       rot @ np.diag(inertia) @ rot.T))
    last = arm_kinematics.N_JOINTS - 1
    mass, com = ARM_FLANGE_MASS_PROPERTIES
    bodies.append((last, mass, tip + flange_rot @ np.asarray(com, dtype=float),
                   flange_rot @ np.diag(ARM_FLANGE_INERTIA_KGM2) @ flange_rot.T))
    if hand:
        bodies.append((last, HAND_MASS_KG,
                       tip + flange_rot @ np.asarray(HAND_COM_ON_FLANGE_M, dtype=float),
                       np.zeros((3, 3))))
    return bodies


def mass_matrix(q: Vector, hand: bool = False) -> np.ndarray:
    """The mass matrix (kg·m², 4×4) of the stepper joints J1..J4 at ``q`` (rad, 7) with the
    wrist's joints held, the joints' hubs included; with ``hand`` the hand on the flange."""
    n = ARM_STEPPER_JOINTS
    origins, axes, _, _ = arm_kinematics.joint_frames(q)
    out = np.diag(np.asarray(STEPPER_HUB_ARMATURE_KGM2, dtype=float))
    for last, mass, com, inertia in _bodies(q, hand):
        linear = np.zeros((3, n))
        angular = np.zeros((3, n))
        for i in range(min(last + 1, n)):
            linear[:, i] = np.cross(axes[i], com - origins[i])
            angular[:, i] = axes[i]
        out += mass * linear.T @ linear + angular.T @ inertia @ angular
    return np.asarray(out)


def gravity_stiffness(q: Vector, hand: bool = False) -> np.ndarray:
    """``∂g/∂q`` (N·m/rad, 4×4) of the stepper joints' holding torques at ``q`` (rad, 7)."""
    n = ARM_STEPPER_JOINTS
    base = np.asarray(q, dtype=float)
    g0 = holding_torques(base, hand)[:n]
    out = np.zeros((n, n))
    for j in range(n):
        moved = base.copy()
        moved[j] += GRAVITY_STEP_RAD
        out[:, j] = (holding_torques(moved, hand)[:n] - g0) / GRAVITY_STEP_RAD
    return out
