"""Joint-space paths for the arm: waypoints, their interpolation, and timing a path to the
joints' speed and acceleration limits (pure: no I/O).

A :class:`Trajectory` interpolates through :class:`Waypoint` s linearly, or with ``smooth``
along a minimum-jerk profile in every segment (for point-to-point moves: it slows into the
goal, so the stop does not set the elastic joints ringing).  :func:`timed_path` times a list
of joint positions so that no joint is faster or accelerates more than its limit, which is
what :func:`host.arm.gate.check_path` asks of a path before the joint loop
(:mod:`host.arm.joint_loop`) follows it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.arm.state import N_JOINTS, N_STEPPERS
from host.errors import UsageError
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_JOINT_ACCEL_LIMITS,
    ARM_JOINT_SPEED_LIMITS,
)

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
    than its speed alone asks, so :func:`host.arm.gate.check_path` passes it."""
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


#: How long (s) :meth:`host.arm.facade.Arm.move` takes to bring its steppers up to speed, and to
#: brake them into their goals (:func:`move_speed_limits`).  The nodes' own profile changes
#: speed at π rad/s² (the hardware's), which at the speeds of a move takes 0.1-0.45 s: about
#: half a period of the shoulder and elbow swinging together (1.2-2.5 Hz), the ramp that
#: leaves the most swing behind.  A ramp of a period or more leaves little: on the emulator
#: (homed at zero, a speed of 0.5-1.44 rad/s to eight poses, each joint on its own time)
#: ramps of 0.3 s up and the nodes' braking latched J2 or J4 STALLED in 27 of 40 moves (a
#: J2 at 0.5 rad/s too); 0.6 s up and down in 3, all at J2's full speed (1.44 rad/s), where
#: the elastic elements carry up to 130 of their 150 counts statically in the loaded poses
#: on the way.  The moves also came to rest sooner: 4.0-7.0 s against 3.7-7.9 s.
MOVE_RAMP_S: Final = 0.6
#: The least speed limit (rad/s) a move's braking sends a stepper (:func:`move_speed_limits`):
#: a goal the node is still short of by a count or two is reached in a few tens of ms.
MOVE_BRAKE_FLOOR: Final = 0.02
#: A motor this close to its goal (rad at the joint: two encoder counts) has arrived: its
#: speed limit is the move's again, which the node keeps for later goals sent without one
#: (a joint loop's, a hold's return), instead of the braking's last.
MOVE_ARRIVED_RAD: Final = 2 * 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV
#: Half a count of a stepper node's ``velocity_limit`` (rad/s at the joint).
_HALF_COUNT_RAD: Final = 0.5 * 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV


def ramped_speeds(speeds: Sequence[float | None], elapsed: float, *,
                  servos: bool = False) -> list[float | None]:
    """The speed limits (rad/s) a move sends ``elapsed`` s after it began, before braking:
    each stepper's of ``speeds`` scaled by ``elapsed`` / :data:`MOVE_RAMP_S` (at most 1),
    the servos' as they are with ``servos`` (the first command), else None (not sent
    again: an RX-64 keeps its moving speed, and the move's goals lead it along its way)."""
    scale = min(1.0, max(elapsed, 0.0) / MOVE_RAMP_S)
    return [(None if s is None else s * scale) if i < N_STEPPERS else (s if servos else None)
            for i, s in enumerate(speeds)]


def move_speed_limits(speeds: Sequence[float | None], elapsed: float,
                      left: Sequence[float] | None = None, *, servos: bool = False,
                      sent: Sequence[float | None] | None = None) -> list[float | None]:
    """The speed limits (rad/s) a move sends ``elapsed`` s after it began: each stepper's
    speed of ``speeds`` raised over :data:`MOVE_RAMP_S` (:func:`ramped_speeds`) and, as its
    motor comes within ``left`` (rad, the motor's distance to its goal, one per stepper;
    None: not near) of its goal, lowered so it brakes into it over :data:`MOVE_RAMP_S`:
    ``√(2·a·left)`` with ``a = speed / MOVE_RAMP_S``; the move's speed again once the motor
    has arrived (:data:`MOVE_ARRIVED_RAD`); never below :data:`MOVE_BRAKE_FLOOR` (nor
    above the speed).  A stepper's limit that is what ``sent`` (rad/s, per stepper, as
    the nodes last took it) already says, to the register's count, is None (not sent
    again); the servos' as in :func:`ramped_speeds`."""
    out = ramped_speeds(speeds, elapsed, servos=servos)
    for i in range(N_STEPPERS):
        speed, limit = speeds[i], out[i]
        if speed is None or limit is None:
            continue
        if left is not None and left[i] > MOVE_ARRIVED_RAD:
            limit = min(limit, math.sqrt(2.0 * (speed / MOVE_RAMP_S) * float(left[i])))
        limit = max(limit, min(speed, MOVE_BRAKE_FLOOR))
        last = None if sent is None else sent[i]
        out[i] = None if last is not None and abs(limit - last) < _HALF_COUNT_RAD else limit
    return out


def travel_time(start: Sequence[float], goals: Sequence[float],
                speeds: Sequence[float | None]) -> float:
    """The time (s) the slowest joint needs from ``start`` to ``goals`` (rad) at its speed
    of ``speeds`` (rad/s; None: the node's own, taken as the joint's speed limit), with the
    steppers' ramps up and down (:data:`MOVE_RAMP_S` each, about half of each lost; a
    joint too close to reach its speed takes ``2·√(distance·MOVE_RAMP_S/speed)``)."""
    worst = 0.0
    for i, (a, b, s) in enumerate(zip(start, goals, speeds, strict=True)):
        limit = ARM_JOINT_SPEED_LIMITS[i]
        speed = min(s, limit) if s else limit
        far = abs(b - a)
        if i < N_STEPPERS:
            ramped = far / speed + MOVE_RAMP_S if far >= speed * MOVE_RAMP_S else \
                2.0 * math.sqrt(far * MOVE_RAMP_S / speed)
            worst = max(worst, ramped)
        else:
            worst = max(worst, far / speed)
    return worst
