"""Stopping the arm where it is: what an interrupted, failed or alarmed motion leaves.

:func:`hold` (``Arm.hold()``; ``with Arm.open(...) as arm:`` calls it when the block raises,
Ctrl-C included) reads the arm and, in the next cycle, sets every joint whose torque is on
to hold where it is:

* a stepper node's goal := where its motor comes to a stop braking at its
  ``acceleration_limit`` from the speed it turns at (from the step counts of the last two
  states read; :func:`hold_goals`).  Its motor, not its joint: under load the joint sags off
  the motor by the spring's deflection, and a goal at the joint angle would let the arm
  drop by that much.  Its stopping point, not its present angle: the node would brake past
  that and come back, winding the spring up against a link that still moves on, which is
  what made a Ctrl-C early in a move latch STALLED on a loaded elbow; for the same reason
  the goal lies a margin beyond the estimated stopping point (the speed's and the states'
  timestamps' errors), never short of it.  The goal goes with
  the coupling offset of the joints as they are now (``deflection_offset``, see
  :mod:`host.arm.facade`), so the node's SLIP/STALLED watch keeps seeing the elastic element and
  not the belt and cable routes' coupling, with no host feeding goals any longer;
* a servo's goal := where it is driving to: its present angle plus the position error its
  compliance needs for the torque it applies (``present_load``, the RX-64's compliance
  registers at their defaults; :func:`servo_setpoint`).  Its present angle alone let the
  servo give way by that error (a loaded wrist sagged 1.5°).

The goals go out at once, computed from the last state read (:attr:`host.arm.facade.Arm.last_state`,
looked ahead to the moment they are sent) and sent by :meth:`host.arm.facade.Arm.send`, a write
waiting for no reply: Ctrl-C may have cut an exchange short whose late replies would not fit
a read.  Not into those replies, though: on the half-duplex line a write collides with them
and is lost (the nodes then drove on for the drain's 100 ms, and the goals sent after it lay
behind the motors: J2 or J4 drove back and latched), so the bus first lets them pass
(:meth:`host.arm.bus.DynamixelBus.wait_out_replies`).  Then the line is drained, the
torque and two states a cycle apart read, and each joint's goal sent again from how it moves
then, with fresh coupling offsets: a motor the first write stopped is at rest there, one it
never reached is stopped where it stops now, not driven back.

Torque stays as it is: a joint whose torque is off (its node turned it off after an alarm,
or the host did) is left alone and named.  Nothing is latched by holding.
:func:`stop_for_alarms` is what a motion does when a node latches an alarm on the way: hold
the rest (re-sending the hold while the arm comes to rest, at most :data:`ALARM_SETTLE_S`),
then raise :class:`~host.errors.JointAlarmError` naming the joint and the latch.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from math import copysign, pi
from typing import Final

from host.arm.gate import describe_latches, latches
from host.arm.interface import CyclingArm
from host.arm.rest import RestWatch, servo_setpoint
from host.arm.state import JOINT_NAMES, N_STEPPERS, ArmState, Command, JointInfo
from host.errors import JointAlarmError, NodeError, ReplyTimeout
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE, StepperFlag
from protocol.robot import ARM_ENCODER_COUNTS_PER_REV, ARM_JOINT_SPEED_LIMITS

_R = RX64_TABLE
#: After an alarm, how long (s) the hold goals are sent again while the arm comes to rest.
ALARM_SETTLE_S: Final = 3.0
#: Tries of a hold whose exchange failed (a late reply of an interrupted one in the way).
HOLD_ATTEMPTS: Final = 3
#: The longest :func:`drain` (in the link's latencies, :attr:`DynamixelBus.latency_s`): the
#: replies to an exchange cut short are all in by then.
DRAIN_LATENCIES: Final = 3
#: How hard a stepper node brakes towards a goal (rad/s² at the joint): its
#: ``acceleration_limit`` at power-up, which this library leaves as it is.
STEPPER_BRAKING_RAD_S2: Final = (STEPPER_TABLE["acceleration_limit"].default * 2 * pi
                                 / ARM_ENCODER_COUNTS_PER_REV)
#: Two states further apart than this (s) tell nothing of how fast a motor turns now.
SPEED_SPAN_MAX_S: Final = 0.05
#: The longest (s) a hold's goals look ahead of the state they start from (the motors
#: turning on at their speed meanwhile): a Ctrl-C's wait for a cut exchange's replies.
EXTRAPOLATE_MAX_S: Final = 0.1
#: How far a motor speed from two states' step counts may be off (a share of it), and how
#: late a state's time (s) may be: each state is stamped when its replies were decoded,
#: on a serial port or a pty a few ms after the nodes read their step counters (through
#: the ptys the speeds came out up to 12 % off).  A hold sets each stepper's goal where the
#: motor stops if it turns that much faster, that much longer (:func:`hold_goals`): a goal
#: short of where it stops brakes the motor past the goal and drives it back while the
#: link swings on, and the spring winds up.
SPEED_ERROR: Final = 0.25
TIME_ERROR_S: Final = 0.005


@dataclass(frozen=True)
class Held:
    """What :func:`hold` did: the ``state`` read before (the angles held), the ``joints``
    set to hold there (names), and the joints left alone with why (``skipped``)."""

    state: ArmState
    joints: tuple[str, ...]
    skipped: dict[str, str] = field(default_factory=dict)

    def describe(self) -> str:
        """One line: ``J1-J7 held where they were (torque on)``, naming the ones left out."""
        if not self.joints:
            text = "nothing held"
        else:
            angles = ", ".join(f"{n} {self.state.joints[JOINT_NAMES.index(n)]:+.3f}"
                               for n in self.joints)
            text = f"held where they were, torque on: {angles} rad"
        reasons: dict[str, list[str]] = {}
        for name, why in self.skipped.items():
            reasons.setdefault(why, []).append(name)
        for why, names in reasons.items():
            text += f"; {', '.join(names)}: {why}"
        return text


def hold(arm: CyclingArm, settle_s: float = 0.0, period: float = 0.01) -> Held:
    """:func:`hold_once`, tried up to :data:`HOLD_ATTEMPTS` times: an interrupted program's
    last exchange may still be answering (its replies, late, do not fit the hold's reads),
    so what is on the line is let through and dropped before each attempt."""
    goals: dict[int, float] = {}
    # not into the replies of an exchange Ctrl-C cut short: the write would collide with
    # them on the line and be lost, and the nodes drive on
    arm.bus.wait_out_replies()
    last = arm.last_state
    if last is not None:  # at once, from the last state read: nothing to read first
        goals = {i: q for i, q in hold_goals(last, arm.previous_state, arm.joints,
                                             at=arm.transport.now(),
                                             limits=arm.stepper_speed_limits).items()
                 if i not in arm.unpowered_steppers}
        arm.send([arm.make_position(i, q) for i, q in goals.items()])
    for attempt in range(HOLD_ATTEMPTS):
        drain(arm)
        try:
            return hold_once(arm, settle_s, period, goals)
        except (NodeError, ReplyTimeout):
            if attempt == HOLD_ATTEMPTS - 1:
                raise
    raise AssertionError("unreachable")


def hold_goals(state: ArmState, before: ArmState | None = None,
               joints: tuple[JointInfo, ...] = (), at: float | None = None,
               limits: Sequence[float | None] = ()) -> dict[int, float]:
    """Where to hold each joint of ``state`` (rad): a stepper where its motor stops, braking
    at :data:`STEPPER_BRAKING_RAD_S2` from its speed between ``before`` and ``state``
    (:func:`motor_speeds`; at its angle without them) once the goal reaches it at ``at``
    (s, the clock of the states' ``t``; at most :data:`EXTRAPOLATE_MAX_S` after ``state``:
    it turns on at that speed until then), plus what the estimate may be off by
    (:data:`SPEED_ERROR`, :data:`TIME_ERROR_S`, a microstep of the step counts; a speed
    no faster than the node's speed limit in ``limits``, rad/s, None: not known), and
    never beyond the goal it was going
    to; a servo where it drives to (:func:`servo_setpoint`); a stepper its node stopped
    (STALLED, a hardware error) is left out.  A goal short of where the motor stops would
    brake it past the goal and drive it back against a link that swings on: the spring
    winds up."""
    speeds = motor_speeds(state, before, joints)
    span = state.t - before.t if before is not None else 0.0
    ahead = 0.0 if at is None else min(max(at - state.t, 0.0), EXTRAPOLATE_MAX_S)
    goals: dict[int, float] = {}
    for s in state.steppers:
        if s.flags & (StepperFlag.STALLED | StepperFlag.HARDWARE_ERROR):
            continue
        v = speeds[s.joint]
        if v and span > 0:  # the step counts' rounding: up to a microstep over the span
            j = joints[s.joint]
            v += copysign(2 * pi / (j.encoder_counts_per_rev * j.microsteps_per_count) / span, v)
        v /= 1 - SPEED_ERROR  # as fast as it may turn
        limit = limits[s.joint] if s.joint < len(limits) else None
        if limit is not None and abs(v) > limit:  # the node turns it no faster
            v = copysign(limit, v)
        stop = (s.motor_angle + v * (ahead + TIME_ERROR_S)
                + v * abs(v) / (2 * STEPPER_BRAKING_RAD_S2))
        if (s.goal - s.motor_angle) * v > 0:  # not beyond the goal it was heading for
            stop = min(stop, s.goal) if v > 0 else max(stop, s.goal)
        goals[s.joint] = stop
    goals.update({v.joint: servo_setpoint(v) for v in state.servos})
    return goals


def motor_speeds(state: ArmState, before: ArmState | None,
                 joints: tuple[JointInfo, ...]) -> list[float]:
    """Each stepper motor's speed (rad/s at the joint) between the states ``before`` and
    ``state`` of ``joints``, from their step counts (microsteps: the motor angles are whole
    encoder counts, 0.06 rad/s a count over a 10 ms cycle); 0 for all without ``before``
    or ``joints``, or with the states more than :data:`SPEED_SPAN_MAX_S` apart, and for
    a motor faster than its joint can go (its step count zeroed or re-synced between)."""
    span = state.t - before.t if before is not None else 0.0
    if before is None or len(joints) < N_STEPPERS or not 0 < span <= SPEED_SPAN_MAX_S:
        return [0.0] * N_STEPPERS
    speeds = []
    for i, (now, then) in enumerate(zip(state.steppers, before.steppers, strict=True)):
        steps = now.step_count - then.step_count
        speed = joints[i].counts_to_rad(steps / joints[i].microsteps_per_count) / span
        speeds.append(speed if abs(speed) <= ARM_JOINT_SPEED_LIMITS[i] else 0.0)
    return speeds


def drain(arm: CyclingArm) -> None:
    """Drop what the bus still carries: replies to an exchange cut short, arriving until
    nothing more comes for the link's latency (at least 2 ms), for at most
    :data:`DRAIN_LATENCIES` latencies: a line another program keeps busy (a monitor polling
    the joints on its own adapter) is never quiet that long, and what it carries after the
    replies due have come is that program's, which the hold's reads skip."""
    transport = arm.transport
    quiet = max(arm.bus.latency_s, 0.002)
    end = transport.now() + DRAIN_LATENCIES * quiet
    while transport.recv(min(quiet, end - transport.now())) and transport.now() < end:
        pass


def hold_once(arm: CyclingArm, settle_s: float = 0.0, period: float = 0.01,
              goals: dict[int, float] | None = None) -> Held:
    """Hold every joint whose torque is on where it is (see the module docs): each where
    it stops from how it moves between two states read ``period`` (s) apart; a stepper
    whose speed they do not give (too far apart) at its goal in ``goals`` (the first
    write's) or else its motor's angle.  With ``settle_s`` (s) the same goals are sent again every ``period`` (s) until the arm is
    at rest (:class:`~host.arm.rest.RestWatch`) or that time has passed, each time with the
    coupling offsets of the joints as they are by then: after an alarm a joint whose torque
    is off may fall to its stop, turning the capstans of the joints after it through the
    routes, which a goal sent only once would let the nodes read as deflection."""
    enabled = arm.torque_enabled()
    clock = arm.transport
    before = arm.cycle()
    clock.sleep(period)
    state = arm.cycle()
    # where each motor stops from how it turns now: where the first hold left it, at rest,
    # or (that write lost) on its way
    fresh = hold_goals(state, before, arm.joints, at=clock.now(),
                       limits=arm.stepper_speed_limits)
    if not 0 < state.t - before.t <= SPEED_SPAN_MAX_S:  # how fast they turn is not known
        fresh = {i: q for i, q in fresh.items() if i >= N_STEPPERS}
    goals = {**(goals or {}), **fresh}
    found = latches(state)
    commands: list[Command] = []
    held: list[str] = []
    skipped: dict[str, str] = {}
    for i, name in enumerate(JOINT_NAMES):
        if not enabled[i]:
            why = describe_latches({name: found[name]}) if name in found else ""
            skipped[name] = "torque off" + (f" ({why.removeprefix(name + ' ')})" if why else "")
            continue
        angle = state.motor_joints[i] if i < N_STEPPERS else state.joints[i]
        commands.append(arm.make_position(i, goals.get(i, angle)))
        held.append(name)
    if commands:
        now = arm.cycle(commands)
        end = clock.now() + settle_s
        rest = RestWatch()
        while clock.now() < end and not rest.update(now):
            clock.sleep(period)
            now = arm.cycle(commands)
    return Held(state, tuple(held), skipped)


def new_latches(state: ArmState, before: Mapping[str, tuple[str, ...]]
                ) -> dict[str, tuple[str, ...]]:
    """The joints of ``state`` with latches or alarm bits they had not in ``before``
    (:func:`~host.arm.gate.latches` of an earlier state)."""
    return {k: v for k, v in latches(state).items() if not set(v) <= set(before.get(k, ()))}


def stop_for_alarms(arm: CyclingArm, state: ArmState, before: Mapping[str, tuple[str, ...]],
                    what: str = "the move", ignore: Collection[str] = ()) -> None:
    """If ``state`` shows a latch or alarm that ``before`` did not (on a joint not in
    ``ignore``), hold the arm where it is and raise :class:`~host.errors.JointAlarmError`
    naming the joint and the latch."""
    found = {k: v for k, v in new_latches(state, before).items() if k not in ignore}
    if not found:
        return
    held = hold(arm, settle_s=ALARM_SETTLE_S)
    name = next(iter(found))
    raise JointAlarmError(
        f"{describe_latches(found)} during {what}; the motion stopped ({held.describe()}). "
        f"A latched joint's node may have turned its torque off: check that {name} moves "
        f"freely and nothing holds it (armctl status), then armctl clear and armctl "
        f"torque on", joint=name, latches=found[name])
