"""Where a hold sets a stepper's goal (host.arm.hold.hold_goals), from states built by hand:
never short of where the motor stops braking, however far off (within SPEED_ERROR and
TIME_ERROR_S) the speed and the states' timestamps are, and never past the goal the motor
was heading for.

Through the ptys the two states' timestamps (taken when their replies were decoded) made
the speed 20-30 % off; a goal 2-3 counts short of the braking end made J4's node brake past
it and drive back while the elbow's link swung on, and it latched STALLED.
"""

from __future__ import annotations

import math

from hypothesis import example, given
from hypothesis import strategies as st

from host.arm.hold import SPEED_ERROR, STEPPER_BRAKING_RAD_S2, TIME_ERROR_S, hold_goals
from host.arm.state import ArmState, JointInfo, StepperState
from protocol.control_tables import StepperFlag
from protocol.dynamixel import ErrorBit

COUNTS_PER_REV = 10_000
#: Four stepper joints of 50 microsteps per encoder count (and three servos, unused).
JOINTS = tuple(JointInfo(i, i + 1, "stepper", 0, 0, 50.0, 200, 5, COUNTS_PER_REV, 200.0)
               for i in range(4)) + tuple(JointInfo(i, i + 1, "servo", 0, 0)
                                          for i in range(4, 7))
RAD_PER_STEP = 2 * math.pi / COUNTS_PER_REV / JOINTS[0].microsteps_per_count


def state(t: float, steps: int, goal: float) -> ArmState:
    """The arm at ``t`` (s) with J1's motor ``steps`` microsteps from 0, heading for
    ``goal`` (rad); the other steppers at rest at 0."""
    def stepper(joint: int, count: int, to: float) -> StepperState:
        angle = count * RAD_PER_STEP
        return StepperState(joint, angle, 0.0, angle, count, 0, 0.0, 0.0,
                            StepperFlag(0), ErrorBit(0), to)
    return ArmState(t, (stepper(0, steps, goal), *(stepper(j, 0, 0.0) for j in (1, 2, 3))),
                    ())


@given(speed=st.floats(0.02, 0.25), sign=st.sampled_from([-1, 1]),
       speed_error=st.floats(-SPEED_ERROR, SPEED_ERROR),
       late=st.floats(0.0, TIME_ERROR_S), ahead=st.floats(0.0, 0.02), goal_far=st.booleans(),
       cruising=st.booleans())
# the speed 25 % low and its step count rounded down: the rounding's microstep counts too
@example(speed=0.125, sign=-1, speed_error=-0.25, late=0.00390625, ahead=0.0, goal_far=True,
         cruising=False)
def test_a_hold_goal_is_never_short_of_where_the_motor_stops(
        speed: float, sign: int, speed_error: float, late: float, ahead: float,
        goal_far: bool, cruising: bool) -> None:
    """A motor turning at ``speed`` (rad/s), seen in two states 10 ms apart whose step
    counts give a speed ``speed_error`` (a share) off, the last one stamped ``late`` (s)
    after the node read its counter, the goal sent ``ahead`` (s) after that stamp (with
    ``cruising``, at the speed limit the arm gave its node): the goal lies at or beyond
    where braking from that speed ends, not past the move's goal, and (cruising, the
    speed then known) within the stamps' error of where it stops."""
    v = sign * speed
    moved = round(v * (1 + speed_error) * 0.01 / RAD_PER_STEP)
    move_goal = sign * (2.0 if goal_far else 0.02)
    limits = [speed if cruising else None, None, None, None]
    goal = hold_goals(state(0.01, moved, move_goal), state(0.0, 0, move_goal), JOINTS,
                      at=0.01 + ahead, limits=limits)[0]
    there = moved * RAD_PER_STEP + v * (late + ahead)  # when the goal comes
    stops = there + v * abs(v) / (2 * STEPPER_BRAKING_RAD_S2)
    if goal_far:
        assert (goal - stops) * sign >= -RAD_PER_STEP, "short of where the motor stops"
        if cruising and abs(speed_error) < 0.2:
            assert (goal - stops) * sign <= speed * TIME_ERROR_S + RAD_PER_STEP
    assert (goal - move_goal) * sign <= 1e-12, "past the goal it was heading for"


def test_a_motor_at_rest_is_held_where_it_is() -> None:
    before, now = state(0.0, 1234, 1.0), state(0.01, 1234, 1.0)
    assert hold_goals(now, before, JOINTS, at=0.05)[0] == 1234 * RAD_PER_STEP
