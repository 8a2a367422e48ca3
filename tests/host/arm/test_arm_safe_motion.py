"""Safe motion of the arm, on the in-process emulator (simulation clock): an interrupted
motion leaves the arm held where it was, one gate refuses what the arm cannot do before
anything moves, an alarm mid-move stops it naming the joint, and "settled" means at rest.
Judged on the plant's ground truth where it matters (what the arm really did)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.cartesian import choose_ik
from host.arm.facade import Arm
from host.arm.gate import check_path, path_rates, slowdown
from host.arm.state import ArmState
from host.arm.trajectory import Waypoint, timed_path
from host.arm.waypoints import play_waypoints
from host.errors import JointAlarmError, LimitError
from protocol.robot import (
    ARM_JOINT_ACCEL_LIMITS,
    ARM_JOINT_LIMITS,
    ARM_JOINT_SPEED_LIMITS,
    RX64_RAD_PER_UNIT,
)
from tests.ground_truth import arm_joints, arm_velocities

#: The issue's move: shoulder and elbow lifted over 6 s.
LIFT = [0.0, 1.5, 0.0, 1.5, 0.0, 0.2, 0.0]
TWO_DEGREES = math.radians(2.0)


@pytest.fixture()
def url(request: pytest.FixtureRequest) -> Iterator[str]:
    """A freshly powered arm of its own (torque off, not homed) for each test."""
    forget_shared_emulators()
    yield f"emu://arm/arm?name=safe_{request.node.name}"
    forget_shared_emulators()


def _interrupt_after(arm: Arm, seconds: float, seen: dict[str, np.ndarray]) -> None:
    """Raise KeyboardInterrupt (as Ctrl-C does) in the first cycle ``seconds`` from now,
    noting the plant's joints then in ``seen["at"]``."""
    stop_at = arm.transport.now() + seconds

    def ctrl_c(_state: ArmState) -> None:
        if "at" not in seen and arm.transport.now() >= stop_at:
            seen["at"] = arm_joints(arm)
            raise KeyboardInterrupt

    arm.state_taps.append(ctrl_c)


def _still_held(url: str, at: np.ndarray, seconds: float = 2.0) -> None:
    """Reopen the arm (a new program), let ``seconds`` pass, and check on the plant that no
    joint moved more than 2° from ``at``, every joint's torque is on and nothing latched."""
    with Arm.open(url) as arm:
        worst = 0.0
        for _ in range(int(seconds / 0.1)):
            arm.transport.sleep(0.1)
            worst = max(worst, float(np.max(np.abs(arm_joints(arm) - at))))
        state = arm.state()
        assert worst <= TWO_DEGREES, f"a joint moved {math.degrees(worst):.1f}° after the hold"
        assert arm.torque_enabled() == (True,) * 7
        assert not any(s.stalled or s.slip for s in state.steppers) and state.errors == {}


def test_ctrl_c_mid_move_holds_the_arm_where_it_was(url: str) -> None:
    """Before, Ctrl-C sent nothing: the nodes drove on to the goal (J2 0.47 → 1.17 rad),
    J3 latched STALLED and the arm fell."""
    seen: dict[str, np.ndarray] = {}
    arm = Arm.open(url)
    arm.torque(True, hold=True)
    _interrupt_after(arm, 1.5, seen)
    with pytest.raises(KeyboardInterrupt) as caught, arm:
        arm.move(LIFT, duration=6.0)
    assert "the arm: held where they were, torque on: J1" in " ".join(caught.value.__notes__)
    assert seen["at"][1] > 0.1  # it was on its way
    _still_held(url, seen["at"])


