"""Finger kinematics the host needs: joint angles (rad) ↔ motor positions (hall counts).

Joint order J0, J1, J2 (base, proximal, distal); motor i mainly drives joint i.  With
K = 36/(2π) hall states per rad of motor shaft, gear ratios g and tendon coupling c::

    m2 = K·g2·q2
    m1 = K·(g1·q1 − c·g2·q2)
    m0 = K·(g0·q0 + g1·q1 + c·g2·q2)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

# TODO(merge): replace with protocol.robot
#: Hall states per radian of motor shaft.
HALL_STATES_PER_RAD: Final = 36.0 / (2.0 * math.pi)
#: Gear ratios of motors 0, 1, 2.
GEAR_RATIOS: Final = (173.4, 196.7, 231.0)
#: Tendon coupling of the distal joint into the proximal motors.
TENDON_COUPLING: Final = 0.89
#: Joints (and motors) per finger.
JOINTS_PER_FINGER: Final = 3
#: Default firmware joint limits (rad), the ``joint_lower_*`` / ``joint_upper_*`` params.
DEFAULT_LOWER: Final = (-1.57, -1.57, -1.57)
DEFAULT_UPPER: Final = (1.57, 1.57, 1.57)
#: The fmcb's default position deadband (hall counts).
DEFAULT_DEADBAND: Final = 50

Vec3 = tuple[float, float, float]


def joint_to_motor(q: Sequence[float]) -> Vec3:
    """Motor positions (hall counts) for joint angles ``q`` (rad)."""
    g0, g1, g2 = GEAR_RATIOS
    c, k = TENDON_COUPLING, HALL_STATES_PER_RAD
    q0, q1, q2 = (float(v) for v in q)
    return (k * (g0 * q0 + g1 * q1 + c * g2 * q2), k * (g1 * q1 - c * g2 * q2), k * g2 * q2)


def motor_to_joint(m: Sequence[float]) -> Vec3:
    """Joint angles (rad) for motor positions ``m`` (hall counts)."""
    g0, g1, g2 = GEAR_RATIOS
    c, k = TENDON_COUPLING, HALL_STATES_PER_RAD
    m0, m1, m2 = (float(v) / k for v in m)
    q2 = m2 / g2
    q1 = (m1 + c * g2 * q2) / g1
    q0 = (m0 - g1 * q1 - c * g2 * q2) / g0
    return (q0, q1, q2)
