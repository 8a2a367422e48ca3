"""The one gate every arm motion passes before anything moves.

:meth:`host.arm.facade.Arm.move`, the joint controller's paths (:meth:`host.arm.joint_loop.JointController.run`:
:func:`~host.arm.cartesian.moveto`, :func:`~host.arm.waypoints.play_waypoints`, the demo's
joint paths) and ``armctl`` all check here, and a refusal is a
:class:`~host.errors.LimitError` (a :class:`~host.errors.UsageError`: ``armctl`` exits 2)
naming the joint, raised before a single goal is sent:

* **finite numbers**: goals, times, durations, Cartesian targets (:func:`check_finite`);
* **the joint's range** (:data:`protocol.robot.ARM_JOINT_LIMITS`), for the servos always and
  for the steppers once the arm is homed; a goal within ``tolerance`` of where a joint
  already is passes (a joint out there may hold).  A stepper of an arm not homed counts
  its angle from power-up, so its range is unknown, but a goal further from its present
  angle than the joint's whole range is beyond a stop wherever the joint is: refused
  (:func:`check_goals`);
* **a move's speed** (:meth:`host.arm.facade.Arm.move`): no stepper joint faster than
  :data:`MOVE_STEPPER_SPEED_RAD_S` (0.8 rad/s: faster, its elastic element winds past its
  stall limit in loaded poses), a ``duration`` needing more refused (:func:`check_speeds`);
* **speed and acceleration** (:data:`~protocol.robot.ARM_JOINT_SPEED_LIMITS`,
  :data:`~protocol.robot.ARM_JOINT_ACCEL_LIMITS`): a timed path whose segments need more
  speed, or whose corners more acceleration, than a joint has is refused, not clamped
  (:func:`check_path`); it says how much slower would do.  A path starts where the arm
  is (within :data:`START_TOLERANCE_RAD`) and at rest, and ends at rest: the
  acceleration at a corner is the change of speed over the mean of the two segments' times
  (at the path's ends, from and to rest over the first and last segment's time), less what
  the sensors' resolution could make of a recorded path (a count, a position unit at each
  end of a segment);
* **torque on** for every joint a motion drives (:func:`require_torque`): a goal sent to a
  joint whose torque is off waits in its node, and the joint jumps there when the torque
  comes on; a joint its node turned off after an alarm is named with its latch;
* **Cartesian targets** finite, orientations within ±2π (:func:`check_cartesian`); reach is
  the IK's to judge (:func:`host.arm.cartesian.choose_ik`), but a target further than
  :data:`REACH_M` from the base is refused at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

import numpy as np

from host.arm.interface import ArmReader
from host.arm.state import JOINT_NAMES, N_JOINTS, N_STEPPERS, ArmState
from host.errors import LimitError
from protocol.control_tables import StepperFlag
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_FLANGE_OFFSET_M,
    ARM_JOINT_ACCEL_LIMITS,
    ARM_JOINT_LIMITS,
    ARM_JOINT_OFFSETS_M,
    ARM_JOINT_SPEED_LIMITS,
    RX64_RAD_PER_UNIT,
)

#: A goal this close (rad) to where its joint is passes the range check.
HOLD_TOLERANCE_RAD: Final = 0.02
#: A path must start this close (rad) to the joint angles the arm is at.
START_TOLERANCE_RAD: Final = 0.05
#: Largest orientation angle (rad) a Cartesian goal may give.
MAX_RPY_RAD: Final = 2 * math.pi
#: Farthest the flange can be from the arm's base frame origin (m): every link stretched.
REACH_M: Final = float(sum(np.linalg.norm(o) for o in (*ARM_JOINT_OFFSETS_M,
                                                      ARM_FLANGE_OFFSET_M)))
#: The latches a stepper node reports in its flags (besides the status packet's alarm bits).
STEPPER_LATCHES: Final = StepperFlag.SLIP | StepperFlag.STALLED | StepperFlag.HARDWARE_ERROR
_SPEED = np.array(ARM_JOINT_SPEED_LIMITS)
#: Each joint's sensor resolution (rad): an encoder count, an RX-64 position unit.
_RESOLUTION = np.array([2 * math.pi / ARM_ENCODER_COUNTS_PER_REV] * N_STEPPERS
                       + [RX64_RAD_PER_UNIT] * (N_JOINTS - N_STEPPERS))
_ACCEL = np.array(ARM_JOINT_ACCEL_LIMITS)
#: Up to this many times slower, a refused path's message says how much slower would do
#: (beyond, the path has a jump in it, not a pace too fast).
MAX_SLOWDOWN_HINT: Final = 20.0
#: Slack (relative) on the speed and acceleration limits, for rounding in the caller's times.
_SLACK: Final = 1e-6
#: The most speed (rad/s) :meth:`host.arm.facade.Arm.move` gives a stepper joint, below the
#: controllers' step rates (1.1-1.44 rad/s): the nodes run a move as a trapezoid, and
#: accelerating or braking a loaded arm faster winds the elastic elements past their stall
#: limit (150 counts).  On the emulator, with the move's ramps (0.6 s up and down), moves at
#: 1.0-1.44 rad/s latched J2 or J4 STALLED in 7 of 32 (up from the arm's own pose to eight
#: poses, down from four raised ones); at up to 0.8 rad/s none of 24, peaks up to 120 counts.
MOVE_STEPPER_SPEED_RAD_S: Final = 0.8
#: Each joint's speed limit (rad/s) in :meth:`host.arm.facade.Arm.move`: the steppers'
#: :data:`MOVE_STEPPER_SPEED_RAD_S`, the servos' their own.
MOVE_SPEED_LIMITS: Final[tuple[float, ...]] = tuple(
    min(limit, MOVE_STEPPER_SPEED_RAD_S) if i < N_STEPPERS else limit
    for i, limit in enumerate(ARM_JOINT_SPEED_LIMITS))


def check_finite(values: Sequence[float] | np.ndarray, what: str,
                 names: Sequence[str] = JOINT_NAMES) -> None:
    """Refuse ``values`` (``what`` they are, each named by ``names``) unless every one is a
    finite number."""
    for name, v in zip(names, np.asarray(values, dtype=float).ravel(), strict=False):
        if not math.isfinite(v):
            raise LimitError(f"{name} {what} {v} is not a finite number",
                             joint=name if name in JOINT_NAMES else None)


def check_goals(goals: Sequence[float] | np.ndarray, present: Sequence[float], *,
                homed: bool, what: str = "goal",
                tolerance: float = HOLD_TOLERANCE_RAD) -> None:
    """Refuse joint goals (rad, J1..J7) that are not finite or outside their joint's range
    (see the module docs); ``present`` is where the joints are (rad), ``homed`` whether the
    stepper angles are absolute.  ``what`` says which goal in the message."""
    if len(goals) != N_JOINTS:
        raise LimitError(f"give {N_JOINTS} joint angles, J1..J7 (got {len(goals)})")
    check_finite(goals, what)
    for i, (goal, (lo, hi)) in enumerate(zip(goals, ARM_JOINT_LIMITS, strict=True)):
        name, here = JOINT_NAMES[i], float(present[i])
        if abs(goal - here) <= tolerance:
            continue
        if i < N_STEPPERS and not homed:
            width = hi - lo
            if abs(goal - here) > width:
                raise LimitError(
                    f"{name} {what} {goal:+.3f} rad is {abs(goal - here):.2f} rad from where "
                    f"the joint is ({here:+.3f} rad, from power-up: the arm is not homed), "
                    f"more than its whole range ({width:.2f} rad): it would drive into a "
                    f"stop; home the arm (armctl home) to move by absolute angles",
                    joint=name)
            continue
        if not lo <= goal <= hi:
            raise LimitError(f"{name} {what} {goal:+.3f} rad is outside the joint's range "
                             f"{lo:+.2f} … {hi:+.2f} rad", joint=name)


def check_duration(duration: float, what: str = "move duration") -> None:
    """Refuse a time (s) that is not a finite number > 0."""
    if not (math.isfinite(duration) and duration > 0):
        raise LimitError(f"{what} {duration} must be a finite number of seconds > 0")


def check_speeds(goals: Sequence[float], present: Sequence[float], duration: float,
                 limits: Sequence[float] = MOVE_SPEED_LIMITS) -> None:
    """Refuse a move from ``present`` to ``goals`` (rad) in ``duration`` (s) that needs a
    joint faster than its speed limit of ``limits`` (rad/s; a move's,
    :data:`MOVE_SPEED_LIMITS`, by default); the message gives the least duration that would
    do."""
    check_duration(duration)
    need = np.abs(np.asarray(goals, dtype=float) - np.asarray(present, dtype=float)) / duration
    most = np.asarray(limits, dtype=float)
    ratio = need / most
    j = int(np.argmax(ratio))
    if ratio[j] > 1 + _SLACK:
        least = duration * float(ratio[j])
        why = (" (a move's, for its elastic element; the controller steps at up to "
               f"{_SPEED[j]:.2f})") if most[j] < _SPEED[j] else ""
        raise LimitError(f"{JOINT_NAMES[j]} would need {need[j]:.2f} rad/s to arrive in "
                         f"{duration:g} s; its limit is {most[j]:.2f} rad/s{why}: take at "
                         f"least {math.ceil(least * 10) / 10:g} s", joint=JOINT_NAMES[j])


def path_rates(times: Sequence[float] | np.ndarray, points: np.ndarray, *, smooth: bool = False
               ) -> tuple[np.ndarray, np.ndarray]:
    """The speeds (rad/s, one row per segment) and accelerations (rad/s², one row per point)
    a timed path through ``points`` (rad, n × 7) at ``times`` (s) needs, starting and
    ending at rest; linear segments (corners as in the module docs, less the change of
    speed that the joints' sensor resolution could make: a recorded servo angle flickering
    by a position unit between two samples 20 ms apart is no acceleration), or with ``smooth``
    minimum-jerk ones (peak speed 1.875 × the mean, peak acceleration 5.77 × Δq/T²).  A
    segment of no time that moves needs an infinite speed."""
    t = np.asarray(times, dtype=float)
    q = np.asarray(points, dtype=float)
    dq = np.diff(q, axis=0)
    dt = np.diff(t)[:, None]
    moving = np.abs(dq) > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(moving, dq / np.where(dt > 0, dt, 0.0), 0.0)
        # how much of each speed the sensors' resolution could make up (both ends)
        blur = np.where(dt > 0, 2 * _RESOLUTION / np.where(dt > 0, dt, 1.0), 0.0)
    v = np.where(moving & (dt <= 0), np.inf, v)
    if smooth:
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(moving, 10 / math.sqrt(3) * np.abs(dq) / np.where(dt > 0, dt, 0.0) ** 2,
                         0.0)
        a = np.where(moving & (dt <= 0), np.inf, a)
        return np.abs(v) * 1.875, a
    if len(dq) == 0:
        return np.zeros((0, q.shape[1])), np.zeros((1, q.shape[1]))
    rest = np.zeros((1, q.shape[1]))
    speeds = np.vstack([rest, v, rest])
    spans = np.vstack([dt[:1], dt, dt[-1:]])
    blurs = np.vstack([rest, blur, rest])
    mean = (spans[:-1] + spans[1:]) / 2
    change = np.maximum(np.abs(np.diff(speeds, axis=0)) - blurs[:-1] - blurs[1:], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        accel = np.where(change > 0, change / np.where(mean > 0, mean, 0.0), 0.0)
    accel = np.where((change > 0) & (mean <= 0), np.inf, accel)
    return np.abs(v), accel


def slowdown(times: Sequence[float] | np.ndarray, points: np.ndarray, *,
             smooth: bool = False) -> float:
    """How many times slower a path must run so no joint needs more than its speed and
    acceleration limits (≤ 1: it runs as it is; inf: a jump, no time scale helps)."""
    speeds, accels = path_rates(times, points, smooth=smooth)
    worst_speed = float(np.max(speeds / _SPEED, initial=0.0))
    worst_accel = float(np.max(accels / _ACCEL, initial=0.0))
    return max(worst_speed, math.sqrt(worst_accel))


def check_path(times: Sequence[float] | np.ndarray, points: Sequence[Sequence[float]] | np.ndarray,
               present: Sequence[float], *, homed: bool, smooth: bool = False,
               label: Callable[[int], str] = lambda k: f"point {k}",
               slower: str = "") -> None:
    """Refuse a timed joint path (``times`` s, ``points`` rad, n × 7) that any check of the
    module docs fails: every point finite and in range, the path starting at ``present``
    (rad) and no segment faster, no corner sharper than the joints' limits.  ``label(k)``
    names point ``k`` in messages; ``slower`` (e.g. ``"a time scale of"``) names what the
    caller offers to slow a path down, and the message says by how much."""
    t = np.asarray(times, dtype=float)
    q = np.asarray(points, dtype=float)
    if q.ndim != 2 or q.shape[1] != N_JOINTS or len(t) != len(q) or not len(q):
        raise LimitError(f"a path needs points of {N_JOINTS} joint angles, each with a time")
    check_finite(t, "time", [label(k) for k in range(len(t))])
    if np.any(np.diff(t) < 0):
        raise LimitError("path times must not decrease")
    for k, point in enumerate(q):
        check_goals(point, present, homed=homed, what=f"goal ({label(k)})")
    off = np.abs(q[0] - np.asarray(present, dtype=float))
    j = int(np.argmax(off))
    if off[j] > START_TOLERANCE_RAD:
        raise LimitError(f"the path starts {off[j]:.3f} rad from where {JOINT_NAMES[j]} is: "
                         f"start it at the present joint angles", joint=JOINT_NAMES[j])
    speeds, accels = path_rates(t, q, smooth=smooth)
    scale = slowdown(t, q, smooth=smooth)
    hint = ""
    if slower and scale <= MAX_SLOWDOWN_HINT:
        hint = f"; {slower} {math.ceil(scale * 10) / 10:g} or more plays it slowly enough"
    over = speeds / _SPEED
    if over.size and float(over.max()) > 1 + _SLACK:
        k, w = (int(x) for x in np.unravel_index(int(np.argmax(over)), over.shape))
        need = speeds[k, w]
        what = "a jump (no time between the points)" if math.isinf(need) else \
            f"{need:.2f} rad/s"
        raise LimitError(f"{JOINT_NAMES[w]} from {label(k)} to {label(k + 1)} needs "
                         f"{what}; its speed limit is {_SPEED[w]:.2f} rad/s{hint}",
                         joint=JOINT_NAMES[w])
    over = accels / _ACCEL
    if over.size and float(over.max()) > 1 + _SLACK:
        k, w = (int(x) for x in np.unravel_index(int(np.argmax(over)), over.shape))
        raise LimitError(f"{JOINT_NAMES[w]} at {label(k)} needs {accels[k, w]:.2f} "
                         f"rad/s² to change its speed; its acceleration limit is "
                         f"{_ACCEL[w]:.2f} rad/s²{hint}", joint=JOINT_NAMES[w])


def latches(state: ArmState) -> dict[str, tuple[str, ...]]:
    """Each joint's latches and alarm bits in ``state``, by name (a stepper's SLIP, STALLED,
    HARDWARE_ERROR flags, then its status packet's alarm bits, e.g. ``("STALLED",
    "OVERLOAD")``); joints without any are left out."""
    out: dict[str, tuple[str, ...]] = {}
    errors = state.errors
    for s in state.steppers:
        flags = tuple(f.name or "" for f in StepperFlag if s.flags & f & STEPPER_LATCHES)
        if flags or JOINT_NAMES[s.joint] in errors:
            out[JOINT_NAMES[s.joint]] = flags + tuple(errors.get(JOINT_NAMES[s.joint], ()))
    for v in state.servos:
        if JOINT_NAMES[v.joint] in errors:
            out[JOINT_NAMES[v.joint]] = tuple(errors[JOINT_NAMES[v.joint]])
    return out


def describe_latches(found: dict[str, tuple[str, ...]]) -> str:
    """``J2 latched STALLED, SLIP (OVERLOAD)``-style text for :func:`latches`' result."""
    parts = []
    for name, items in found.items():
        flags = [x for x in items if x in StepperFlag.__members__]
        bits = [x for x in items if x not in flags]
        text = ", ".join(flags) if flags else ", ".join(bits)
        if flags and bits:
            text += f" ({', '.join(bits)})"
        parts.append(f"{name} latched {text}")
    return "; ".join(parts)


