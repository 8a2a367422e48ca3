"""Arm homing: find each stepper joint's encoder index mark and fix its absolute angle.

A stepper node counts its joint encoder from power-up (count 0 wherever the joint then is),
and integrates its motor steps from power-up too, so both are relative.  Each joint encoder
has an index mark at a known joint angle (:data:`protocol.robot.ARM_INDEX_ANGLES`); the node
latches the encoder count *of the mark* and its step count at the first index pulse after
power-up or after ``clear_flags`` REARM_INDEX (``index_seen``, ``index_encoder_count``,
``index_step_count``, flag INDEX_SEEN).

:func:`home` re-arms the latches, enables the steppers' torque and drives J1..J4 slowly
together, each in a widening search about where it started (``+s, −s, +2s, −2s`` … until the
search has covered the joint's whole range) until every joint has latched its index, sending
every node its goal with each cycle (the goal carries the routes' coupling offset, which
must follow the other joints' search); then it reads the latches and drives the joints back
where they started, at the search's speed.  An arm homed already is homed again from
wherever it is held, each joint going first straight over where its mark is (its stops and
marks are known), then searching as above inside its range should the mark not be there.  A joint whose elastic element is wound past its node's stall
limit when the search starts (driven into a stop, its latch cleared) searches only the other
way and returns to where the joint, not its motor, was.  The joint's offset (rad,
absolute angle = node angle + offset) is ``index angle − index_encoder_count`` in rad; the
latched step count is the motor's position at the mark (``index_step_count``), recorded for
force-sensing calibration.  The RX-64 servos measure absolute angles already: offset 0.

:class:`~host.arm.state.JointCalibration` (the result) turns states and commands between the nodes' frame and the
absolute (kinematic) frame; :class:`~host.arm.facade.Arm` applies it in every cycle once homed.
Because the latches live in the nodes, a new host process can pick a calibration up again
without moving the arm (:func:`restore`), as long as the nodes have not been power-cycled or
re-armed since.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Final

from host.arm.interface import DrivenArm
from host.arm.state import (
    JOINT_NAMES,
    N_JOINTS,
    N_STEPPERS,
    ArmState,
    JointCalibration,
)
from host.errors import HomingError, UsageError
from protocol.control_tables import STEPPER_TABLE, StepperClear, StepperFlag
from protocol.robot import ARM_INDEX_ANGLES, ARM_JOINT_LIMITS

_S = STEPPER_TABLE
#: The index latch registers read after homing: index_step_count, index_encoder_count.
_LATCH_AT: Final = _S["index_step_count"].address
_LATCH = struct.Struct("<ii")
assert _S["index_encoder_count"].address == _LATCH_AT + 4
#: Default search speed (rad/s at the joint) and search step (rad).
SEARCH_SPEED_RAD_S: Final = 0.15
SEARCH_STEP_RAD: Final = 0.12
#: The search's polling cycle (s), and how near (rad) its node must stop a motor to a search
#: target for it to count as reached.
SEARCH_PERIOD_S: Final = 0.01
SEARCH_TOLERANCE_RAD: Final = 0.01
#: A joint whose elastic element is wound this far (its node's stall limit, counts) when
#: the search starts is pressed against something that way (a stop it was driven into, its
#: latch cleared): the search goes the other way only (searching into the stop latched it
#: again, every time).
WOUND_COUNTS: Final = int(_S["deflection_limit"].default)
#: How far inside its range (rad) the search of an arm homed already keeps a joint: the
#: search is for a joint whose stops are unknown (after power-up it may start anywhere, and
#: it goes as far each way as the joint's whole range); once homed they are known, and from
#: the outstretched ``[0, 1.5, 0, 1.5, …]`` that search drove J4 into its upper stop (2.6
#: rad) and latched it STALLED.  A search target is the motor's; the joint sits off it by its
#: element's deflection (up to 150 counts, 0.09 rad).
RANGE_MARGIN_RAD: Final = 0.15
#: The stepper node's default velocity limit (counts/s), restored after the search.
DEFAULT_VELOCITY_COUNTS: Final = int(_S["velocity_limit"].default)


def calibration_from_latches(arm: DrivenArm, encoder_counts: Sequence[int],
                             step_counts: Sequence[int]) -> JointCalibration:
    """The calibration for the stepper nodes' latched index counts."""
    offsets = [ARM_INDEX_ANGLES[i] - j.counts_to_rad(encoder_counts[i])
               for i, j in enumerate(arm.steppers)]
    return JointCalibration(tuple(offsets) + (0.0,) * (N_JOINTS - N_STEPPERS),
                            tuple(int(c) for c in encoder_counts),
                            tuple(int(c) for c in step_counts))


