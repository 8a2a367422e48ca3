"""A move's steppers come up to speed and brake into their goals over
:data:`~host.arm.trajectory.MOVE_RAMP_S`, fed as speed limits by the host
(:func:`~host.arm.trajectory.move_speed_limits`): the nodes' own profile (π rad/s²) takes
0.1-0.45 s, about half a period of the shoulder and elbow swinging together, and set the
elastic joints ringing for the whole move and winding past their stall limit at speeds the
gate allows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.arm.gate import MOVE_SPEED_LIMITS, MOVE_STEPPER_SPEED_RAD_S, check_speeds
from host.arm.state import N_JOINTS, N_STEPPERS, ArmState
from host.arm.trajectory import (
    MOVE_ARRIVED_RAD,
    MOVE_BRAKE_FLOOR,
    MOVE_RAMP_S,
    move_speed_limits,
    ramped_speeds,
    travel_time,
)
from host.errors import LimitError
from protocol.control_tables import STEPPER_TABLE
from protocol.robot import ARM_JOINT_SPEED_LIMITS
from tests.ground_truth import arm_plant_of, emulator_of

HOME = [0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0]
OUTSTRETCHED = [0.0, 1.5, 0.0, 1.5, 0.0, 0.2, 0.0]
DEFLECTION_LIMIT = STEPPER_TABLE["deflection_limit"].default

_speed = st.floats(0.01, 1.5)


@given(speeds=st.lists(_speed, min_size=N_JOINTS, max_size=N_JOINTS),
       elapsed=st.floats(0.0, 10.0),
       left=st.lists(st.one_of(st.floats(0.0, 3.0), st.floats(0.0, 0.002)),
                     min_size=N_STEPPERS, max_size=N_STEPPERS))
def test_a_steppers_limit_ramps_up_and_brakes_into_its_goal(
        speeds: list[float], elapsed: float, left: list[float]) -> None:
    limits = move_speed_limits(speeds, elapsed, left)
    for i in range(N_STEPPERS):
        v, limit = speeds[i], limits[i]
        assert limit is not None
        floor = min(v, MOVE_BRAKE_FLOOR)
        assert floor - 1e-12 <= limit <= v + 1e-12
        ramp = v * min(1.0, elapsed / MOVE_RAMP_S)
        if left[i] <= MOVE_ARRIVED_RAD:  # arrived: the move's speed for what comes next
            assert limit == pytest.approx(max(ramp, floor))
            continue
        brake = math.sqrt(2.0 * v / MOVE_RAMP_S * left[i])
        assert limit <= max(min(ramp, brake), floor) + 1e-12
        if elapsed >= MOVE_RAMP_S and left[i] >= v * MOVE_RAMP_S / 2:
            assert limit == pytest.approx(v)  # cruising: the move's own speed
    assert limits[N_STEPPERS:] == [None] * (N_JOINTS - N_STEPPERS)


def test_the_first_command_carries_the_servos_speeds_and_a_limit_sent_already_is_not_sent_again(
        ) -> None:
    speeds = [0.5] * N_JOINTS
    first = move_speed_limits(speeds, 0.01, servos=True)
    assert first[N_STEPPERS:] == speeds[N_STEPPERS:]
    # the ramp's first step, or the least limit a move sends
    assert first[:N_STEPPERS] == pytest.approx(
        [max(0.5 * 0.01 / MOVE_RAMP_S, MOVE_BRAKE_FLOOR)] * N_STEPPERS)
    cruising = move_speed_limits(speeds, 2.0, [1.0] * N_STEPPERS,
                                 sent=[0.5, 0.5001, 0.499, None])
    assert cruising[:N_STEPPERS] == [None, None, 0.5, 0.5]
    # without a distance to go, a limit is the ramp's alone
    assert move_speed_limits(speeds, 0.1) == ramped_speeds(speeds, 0.1)
    # the move's speed again once arrived, for the goals that come later without one
    assert move_speed_limits(speeds, 2.0, [0.0, 0.001, 0.01, 0.2])[:N_STEPPERS] == \
        pytest.approx([0.5, 0.5, math.sqrt(2 * 0.5 / MOVE_RAMP_S * 0.01), 0.5])


def test_travel_time_adds_the_ramps_and_a_short_move_never_reaches_its_speed() -> None:
    start = [0.0] * 7
    goals = [0.0, 1.0, 0.0, -0.5, 0.0, 0.0, 0.0]
    assert travel_time(start, goals, [0.5] * 7) == pytest.approx(2.0 + MOVE_RAMP_S)
    # a joint without a speed goes at its limit
    assert travel_time(start, goals, [None] * 7) == pytest.approx(
        max(1.0 / ARM_JOINT_SPEED_LIMITS[1], 0.5 / ARM_JOINT_SPEED_LIMITS[3]) + MOVE_RAMP_S)
    short = [0.0, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0]  # 0.05 rad at 0.5 rad/s: a triangle
    assert travel_time(start, short, [0.5] * 7) == pytest.approx(
        2.0 * math.sqrt(0.05 * MOVE_RAMP_S / 0.5))
    # the servos have no ramp of the host's
    wrist = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert travel_time(start, wrist, [0.5] * 7) == pytest.approx(2.0)


def _homed_arm(name: str) -> Arm:
    arm = Arm.open(f"emu://full/arm?ready=0&name={name}")
    arm.torque(True, hold=True)
    arm.home()
    return arm


def test_a_move_gives_the_steppers_at_most_their_elastic_speed() -> None:
    """The controllers step J2 at up to 1.44 rad/s, but a move at more than 0.8 rad/s winds
    a loaded arm's elastic elements past their stall limit: a duration needing more is
    refused, naming the joint and the time that would do; the servos keep their own."""
    start = [0.0] * 7
    assert MOVE_SPEED_LIMITS[:N_STEPPERS] == (MOVE_STEPPER_SPEED_RAD_S,) * N_STEPPERS
    assert MOVE_SPEED_LIMITS[N_STEPPERS:] == ARM_JOINT_SPEED_LIMITS[N_STEPPERS:]
    with pytest.raises(LimitError, match=r"J2 would need 1.00 rad/s to arrive in 1 s; its "
                                         r"limit is 0.80 rad/s \(a move's, for its elastic "
                                         r"element; the controller steps at up to 1.45\): "
                                         r"take at least 1.3 s") as refused:
        check_speeds([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], start, 1.0)
    assert refused.value.joint == "J2"
    check_speeds([0.0, 0.8, 0.0, 0.0, 0.0, 1.0, 0.0], start, 1.0)  # J6 at 1 rad/s: its own
    # the hardware's limits, where a caller asks for them
    check_speeds([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], start, 1.0, ARM_JOINT_SPEED_LIMITS)


@pytest.mark.slow
def test_a_move_asked_for_more_speed_takes_the_steppers_at_their_elastic_speed() -> None:
    """Down from a raised pose at 1.2 rad/s the elbow's element wound past its stall limit
    braking the falling forearm (J4 latched STALLED at 198-248 counts of its 150, with the
    host's ramps or without); a ``speed`` caps the steppers at
    :data:`~host.arm.gate.MOVE_STEPPER_SPEED_RAD_S`."""
    arm = _homed_arm("ramps-down")
    try:
        arm.move([0.0, 1.0, 0.0, 1.4, 0.0, 0.0, 0.0], duration=5.0)
        _, settled = arm.move(HOME, speed=1.2, timeout=10.0)
        state = arm.state()
        assert not any(s.stalled or s.slip for s in state.steppers)
        assert settled
        assert max(v or 0.0 for v in arm.wire.stepper_speed_limits) <= MOVE_STEPPER_SPEED_RAD_S + 1e-3
    finally:
        arm.close()
        forget_shared_emulators()


@pytest.mark.slow
def test_a_move_at_a_speed_the_gate_allows_does_not_wind_the_elements_past_their_limit() -> None:
    """At 1 rad/s (0.8 for the steppers) to a loaded pose the nodes' own ramps wound J2 to
    168 counts of its 150 and latched it STALLED (151 at 0.8); with the host's ramps the
    elements carry what the pose loads them with, and little more."""
    arm = _homed_arm("ramps-fast")
    peak = [0] * N_STEPPERS

    def tap(state: ArmState) -> None:
        offsets = arm.wire.deflection_offsets()
        for i, s in enumerate(state.steppers):
            peak[i] = max(peak[i], abs(s.deflection - offsets[i]))

    try:
        arm.state_taps.append(tap)
        _, settled = arm.move([0.0, 1.0, 0.0, 1.4, 0.0, 0.0, 0.0], speed=1.0, timeout=10.0)
        state = arm.state()
        assert not any(s.stalled or s.slip for s in state.steppers)
        assert settled
        assert max(peak) < 0.87 * DEFLECTION_LIMIT  # 130 counts: the load's 115 and the ramps'
    finally:
        arm.close()
        forget_shared_emulators()


@pytest.mark.slow
def test_the_arm_runs_quietly_at_its_speed_once_it_is_up_to_it() -> None:
    """Through the 6 s move's cruise (1-3 s in) the shoulder and elbow swung about their
    speed by 0.026-0.047 rad/s (standard deviation) after the nodes' own 0.3 s ramp; the
    host's ramp leaves a few thousandths."""
    arm = _homed_arm("ramps-quiet")
    plant = arm_plant_of(emulator_of(arm))
    trace: list[tuple[float, float, float]] = []
    try:
        arm.move(HOME, duration=3.0)
        start = arm.transport.now()

        def tap(_: object) -> None:
            v = plant.joint_velocities()
            trace.append((arm.transport.now() - start, float(v[1]), float(v[3])))

        arm.state_taps.append(tap)
        arm.move(OUTSTRETCHED, duration=6.0)
        rows = np.array([r for r in trace if 1.0 <= r[0] < 3.0])
        assert len(rows) > 100
        assert float(np.std(rows[:, 1])) < 0.015
        assert float(np.std(rows[:, 2])) < 0.015
    finally:
        arm.close()
        forget_shared_emulators()