def require_torque(arm: ArmReader, joints: Sequence[int] = range(N_JOINTS), what: str = "moving"
                   ) -> None:
    """Refuse ``what`` while the torque of one of ``joints`` (0..6) is off, naming the joints
    and, for one its node turned off, the latch."""
    enabled = arm.torque_enabled()
    off = [i for i in joints if not enabled[i]]
    if not off:
        return
    names = [JOINT_NAMES[i] for i in off]
    found = {k: v for k, v in latches(arm.state()).items() if k in names}
    why = f" ({describe_latches(found)}: clear it with armctl clear / " \
          "Arm.clear_errors())" if found else ""
    raise LimitError(f"torque is off on {', '.join(names)}{why}: turn it on first (armctl "
                     f"torque on / Arm.torque(True, hold=True)) before {what}",
                     joint=names[0])


def check_cartesian(xyz: Sequence[float] | np.ndarray,
                    rpy: Sequence[float] | np.ndarray | None) -> None:
    """Refuse a flange target (m) or orientation (rad) that is not finite, and an
    orientation angle beyond ±2π (a number that large means nothing as an angle)."""
    if len(xyz) != 3:
        raise LimitError("a flange target is x y z (m, base frame)")
    check_finite(xyz, "coordinate", ("x", "y", "z"))
    distance = math.hypot(*(float(v) for v in xyz))
    if distance > REACH_M:
        raise LimitError(f"{tuple(float(v) for v in xyz)} m is out of reach: {distance:.3g} m "
                         f"from the arm's base, which no pose reaches beyond {REACH_M:.2f} m")
    if rpy is None:
        return
    if len(rpy) != 3:
        raise LimitError("an orientation is roll pitch yaw (rad)")
    check_finite(rpy, "angle", ("roll", "pitch", "yaw"))
    for name, angle in zip(("roll", "pitch", "yaw"), rpy, strict=True):
        if abs(angle) > MAX_RPY_RAD:
            raise LimitError(f"{name} {angle:g} rad is not an orientation angle: give roll "
                             f"pitch yaw within ±{MAX_RPY_RAD:.2f} rad")