def read_latches(arm: DrivenArm) -> tuple[list[bool], list[int], list[int]]:
    """Each stepper node's index latch: seen, encoder count, step count."""
    state = arm.cycle()
    seen = [bool(s.flags & StepperFlag.INDEX_SEEN) for s in state.steppers]
    encoder, steps = [], []
    for j in arm.steppers:
        step_count, encoder_count = _LATCH.unpack(arm.bus.read(j.dxl_id, _LATCH_AT, _LATCH.size))
        encoder.append(encoder_count)
        steps.append(step_count)
    return seen, encoder, steps


def restore(arm: DrivenArm) -> bool:
    """Take the calibration from the nodes' index latches if every stepper has one (a
    previous :func:`home`, or the index crossed since power-up); True if the arm is homed."""
    if arm.calibration is not None:
        return True
    seen, encoder, steps = read_latches(arm)
    if all(seen):
        arm.calibration = calibration_from_latches(arm, encoder, steps)
    return arm.calibration is not None


def search_targets(width: float, step: float) -> list[float]:
    """Offsets (rad) from the start that the search visits in turn for a joint whose range
    is ``width`` rad: ``+step, −step, +2·step, −2·step, …`` until the span searched
    (``2·k·step``) covers ``width``."""
    if not step > 0 or not width > 0:
        raise UsageError("the search step and the joint range must be > 0 rad")
    out: list[float] = []
    k = 1
    while True:
        out += [k * step, -k * step]
        if 2 * k * step >= width:
            return out
        k += 1


def within_range(plan: Sequence[float], angle: float, limits: tuple[float, float],
                 margin: float = RANGE_MARGIN_RAD) -> list[float]:
    """``plan`` (search offsets, rad) for a joint at ``angle`` (rad, absolute) whose range
    ``limits`` (rad) is known: each target kept ``margin`` (rad) inside the range, a leg
    that would repeat the one before dropped."""
    lo, hi = limits[0] + margin - angle, limits[1] - margin - angle
    out: list[float] = []
    for offset in plan:
        target = min(max(offset, lo), hi)
        if not out or abs(target - out[-1]) > 1e-9:
            out.append(target)
    return out


def straight_to_the_mark(plan: Sequence[float], angle: float, joint: int,
                         step: float = SEARCH_STEP_RAD) -> list[float]:
    """``plan`` (search offsets, rad) for stepper joint ``joint`` of an arm homed already, at
    ``angle`` (rad, absolute): first straight over where its index mark is
    (:data:`~protocol.robot.ARM_INDEX_ANGLES`) to ``step`` (rad) beyond it (the motor is off
    the joint by its element's deflection, at most 0.09 rad), then the widening search
    about the start should the mark not be there.

    From the outstretched ``[0, 1.5, 0, 1.5, …]`` the widening search alone went back and
    forth over 22 rad before J2 crossed its mark, 4.7 minutes at the search's speed; straight
    there it is 1.6 rad, 11 s."""
    to_mark = ARM_INDEX_ANGLES[joint] - angle
    return [to_mark + math.copysign(step, to_mark), *plan]


