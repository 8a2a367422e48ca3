"""The finger module's conventions and control law, in one tested place.

Joint order J0, J1, J2 (base abduction/flexion, proximal, distal); motor i is the motor
whose tendon mainly drives joint i.  Joint angles in rad, motor positions in hall counts
(transitions of the three hall sensors), efforts in 1/255 of full PWM (signed, the
original's 8-bit PWM), velocities in hall counts/s.

Tendon coupling (original hand): with K = 36/(2π) hall states per rad of motor shaft,
gear ratios g = (173.4, 196.7, 231) and coupling c = 0.89::

    m2 = K·g2·q2
    m1 = K·(g1·q1 − c·g2·q2)
    m0 = K·(g0·q0 + g1·q1 + c·g2·q2)

Hall sign convention: a transition forward along :data:`HALL_SEQUENCE` counts +1, and a
positive duty drives the motor forward (the plant implements the same convention).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

#: Hall states per radian of motor shaft.
HALL_STATES_PER_RAD: Final = 36.0 / (2.0 * math.pi)
#: Gear ratios of motors 0, 1, 2.
GEAR_RATIOS: Final = (173.4, 196.7, 231.0)
#: Tendon coupling of the distal joint into the proximal motors.
TENDON_COUPLING: Final = 0.89
#: Largest effort magnitude (full PWM).
EFFORT_FULL: Final = 255

#: The six valid hall states in forward order (120° sensors); 0 and 7 never occur.
HALL_SEQUENCE: Final = (1, 3, 2, 6, 4, 5)
_HALL_INDEX: Final = {state: i for i, state in enumerate(HALL_SEQUENCE)}

Vec3 = tuple[float, float, float]


def coupling_matrix() -> np.ndarray:
    """M with m = M·q: joint angles (rad) → motor positions (hall counts)."""
    g0, g1, g2 = GEAR_RATIOS
    c = TENDON_COUPLING
    return HALL_STATES_PER_RAD * np.array(
        [[g0, g1, c * g2],
         [0.0, g1, -c * g2],
         [0.0, 0.0, g2]]
    )


def joint_to_motor(q: Sequence[float]) -> Vec3:
    """Motor positions (hall counts) for joint angles ``q`` (rad)."""
    g0, g1, g2 = GEAR_RATIOS
    c = TENDON_COUPLING
    k = HALL_STATES_PER_RAD
    q0, q1, q2 = (float(v) for v in q)
    return (k * (g0 * q0 + g1 * q1 + c * g2 * q2),
            k * (g1 * q1 - c * g2 * q2),
            k * g2 * q2)


def motor_to_joint(m: Sequence[float]) -> Vec3:
    """Joint angles (rad) for motor positions ``m`` (hall counts): the inverse coupling."""
    g0, g1, g2 = GEAR_RATIOS
    c = TENDON_COUPLING
    k = HALL_STATES_PER_RAD
    m0, m1, m2 = (float(v) / k for v in m)
    q2 = m2 / g2
    q1 = (m1 + c * g2 * q2) / g1
    q0 = (m0 - g1 * q1 - c * g2 * q2) / g0
    return (q0, q1, q2)


class HallCounter:
    """Counts hall transitions of one motor.

    ``update(state)`` takes the 3-bit hall state: a step forward along
    :data:`HALL_SEQUENCE` counts +1, a step back −1; a jump of two or three positions or an
    invalid state (0 or 7) is not counted and increments ``invalid`` (the reference state is
    kept, so counting resumes from the next valid neighbour).
    """

    __slots__ = ("count", "invalid", "_index")

    def __init__(self) -> None:
        self.count = 0
        self.invalid = 0
        self._index: int | None = None

    def update(self, state: int) -> int:
        """Account for the hall ``state`` read now; returns the count (hall counts)."""
        idx = _HALL_INDEX.get(state & 7)
        if idx is None:
            self.invalid += 1
            return self.count
        if self._index is None:
            self._index = idx
            return self.count
        step = (idx - self._index) % 6
        if step == 1:
            self.count += 1
        elif step == 5:
            self.count -= 1
        elif step != 0:
            self.invalid += 1
            return self.count
        self._index = idx
        return self.count


def min_cap(*caps: int) -> int:
    """The effective effort cap (1/255 PWM): the smallest of all caps, within 0..255."""
    return max(0, min(EFFORT_FULL, *caps))


def clamp_effort(effort: float, cap: int) -> int:
    """``effort`` rounded and clamped to ±``cap`` (1/255 PWM)."""
    e = int(round(effort))
    return cap if e > cap else -cap if e < -cap else e


def pd_effort(error: float, velocity: float, kp: float, kd: float, deadband: float,
              cap: int) -> int:
    """PD on hall counts: effort (1/255 PWM) for a position error and velocity.

    ``error`` = target − position (hall counts), ``velocity`` in hall counts/s; inside the
    deadband (|error| ≤ ``deadband``) the effort is 0, so the motor stops; otherwise
    ``kp·error − kd·velocity`` clamped to ±``cap``.
    """
    if abs(error) <= deadband:
        return 0
    return clamp_effort(kp * error - kd * velocity, cap)


def clamp_joints(q: Sequence[float], lower: Sequence[float], upper: Sequence[float]) -> Vec3:
    """Joint angles (rad) clamped into [lower, upper] per joint."""
    out = [min(max(float(v), lo), hi) for v, lo, hi in zip(q, lower, upper, strict=True)]
    return (out[0], out[1], out[2])
