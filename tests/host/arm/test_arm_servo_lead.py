"""The goals :meth:`host.arm.facade.Arm.move` sends the RX-64s: a short lead ahead of their way."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from host.arm.trajectory import SERVO_GOAL_LEAD_S, servo_lead

ANGLE = st.floats(-2.5, 2.5)


def test_the_wrist_goal_runs_the_lead_ahead_and_stops_at_the_move_s_end():
    start = [0.1, 0.2, 0.3, 0.4, 0.0, 0.0, 0.5]
    goals = [1.0, 1.5, -0.3, 0.9, 0.0, 0.2, -0.5]
    speeds = [0.2] * 7
    out = servo_lead(start, goals, speeds, 0.25)
    assert out[:4] == goals[:4]  # the stepper nodes plan their own way
    assert out[4] == 0.0  # not moving
    assert out[5] == pytest.approx(0.2 * (0.25 + SERVO_GOAL_LEAD_S))
    assert out[6] == pytest.approx(0.5 - 0.2 * (0.25 + SERVO_GOAL_LEAD_S))
    assert servo_lead(start, goals, speeds, 10.0) == goals
    assert servo_lead(start, goals, [None] * 7, 0.0) == goals  # no speed: the goal itself


@given(st.lists(ANGLE, min_size=7, max_size=7), st.lists(ANGLE, min_size=7, max_size=7),
       st.floats(0.01, 5.0), st.floats(0.0, 20.0))
def test_a_lead_goal_lies_between_the_start_and_the_goal(start, goals, speed, elapsed):
    out = servo_lead(start, goals, [speed] * 7, elapsed)
    for s, g, o in zip(start, goals, out, strict=True):
        assert min(s, g) <= o <= max(s, g)
        assert abs(o - s) <= speed * (elapsed + SERVO_GOAL_LEAD_S) + 1e-12 or o == g