def test_ctrl_c_mid_controlled_path_holds_the_arm_where_it_was(url: str) -> None:
    """The joint controller's paths (waypoints, moveto) feed the coupling feed-forward every
    10 ms and their goals lead the path by little, so a controller merely stopping already
    leaves the arm near where it was: this guards that the hold (motor goals, fresh
    coupling offsets) keeps it so, rather than proving a change."""
    seen: dict[str, np.ndarray] = {}
    arm = Arm.open(url)
    arm.torque(True, hold=True)
    start = arm.state().joints
    path = [Waypoint(0.0, tuple(start)), Waypoint(4.0, (0.3, 0.9, 0.3, 1.0, 0.0, 0.3, 0.0))]
    _interrupt_after(arm, 2.5, seen)
    with pytest.raises(KeyboardInterrupt), arm:
        play_waypoints(arm, path)
    assert seen["at"][3] > 0.1
    _still_held(url, seen["at"])


def test_a_latch_mid_move_stops_it_naming_the_joint_and_holds_the_rest(url: str) -> None:
    """On a fresh arm J2 at −3 rad from power-up is within its whole range of where it is,
    so the gate lets it go; J2 meets its stop.  Before, armctl waited out its timeout and
    asked whether the torque was on."""
    with Arm.open(url) as arm:
        arm.torque(True, hold=True)
        with pytest.raises(JointAlarmError, match=r"J2 latched STALLED") as caught:
            arm.move([0.0, -3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        assert caught.value.joint == "J2" and "STALLED" in caught.value.latches
        at = arm_joints(arm)
        arm.transport.sleep(1.0)
        enabled = arm.torque_enabled()
        state = arm.state()
    assert enabled[0] and enabled[2:] == (True,) * 5  # J2's node holds it, latched
    moved = np.abs(arm_joints(arm) - at)
    assert max(moved[0], *moved[2:]) <= TWO_DEGREES  # the rest held
    assert not any(s.stalled for s in state.steppers if s.joint != 1)


def test_an_unhomed_shoulder_that_meets_its_stop_latches_alone_with_the_hand_on(
        request: pytest.FixtureRequest) -> None:
    """The full arm (the hand on the wrist): J2 sent to −3 rad unhomed meets its lower stop.
    At the nodes' full speed the jolt swung the forearm and J4 latched STALLED/OVERLOAD as
    well; an unhomed move meets a stop at UNHOMED_STEPPER_SPEED, and only J2 latches."""
    forget_shared_emulators()
    try:
        with Arm.open(f"emu://full/arm?name=stop_{request.node.name}") as arm:
            assert not arm.homed
            arm.torque(True, hold=True)
            with pytest.raises(JointAlarmError, match=r"J2 latched STALLED"):
                arm.move([0.0, -3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            arm.transport.sleep(1.0)
            state = arm.state()
    finally:
        forget_shared_emulators()
    assert set(state.errors) == {"J2"}, state.errors
    assert [s.joint for s in state.steppers if s.stalled] == [1]


def test_the_library_move_refuses_joints_whose_torque_is_off_and_sends_nothing(
        url: str) -> None:
    """Arm.move used to write the goals anyway: they waited in the nodes, and the joints
    jumped there when the torque came on.  J3 is named too: it stays at 0, but the routes
    turn its capstan with J2, so its motor must move to keep it there."""
    with Arm.open(url) as arm:
        goals = list(arm.stepper_goals)
        with pytest.raises(LimitError, match="torque is off on J2, J3, J4: turn it on"):
            arm.move([0.0, 0.3, 0.0, 0.2, 0.0, 0.0, 0.0])
        arm.read_goals()
        assert arm.stepper_goals == goals


@pytest.mark.parametrize(("goals", "options", "match"), [
    ([0.0, -4.0, 0.0, 0.0, 0.0, 0.0, 0.0], {}, r"J2 goal -4\.000 rad is 4\.00 rad from where "
                                               r"the joint is .* more than its whole range"),
    ([0.0, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0], {}, "J2 goal nan is not a finite number"),
    ([0.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0], {"duration": 0.5},
     r"J2 would need 3\.00 rad/s to arrive in 0\.5 s; its limit is 0\.80 rad/s \(a move's, "
     r"for its elastic element; the controller steps at up to 1\.45\): take at least 1\.9 s"),
    ([0.0] * 7, {"duration": math.inf}, "must be a finite number of seconds"),
])
def test_the_gate_refuses_a_move_before_anything_moves(
        url: str, goals: list[float], options: dict[str, float], match: str) -> None:
    with Arm.open(url) as arm:
        arm.torque(True, hold=True)
        before = arm_joints(arm)
        sent = arm.bus.stats.bytes_sent
        with pytest.raises(LimitError, match=match):
            arm.move(goals, **options)  # type: ignore[arg-type]
        # the gate read the arm, but wrote no goal: it reads a state and, at most, the
        # torque registers (under 30 bytes each exchange)
        assert arm.bus.stats.bytes_sent - sent < 60
        arm.transport.sleep(0.5)
        assert np.max(np.abs(arm_joints(arm) - before)) < math.radians(0.5)


def test_settled_means_at_rest(url: str) -> None:
    """A move used to report settled while the elastic arm still swung (one reading of the
    nodes' 10 ms velocity, in steps of 0.063 rad/s, said 'still')."""
    with Arm.open(url) as arm:
        arm.torque(True, hold=True)
        state, settled = arm.move([0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0], timeout=10.0)
        assert settled
        at = arm_joints(arm)
        worst = 0.0
        for _ in range(10):
            arm.transport.sleep(0.05)
            worst = max(worst, float(np.max(np.abs(arm_joints(arm) - at))))
    assert worst < 0.002, f"still moving {worst:.4f} rad after 'settled'"


# ----------------------------------------------------------------------------- the gate


def _path(*points: tuple[float, list[float]]) -> tuple[list[float], np.ndarray]:
    return [t for t, _ in points], np.array([q for _, q in points])


def test_a_waypoint_beyond_its_joints_range_is_refused_naming_it() -> None:
    times, q = _path((0.0, [0.0] * 7), (3.0, [0.0, 3.5, 0.0, 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(LimitError, match=r"J2 goal \(point 1\) \+3\.500 rad is outside the "
                                         r"joint's range -0\.35 … \+2\.80 rad") as caught:
        check_path(times, q, [0.0] * 7, homed=True)
    assert caught.value.joint == "J2"


def test_a_jump_is_refused_and_no_slowing_down_is_offered() -> None:
    times, q = _path((0.0, [0.0] * 7), (0.001, [2.5] * 7))
    with pytest.raises(LimitError, match=r"J3 from point 0 to point 1 needs 2500\.00 rad/s; "
                                         r"its speed limit is 1\.11 rad/s$"):
        check_path(times, q, [0.0] * 7, homed=True, slower="a time scale of")


def test_a_path_too_brisk_is_refused_with_the_time_scale_that_would_do() -> None:
    times, q = _path((0.0, [0.0] * 7), (0.5, [0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]),
                     (1.0, [0.0] * 7))
    with pytest.raises(LimitError, match=r"J2 at point 1 needs 3\.99 rad/s² .* a time scale "
                                         r"of 1\.2 or more"):
        check_path(times, q, [0.0] * 7, homed=True, slower="a time scale of")
    scale = slowdown(times, q)
    check_path([t * scale for t in times], q, [0.0] * 7, homed=True)


@pytest.mark.parametrize(("xyz", "rpy", "match"), [
    ((math.nan, 0.0, -0.5), None, "x coordinate nan is not a finite number"),
    ((0.25, -0.08, -0.52), (math.inf, 0.0, 0.0), "roll angle inf is not a finite number"),
    ((0.25, -0.08, -0.52), (1e300, 0.0, 0.0), "roll 1e[+]300 rad is not an orientation angle"),
    ((0.0, 1e300, 0.0), None, "is out of reach"),
])
def test_cartesian_targets_must_be_finite_and_within_reach(
        xyz: tuple[float, ...], rpy: tuple[float, ...] | None, match: str) -> None:
    """nan gave a ValueError, inf LinAlgError: SVD did not converge, 1e300 rad a meaningless
    orientation the arm moved to."""
    with pytest.raises(LimitError, match=match):
        choose_ik(xyz, rpy, [0.0] * 7)


def test_a_path_must_start_where_the_arm_is() -> None:
    times, q = _path((0.0, [0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]),
                     (5.0, [0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(LimitError, match="the path starts 0.500 rad from where J2 is"):
        check_path(times, q, [0.0] * 7, homed=True)


def test_a_servo_angle_flickering_by_a_position_unit_is_no_acceleration() -> None:
    """Recorded at 50 Hz, J6 read one unit (5 mrad) off and back: 0.25 rad/s each way in
    20 ms, 25 rad/s² by the numbers, which refused a recording of the base turning."""
    unit = RX64_RAD_PER_UNIT
    times, q = _path((0.0, [0.0] * 7), (0.02, [0.0] * 5 + [unit, 0.0]),
                     (0.04, [0.0] * 7), (0.06, [0.0] * 5 + [unit, 0.0]))
    check_path(times, q, [0.0] * 7, homed=True)
    assert float(np.max(path_rates(times, q)[1])) == 0.0


_IN_RANGE = st.tuples(*(st.floats(lo, hi) for lo, hi in ARM_JOINT_LIMITS))


@settings(deadline=None, max_examples=60)
@given(a=_IN_RANGE, b=_IN_RANGE, speed=st.floats(0.01, min(ARM_JOINT_SPEED_LIMITS)),
       smooth=st.booleans())
def test_a_timed_path_between_poses_in_range_passes_the_gate(
        a: tuple[float, ...], b: tuple[float, ...], speed: float, smooth: bool) -> None:
    path = timed_path([a, b], speed, smooth=smooth)
    times, points = [w.t for w in path], np.array([w.joints for w in path])
    check_path(times, points, a, homed=True, smooth=smooth)
    speeds, accels = path_rates(times, points, smooth=smooth)
    assert np.all(speeds <= np.array(ARM_JOINT_SPEED_LIMITS) * (1 + 1e-6))
    assert np.all(accels <= np.array(ARM_JOINT_ACCEL_LIMITS) * (1 + 1e-6))


@settings(deadline=None, max_examples=60)
@given(points=st.lists(_IN_RANGE, min_size=2, max_size=6),
       steps=st.lists(st.floats(0.01, 2.0), min_size=5, max_size=5))
def test_any_path_slowed_down_as_the_gate_says_passes_it(
        points: list[tuple[float, ...]], steps: list[float]) -> None:
    times = np.concatenate([[0.0], np.cumsum(steps[:len(points) - 1])])
    q = np.array(points)
    scale = slowdown(times, q)
    check_path(times * scale * (1 + 1e-6), q, q[0], homed=True)


@pytest.mark.parametrize("after_s", [0.6, 2.5])
def test_a_move_started_at_once_after_a_ctrl_c_hold_latches_nothing(url: str,
                                                                      after_s: float) -> None:
    """The user's next command comes while the held arm still rings (the hold stops the
    motors within about 0.2 s; the elastic joints swing on for a second or two): the new
    move must start from the swinging arm without latching a stall, and get there."""
    seen: dict[str, np.ndarray] = {}
    arm = Arm.open(url)
    arm.torque(True, hold=True)
    _interrupt_after(arm, after_s, seen)
    with pytest.raises(KeyboardInterrupt), arm:
        arm.move(LIFT, duration=6.0)
    back = [0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0]
    with Arm.open(url) as again:  # a new program, at once
        moving = max(abs(v) for v in arm_velocities(again)[:4])
        again.move(back, duration=6.0)
        state = again.state()
    assert moving > 0.02, "the arm was at rest already: nothing was tested"
    assert not any(s.stalled or s.slip for s in state.steppers) and state.errors == {}
    assert float(np.max(np.abs(arm_joints(arm)[:4] - np.array(back[:4])))) < 0.05
