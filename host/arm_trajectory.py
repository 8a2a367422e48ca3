"""Joint-space paths for the arm: waypoints, their interpolation, and timing a path to the
joints' speed and acceleration limits (pure: no I/O).

A :class:`Trajectory` interpolates through :class:`Waypoint` s linearly, or with ``smooth``
along a minimum-jerk profile in every segment (for point-to-point moves: it slows into the
goal, so the stop does not set the elastic joints ringing).  :func:`timed_path` times a list
of joint positions so that no joint is faster or accelerates more than its limit, which is
what :func:`host.arm_gate.check_path` asks of a path before the joint loop
(:mod:`host.arm_joint_loop`) follows it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.arm_state import N_JOINTS, N_STEPPERS
from host.errors import UsageError
from protocol.robot import ARM_JOINT_ACCEL_LIMITS

#: Joint angles or a vector: a sequence of floats or a numpy array.
Vector = Sequence[float] | np.ndarray


@dataclass(frozen=True)
class Waypoint:
    """A joint-space waypoint: ``t`` (s) and ``joints`` (7 absolute angles, rad)."""

    t: float
    joints: tuple[float, ...]


#: Peak speed over mean speed of a minimum-jerk segment (``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵``).
MIN_JERK_PEAK: Final = 1.875


def _min_jerk(a: float) -> tuple[float, float]:
    """Minimum-jerk progress ``s`` and ``ds/dτ`` at ``a`` (0..1) of a segment."""
    return a * a * a * (10.0 + a * (-15.0 + 6.0 * a)), 30.0 * a * a * (1.0 - a) * (1.0 - a)


class Trajectory:
    """Joint-space interpolation through waypoints (times strictly increasing after the
    first; before the first the first holds, after the last the last): linear, or with
    ``smooth`` a minimum-jerk profile in every segment - it leaves and reaches each waypoint
    at rest with no step in acceleration, slowing into the goal, so an elastic joint is not
    set ringing by the stop (for point-to-point moves; a recorded path through many waypoints
    wants ``smooth=False``)."""

    def __init__(self, waypoints: Sequence[Waypoint], smooth: bool = False) -> None:
        if not waypoints:
            raise UsageError("a trajectory needs at least one waypoint")
        self.smooth = smooth
        self.times = np.array([w.t for w in waypoints], dtype=float)
        self.points = np.array([w.joints for w in waypoints], dtype=float)
        if self.points.shape[1] != N_JOINTS:
            raise UsageError(f"waypoints need {N_JOINTS} joint angles")
        if np.any(np.diff(self.times) < 0):
            raise UsageError("waypoint times must not decrease")

    @property
    def duration(self) -> float:
        """Time of the last waypoint (s)."""
        return float(self.times[-1])

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired joint angles (rad) and velocities (rad/s) at ``t`` (s)."""
        times, points = self.times, self.points
        if t <= times[0]:
            return points[0].copy(), np.zeros(N_JOINTS)
        if t >= times[-1]:
            return points[-1].copy(), np.zeros(N_JOINTS)
        k = int(np.searchsorted(times, t, side="right")) - 1
        span = times[k + 1] - times[k]
        if span <= 0:
            return points[k + 1].copy(), np.zeros(N_JOINTS)
        a = (t - times[k]) / span
        rate = 1.0
        if self.smooth:
            a, rate = _min_jerk(a)
        delta = points[k + 1] - points[k]
        return points[k] + a * delta, rate * delta / span


def timed_path(points: Sequence[Vector], max_speed: float, start_t: float = 0.0,
               min_segment_s: float = 0.05, smooth: bool = False,
               accel: Vector | None = ARM_JOINT_ACCEL_LIMITS) -> list[Waypoint]:
    """Waypoints through ``points`` (7 rad each), each segment timed so no joint is faster
    than ``max_speed`` (rad/s) and, from rest and to rest, accelerates no more than
    ``accel`` (rad/s², per joint; None: no such bound): linearly interpolated, or with
    ``smooth`` for a ``Trajectory(..., smooth=True)`` (:data:`MIN_JERK_PEAK` times longer;
    its peak acceleration is 10/√3 · Δq/T²).  A short segment then takes a little longer
    than its speed alone asks, so :func:`host.arm_gate.check_path` passes it."""
    if not (max_speed > 0 and math.isfinite(max_speed)):
        raise UsageError(f"joint speed {max_speed} must be a finite number > 0 rad/s")
    out = [Waypoint(start_t, tuple(float(v) for v in points[0]))]
    t = start_t
    stretch = MIN_JERK_PEAK if smooth else 1.0
    sharpness = 10 / math.sqrt(3) if smooth else 1.0
    limits = None if accel is None else np.asarray(accel, dtype=float)
    for a, b in zip(points, points[1:], strict=False):
        step = np.abs(np.subtract(b, a, dtype=float))
        span = max(stretch * float(np.max(step)) / max_speed, min_segment_s)
        if limits is not None:
            span = max(span, float(np.max(np.sqrt(sharpness * step / limits))) * (1 + 1e-9))
        t += span
        out.append(Waypoint(t, tuple(float(v) for v in b)))
    return out


#: How far ahead of its way (s of its speed) a move sends an RX-64 its goal
#: (:func:`servo_lead`): five of a move's 10 ms cycles, so a late cycle does not stall it.
SERVO_GOAL_LEAD_S: Final = 0.05


def servo_lead(start: Sequence[float], goals: Sequence[float],
               speeds: Sequence[float | None], elapsed: float) -> list[float]:
    """The goals a move sends ``elapsed`` seconds after it began from ``start`` towards
    ``goals`` (rad): the steppers' own (their nodes plan the way and stop by themselves
    when the host vanishes), each RX-64's only :data:`SERVO_GOAL_LEAD_S` of its ``speed``
    (rad/s; None: the goal itself) ahead of where that speed has taken it by then.  An
    RX-64 moves its setpoint at the same speed, so the motion is the one the move's end as
    goal would give; but it has no watchdog and drives on to the goal it was sent, so a
    host that vanishes leaves it at most that lead further on (0.01 rad at 0.2 rad/s, and
    its lag behind its setpoint), not at the move's end."""
    out = list(goals)
    for j in range(N_STEPPERS, N_JOINTS):
        speed = speeds[j]
        if speed is None:
            continue
        span = goals[j] - start[j]
        reach = speed * (elapsed + SERVO_GOAL_LEAD_S)
        if reach < abs(span):
            out[j] = start[j] + math.copysign(reach, span)
    return out
