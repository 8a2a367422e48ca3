"""A joint-space move of the arm (:meth:`host.arm.facade.Arm.move`, which documents it): the gate,
the steppers' motor goals (:mod:`host.arm.motor_goals`), their speeds and ramps
(:func:`host.arm.trajectory.move_speed_limits`), the cycles, and the wait until the arm
settled and is at rest.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

from host.arm.gate import MOVE_SPEED_LIMITS, check_goals, check_speeds, latches, require_torque
from host.arm.hold import stop_for_alarms
from host.arm.interface import DrivenArm
from host.arm.motor_goals import coupled_at, motor_goals, on_the_way, power_up_angles
from host.arm.rest import RestWatch, settled
from host.arm.state import N_JOINTS, N_STEPPERS, ArmState
from host.arm.trajectory import MOVE_RAMP_S, move_speed_limits, servo_lead, travel_time
from host.errors import LimitError

#: The least speed limit (rad/s) :meth:`Arm.move` with a ``duration`` gives a joint: one
#: that barely moves (or not at all) still returns briskly when pushed off its goal, and a
#: later command without a speed does not crawl.
MOVE_MIN_SPEED: Final = 0.2
#: The speed (rad/s) of the joint that moves furthest in an :meth:`Arm.move` given neither
#: a ``duration`` nor a ``speed``; the others arrive with it.  The nodes' own limits (the
#: controllers' full step rate at π rad/s², the hardware's) wind the shoulder's and elbow's
#: elastic elements to their stall limit (150 counts): homed at zero, J2 latched STALLED on
#: the way to the outstretched ``[0, 1.5, 0, 1.5, 0, 0, 0]`` (211 counts) and came within 3
#: counts of it to ``[0, 0.3, 0, 0.4, 0, 0, 0]``.  Each joint at 0.5 rad/s on its own time
#: still latched J4 to ``[0, 0.5, 0, 0.8, 0, 0, 0]`` (157: joints that stop one after the
#: other set the shoulder and elbow ringing together); arriving together 107-125.
MOVE_DEFAULT_SPEED: Final = 0.5
#: The most speed (rad/s) :meth:`Arm.move` gives a stepper joint of an arm that is not homed:
#: the host does not know where its stops are then, and a shoulder that meets its stop at
#: the nodes' full speed jolts the forearm hard enough that the elbow's spring deflects past
#: its stall torque and its node latches too (on the emulator: J2 to its lower stop at full
#: speed latched J4 as well; at 0.5 rad/s only J2, the joint that met the stop).
UNHOMED_STEPPER_SPEED: Final = 0.5


def motor_goals_of(arm: DrivenArm, angles: Sequence[float]) -> list[float]:
    """:func:`host.arm.motor_goals.motor_goals` for ``arm`` (its power-up angles, the sag
    once homed, its hand): see :meth:`host.arm.facade.Arm.motor_goals`."""
    q_ref = power_up_angles(arm.calibration, arm.steppers, arm.encoder_at_power_up)
    return motor_goals(angles, q_ref, arm.steppers, gravity=arm.homed, hand=arm.hand)


def _send(arm: DrivenArm, angles: Sequence[float], speeds: Sequence[float | None]) -> ArmState:
    """One cycle with all seven joints' goals (rad) and speed limits (rad/s or None)."""
    return arm.cycle([arm.make_position(i, a, s)
                      for i, (a, s) in enumerate(zip(angles, speeds, strict=True))])


def move(arm: DrivenArm, angles: Sequence[float], *, duration: float | None = None,
         speed: float | None = None, tolerance: float = 0.02, settle_speed: float = 0.05,
         timeout: float = 10.0, period: float = 0.01, rest: RestWatch | None = None,
         unhomed_speed: float | None = UNHOMED_STEPPER_SPEED,
         motors: bool = False) -> tuple[ArmState, bool]:
    """:meth:`host.arm.facade.Arm.move` (which documents it) for ``arm``."""
    if len(angles) != N_JOINTS:
        raise LimitError(f"give {N_JOINTS} joint angles, J1..J7")
    if not (timeout > 0 and not math.isnan(timeout)):
        raise LimitError(f"move timeout {timeout} must be > 0 s")
    now = arm.state()
    check_goals(angles, now.joints, homed=arm.homed, tolerance=tolerance)
    # the steppers' motors go where their joints land on the goals (the routes'
    # coupling, the springs' sag); speeds and arrival are the motors'
    goals = list(angles) if motors else motor_goals_of(arm, angles)
    origin = [*(s.motor_angle for s in now.steppers), *now.joints[N_STEPPERS:]]
    speeds: list[float | None] = [None] * N_JOINTS
    if duration is None and speed is None:  # together, the furthest at the default
        duration = max(max(abs(a - b) for a, b in zip(goals, origin, strict=True))
                       / MOVE_DEFAULT_SPEED, MOVE_RAMP_S)
    if duration is not None:
        check_speeds(goals, origin, duration)
        speeds = [max(abs(a - b) / duration, MOVE_MIN_SPEED)
                  for a, b in zip(goals, origin, strict=True)]
    elif speed is not None:
        if not (math.isfinite(speed) and speed > 0):
            raise LimitError(f"move speed {speed} must be a finite number > 0 rad/s")
        speeds = [min(speed, limit) for limit in MOVE_SPEED_LIMITS]
    driven = [i for i in range(N_JOINTS) if abs(angles[i] - now.joints[i]) > tolerance
              or abs(goals[i] - origin[i]) > tolerance]
    require_torque(arm, driven, "moving them")
    if not arm.homed and unhomed_speed is not None:  # stops unknown: meet one gently
        speeds[:N_STEPPERS] = [min(s or unhomed_speed, unhomed_speed)
                               for s in speeds[:N_STEPPERS]]
    before = latches(now)
    watch = rest if rest is not None else RestWatch()
    watch.reset()
    clock = arm.transport
    start = clock.now()

    def aim(state: ArmState, elapsed: float) -> list[float]:
        """This cycle's goals: the steppers' with the routes' coupling cancelled where
        the move has got to (:func:`on_the_way`), the servos' led along their way."""
        led = servo_lead(origin, goals, speeds, elapsed)
        if motors:
            return led
        way = on_the_way(now.joints, angles, origin, goals,
                         [s.motor_angle for s in state.steppers])
        return [*coupled_at(goals, angles, way), *led[N_STEPPERS:]]

    state = _send(arm, aim(now, 0.0), move_speed_limits(speeds, period, servos=True))
    deadline = start + timeout + travel_time(origin, goals, speeds)
    while True:
        stop_for_alarms(arm, state, before)
        still = watch.update(state)
        if settled(state, goals, tolerance, settle_speed) and still:
            return state, True
        if clock.now() >= deadline:
            return state, False
        clock.sleep(period)
        # the goals again, with the coupling offsets of the joints as they are now; a
        # motor brakes into the nearer of this cycle's goal and the move's end
        elapsed = clock.now() - start
        left = [min(abs(s.goal - s.motor_angle), abs(goals[s.joint] - s.motor_angle))
                for s in state.steppers]
        limits = move_speed_limits(speeds, elapsed + period, left,
                                   sent=arm.stepper_speed_limits)
        state = _send(arm, aim(state, elapsed), limits)
