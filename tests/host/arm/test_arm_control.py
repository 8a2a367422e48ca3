"""Arm control math (PID, coupling feed-forward, interpolation, waypoint files) and the arm
end to end on the in-process emulator: homing, Cartesian moves, waypoints, armctl."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm import kinematics as arm_kinematics
from host.arm.facade import Arm
from host.arm.joint_loop import (
    ENCODER_COUNT_RAD,
    STALL_RETRIES,
    STEPPER_ACCEL_RAD_S2,
    JointController,
    JointPid,
    PidGains,
    TrackingLog,
    braking_lead,
    coupling_feedforward,
)
from host.arm.state import ArmState
from host.arm.trajectory import MIN_JERK_PEAK, Trajectory, Waypoint, timed_path
from host.arm.waypoints import load_waypoints, play_waypoints, record_waypoints, save_waypoints
from host.errors import LimitError, StallError, UsageError
from protocol.robot import ARM_INDEX_ANGLES
from tests.ground_truth import arm_plant_of, emulator_of, planted_of
from tools.cli import armctl

# ----------------------------------------------------------------------------- math


def test_pid_proportional_integral_and_derivative_terms() -> None:
    gains = PidGains(kp=(2.0,) * 7, ki=(10.0,) * 7, kd=(0.5,) * 7, integral_limit=(0.3,) * 7,
                     deadband=(0.0,) * 7, integral_error=(1.0,) * 7)
    pid = JointPid(gains)
    q_des = [0.1] * 7
    out = pid.update(q_des, [0.0] * 7, 0.01, qd_des=[0.0] * 7, qd=[0.2] * 7)
    # 2·0.1 + 10·0.1·0.01 + 0.5·(0 − 0.2) = 0.2 + 0.01 − 0.1
    assert out == pytest.approx([0.11] * 7)
    for _ in range(100):  # the integral saturates at its limit
        out = pid.update(q_des, [0.0] * 7, 0.01)
    assert out == pytest.approx([0.2 + 0.3] * 7)


def test_pid_deadband_holds_the_integral_and_large_errors_wind_it_slowly() -> None:
    gains = PidGains(kp=(0.0,) * 7, ki=(1.0,) * 7, integral_limit=(1.0,) * 7,
                     deadband=(0.001,) * 7, integral_error=(0.01,) * 7)
    pid = JointPid(gains)
    pid.update([0.0005] * 7, [0.0] * 7, 1.0)  # within the deadband: nothing to integrate
    assert pid.integral == pytest.approx([0.0] * 7)
    pid.update([0.5] * 7, [0.0] * 7, 1.0)  # a large error winds it as a 0.01 rad one
    assert pid.integral == pytest.approx([0.01] * 7)
    pid.update([-0.002] * 7, [0.0] * 7, 1.0)  # outside the deadband: integrates as it is
    assert pid.integral == pytest.approx([0.008] * 7)


def test_a_smooth_trajectory_leaves_and_reaches_its_goal_at_rest() -> None:
    path = timed_path([(0.0,) * 7, (1.0,) + (0.0,) * 6], max_speed=0.5, smooth=True)
    assert path[-1].t == pytest.approx(2.0 * MIN_JERK_PEAK)
    traj = Trajectory(path, smooth=True)
    end = path[-1].t
    speeds = [traj(t)[1][0] for t in np.linspace(0.0, end, 201)]
    assert max(speeds) == pytest.approx(0.5, rel=1e-3)  # no faster than asked
    assert speeds[0] == pytest.approx(0.0) and speeds[-1] == pytest.approx(0.0)
    assert abs(traj(0.99 * end)[1][0]) < 0.01  # slowing into the goal
    assert traj(end / 2)[0][0] == pytest.approx(0.5)


def test_coupling_feedforward_cancels_the_route_coupling() -> None:
    q_ref = [0.0, 0.1, 0.2, 0.0, 0, 0, 0]
    q_des = [0.5, 0.6, 0.7, 0.3, 0, 0, 0]   # Δq = 0.5 everywhere on J1..J3
    ff = coupling_feedforward(q_des, q_ref)
    # J3 capstan turns −0.12·Δq2 → add +0.06; J4 turns 0.18·Δq2 + 0.08·Δq3 → add −0.13
    assert ff == pytest.approx([0.0, 0.0, 0.06, -0.13])
    assert coupling_feedforward(q_ref, q_ref) == pytest.approx([0.0] * 4)


def test_trajectory_interpolates_linearly_and_holds_the_ends() -> None:
    traj = Trajectory([Waypoint(0.0, (0.0,) * 7), Waypoint(2.0, (1.0, -1.0, 0, 0, 0, 0, 0.5))])
    q, qd = traj(0.5)
    assert q == pytest.approx([0.25, -0.25, 0, 0, 0, 0, 0.125])
    assert qd == pytest.approx([0.5, -0.5, 0, 0, 0, 0, 0.25])
    assert traj(5.0)[0] == pytest.approx([1.0, -1.0, 0, 0, 0, 0, 0.5])
    assert traj(-1.0)[1] == pytest.approx([0.0] * 7)


def test_waypoint_file_round_trip_and_bad_lines(tmp_path: Path) -> None:
    path = tmp_path / "w.jsonl"
    points = [Waypoint(0.0, (0.0,) * 7), Waypoint(1.5, (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7))]
    save_waypoints(path, points)
    lines = path.read_text().splitlines()
    assert json.loads(lines[0])["kind"] == "arm-waypoints"
    assert json.loads(lines[2]) == {"t": 1.5, "joints": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]}
    assert load_waypoints(path) == points
    path.write_text('{"t": 0, "joints": [0, 0, 0]}\n')
    with pytest.raises(UsageError, match=r"w.jsonl:1: bad waypoint line"):
        load_waypoints(path)


# ----------------------------------------------------------------------------- end to end

URL = "emu://arm/arm?name=test_arm_control"
#: armctl gets an emulator of its own: the in-process link delivers to the newest transport.
CLI_URL = "emu://arm/arm?name=test_arm_control_cli"


def flange_truth(arm: Arm) -> np.ndarray:
    """The MuJoCo flange body's position in the arm's base frame (m)."""
    plant = arm_plant_of(emulator_of(arm))
    model, data = plant.model, plant.data
    flange = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm/flange")
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm/base")
    return np.asarray(data.xmat[base].reshape(3, 3).T @ (data.xpos[flange] - data.xpos[base]))


def run(*argv: str) -> tuple[int, str]:
    out = io.StringIO()
    return armctl.main(["--port", CLI_URL, "--json", *argv], out), out.getvalue()


@pytest.mark.slow
def test_armctl_refuses_moves_before_homing_and_remembers_homing(
        capsys: pytest.CaptureFixture[str]) -> None:
    code, out = run("status")
    assert code == 0 and json.loads(out)["homed"] is False
    code, _ = run("moveto", "0.1", "0.0", "-0.6")
    assert code == armctl.EXIT_USAGE
    assert "home it first (armctl home)" in capsys.readouterr().err
    code, _ = run("move", "--joints", *["0"] * 7)
    assert code == armctl.EXIT_USAGE
    code, out = run("home")
    assert code == 0 and json.loads(out)["homed"] is True
    # a later armctl picks the calibration up from the nodes' latches
    code, out = run("status")
    assert code == 0 and json.loads(out)["homed"] is True
    # homing turned on the steppers only: the servos would not follow the path
    code, _ = run("moveto", "0.1", "0.0", "-0.6")
    assert code == armctl.EXIT_USAGE
    assert "torque is off on J5, J6, J7" in capsys.readouterr().err
    assert run("torque", "on")[0] == 0
    code, out = run("moveto", "0.1", "0.0", "-0.6")
    assert code == 0 and json.loads(out)["reached"] is True
    forget_shared_emulators()


def test_arm_moveto_is_refused_before_homing(arm: Arm) -> None:
    assert not arm.homed
    with pytest.raises(UsageError, match="home it first"):
        arm.moveto((0.1, 0.0, -0.6))


def test_home_finds_every_index_and_fixes_absolute_angles(arm: Arm) -> None:
    calibration = arm.home()
    assert arm.homed
    plant = arm_plant_of(emulator_of(arm))
    counts_per_rad = 10_000 / (2 * np.pi)
    # the plant's encoders count from the power-up pose (0 here): the index's count, the
    # mark where the built arm has it (its drawn angle plus the planted mounting error)
    index = np.array(ARM_INDEX_ANGLES) + planted_of(arm).arm_index_offsets_rad
    assert calibration.index_encoder_counts == tuple(
        int(np.floor(a * counts_per_rad + 0.5)) for a in index)
    # absolute angles, as far as the drawn index angles are right: off by the mounting error
    state = arm.state()
    assert state.joints[:4] == pytest.approx(
        plant.joint_angles()[:4] - planted_of(arm).arm_index_offsets_rad, abs=2e-3)


def test_moveto_reaches_a_cartesian_goal_within_5_mm(arm: Arm) -> None:
    if not arm.homed:
        arm.home()
    target = (0.25, -0.08, -0.52)
    result = arm.moveto(target)
    assert result.reached
    # where the host's kinematics puts the flange from its readings: on the goal; the built
    # arm's flange itself is off by its uncalibrated geometry (~10 mm, docs/EMULATOR.md)
    assert np.linalg.norm(arm_kinematics.forward(arm.state().joints).position - target) < 0.005
    assert np.linalg.norm(flange_truth(arm) - target) < 0.020
    assert arm_kinematics.forward(result.goals).position == pytest.approx(target, abs=1e-3)
    assert not any(s.stalled for s in result.state.steppers)


def test_a_guarded_moveto_stops_where_until_says_and_holds_there(arm: Arm) -> None:
    """``until`` (a contact felt) ends the path the first cycle it is true; the arm is held
    there, short of the target, and the result says it stopped."""
    if not arm.homed:
        arm.home()
    start = arm_kinematics.forward(arm.state().joints).position
    target = start + np.array([0.0, 0.0, -0.05])
    low = start[2] - 0.02
    result = arm.moveto(target, until=lambda s: arm_kinematics.forward(s.joints).position[2]
                        <= low)
    assert result.stopped and not result.reached
    here = arm_kinematics.forward(arm.state().joints).position
    assert here[2] == pytest.approx(low, abs=0.004)  # held where it stopped, not at the goal
    assert result.position_error > 0.02
    assert arm.moveto(target).reached  # the same move, unguarded, gets there


def test_waypoints_recorded_by_hand_play_back(arm: Arm, tmp_path: Path) -> None:
    if not arm.homed:
        arm.home()
    plant = arm_plant_of(emulator_of(arm))
    # record from the hanging pose: with torque off an arm held elsewhere falls, and its
    # unpowered rotors turn with it, which the step counts cannot follow
    arm.torque(True)
    arm.move([0.0] * 7, timeout=5.0)
    start = arm.state().joints

    def hand(state: object) -> None:  # a hand turning the base and the wrist
        t = arm.transport.now() - t0
        plant.push(0, 1.0 if t < 0.3 else -1.0 if t < 0.6 else 0.0)
        plant.push(5, 0.4 if t < 0.2 else -0.4 if t < 0.4 else 0.0)

    t0 = arm.transport.now()
    points = record_waypoints(arm, 1.0, on_sample=hand)
    plant.push(0, 0.0)
    plant.push(5, 0.0)
    assert len(points) >= 3
    moved = np.abs(np.array([p.joints for p in points]) - start).max(axis=0)
    assert moved[0] > 0.05 and moved[5] > 0.05
    path = tmp_path / "hand.jsonl"
    save_waypoints(path, points)
    # the rotors turned with the joints while unpowered: re-enabling torque re-syncs them
    # instead of latching STALLED
    state = arm.torque(True)
    assert not any(s.stalled or s.slip for s in state.steppers)
    arm.move(start, timeout=5.0)  # somewhere else first
    before = arm.state().joints
    # a hand turns the hanging arm faster than its steppers can: played as recorded, the
    # path is refused before anything moves (it used to be sent, the joints trailing it)
    # and the message says how much slower will do
    with pytest.raises(LimitError, match=r"J1 at waypoint \d+ needs [\d.]+ rad/s² .* "
                                         r"time scale .* of [\d.]+ or more") as refused:
        play_waypoints(arm, load_waypoints(path))
    scale = float(re.search(r"of ([\d.]+) or more", str(refused.value))[1])  # type: ignore[index]
    assert arm.state().joints == pytest.approx(before, abs=0.006)  # a servo unit
    log = TrackingLog()
    play_waypoints(arm, load_waypoints(path), log=log, time_scale=scale)
    assert log.stall_events == []
    final = np.array(arm.state().joints)
    assert final == pytest.approx(points[-1].joints, abs=0.03)


def test_the_controller_settles_within_its_deadband(arm: Arm) -> None:
    control = JointController(arm)
    state = control.start()
    goals = np.array(state.joints)
    state = control.run(lambda _t: (goals, np.zeros(7)), 3.0,
                        until=lambda s: control.settled(s, goals))
    assert control.settled(state, goals)
    off = goals.copy()
    off[0] += 3 * ENCODER_COUNT_RAD  # three counts off: not where the loop rests
    assert not control.settled(state, off)


def test_the_controller_gives_up_on_a_joint_that_stays_held() -> None:
    """A hand holding the forearm while the elbow is driven: the node latches STALLED, the
    controller clears and re-enables it a few times, then raises StallError naming J4 and
    leaves it held (the node stops and holds a STALLED joint) instead of driving it again
    and again."""
    with Arm.open("emu://arm/arm?name=test_stall_gives_up") as held:
        plant = arm_plant_of(emulator_of(held))
        try:
            control = JointController(held)
            start = np.array(control.start().joints)
            plant.push(3, -25.0)  # more than the elbow's stepper moves against
            goal = start.copy()
            goal[3] += 0.6
            log = TrackingLog()
            t0 = held.transport.now()
            with pytest.raises(StallError) as caught:
                control.run(Trajectory(timed_path([start, goal], 0.3)), 10.0, log)
            assert caught.value.joint == "J4" and "J4 latched STALLED" in str(caught.value)
            assert log.stall_events.count("J4") == STALL_RETRIES + 1
            assert held.transport.now() - t0 < 10.0  # gave up long before the run's end
            held.transport.sleep(0.1)
            assert held.state().steppers[3].stalled  # latched, and left so: held
        finally:
            plant.push(3, 0.0)
            forget_shared_emulators()


def test_waypoints_recorded_by_one_program_play_back_in_another(tmp_path: Path) -> None:
    """``armctl waypoints record`` then ``armctl waypoints play``: two processes, so the
    second arm never turned the torque off itself.  Moved by hand while unpowered, a stepper
    neither latches STALLED (a node does not once the host turned its coils off) nor does enabling
    its torque in the second program latch it: the arm re-syncs the node it found unpowered."""
    url = "emu://arm/arm?name=test_arm_two_programs"
    path = tmp_path / "by_hand.jsonl"
    try:
        with Arm.open(url) as first:
            first.home()
            first.torque(True)
            first.move([0.0] * 7, timeout=5.0)
            plant = arm_plant_of(emulator_of(first))
            t0 = first.transport.now()

            def hand(state: object) -> None:  # a hand turning the base one way
                plant.push(0, 1.0 if first.transport.now() - t0 < 0.3 else 0.0)

            points = record_waypoints(first, 1.0, on_sample=hand)
            plant.push(0, 0.0)
            state = first.state()
            assert state.joints[0] > 0.05  # the base turned, the rotor with it
            assert not any(s.stalled or s.slip for s in state.steppers)
            save_waypoints(path, points)
        with Arm.open(url) as second:
            second.calibration = None  # as a new process would: home again first
            second.home()
            log = TrackingLog()
            loaded = load_waypoints(path)
            try:  # a hand may turn the base faster than its stepper can: slower then
                play_waypoints(second, loaded, log=log)
            except LimitError as refused:
                scale = float(re.search(r"of ([\d.]+) or more", str(refused))[1])  # type: ignore[index]
                play_waypoints(second, loaded, log=log, time_scale=scale)
            assert log.stall_events == []
            assert np.array(second.state().joints) == pytest.approx(points[-1].joints,
                                                                    abs=0.03)
    finally:
        forget_shared_emulators()


def test_braking_lead_is_the_stopping_distance_at_the_paths_speed() -> None:
    # v²/(2a): 0.4²/(2·2) = 0.04 rad ahead, behind for a joint moving the other way, none at rest
    assert braking_lead([0.4, -0.4, 0.0], 2.0) == pytest.approx([0.04, -0.04, 0.0])
    # the nodes' power-up acceleration_limit, 5000 counts/s², in rad/s²
    assert STEPPER_ACCEL_RAD_S2 == pytest.approx(5000 * ENCODER_COUNT_RAD)


def _lag_on_a_ramp(arm: Arm, accel: float | None) -> float:
    """Mean lag (rad) of J1 behind a 0.4 rad/s ramp over its second half, back to back."""
    arm.torque(True)
    arm.move([0.0] * 7, timeout=5.0)
    control = JointController(arm, rate_hz=None, stepper_accel=accel)
    q0 = np.array(control.start().joints)
    seen: list[tuple[float, float]] = []

    def ramp(t: float) -> tuple[np.ndarray, np.ndarray]:
        q, qd = q0.copy(), np.zeros(7)
        q[0] += 0.4 * min(t, 1.0)
        qd[0] = 0.4 if t < 1.0 else 0.0
        assert control.state is not None
        seen.append((t, q[0] - control.state.joints[0]))
        return q, qd

    control.run(ramp, 1.3)
    return float(np.mean([e for t, e in seen if 0.5 < t < 1.0]))


def test_stepper_goals_led_by_their_braking_distance_keep_up_with_a_ramp() -> None:
    """Goals sent back to back along a 0.4 rad/s ramp on J1: each is a stop to its node,
    which then trails the ramp by about a centiradian; led by the braking distance, the
    joint keeps within half of that of it (a little ahead: the loop's gains act too).  Its
    own arm: earlier moves leave the nodes' velocity limits lower than the ramp's speed."""
    arm = Arm.open("emu://arm/arm?name=test_arm_braking_lead")
    arm.home()
    unled = _lag_on_a_ramp(arm, None)
    led = _lag_on_a_ramp(arm, STEPPER_ACCEL_RAD_S2)
    arm.close()
    assert unled > 0.006  # the cause: unled, the joint trails its goals
    assert abs(led) < unled / 2


def test_a_controller_taking_over_keeps_holding_the_load_the_last_one_held() -> None:
    """An unmodelled load (a 6 N·m push on the shoulder J2, as a mug in the hand is to the
    arm's model) held by one controller's integral stays held when a new controller takes
    the arm (every Cartesian move makes its own): J2 moves less than three encoder counts
    over the new controller's first second, where an integral starting from zero dropped it
    by the load's whole deflection (about 0.03 rad, sixteen counts)."""
    with Arm.open("emu://arm/arm?name=test_take_over") as taken:
        plant = arm_plant_of(emulator_of(taken))
        try:
            first = JointController(taken)
            goals = np.array(first.start().joints)
            plant.push(1, -6.0)
            first.run(lambda _t: (goals, np.zeros(7)), 4.0)
            assert abs(first.pid.integral[1]) > 0.02  # holding the push

            second = JointController(taken)
            second.start()
            assert second.pid.integral[1] == pytest.approx(first.pid.integral[1], abs=0.003)
            worst = 0.0

            def watch(s: ArmState) -> bool:
                nonlocal worst
                worst = max(worst, abs(s.joints[1] - goals[1]))
                return False

            second.run(lambda _t: (goals, np.zeros(7)), 1.0, until=watch)
            assert worst < 3 * ENCODER_COUNT_RAD
        finally:
            plant.push(1, 0.0)
            forget_shared_emulators()
