"""Homing an arm that is homed already, from wherever it was left (moved, extended, stopped
by its nodes' watchdog when its host vanished), and moves given neither a duration nor a
speed: the nodes' coupling offsets follow the search, a move goes at a speed the elastic
shoulder and elbow take, and a wrist servo that sags by its compliance under the hand's
weight is where it holds, not on its way."""

from __future__ import annotations

import numpy as np
import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import MOVE_DEFAULT_SPEED, Arm
from host.arm.homing import (
    RANGE_MARGIN_RAD,
    next_leg,
    search_targets,
    straight_to_the_mark,
    within_range,
)
from host.arm.rest import settled
from host.arm.state import ArmState, ServoState
from protocol.dynamixel import ErrorBit
from tests.ground_truth import arm_plant_of, emulator_of

HOME = [0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0]
EXTENDED = [0.0, 0.8, 0.0, 1.0, 0.0, 0.0, 0.0]
OUTSTRETCHED = [0.0, 1.5, 0.0, 1.5, 0.0, 0.0, 0.0]


class _Gone(BaseException):
    """The host vanishing mid-move (nothing more is sent)."""


def _homed_arm(name: str) -> Arm:
    arm = Arm.open(f"emu://full/arm?ready=0&name={name}")
    arm.torque(True, hold=True)
    arm.home()
    return arm


def _latched(arm: Arm) -> list[str]:
    state = arm.state()
    return [f"J{i + 1}" for i, s in enumerate(state.steppers) if s.stalled or s.slip]


def _servo(joint: int, angle: float, load: float) -> ServoState:
    return ServoState(joint=joint, angle=angle, velocity=0.0, load=load, temperature=25.0,
                      voltage=18.0, errors=ErrorBit(0))


def test_a_servo_counts_as_arrived_where_its_compliance_holds_its_load() -> None:
    """An RX-64 as it comes (margin 1, slope 32 position units of 0.29°, punch 32) holding
    13 % of its torque towards its goal sits about 0.022 rad short of it: arrived; with no
    load, or its load pulling away from the goal, the same angle is not."""
    goals = [0.0] * 7
    for load, expected in ((0.13, True), (0.0, False), (-0.13, False)):
        state = ArmState(t=0.0, steppers=(), servos=(
            _servo(4, 0.0, 0.0), _servo(5, -0.035, load), _servo(6, 0.0, 0.0)))
        assert settled(state, goals, 0.02) is expected


@pytest.mark.slow
@pytest.mark.parametrize("pose", [HOME, EXTENDED], ids=["home-pose", "extended"])
def test_an_arm_homed_again_where_it_was_moved_finds_its_indexes_and_latches_nothing(
        pose: list[float]) -> None:
    """The search drives J2 over up to ±0.7 rad about where it starts; a node whose goal (and
    with it the routes' coupling offset) was sent only when its own search leg changed saw
    the elbow's element wound past its stall limit (J4 latched STALLED on every second
    homing); from an extended pose the return at the nodes' full speed latched it too."""
    arm = _homed_arm(f"rehome-{pose[1]}")
    try:
        first = arm.calibration
        assert first is not None
        arm.move(pose, duration=4.0)
        again = arm.home()
        assert again.index_encoder_counts == first.index_encoder_counts
        assert _latched(arm) == []
        # back where the search started
        truth = arm_plant_of(emulator_of(arm)).joint_angles()[:4]
        assert np.abs(truth - np.array(pose[:4])).max() < 0.1
    finally:
        arm.close()
        forget_shared_emulators()


def test_the_search_of_an_arm_homed_already_keeps_inside_the_joints_range() -> None:
    """The search goes as far each way as the joint's whole range (its stops unknown after
    power-up); once homed, its targets stay a margin inside the range."""
    plan = search_targets(2.95, 0.12)  # J4's range, -0.35 .. 2.6 rad
    assert max(plan) > 1.4 and min(plan) < -1.4
    kept = within_range(plan, 1.5, (-0.35, 2.6))
    assert 1.5 + max(kept) == pytest.approx(2.6 - RANGE_MARGIN_RAD)
    assert min(kept) == pytest.approx(min(plan))  # -1.56: inside the range that way
    # from near the lower stop the other side is kept in
    low = within_range(plan, -0.2, (-0.35, 2.6))
    assert -0.2 + min(low) == pytest.approx(-0.35 + RANGE_MARGIN_RAD)
    assert kept[:4] == pytest.approx(plan[:4])  # the first legs are as they were
    assert all(abs(b - a) > 1e-9 for a, b in zip(kept, kept[1:], strict=False))


@pytest.mark.slow
def test_an_arm_homed_again_at_the_outstretched_pose_stays_off_its_stops() -> None:
    """From ``[0, 1.5, 0, 1.5, …]`` the search drove J4 into its upper stop (2.6 rad) and its
    node latched STALLED, at any search speed."""
    arm = _homed_arm("rehome-outstretched")
    try:
        first = arm.calibration
        assert first is not None
        arm.move(OUTSTRETCHED, duration=4.0)
        before = np.array(arm.state().joints[:4])
        arm.close()  # armctl home is another program: it knows the arm homed from the nodes
        arm = Arm.open("emu://full/arm?ready=0&name=rehome-outstretched")
        arm.torque(True, hold=True)
        t0 = arm.transport.now()
        again = arm.home()
        # straight over the marks and back (J2 1.6 rad each way at 0.15 rad/s), not the
        # widening search's 22 rad (281 s of the arm's time)
        assert arm.transport.now() - t0 < 30.0
        assert again.index_encoder_counts == first.index_encoder_counts
        assert _latched(arm) == []
        truth = arm_plant_of(emulator_of(arm)).joint_angles()[:4]
        assert np.abs(truth - before).max() < 0.05
    finally:
        arm.close()
        forget_shared_emulators()


