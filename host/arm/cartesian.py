"""Cartesian moves of the arm's flange: inverse kinematics chosen for what the stepper
joints can hold against gravity, then a smooth joint-space move on the joint loop.

:func:`choose_ik` solves the IK from several starting points (the present joints, the IK's
default, :data:`IK_SEEDS`) and takes the solution nearest the present joints whose every
stepper joint holds at most :data:`MOVETO_LOAD_LIMIT` of its stall torque against gravity
(:mod:`host.arm.gravity`), at the goal and on the way there.  :func:`moveto` drives there
along a minimum-jerk path (:class:`~host.arm.trajectory.Trajectory` with ``smooth``) on a
:class:`~host.arm.joint_loop.JointController`, then holds the goals until the flange (by
forward kinematics of the measured joints) is within the tolerance and the arm at rest.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

import host.arm.gravity as arm_gravity
import host.arm.kinematics as arm_kinematics
from host.arm.gate import check_cartesian
from host.arm.geometry import ArmGeometry
from host.arm.interface import DrivenArm
from host.arm.joint_loop import JointController, TrackingLog
from host.arm.rest import RestWatch
from host.arm.state import JOINT_NAMES, N_JOINTS, ArmState
from host.arm.trajectory import Trajectory, Vector, timed_path
from host.errors import LimitError, UsageError

#: :func:`moveto`'s defaults: the fastest joint's speed on the way (rad/s), how near the
#: flange must come to the target (m), and how long the goals are held for it (s).
MOVETO_SPEED_RAD_S: Final = 0.4
MOVETO_TOLERANCE_M: Final = 0.002
MOVETO_SETTLE_S: Final = 8.0


@dataclass(frozen=True)
class CartesianMove:
    """A Cartesian move's outcome: ``goals`` (the IK's joint goals, rad, 7), ``ik``, the last
    ``state``, the flange's ``position_error`` (m: FK of the measured joints vs the target)
    and ``reached`` (within the tolerance asked); ``stopped``: a guarded move's ``until``
    held the arm where it was before the target (``reached`` is then False)."""

    goals: tuple[float, ...]
    ik: arm_kinematics.IkResult
    state: ArmState
    position_error: float
    reached: bool
    stopped: bool = False


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
#: The most of its stall torque (:func:`host.arm.gravity.stall_torques`) a stepper joint may
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
              load_limit: float = MOVETO_LOAD_LIMIT,
              geometry: ArmGeometry | None = None) -> arm_kinematics.IkResult:
    """The IK solution :func:`moveto` drives to: among the solutions from the present joints
    ``q_now`` (rad), the IK's default start and :data:`IK_SEEDS` that reach ``xyz`` (m)
    within 1 mm (and ``rpy`` within 0.01 rad if given), the nearest to ``q_now`` (largest
    joint change) whose every stepper joint holds at most ``load_limit`` of its stall torque
    against gravity (:mod:`host.arm.gravity`, ``hand`` on the flange or not) at the goal, and
    on the straight joint path there at most that or what it holds at ``q_now``; the IK of
    ``geometry`` (None: the CAD model).  :class:`~host.errors.UsageError` if the target is out
    of reach, or if every solution overloads a joint (naming it, its torque and its
    limit)."""
    check_cartesian(xyz, rpy)
    here = np.asarray(q_now, dtype=float)
    try:
        solutions = [arm_kinematics.solve_ik(xyz, rpy, q0=seed, geometry=geometry)
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


def moveto(arm: DrivenArm, xyz: Vector, rpy: Vector | None = None, *,
           speed: float = MOVETO_SPEED_RAD_S, tolerance_m: float = MOVETO_TOLERANCE_M,
           settle_timeout: float = MOVETO_SETTLE_S,
           controller: JointController | None = None, allow_unhomed: bool = False,
           hand: bool = True, log: TrackingLog | None = None,
           until: Callable[[ArmState], bool] | None = None,
           geometry: ArmGeometry | None = None) -> CartesianMove:
    """Move the flange to ``xyz`` (m, base frame), oriented ``rpy`` (rad) if given: IK
    (:func:`choose_ik`: the solution nearest the present joints that no stepper joint holds
    more than :data:`MOVETO_LOAD_LIMIT` of its stall torque in, ``hand`` saying whether the
    hand's weight is on the flange; assuming it is errs on the safe side), a straight
    joint-space path at ``speed`` (rad/s, fastest joint), then the PID holds the goals until
    the flange (by FK of the measured joints) is within ``tolerance_m`` and the arm is at
    rest (:class:`~host.arm.rest.RestWatch`), or ``settle_timeout`` (s) passes.

    A guarded move: ``until(state)``, asked every cycle of the path, stops it where the arm
    is the first time it is true (a contact felt), and the PID then holds the joints there
    until the arm is at rest (``stopped`` in the result).

    ``geometry``: the arm's kinematics (:class:`~host.arm.geometry.ArmGeometry`: its
    calibration, perhaps with a tool's tip as the point moved; None: the CAD model's flange).

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
    ik = choose_ik(xyz, rpy, q_now, hand=hand, geometry=geometry)
    goals = ik.q
    trajectory = Trajectory(timed_path([q_now, goals], speed, smooth=True), smooth=True)
    state = control.run(trajectory, trajectory.duration, log, until=until)
    target = np.asarray(xyz, dtype=float)
    stopped = until is not None and until(state)
    hold = np.array(state.joints) if stopped else goals
    held_at = arm_kinematics.forward(hold, geometry).position if stopped else target

    rest = RestWatch()

    def settled(s: ArmState) -> bool:
        err = float(np.linalg.norm(arm_kinematics.forward(s.joints, geometry).position
                                   - held_at))
        still = rest.update(s)
        return err <= tolerance_m and still

    state = control.run(lambda _t: (hold, np.zeros(N_JOINTS)), settle_timeout, log,
                        until=settled)
    error = float(np.linalg.norm(arm_kinematics.forward(state.joints, geometry).position
                                 - target))
    return CartesianMove(tuple(float(v) for v in goals), ik, state, error,
                         not stopped and error <= tolerance_m, stopped)
