"""Joint-space control of the arm on the link's clock: PID with the route-coupling
feed-forward, linear interpolation of waypoints, Cartesian moves, waypoint record and play.

**The loop.**  Every ``1/rate_hz`` seconds of the transport's clock (100 Hz by default, as on
the original arm; ``rate_hz=None`` cycles back to back, as fast as the wire allows) one
:meth:`~host.arm.Arm.cycle` sends the goals computed from the previous cycle's state and
reads the new state.  Each joint's goal is

    u = q_des + Kp·e + Ki·∫e dt + Kd·(q̇_des − q̇)          e = q_des − q   (rad)

(the integral clamped to ±``integral_limit``).  The stepper nodes and the RX-64s are position
servos themselves, so ``q_des`` is the feed-forward and the PID only removes what they
cannot see: the series-elastic deflection under load (a stepper's motor reaches its goal;
its joint sags by torque/stiffness) and the RX-64's compliance margin.  The gains are low on
purpose: the elastic joints ring at a few hertz, lightly damped (a derivative term on the
nodes' 10 ms, one-count-quantised velocity destabilises them: ``kd`` is 0).

Two things keep the integral honest (:class:`PidGains`): an error within the *deadband*
(one encoder count on the steppers, one position unit on the RX-64s) is no error, so the
integral holds once the joint is as close as its sensor can tell instead of hunting across
the last count against the bearings' stiction; and the integral takes the error clipped to
``integral_error`` (1°), so a step or a joint still on its way winds it up no faster than a
steady sag would (anti-windup: the closed-loop 10° shoulder step overshoots ~20 % instead of
~50 %).  :meth:`JointController.settled` is the loop's own settle test.  Point-to-point
moves (:func:`moveto`) follow a minimum-jerk path (``Trajectory(..., smooth=True)``),
slowing into the goal, so the stop does not set the elastic joints ringing.

**Coupling feed-forward** (the first four joints).  The belt and cable routes turn the
capstans of J1..J4 by ``C·Δq`` (:data:`protocol.robot.ARM_ROUTE_COUPLING`, ``Δq`` the joint
angles since the nodes' power-up, when motor and capstan were aligned), so a stepper goal
``u`` puts the capstan at ``u + C·Δq``.  The controller sends the steppers

    u_motor = u − C·(q_des − q_power_up)

(:func:`coupling_feedforward`), which keeps each capstan where the PID wants it whatever the
joints before it do.  A node cannot see the other joints: its ``deflection`` register
(motor after reduction − joint) differs from the elastic element's true deflection by
``−C·Δq`` (:func:`elastic_deflections` gives the true one), and :meth:`host.arm.Arm.cycle`
sends it that offset with every goal (``deflection_offset``), so its SLIP/STALLED
protection watches the elastic element and does not trip under this compensation.

**Braking lead** (the first four joints).  A stepper node plans every goal as a stop: it
brakes towards it at its ``acceleration_limit``.  Goals a few milliseconds apart along a path
would each be a stop it must be able to make, so the joint slows to what it could stop from
within one step and trails the path (more, the faster the cycle).  The controller puts each
stepper goal ahead by the braking distance at the path's speed, ``sign(q̇_des)·q̇_des²/(2a)``
(:func:`braking_lead`); at the path's end ``q̇_des`` is 0 and the goal is the path's.

**Waypoint files** are JSON lines (UTF-8, one JSON object per line)::

    {"kind": "arm-waypoints", "version": 1, "joints": ["J1", …, "J7"], "units": "rad, s"}
    {"t": 0.0, "joints": [0.0, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0]}
    {"t": 1.25, "joints": [0.05, 0.15, 0.0, 0.3, 0.0, -0.1, 0.0]}

The first line is the header (optional on reading; a line with ``"kind"`` is a header); every
other line is one waypoint: ``t`` (s since the recording started, non-decreasing) and
``joints`` (seven absolute joint angles, rad, J1..J7).  Playback interpolates linearly in
joint space between waypoints at their times (reaching the first from wherever the arm is at
a joint speed of ``approach_speed``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from host import arm_gravity, arm_kinematics
from host.arm_gate import (
    check_cartesian,
    check_finite,
    check_goals,
    check_path,
    latches,
    require_torque,
)
from host.arm_hold import stop_for_alarms
from host.arm_rest import RestWatch
from host.arm_state import JOINT_NAMES, N_JOINTS, N_STEPPERS, ArmState, Command
from host.errors import LimitError, StallError, UsageError
from protocol.control_tables import STEPPER_TABLE
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_JOINT_ACCEL_LIMITS,
    RX64_RAD_PER_UNIT,
    arm_route_coupling_matrix,
)

#: Joint angles or a vector: a sequence of floats or a numpy array.
Vector = Sequence[float] | np.ndarray

if TYPE_CHECKING:
    from host.arm import Arm

#: The original arm's control rate (Hz).
DEFAULT_RATE_HZ: Final = 100.0
#: A stepper joint's STALLED latches the controller clears and re-enables within
#: :data:`STALL_WINDOW_S` (s) before it gives up (:class:`~host.errors.StallError`): a joint
#: that someone holds, or that carries more than it can, is not driven again and again.
STALL_RETRIES: Final = 3
STALL_WINDOW_S: Final = 2.0
#: Waypoint file header.
WAYPOINTS_KIND: Final = "arm-waypoints"
WAYPOINTS_VERSION: Final = 1


# ----------------------------------------------------------------------------- the math


#: One joint encoder count (rad): the steppers' resolution.
ENCODER_COUNT_RAD: Final = 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV
#: The stepper nodes' acceleration limit at power-up (rad/s²): their motion profile brakes
#: towards each goal at this rate.
STEPPER_ACCEL_RAD_S2: Final = STEPPER_TABLE["acceleration_limit"].default * ENCODER_COUNT_RAD


def braking_lead(qd_des: Vector, accel: float = STEPPER_ACCEL_RAD_S2) -> np.ndarray:
    """How far ahead of the path to put a stepper's goal (rad) so that its node, which
    plans every goal as a stop and brakes towards it at ``accel`` (rad/s²), keeps the
    path's speed ``qd_des`` (rad/s): the braking distance ``sign(v)·v²/(2·accel)``.  Without
    it a joint sent goals a few milliseconds apart along a path slows to what it could stop
    from within each step and trails the path; at the path's end ``qd_des`` is 0 and so is
    the lead."""
    v = np.asarray(qd_des, dtype=float)
    return np.sign(v) * v * v / (2.0 * accel)


@dataclass(frozen=True)
class PidGains:
    """Per-joint gains (7 each, J1..J7): ``kp`` (rad/rad), ``ki`` (rad/(rad·s)), ``kd``
    (rad/(rad/s)), ``integral_limit`` (rad, the most the integral term adds), ``deadband``
    (rad: an error this small is no error - the integral holds - so the loop does not hunt
    across the sensor's last count against stiction; one encoder count on the steppers, one
    position unit on the RX-64s) and ``integral_error`` (rad: the integral takes the error
    clipped to this, so a large transient error - a step, a joint still on its way - winds it
    up no faster than a small steady one; anti-windup)."""

    kp: tuple[float, ...] = (0.05,) * 4 + (0.1,) * 3
    ki: tuple[float, ...] = (1.5,) * 4 + (1.0,) * 3
    kd: tuple[float, ...] = (0.0,) * 7
    integral_limit: tuple[float, ...] = (0.15,) * 4 + (0.1,) * 3
    deadband: tuple[float, ...] = (ENCODER_COUNT_RAD,) * 4 + (RX64_RAD_PER_UNIT,) * 3
    integral_error: tuple[float, ...] = (math.radians(1.0),) * 7

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "integral_limit", "deadband", "integral_error"):
            if len(getattr(self, name)) != N_JOINTS:
                raise UsageError(f"PID {name} needs {N_JOINTS} values, J1..J7")


class JointPid:
    """The PID of all seven joints (pure: no I/O).  :meth:`update` gives the correction
    (rad) to add to the desired angles."""

    def __init__(self, gains: PidGains | None = None) -> None:
        self.gains = gains or PidGains()
        self._kp = np.array(self.gains.kp)
        self._ki = np.array(self.gains.ki)
        self._kd = np.array(self.gains.kd)
        self._limit = np.array(self.gains.integral_limit)
        self._deadband = np.array(self.gains.deadband)
        self._integral_error = np.array(self.gains.integral_error)
        #: The integral term (rad), already multiplied by ``ki``.
        self.integral = np.zeros(N_JOINTS)

    def reset(self) -> None:
        """Forget the integral."""
        self.integral[:] = 0.0

    def update(self, q_des: Vector, q: Vector, dt: float,
               qd_des: Vector | None = None, qd: Vector | None = None
               ) -> np.ndarray:
        """Correction (rad, 7) for desired ``q_des`` and measured ``q`` (rad), after ``dt``
        (s) since the last update; velocities (rad/s) for the derivative term.  Errors within
        the deadband count as 0; the integral takes the error clipped to ``integral_error``
        and is clamped to ``integral_limit``."""
        e = np.asarray(q_des, dtype=float) - np.asarray(q, dtype=float)
        e = np.where(np.abs(e) <= self._deadband, 0.0, e)
        bounded = np.clip(e, -self._integral_error, self._integral_error)
        self.integral = np.clip(self.integral + self._ki * bounded * dt, -self._limit,
                                self._limit)
        out = self._kp * e + self.integral
        if qd is not None:
            ed = (np.zeros(N_JOINTS) if qd_des is None else np.asarray(qd_des, dtype=float)) \
                - np.asarray(qd, dtype=float)
            out = out + self._kd * ed
        return out


def coupling_feedforward(q_des: Vector, q_ref: Vector) -> np.ndarray:
    """What to add to the stepper goals of J1..J4 (rad, 4) so the capstans end up where the
    goals say although the routes turn them by ``C·(q − q_ref)``: ``−C·(q_des − q_ref)``
    (``q_ref``: joint angles at the nodes' power-up, rad; only J1..J4 are used)."""
    c = arm_route_coupling_matrix()
    dq = np.asarray(q_des, dtype=float)[:N_STEPPERS] - np.asarray(q_ref, dtype=float)[:N_STEPPERS]
    return -(c @ dq)


def elastic_deflections(state: ArmState, q_ref: Vector) -> np.ndarray:
    """The series-elastic elements' true deflections (rad, J1..J4): capstan − joint, with the
    capstan = motor angle + ``C·(q − q_ref)`` (the nodes' own deflection leaves out the
    routes' coupling)."""
    c = arm_route_coupling_matrix()
    q = np.array([s.angle for s in state.steppers])
    motor = np.array(state.motor_joints)
    return motor + c @ (q - np.asarray(q_ref, dtype=float)[:N_STEPPERS]) - q


# ----------------------------------------------------------------------------- trajectories


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


# ----------------------------------------------------------------------------- the loop


@dataclass
class TrackingLog:
    """What a control run saw, one row per cycle: ``t`` (s, transport clock), ``desired``
    and ``measured`` joint angles (rad, 7), and ``stall_events`` (stepper joint names whose
    node latched STALLED, in order; each was cleared and its torque re-enabled)."""

    t: list[float] = field(default_factory=list)
    desired: list[np.ndarray] = field(default_factory=list)
    measured: list[np.ndarray] = field(default_factory=list)
    stall_events: list[str] = field(default_factory=list)

    def errors(self) -> np.ndarray:
        """Per cycle, desired − measured (rad, n×7)."""
        return np.array(self.desired) - np.array(self.measured)


class JointController:
    """The joint-space PID loop of ``arm`` (see the module docs) at ``rate_hz`` (None: back
    to back), with the coupling feed-forward unless ``feedforward=False``, and the stepper
    goals led by their braking distance at the nodes' ``stepper_accel`` (rad/s²; None: not
    led)."""

    def __init__(self, arm: Arm, gains: PidGains | None = None,
                 rate_hz: float | None = DEFAULT_RATE_HZ, feedforward: bool = True,
                 stepper_accel: float | None = STEPPER_ACCEL_RAD_S2) -> None:
        if rate_hz is not None and not rate_hz > 0:
            raise UsageError(f"control rate {rate_hz} must be > 0 Hz")
        self.arm = arm
        self.pid = JointPid(gains)
        self.period = 0.0 if rate_hz is None else 1.0 / rate_hz
        self.feedforward = feedforward
        #: The stepper nodes' acceleration limit (rad/s²) for :func:`braking_lead`; None:
        #: goals on the path itself.
        self.stepper_accel = stepper_accel
        #: Joint angles (rad, absolute frame when homed) at the stepper nodes' power-up.
        self.q_ref = self.power_up_angles()
        self.state: ArmState | None = None
        self._last_t: float | None = None
        #: Per stepper joint, when (s) its node latched STALLED lately.
        self._stalls: dict[int, list[float]] = {}
        #: The latches and alarm bits there were when the controller took the arm: a new
        #: one (other than a STALLED it clears, below) stops the motion.
        self._latched: dict[str, tuple[str, ...]] = {}

    def power_up_angles(self) -> np.ndarray:
        """Joint angles (rad) where the stepper nodes powered up (their encoder count then,
        in this arm's frame), where each capstan was aligned with its motor."""
        offsets = (self.arm.calibration.offsets if self.arm.calibration is not None
                   else (0.0,) * N_JOINTS)
        q = np.zeros(N_JOINTS)
        for i, j in enumerate(self.arm.steppers):
            q[i] = j.counts_to_rad(self.arm.encoder_at_power_up[i]) + offsets[i]
        return q

    def goals(self, q_des: np.ndarray, qd_des: np.ndarray, state: ArmState, dt: float
              ) -> np.ndarray:
        """The seven joint goals (rad) for the next cycle from the last ``state``."""
        q = np.array(state.joints)
        qd = np.array([s.velocity for s in state.steppers] + [s.velocity for s in state.servos])
        u = q_des + self.pid.update(q_des, q, dt, qd_des, qd)
        if self.feedforward:
            u[:N_STEPPERS] += coupling_feedforward(q_des, self.q_ref)
        if self.stepper_accel is not None:
            u[:N_STEPPERS] += braking_lead(qd_des[:N_STEPPERS], self.stepper_accel)
        return u

    def settled(self, state: ArmState, q_des: Vector, still: float = 0.002) -> bool:
        """True if every joint is within twice its deadband of ``q_des`` (rad: where the
        loop comes to rest - the integral holds within the deadband, and the sensor reads in
        steps of one) and every stepper joint slower than ``still`` (rad/s: its ringing has
        died down)."""
        error = np.abs(np.asarray(q_des, dtype=float) - np.array(state.joints))
        return bool(np.all(error <= 2.0 * np.array(self.pid.gains.deadband) + 1e-9)
                    and all(abs(s.velocity) <= still for s in state.steppers))

    def _count_stalls(self, joints: list[int], t: float) -> None:
        """Note a STALLED latch of each of ``joints`` at ``t`` (s); raise
        :class:`~host.errors.StallError` (the node holds it, latched) for a joint that latched more
        than :data:`STALL_RETRIES` times within :data:`STALL_WINDOW_S`."""
        for joint in joints:
            recent = [u for u in self._stalls.get(joint, []) if t - u < STALL_WINDOW_S] + [t]
            self._stalls[joint] = recent
            if len(recent) > STALL_RETRIES:
                name = JOINT_NAMES[joint]
                raise StallError(
                    f"{name} latched STALLED {len(recent)} times within {STALL_WINDOW_S:g} s "
                    f"although the controller re-enabled it: something holds the joint or its "
                    f"load is more than its stepper holds; its node holds it where it "
                    f"stopped (clear the obstruction or lighten the load, then "
                    f"Arm.clear_errors())",
                    joint=name)

    def start(self) -> ArmState:
        """Enable every joint's torque, each joint whose torque was off holding where it is
        (not heading for a goal its node kept), and take the first state.
        :class:`~host.errors.LimitError` names a joint whose node keeps its torque off (a
        latched alarm: :meth:`~host.arm.Arm.clear_errors` first)."""
        self.arm.torque(True, hold=True)
        require_torque(self.arm, what="the controller drives the arm")
        self.state = self.arm.state()
        self._last_t = self.state.t
        self._latched = latches(self.state)
        return self.state

    def step(self, q_des: Vector, qd_des: Vector | None = None,
             log: TrackingLog | None = None) -> ArmState:
        """One cycle towards ``q_des`` (rad), ``qd_des`` (rad/s)."""
        state = self.state if self.state is not None else self.start()
        qa = np.asarray(q_des, dtype=float)
        qda = np.zeros(N_JOINTS) if qd_des is None else np.asarray(qd_des, dtype=float)
        check_goals(qa, state.joints, homed=self.arm.homed, what="desired angle")
        check_finite(qda, "desired speed")
        stop_for_alarms(self.arm, state, self._latched, "the controlled motion",
                        ignore={JOINT_NAMES[s.joint] for s in state.steppers if s.stalled})
        dt = max(state.t - (self._last_t if self._last_t is not None else state.t), 0.0)
        self._last_t = state.t
        u = self.goals(qa, qda, state, dt if dt > 0 else self.period)
        commands: list[Command] = [self.arm.make_position(i, float(u[i]))
                                   for i in range(N_JOINTS)]
        stalled = [s for s in state.steppers if s.stalled]
        if stalled:  # the node turned its torque off: clear the latch, torque on again
            if log is not None:
                log.stall_events += [JOINT_NAMES[s.joint] for s in stalled]
            self._count_stalls([s.joint for s in stalled], state.t)
            self.arm.clear_errors()
            commands += [self.arm.make_torque(s.joint, True) for s in stalled]
        self.state = self.arm.cycle(commands)
        if log is not None:
            log.t.append(self.state.t)
            log.desired.append(qa)
            log.measured.append(np.array(self.state.joints))
        return self.state

    def run(self, trajectory: Trajectory | Callable[[float], tuple[np.ndarray, np.ndarray]],
            duration: float, log: TrackingLog | None = None,
            until: Callable[[ArmState], bool] | None = None) -> ArmState:
        """Follow ``trajectory(t)`` (``t`` from 0 at the call) for ``duration`` seconds of
        the transport's clock, one cycle per period, or until ``until(state)``.

        A :class:`Trajectory` passes the gate first (:func:`host.arm_gate.check_path`: it
        starts where the arm is, every point in range, no joint faster or accelerating more
        than its limits), or :class:`~host.errors.LimitError` is raised before anything
        moves; every cycle's desired angles are checked against the joint ranges, and a
        new alarm stops the motion, the arm held (:class:`~host.errors.JointAlarmError`)."""
        clock = self.arm.transport
        state = self.state if self.state is not None else self.start()
        if math.isnan(duration) or duration < 0:
            raise LimitError(f"control run duration {duration} must be >= 0 s")
        if isinstance(trajectory, Trajectory):
            check_path(trajectory.times, trajectory.points, state.joints,
                       homed=self.arm.homed, smooth=trajectory.smooth)
        t0 = clock.now()
        tick = 0
        while True:
            now = clock.now()
            if now - t0 >= duration or (until is not None and until(state)):
                return state
            q_des, qd_des = trajectory(now - t0)
            state = self.step(q_des, qd_des, log)
            tick += 1
            if self.period:
                wait = t0 + tick * self.period - clock.now()
                if wait > 0:
                    clock.sleep(wait)


# ----------------------------------------------------------------------------- Cartesian


@dataclass(frozen=True)
class CartesianMove:
    """A Cartesian move's outcome: ``goals`` (the IK's joint goals, rad, 7), ``ik``, the last
    ``state``, the flange's ``position_error`` (m: FK of the measured joints vs the target)
    and ``reached`` (within the tolerance asked)."""

    goals: tuple[float, ...]
    ik: arm_kinematics.IkResult
    state: ArmState
    position_error: float
    reached: bool


#: Extra IK starting points (rad, J1..J7) besides the present joints and the IK's default:
#: the arm hanging, reaching forward high, wrist bent, elbow bent under the shoulder; each
#: leads the redundant arm to another of its configurations for the same flange position.
IK_SEEDS: Final[tuple[tuple[float, ...], ...]] = (
    (0.0,) * 7,
    (0.0, 0.8, 0.0, 0.3, 0.0, 0.3, 0.0),
    (0.0, 0.2, 0.0, 0.6, 0.0, 0.8, 0.0),
    (0.0, 1.0, 0.0, 0.1, 0.0, 0.5, 0.0),
    (0.0, 0.4, 0.0, 1.2, 0.0, -0.6, 0.0),
    (0.0, -0.2, 0.0, 0.5, 0.0, 1.2, 0.0))
#: The most of its stall torque (:func:`host.arm_gravity.stall_torques`) a stepper joint may
#: hold against gravity at a :func:`moveto` goal or on the way there: the rest is the
#: motion's own dynamics' margin.
MOVETO_LOAD_LIMIT: Final = 0.7


@dataclass(frozen=True)
class _Candidate:
    """An IK solution and its worst static load: the stepper ``joint`` (0..3), its holding
    torque (N·m) and that over its stall torque, and whether the solution is ``safe``."""

    ik: arm_kinematics.IkResult
    joint: int
    torque: float
    fraction: float
    safe: bool


def _candidate(ik: arm_kinematics.IkResult, q_now: np.ndarray, hand: bool,
               load_limit: float) -> _Candidate:
    """Rate ``ik`` by the stepper loads along the straight joint path from ``q_now`` (11
    points).  Safe: at the goal every joint within ``load_limit`` of its stall torque, and
    on the way no joint more loaded than that or than it already is at ``q_now`` (a move
    away from a heavy pose is allowed)."""
    stall = arm_gravity.stall_torques()
    start = np.abs(arm_gravity.spring_torques(q_now, hand)) / stall
    allowed = np.maximum(start, load_limit)
    worst = (0, 0.0, -1.0)
    safe = True
    for a in np.linspace(0.0, 1.0, 11)[1:]:
        torques = arm_gravity.spring_torques(q_now + a * (ik.q - q_now), hand)
        fractions = np.abs(torques) / stall
        safe = safe and bool(np.all(fractions <= (load_limit if a == 1.0 else allowed)))
        j = int(np.argmax(fractions))
        if fractions[j] > worst[2]:
            worst = (j, float(torques[j]), float(fractions[j]))
    return _Candidate(ik, *worst, safe)


def choose_ik(xyz: Vector, rpy: Vector | None, q_now: Vector, *, hand: bool = True,
              load_limit: float = MOVETO_LOAD_LIMIT) -> arm_kinematics.IkResult:
    """The IK solution :func:`moveto` drives to: among the solutions from the present joints
    ``q_now`` (rad), the IK's default start and :data:`IK_SEEDS` that reach ``xyz`` (m)
    within 1 mm (and ``rpy`` within 0.01 rad if given), the nearest to ``q_now`` (largest
    joint change) whose every stepper joint holds at most ``load_limit`` of its stall torque
    against gravity (:mod:`host.arm_gravity`, ``hand`` on the flange or not) at the goal, and
    on the straight joint path there at most that or what it holds at ``q_now``.  :class:`~host.errors.UsageError` if the target is out
    of reach, or if every solution overloads a joint (naming it, its torque and its
    limit)."""
    check_cartesian(xyz, rpy)
    here = np.asarray(q_now, dtype=float)
    try:
        solutions = [arm_kinematics.solve_ik(xyz, rpy, q0=seed)
                     for seed in (here, None, *IK_SEEDS)]
    except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        raise LimitError(f"{tuple(float(v) for v in xyz)} m: no joint angles reach it "
                         f"({exc})") from exc
    reaching = [ik for ik in solutions if ik.position_error <= 1e-3
                and (rpy is None or ik.orientation_error <= 0.01)]
    if not reaching:
        miss = min(ik.position_error for ik in solutions)
        raise UsageError(f"{tuple(round(float(v), 3) for v in xyz)} m is out of reach "
                         f"(IK misses it by {miss * 1000:.0f} mm); the flange "
                         f"reaches about 1.04 m from the shoulder axis")
    rated = [_candidate(ik, here, hand, load_limit) for ik in reaching]
    safe = [c for c in rated if c.safe]
    if safe:
        return min(safe, key=lambda c: float(np.max(np.abs(c.ik.q - here)))).ik
    best = min(rated, key=lambda c: c.fraction)
    stall = float(arm_gravity.stall_torques()[best.joint])
    raise UsageError(
        f"{JOINT_NAMES[best.joint]} would carry {abs(best.torque):.1f} N·m of its "
        f"{stall:.1f} N·m stall limit at or on the way to "
        f"{tuple(round(float(v), 3) for v in xyz)} m (at most {load_limit:.0%} allowed, "
        f"{'with' if hand else 'without'} the hand): choose a target nearer the body or "
        f"below the shoulder")


def moveto(arm: Arm, xyz: Vector, rpy: Vector | None = None, *,
           speed: float = 0.4, tolerance_m: float = 0.002, settle_timeout: float = 8.0,
           controller: JointController | None = None, allow_unhomed: bool = False,
           hand: bool = True, log: TrackingLog | None = None) -> CartesianMove:
    """Move the flange to ``xyz`` (m, base frame), oriented ``rpy`` (rad) if given: IK
    (:func:`choose_ik`: the solution nearest the present joints that no stepper joint holds
    more than :data:`MOVETO_LOAD_LIMIT` of its stall torque in, ``hand`` saying whether the
    hand's weight is on the flange; assuming it is errs on the safe side), a straight
    joint-space path at ``speed`` (rad/s, fastest joint), then the PID holds the goals until
    the flange (by FK of the measured joints) is within ``tolerance_m`` and the arm is at
    rest (:class:`~host.arm_rest.RestWatch`), or ``settle_timeout`` (s) passes.

    Refuses (:class:`~host.errors.UsageError`) an arm that is not homed unless
    ``allow_unhomed``, a target the IK cannot reach within 1 mm, and one where every IK
    solution would load a stepper joint beyond the limit."""
    check_cartesian(xyz, rpy)
    if not arm.homed and not allow_unhomed:
        raise UsageError("the arm is not homed: its joint angles are relative to power-up; "
                         "home it first (armctl home / Arm.home())")
    control = controller or JointController(arm)
    state = control.state or control.start()
    q_now = np.array(state.joints)
    ik = choose_ik(xyz, rpy, q_now, hand=hand)
    goals = ik.q
    trajectory = Trajectory(timed_path([q_now, goals], speed, smooth=True), smooth=True)
    state = control.run(trajectory, trajectory.duration, log)
    target = np.asarray(xyz, dtype=float)

    rest = RestWatch()

    def settled(s: ArmState) -> bool:
        err = float(np.linalg.norm(arm_kinematics.forward(s.joints).position - target))
        still = rest.update(s)
        return err <= tolerance_m and still

    state = control.run(lambda _t: (goals, np.zeros(N_JOINTS)), settle_timeout, log,
                        until=settled)
    error = float(np.linalg.norm(arm_kinematics.forward(state.joints).position - target))
    return CartesianMove(tuple(float(v) for v in goals), ik, state, error,
                         error <= tolerance_m)


# ----------------------------------------------------------------------------- waypoints


def record_waypoints(arm: Arm, seconds: float, *, rate_hz: float = 50.0,
                     min_change: float = 0.01,
                     on_sample: Callable[[ArmState], None] | None = None,
                     kept: list[Waypoint] | None = None) -> list[Waypoint]:
    """Turn every joint's torque off and sample the joints at ``rate_hz`` for ``seconds``
    while someone moves the arm by hand; keep a waypoint whenever some joint moved more than
    ``min_change`` (rad) since the last one kept, and the last sample.  ``on_sample`` sees
    every state.  The torque stays off.  The waypoints go into ``kept`` (a new list if
    None) as they come, so a caller keeps those recorded before an error or Ctrl-C."""
    if not seconds > 0 or not rate_hz > 0:
        raise UsageError("record for > 0 s at > 0 Hz")
    clock = arm.transport
    state = arm.torque(False)
    t0 = state.t
    if kept is None:
        kept = []
    kept.append(Waypoint(0.0, tuple(state.joints)))
    last = state
    period = 1.0 / rate_hz
    tick = 0
    while clock.now() - t0 < seconds:
        tick += 1
        wait = t0 + tick * period - clock.now()
        if wait > 0:
            clock.sleep(wait)
        last = arm.cycle()
        if on_sample is not None:
            on_sample(last)
        if max(abs(a - b) for a, b in zip(last.joints, kept[-1].joints, strict=True)) \
                > min_change:
            kept.append(Waypoint(last.t - t0, tuple(last.joints)))
    if kept[-1].t != last.t - t0:
        kept.append(Waypoint(last.t - t0, tuple(last.joints)))
    return kept


def play_waypoints(arm: Arm, waypoints: Sequence[Waypoint], *, approach_speed: float = 0.3,
                   time_scale: float = 1.0, settle_s: float = 1.0,
                   controller: JointController | None = None,
                   log: TrackingLog | None = None) -> ArmState:
    """Play recorded waypoints: from where the arm is to the first at ``approach_speed``
    (rad/s), then through the rest at their recorded times (× ``time_scale``), then hold
    the last for ``settle_s`` seconds.

    The whole path passes the gate before anything moves (:func:`host.arm_gate.check_path`):
    a waypoint outside its joint's range, or steps needing more speed or acceleration than
    a joint has, raise :class:`~host.errors.LimitError` naming the joint and the waypoint
    (and how much larger a ``time_scale`` would do); nothing is clamped."""
    if not waypoints:
        raise UsageError("no waypoints to play")
    for value, what in ((approach_speed, "approach speed (rad/s)"),
                        (time_scale, "time scale")):
        if not (math.isfinite(value) and value > 0):
            raise LimitError(f"{what} {value} must be a finite number > 0")
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise LimitError(f"settle time {settle_s} must be a finite number >= 0 s")
    control = controller or JointController(arm)
    state = control.state or control.start()
    first = np.asarray(waypoints[0].joints, dtype=float)
    check_goals(first, state.joints, homed=arm.homed, what="goal (waypoint 1)")
    approach = timed_path([state.joints, first], approach_speed)
    lead = approach[-1].t
    t_first = waypoints[0].t
    path = approach + [Waypoint(lead + (w.t - t_first) * time_scale, w.joints)
                       for w in waypoints[1:]]
    extra = len(approach) - 1

    def label(k: int) -> str:
        return "where the arm is" if k < extra else f"waypoint {k - extra + 1}"

    check_path([w.t for w in path], np.array([w.joints for w in path]), state.joints,
               homed=arm.homed, label=label,
               slower="a time scale (time_scale=, armctl waypoints play --time-scale) of")
    trajectory = Trajectory(path)
    return control.run(trajectory, trajectory.duration + settle_s, log)


def save_waypoints(path: str | Path, waypoints: Iterable[Waypoint]) -> None:
    """Write a waypoint file (JSON lines, see the module docs)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write(json.dumps({"kind": WAYPOINTS_KIND, "version": WAYPOINTS_VERSION,
                            "joints": list(JOINT_NAMES), "units": "rad, s"}) + "\n")
        for w in waypoints:
            f.write(json.dumps({"t": w.t, "joints": list(w.joints)}) + "\n")


def load_waypoints(path: str | Path) -> list[Waypoint]:
    """Read a waypoint file; :class:`~host.errors.UsageError` names the bad line."""
    out: list[Waypoint] = []
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                if "kind" in record:
                    if record["kind"] != WAYPOINTS_KIND or record.get("version") != 1:
                        raise ValueError(f"not an {WAYPOINTS_KIND} v1 header")
                    continue
                t = float(record["t"])
                joints = tuple(float(v) for v in record["joints"])
                if len(joints) != N_JOINTS or not all(map(math.isfinite, (t, *joints))):
                    raise ValueError(f"needs t and {N_JOINTS} finite joint angles")
                if out and t < out[-1].t:
                    raise ValueError("time goes backwards")
            except (ValueError, KeyError, TypeError) as exc:
                raise UsageError(f"{path}:{number}: bad waypoint line: {exc}") from exc
            out.append(Waypoint(t, joints))
    if not out:
        raise UsageError(f"{path} holds no waypoints")
    return out
