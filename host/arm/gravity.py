"""The arm's static gravity model: the torque each joint holds against gravity at rest, and the
series-elastic joints' stall limits.

Mass properties from :mod:`protocol.robot` (:data:`~protocol.robot.ARM_LINK_MASS_PROPERTIES`,
:data:`~protocol.robot.ARM_FLANGE_MASS_PROPERTIES` and, with the hand mounted,
:data:`~protocol.robot.HAND_MASS_KG` / :data:`~protocol.robot.HAND_COM_ON_FLANGE_M`); frames
from :func:`host.arm.kinematics.joint_frames`.  The base frame's ``z`` points up (the base
plate mounted level).  Units: rad, m, kg, N·m.

**Holding torque** of joint ``i`` (:func:`holding_torques`): what the joint must exert about
its axis (positive counter-clockwise about it, as its angle counts) to hold the arm still,

    τ_i = a_i · Σ_b (c_b − o_i) × (m_b · g · ẑ)

summed over every body ``b`` beyond joint ``i`` (centre of mass ``c_b``; ``o_i``, ``a_i``
the joint's origin and axis).  On a series-elastic joint J1..J4 the spring carries it:
``τ = k · (motor − joint)`` (:data:`~protocol.robot.SERIES_ELASTIC_STIFFNESS_NM_PER_RAD`),
so the node's deflection register reads ``τ / k`` at rest.

**Spring torque** (:func:`spring_torques`): the belt and cable routes couple J1..J4 (the
capstan of ``i`` turns by ``Σ_j C[i][j]·Δq_j``, :data:`~protocol.robot.ARM_ROUTE_COUPLING`),
so by virtual work a spring's torque also acts on the joints its route passes: joint ``j``
feels ``τ_j − Σ_i C[i][j]·τ_i``.  At rest that balances gravity, ``(I − Cᵀ)·τ = g``: the
springs carry more than the holding torques, the shoulder J2 most (+0.18 × the elbow's
spring torque).  This is what the nodes' stall latch sees.

**Stall limit** (:func:`stall_torques`): the node latches STALLED (and stops, holding its motor) when
``|deflection|`` exceeds its ``deflection_limit`` register (150 counts by default,
:data:`protocol.control_tables.STEPPER_TABLE`): ``k · 150 · 2π/10000`` N·m, 8.1 N·m at the
elbow.  A static torque near it leaves no room for the motion's own dynamics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

import host.arm.kinematics as arm_kinematics
from protocol.control_tables import STEPPER_TABLE
from protocol.robot import (
    ARM_FLANGE_MASS_PROPERTIES,
    ARM_JOINT_AXES,
    ARM_LINK_MASS_PROPERTIES,
    ARM_STEPPER_JOINTS,
    HAND_COM_ON_FLANGE_M,
    HAND_MASS_KG,
    SERIES_ELASTIC_STIFFNESS_NM_PER_RAD,
    arm_route_coupling_matrix,
    encoder_counts_to_rad,
)

Vector = Sequence[float] | np.ndarray

#: Standard gravity (m/s²), along the base frame's −z.
GRAVITY_M_PER_S2: Final = 9.81
#: The stepper nodes' ``deflection_limit`` at power-up (joint encoder counts).
DEFAULT_DEFLECTION_LIMIT_COUNTS: Final = STEPPER_TABLE["deflection_limit"].default


def stall_torques(deflection_limit_counts: float = DEFAULT_DEFLECTION_LIMIT_COUNTS
                  ) -> np.ndarray:
    """The torque (N·m, J1..J4) at which each stepper node latches STALLED: its stiffness
    (N·m/rad) times ``deflection_limit_counts`` (encoder counts) in rad."""
    limit_rad = encoder_counts_to_rad(deflection_limit_counts)
    return np.array(SERIES_ELASTIC_STIFFNESS_NM_PER_RAD, dtype=float) * limit_rad


def body_masses(q: Vector, hand: bool = False) -> list[tuple[int, float, np.ndarray]]:
    """Every moving mass at joint angles ``q`` (rad, 7): ``(joint index that moves it, mass
    (kg), centre of mass (m, base frame))``, J1's link first; with ``hand`` the mounted hand
    last."""
    origins, _, tip, flange_rot = arm_kinematics.joint_frames(q)
    qs = [float(v) for v in q]
    masses: list[tuple[int, float, np.ndarray]] = []
    rot = np.eye(3)
    for i, (mass, com) in enumerate(ARM_LINK_MASS_PROPERTIES):
        rot = rot @ arm_kinematics.axis_rotation(ARM_JOINT_AXES[i], qs[i])
        masses.append((i, mass, origins[i] + rot @ np.asarray(com, dtype=float)))
    flange_mass, flange_com = ARM_FLANGE_MASS_PROPERTIES
    masses.append((arm_kinematics.N_JOINTS - 1, flange_mass,
                   tip + flange_rot @ np.asarray(flange_com, dtype=float)))
    if hand:
        masses.append((arm_kinematics.N_JOINTS - 1, HAND_MASS_KG,
                       tip + flange_rot @ np.asarray(HAND_COM_ON_FLANGE_M, dtype=float)))
    return masses


def holding_torques(q: Vector, hand: bool = False) -> np.ndarray:
    """The torque (N·m, J1..J7, about each joint's axis) each joint holds against gravity at
    joint angles ``q`` (rad), the arm at rest; with ``hand`` the hand is on the flange."""
    origins, axes, _, _ = arm_kinematics.joint_frames(q)
    # (joint, weight (N, along −z), x, y of the centre of mass): gravity's moment about a
    # point o is (c − o) × (0, 0, −w) = (−w·(c_y − o_y), w·(c_x − o_x), 0), in plain floats
    # (numpy's cross of 3-vectors cost 4 ms of every 10 ms cycle of a move)
    weights = [(joint, mass * GRAVITY_M_PER_S2, float(com[0]), float(com[1]))
               for joint, mass, com in body_masses(q, hand)]
    torques = np.zeros(arm_kinematics.N_JOINTS)
    for i in range(arm_kinematics.N_JOINTS):
        ox, oy = float(origins[i][0]), float(origins[i][1])
        mx = my = 0.0
        for joint, w, cx, cy in weights:
            if joint >= i:
                mx -= w * (cy - oy)
                my += w * (cx - ox)
        axis = axes[i]
        torques[i] = -(float(axis[0]) * mx + float(axis[1]) * my)  # cancels gravity's moment
    return torques


def spring_torques(q: Vector, hand: bool = False) -> np.ndarray:
    """The torque (N·m) the series-elastic springs of J1..J4 carry holding the arm still at
    ``q`` (rad): ``(I − Cᵀ)⁻¹ · g`` with ``g`` the holding torques of J1..J4 and ``C`` the
    routes' coupling (see the module's docstring); ``k × deflection`` at rest."""
    c = arm_route_coupling_matrix()
    held = holding_torques(q, hand)[:ARM_STEPPER_JOINTS]
    return np.asarray(np.linalg.solve(np.eye(ARM_STEPPER_JOINTS) - c.T, held))


def stepper_load_fractions(q: Vector, hand: bool = False,
                           deflection_limit_counts: float = DEFAULT_DEFLECTION_LIMIT_COUNTS
                           ) -> np.ndarray:
    """``|spring torque| / stall torque`` of J1..J4 at ``q`` (rad): 1 is the STALLED latch."""
    return np.abs(spring_torques(q, hand)) / stall_torques(deflection_limit_counts)