def search_time(plans: Sequence[Sequence[float]], speed: float) -> float:
    """Time (s) allowed for the search: twice the longest joint's path through its
    targets (offsets in rad, from the start) at ``speed`` (rad/s), plus 5 s."""
    longest = max(sum(abs(b - a) for a, b in zip([0.0, *plan], plan, strict=False))
                  for plan in plans)
    return 2 * longest / speed + 5.0


def next_leg(plan: Sequence[float], leg: int, blocked: set[int]) -> int:
    """The leg of ``plan`` (search offsets, rad) after ``leg`` whose target is not on a
    side in ``blocked`` (+1, −1); ``len(plan)`` when none is left."""
    k = leg + 1
    while k < len(plan) and (1 if plan[k] > 0 else -1) in blocked:
        k += 1
    return k


def _check_search(arm: DrivenArm, state: ArmState, found: Sequence[bool], start: Sequence[float],
                  speed: float, late: bool) -> None:
    """Raise :class:`~host.errors.HomingError` for a joint still searching that its node
    stopped (a latched STALLED, held where it stopped, or a hardware error) or, once ``late``, that
    has not found its index in the time the search takes; the others are sent back where
    they started."""
    stopped = [i for i, s in enumerate(state.steppers) if not found[i]
               and s.flags & (StepperFlag.STALLED | StepperFlag.HARDWARE_ERROR)]
    if not stopped and not late:
        return
    arm.cycle([arm.make_position(k, start[k], speed) for k in range(N_STEPPERS)
               if k not in stopped])
    if stopped:
        names = [JOINT_NAMES[i] for i in stopped]
        flags = {JOINT_NAMES[i]: ",".join(f.name or "" for f in StepperFlag
                                          if state.steppers[i].flags & f) for i in stopped}
        raise HomingError(
            f"{', '.join(names)}: the node stopped the joint during the search "
            f"({'; '.join(f'{k}: {v}' for k, v in flags.items())}: it was held or "
            "over-deflected, and it holds where it stopped); check that it moves freely, clear "
            "the latch (Arm.clear_errors(), armctl clear) and home again", joint=names[0])
    names = [JOINT_NAMES[i] for i, ok in enumerate(found) if not ok]
    raise HomingError(
        f"{', '.join(names)}: no index pulse before the search's time ran out (the joint "
        "did not reach its search targets: blocked, or its torque off?); check it moves "
        "freely (armctl status) and home again", joint=names[0])