@pytest.mark.slow
def test_an_arm_homed_again_after_its_host_vanished_mid_move_latches_nothing() -> None:
    arm = _homed_arm("rehome-gone")
    try:
        start = arm.transport.now()

        def vanish(_: object) -> None:
            if arm.transport.now() - start >= 2.6:
                raise _Gone

        arm.state_taps.append(vanish)
        with pytest.raises(_Gone):
            arm.move(OUTSTRETCHED, duration=6.0)
        arm.state_taps.remove(vanish)
        emulator_of(arm).step(2_000_000)  # the nodes' watchdog stops and settles the arm
        arm.close()
        arm = Arm.open("emu://full/arm?ready=0&name=rehome-gone")  # a new host
        arm.torque(True, hold=True)
        arm.home()
        assert _latched(arm) == []
    finally:
        arm.close()
        forget_shared_emulators()


@pytest.mark.slow
def test_a_move_given_no_duration_or_speed_brings_the_joints_together_and_latches_nothing(
        ) -> None:
    """Each joint at 0.5 rad/s on its own time latched J4 (157 counts of its 150): J2 arrived
    first and its stop set the shoulder and elbow ringing together."""
    arm = _homed_arm("default-together")
    try:
        _, settled = arm.move([0.0, 0.5, 0.0, 0.8, 0.0, 0.0, 0.0], timeout=10.0)
        assert _latched(arm) == []
        # the wrist holds the hand there 0.026 rad off its goal, as its compliance gives at
        # that load: settled all the same (it said "J6 is -0.026 rad off its goal")
        assert settled
    finally:
        arm.close()
        forget_shared_emulators()


@pytest.mark.slow
def test_a_move_given_no_duration_or_speed_goes_at_the_default_speed_and_latches_nothing(
        ) -> None:
    """At the nodes' own limits (full step rate, π rad/s²) J2 latched STALLED on the way to
    the outstretched pose (211 counts of its 150)."""
    arm = _homed_arm("default-speed")
    try:
        plant = arm_plant_of(emulator_of(arm))
        peak = np.zeros(4)

        def watch(_: object) -> None:
            np.maximum(peak, np.abs(plant.joint_velocities()[:4]), out=peak)

        arm.state_taps.append(watch)
        state, settled = arm.move(OUTSTRETCHED, timeout=10.0)
        assert settled
        assert _latched(arm) == []
        # the shoulder at about that speed (its full speed is 1.45 rad/s): the link swings
        # about its motor, 0.68 rad/s at most here
        assert 0.8 * MOVE_DEFAULT_SPEED < peak[1] < 1.5 * MOVE_DEFAULT_SPEED
        # a move as long as its timeout at that speed is not cut short: J1 over 1.5 rad
        # takes 3 s, and the outstretched arm swings on its base about 3 s more; the
        # timeout counts from its arrival
        _, settled = arm.move([1.5, *OUTSTRETCHED[1:]], timeout=5.0)
        assert settled
    finally:
        arm.close()
        forget_shared_emulators()


def test_an_arm_homed_already_goes_straight_over_its_marks_then_searches() -> None:
    """From J2 at 1.5 rad (its mark at 0.07): first to a search step beyond the mark, then,
    should the mark not be there, the widening search about the start, inside the range."""
    widening = search_targets(2.0, 0.12)
    plan = straight_to_the_mark(widening, 1.5, 1)
    assert plan[0] == pytest.approx(0.07 - 1.5 - 0.12)
    assert plan[1:] == widening
    assert straight_to_the_mark(widening, -0.5, 1)[0] == pytest.approx(0.07 + 0.5 + 0.12)


def test_a_search_skips_the_legs_on_a_blocked_side() -> None:
    plan = search_targets(1.0, 0.12)  # +0.12, -0.12, +0.24, -0.24 ...
    assert next_leg(plan, -1, {-1}) == 0 and next_leg(plan, 0, {-1}) == 2
    assert next_leg(plan, 0, set()) == 1
    assert next_leg(plan, 0, {1}) == 1 and next_leg(plan, 1, {1}) == 3
    assert next_leg(plan, 0, {1, -1}) == len(plan)


@pytest.mark.slow
def test_an_arm_driven_into_a_stop_unhomed_and_cleared_is_homed() -> None:
    """The user's way out of a latch, as the messages say it (clear, torque on, home): J2
    against its lower stop with its element wound past the stall limit searched into the
    stop and latched again, every time, then went back to its wound start."""
    arm = Arm.open("emu://full/arm?ready=0&name=rehome-stop")
    try:
        arm.torque(True, hold=True)
        with pytest.raises(Exception, match="J2 latched STALLED"):
            arm.move([0.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
        arm.clear_errors()
        arm.torque(True)
        arm.home()
        assert arm.homed and _latched(arm) == []
        assert arm.state().joints[1] == pytest.approx(-0.3, abs=0.08)  # off the stop, held
    finally:
        arm.close()
        forget_shared_emulators()
