"""The arm's joint loop on the link's clock: PID with the route-coupling feed-forward and the
stepper goals' braking lead, following a joint-space path (:mod:`host.arm.trajectory`).

**The loop.**  Every ``1/rate_hz`` seconds of the transport's clock (100 Hz by default, as on
the original arm; ``rate_hz=None`` cycles back to back, as fast as the wire allows) one
:meth:`~host.arm.facade.Arm.cycle` sends the goals computed from the previous cycle's state and
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

(:func:`host.arm.motor_goals.coupling_feedforward`), which keeps each capstan where the PID wants it whatever the
joints before it do.  A node cannot see the other joints: its ``deflection`` register
(motor after reduction − joint) differs from the elastic element's true deflection by
``−C·Δq`` (:func:`elastic_deflections` gives the true one), and :meth:`host.arm.facade.Arm.cycle`
sends it that offset with every goal (``deflection_offset``), so its SLIP/STALLED
protection watches the elastic element and does not trip under this compensation.

**Braking lead** (the first four joints).  A stepper node plans every goal as a stop: it
brakes towards it at its ``acceleration_limit``.  Goals a few milliseconds apart along a path
would each be a stop it must be able to make, so the joint slows to what it could stop from
within one step and trails the path (more, the faster the cycle).  The controller puts each
stepper goal ahead by the braking distance at the path's speed, ``sign(q̇_des)·q̇_des²/(2a)``
(:func:`braking_lead`); at the path's end ``q̇_des`` is 0 and the goal is the path's.

**Taking over** (:meth:`JointController.start`).  A controller that takes the arm from
another one (each Cartesian move makes its own), from a plain move or from another program
starts its integral where each resting stepper's goal already is: ``goal − q − feed-forward``
(clamped to ``integral_limit``), so a load the last commander held (a mug in the hand, a
push, an unmodelled payload) stays held.  With the integral from zero the arm dropped by the
whole load's deflection at every new move (the mug demo's hand fell 6 cm in 0.3 s, and the
mug slid in the grip).

Cartesian moves (:mod:`host.arm.cartesian`) and waypoint playback (:mod:`host.arm.waypoints`)
run on this loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from host.arm.gate import check_finite, check_goals, check_path, latches, require_torque
from host.arm.hold import stop_for_alarms
from host.arm.interface import DrivenArm
from host.arm.motor_goals import coupling_feedforward, power_up_angles
from host.arm.state import JOINT_NAMES, N_JOINTS, N_STEPPERS, ArmState, Command
from host.arm.trajectory import Trajectory, Vector
from host.errors import LimitError, StallError, UsageError
from protocol.control_tables import STEPPER_TABLE
from protocol.robot import ARM_ENCODER_COUNTS_PER_REV, RX64_RAD_PER_UNIT, arm_route_coupling_matrix

#: The original arm's control rate (Hz).
DEFAULT_RATE_HZ: Final = 100.0
#: A stepper joint's STALLED latches the controller clears and re-enables within
#: :data:`STALL_WINDOW_S` (s) before it gives up (:class:`~host.errors.StallError`): a joint
#: that someone holds, or that carries more than it can, is not driven again and again.
STALL_RETRIES: Final = 3
STALL_WINDOW_S: Final = 2.0
#: A stepper joint slower than this (rad/s), its node not moving, is at rest: a controller
#: taking the arm over starts its integral where that joint's goal already is (bumpless).
TAKE_OVER_STILL_RAD_S: Final = 0.02


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


def elastic_deflections(state: ArmState, q_ref: Vector) -> np.ndarray:
    """The series-elastic elements' true deflections (rad, J1..J4): capstan − joint, with the
    capstan = motor angle + ``C·(q − q_ref)`` (the nodes' own deflection leaves out the
    routes' coupling)."""
    c = arm_route_coupling_matrix()
    q = np.array([s.angle for s in state.steppers])
    motor = np.array(state.motor_joints)
    return motor + c @ (q - np.asarray(q_ref, dtype=float)[:N_STEPPERS]) - q


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

    def __init__(self, arm: DrivenArm, gains: PidGains | None = None,
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
        return power_up_angles(self.arm.calibration, self.arm.steppers,
                               self.arm.encoder_at_power_up)

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
        latched alarm: :meth:`~host.arm.facade.Arm.clear_errors` first)."""
        self.arm.torque(True, hold=True)
        require_torque(self.arm, what="the controller drives the arm")
        self.state = self.arm.state()
        self._last_t = self.state.t
        self._latched = latches(self.state)
        self.take_over(self.state)
        return self.state

    def take_over(self, state: ArmState) -> None:
        """Start the integral (rad) of each stepper joint at rest in ``state`` where its
        node's goal already is, ``goal − q − feed-forward(q)`` clamped to ``integral_limit``,
        so the first cycle's goal holding ``q`` is the goal the node has (bumpless
        transfer); a joint still moving starts from zero."""
        q = np.array(state.joints)
        held = np.array([s.goal for s in state.steppers]) - q[:N_STEPPERS]
        if self.feedforward:
            held -= coupling_feedforward(q, self.q_ref)
        limit = np.array(self.pid.gains.integral_limit[:N_STEPPERS])
        rest = np.array([not s.moving and abs(s.velocity) < TAKE_OVER_STILL_RAD_S
                         for s in state.steppers])
        self.pid.integral[:N_STEPPERS] = np.where(rest, np.clip(held, -limit, limit), 0.0)

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

        A :class:`Trajectory` passes the gate first (:func:`host.arm.gate.check_path`: it
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