def home(arm: DrivenArm, *, speed: float = SEARCH_SPEED_RAD_S, step: float = SEARCH_STEP_RAD,
         period: float = SEARCH_PERIOD_S,
         tolerance: float = SEARCH_TOLERANCE_RAD) -> JointCalibration:
    """Home the arm (see the module docs); returns the calibration, also set on ``arm``.

    ``speed`` (rad/s) and ``step`` (rad) shape the search; ``period`` (s) is the polling
    cycle; a search target counts as reached when the node stopped with its motor within
    ``tolerance`` (rad) of it.  Raises :class:`~host.errors.HomingError` naming the first
    joint whose index was not found within its range, that its node stopped (a latched
    STALLED: held) or that did not get through its search in :func:`search_time`."""
    if not speed > 0:
        raise UsageError(f"homing speed {speed} must be > 0 rad/s")
    # homed already (by this program, or by another since the nodes' power-up: their index
    # latches still hold): the stops are known
    homed_before = arm.calibration if restore(arm) else None
    arm.calibration = None
    clear = _S["clear_flags"].encode(int(StepperClear.REARM_INDEX))
    arm.bus.sync_write(_S["clear_flags"].address, 1, {j.dxl_id: clear for j in arm.steppers})
    state = arm.torque(True, range(N_STEPPERS))
    start = [s.motor_angle for s in state.steppers]
    joint_start = [s.angle for s in state.steppers]
    plans = [search_targets(hi - lo, step) for lo, hi in ARM_JOINT_LIMITS[:N_STEPPERS]]
    if homed_before is not None:  # the marks and the stops are known
        plans = [within_range(straight_to_the_mark(plans[i], joint_start[i]
                                                   + homed_before.offsets[i], i, step),
                              joint_start[i] + homed_before.offsets[i], ARM_JOINT_LIMITS[i])
                 for i in range(N_STEPPERS)]
    found = [bool(s.flags & StepperFlag.INDEX_SEEN) for s in state.steppers]
    clock = arm.transport
    deadline = clock.now() + search_time(plans, speed)
    # each joint's goal: its search leg's target, or where it found its index (held)
    # the sides a joint cannot search: pressed against something that way (the motor beyond
    # the joint by a stall's worth)
    offsets = arm.deflection_offsets()
    blocked = [{1 if s.deflection - offsets[i] > 0 else -1}
               if abs(s.deflection - offsets[i]) >= WOUND_COUNTS else set()
               for i, s in enumerate(state.steppers)]
    leg = [0 if not blocked[i] else next_leg(plans[i], -1, blocked[i])
           for i in range(N_STEPPERS)]
    # where the search returns the joints: where they started; one that started pressed
    # against something to where the joint was, its element relaxed (its motor's start would
    # wind it up again)
    back_to = [joint_start[i] if blocked[i] else start[i] for i in range(N_STEPPERS)]
    targets = [start[i] if found[i] else start[i] + plans[i][leg[i]] for i in range(N_STEPPERS)]
    while not all(found):
        # every stepper its goal with every cycle, not only when it changes: the goal
        # carries the node's coupling offset, which must follow the other joints as they
        # search (the routes turn J4's capstan by 0.18 of J2's travel; left stale over
        # J2's search from an extended pose, the elbow's node saw a stall that was not)
        state = arm.cycle([arm.make_position(i, targets[i], None if found[i] else speed)
                           for i in range(N_STEPPERS)])
        _check_search(arm, state, found, back_to, speed, clock.now() >= deadline)
        for i, s in enumerate(state.steppers):
            if found[i]:
                continue
            if s.flags & StepperFlag.INDEX_SEEN:
                found[i] = True
                targets[i] = s.motor_angle  # hold here
                continue
            if s.moving or abs(s.motor_angle - targets[i]) > tolerance:
                continue
            leg[i] = next_leg(plans[i], leg[i], blocked[i])
            if leg[i] == len(plans[i]):
                arm.cycle([arm.make_position(k, back_to[k], speed) for k in range(N_STEPPERS)])
                sides = " and ".join("+" if d > 0 else "-" for d in sorted(blocked[i],
                                                                          reverse=True))
                where = (f"; pressed against something going {sides}, searched the other way"
                         if blocked[i] else "")
                raise HomingError(
                    f"{JOINT_NAMES[i]}: no index pulse within its range "
                    f"({plans[i][-2]:+.2f} … {plans[i][-1]:+.2f} rad about where it "
                    f"started{where}); check the encoder's index channel and that the joint "
                    f"moves freely", joint=JOINT_NAMES[i])
            targets[i] = start[i] + plans[i][leg[i]]
        if not all(found):
            clock.sleep(period)
    seen, encoder, steps = read_latches(arm)
    missing = [JOINT_NAMES[i] for i, ok in enumerate(seen) if not ok]
    if missing:
        raise HomingError(f"{', '.join(missing)}: the index latch was lost after the search "
                          "(a node restarted?); home again", joint=missing[0])
    back = arm.steppers[0].counts_to_rad(DEFAULT_VELOCITY_COUNTS)
    # back over the ground the search just covered, at its speed: no stop to meet, but
    # from an extended pose the elbow's element carries most of what it can statically
    # (at J2 0.73, J4 1.05 rad with the hand, 112 of its 150 counts) and a faster move's
    # dynamics latched it
    state, _ = arm.move([*back_to, *state.joints[N_STEPPERS:]], speed=speed, timeout=10.0,
                        unhomed_speed=None, motors=True)
    arm.cycle([arm.make_position(i, start[i], back) for i in range(N_STEPPERS)])
    arm.calibration = calibration_from_latches(arm, encoder, steps)
    return arm.calibration
