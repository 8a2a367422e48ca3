"""The touch calibration's touches (host.arm.touches): the seating push is a force into the
dimple, a touch off its dimple is told by its distances, the rig is crossed above it, the
table is touched clear of the board; and (slow) one touch on the emulated rig, judged by the
plant's truth: the ball at the dimple's bottom, and the arm's next move where it was sent."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

import host.arm.calibration_rig as rig
import host.arm.gravity as arm_gravity
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport
from host.arm import touches
from host.arm.calibration import BoardTouches, CalibrationData, calibrate
from host.arm.facade import Arm
from host.arm.geometry import ArmGeometry
from host.arm.kinematics import forward, jacobian
from host.arm.state import N_STEPPERS, ArmState, ServoState, StepperState
from host.errors import NotSeated
from protocol.control_tables import StepperFlag
from protocol.dynamixel import ErrorBit
from protocol.robot import (
    ARM_PROBE_BALL_RADIUS_M,
    ARM_PROBE_TIP_M,
    SERIES_ELASTIC_STIFFNESS_NM_PER_RAD,
    arm_route_coupling_matrix,
)

#: A pose of the arm over the board, the probe pointing down (rad).
OVER_THE_BOARD = np.array([-0.12, 0.24, 0.06, 1.07, 0.3, -1.35, 0.3])
GEOMETRY = ArmGeometry.nominal().with_tool(ARM_PROBE_TIP_M)
#: The servos' goals a hold gave them (rad, J5..J7).
SERVOS = [0.31, -1.36, 0.29]


#: What a hold left: the arm over the board, its motors 0.02 rad ahead of the joints (the
#: springs carrying its weight), the servos' goals.
HELD = touches.Springs(OVER_THE_BOARD, OVER_THE_BOARD[:N_STEPPERS] + 0.02, tuple(SERVOS))


def _pressed_force(goals: Sequence[float], q: np.ndarray) -> tuple[np.ndarray, float]:
    """The force (N, base frame) the ball meets at ``q`` (rad) from the springs wound to
    ``goals`` beyond the baseline :data:`HELD` (the motors' offset over it times the
    stiffness, the routes passing each torque on), least squares over J1..J4, and what of
    the joints' torques no force at the ball takes (N·m: it would turn the arm about the
    ball instead)."""
    baseline = HELD.goals(q, np.zeros(N_STEPPERS))
    springs = (np.array(goals[:N_STEPPERS]) - np.array(baseline[:N_STEPPERS])) \
        * np.array(SERIES_ELASTIC_STIFFNESS_NM_PER_RAD)
    joints = (np.eye(N_STEPPERS) - arm_route_coupling_matrix().T) @ springs
    j = jacobian(q, GEOMETRY)[:3, :N_STEPPERS]
    force: np.ndarray = np.linalg.lstsq(j.T, joints, rcond=None)[0]
    return force, float(np.linalg.norm(j.T @ force - joints))


def test_the_push_is_a_force_along_the_dimples_axis() -> None:
    """What the springs press the ball with, beyond what they carried at the hold, is the
    force asked, along the dimple's axis, and all of their torques go into it (a motor
    move along the probe, the push this replaces, pressed 34-42° off the probe on the
    emulator: the arm is stiffer along itself than across)."""
    asked = touches.SEAT_FORCE_N * touches.BOARD_AXIS
    goals = HELD.goals(OVER_THE_BOARD, touches.push_torques(OVER_THE_BOARD, asked, GEOMETRY))
    force, rest = _pressed_force(goals, OVER_THE_BOARD)
    assert np.allclose(force, asked, atol=1e-6) and rest < 1e-9
    assert goals[N_STEPPERS:] == SERVOS  # the servos hold where the hold left them


def test_the_baseline_follows_the_joints_less_the_routes() -> None:
    """Where the ball has slid to, the springs carry what they carried at the hold: each
    motor moved with its joint less what the routes turn its capstan by (J3 and J4 with
    the shoulder)."""
    moved = OVER_THE_BOARD + np.array([0.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    goals = HELD.goals(moved, np.zeros(N_STEPPERS))
    capstans = np.array(goals[:N_STEPPERS]) + arm_route_coupling_matrix() @ (
        moved - OVER_THE_BOARD)[:N_STEPPERS]
    deflections = capstans - moved[:N_STEPPERS]
    assert np.allclose(deflections, HELD.motors - OVER_THE_BOARD[:N_STEPPERS], atol=1e-12)


def test_a_push_too_hard_for_a_stepper_is_scaled_down_to_its_share_of_the_stall() -> None:
    torques = touches.push_torques(OVER_THE_BOARD, 100.0 * touches.BOARD_AXIS, GEOMETRY)
    pressed, _ = _pressed_force(HELD.goals(OVER_THE_BOARD, torques), OVER_THE_BOARD)
    assert np.allclose(pressed / np.linalg.norm(pressed), touches.BOARD_AXIS, atol=1e-6)
    loads = (np.abs(arm_gravity.spring_torques(OVER_THE_BOARD)) + np.abs(torques)) \
        / arm_gravity.stall_torques()
    assert loads.max() == pytest.approx(touches.SEAT_LOAD_LIMIT, abs=1e-6)


class _Creeping:
    """An arm whose ball moves ``step`` (rad on J2) at every push, for ``pushes`` pushes;
    the servos' goals it is sent are kept (``servo_goals``, one list a push)."""

    hand = False

    def __init__(self, step: float, pushes: int) -> None:
        self.q = OVER_THE_BOARD.copy()
        self.step = step
        self.left = pushes
        self.moves = 0
        self.servo_goals: list[list[float]] = []

    def state(self) -> ArmState:
        q = [float(v) for v in self.q]
        steppers = tuple(StepperState(i, q[i], 0.0, q[i], 0, 0, 0.0, 0.0, StepperFlag(0),
                                      ErrorBit(0), q[i]) for i in range(N_STEPPERS))
        servos = tuple(ServoState(i, q[i], 0.0, 0.0, 30.0, 12.0, ErrorBit(0))
                       for i in range(N_STEPPERS, len(q)))
        return ArmState(0.0, steppers, servos)

    def move(self, angles: Sequence[float], **_: object) -> tuple[object, bool]:
        self.moves += 1
        self.servo_goals.append(list(angles[N_STEPPERS:]))
        if self.left > 0:
            self.q = self.q + np.array([0.0, self.step, 0, 0, 0, 0, 0.002])
            self.left -= 1
        return self.state(), True


def test_the_pushes_go_on_until_one_leaves_the_ball_where_it_was() -> None:
    arm = _Creeping(step=0.004, pushes=5)
    readings, _ = touches.seat(arm, touches.BOARD_AXIS, GEOMETRY)  # type: ignore[arg-type]
    assert arm.moves == 6  # five moved it, the sixth did not
    assert readings == pytest.approx(list(arm.q))
    # the servos keep the goals they had before the pushes, however the joints give way
    assert arm.servo_goals == [list(OVER_THE_BOARD[N_STEPPERS:])] * 6


def test_a_flat_surface_is_pushed_once() -> None:
    arm = _Creeping(step=0.004, pushes=1000)
    touches.seat(arm, touches.DOWN, GEOMETRY, flat=True)  # type: ignore[arg-type]
    assert arm.moves == 1


def test_a_ball_every_push_still_moves_is_not_seated() -> None:
    arm = _Creeping(step=0.0007, pushes=1000)  # 0.65 mm a push: creeping
    with pytest.raises(NotSeated, match="did not come to rest"):
        touches.seat(arm, touches.BOARD_AXIS, GEOMETRY)  # type: ignore[arg-type]
    assert arm.moves == touches.SEAT_PUSHES


def test_a_ball_the_pushes_carry_off_is_not_in_its_dimple() -> None:
    """Pushes that move the ball 10 mm each (a stop short of the surface, the ball pushed in
    free space) are given up once it is further than the dimple's mouth from the start."""
    arm = _Creeping(step=0.025, pushes=1000)
    with pytest.raises(NotSeated, match="not in the dimple"):
        touches.seat(arm, touches.BOARD_AXIS, GEOMETRY)  # type: ignore[arg-type]
    assert arm.moves < 5


def test_a_touch_off_its_dimple_is_told_by_its_distances_to_the_others() -> None:
    """Twelve touches where a fitted kinematics puts the dimples (0.2 mm scatter, as the
    seated touches on the emulator), one of them a ball left 3 mm up a wall: that one, and
    only it, is off its dimple by more than the fit's check."""
    rng = np.random.default_rng(3)
    points = rig.dimple_points()
    tips = rig.nominal_dimples() + rng.normal(0.0, 0.0002, points.shape)
    assert touches.distance_medians(tips, points).max() < touches.FIT_CHECK_M
    tips[5] += np.array([0.002, 0.002, 0.002])
    medians = touches.distance_medians(tips, points)
    assert [bool(m > touches.FIT_CHECK_M) for m in medians] == [k == 5 for k in range(12)]
    assert not touches.distance_medians(tips[4:6], points[4:6]).any()  # two cannot tell


def test_the_table_is_touched_clear_of_the_board() -> None:
    """Every table touch is further from every dimple (in the table's plane) than the
    dimple's mouth and the ball: the board lies on the table."""
    table = np.array([(x, y) for x, y, _row in rig.table_points()])
    dimples = rig.nominal_dimples()[:, :2]
    gaps = np.linalg.norm(table[:, None, :] - dimples[None, :, :], axis=2)
    assert gaps.min() > rig.DIMPLE_MOUTH_RADIUS_M + ARM_PROBE_BALL_RADIUS_M + 0.03
    assert len({row for _x, _y, row in rig.table_points()}) == 2


class _Recorder:
    """The moves an arm is asked for: ``(xyz, rpy)`` each."""

    hand = False

    def __init__(self) -> None:
        self.targets: list[tuple[list[float], list[float]]] = []

    def moveto(self, xyz: Sequence[float], rpy: Sequence[float], **_: object) -> None:
        self.targets.append((list(xyz), list(rpy)))


def test_the_ball_crosses_the_rig_above_the_dimples_and_the_anchors() -> None:
    arm = _Recorder()
    here = touches.clear_point(rig.nominal_dimples()[11], touches.ORIENTATIONS[0])
    there = np.array([0.47, -rig.TABLE_ROW_Y_M, rig.TABLE_TOP_Z_M + 0.04])
    touches.travel(arm, here, touches.ORIENTATIONS[0], there,  # type: ignore[arg-type]
                   touches.ORIENTATIONS[1], GEOMETRY)
    (up, up_rpy), (over, over_rpy), (down, down_rpy) = arm.targets
    assert up[:2] == pytest.approx(list(here[:2])) and up[2] == rig.TRAVEL_Z_M
    assert over[:2] == pytest.approx(list(there[:2])) and over[2] == rig.TRAVEL_Z_M
    assert down == pytest.approx(list(there))
    assert up_rpy == list(touches.ORIENTATIONS[0]) and over_rpy == down_rpy
    mouths = max(rig.BOARD_ORIGIN_M[2], *(a[2] for a in rig.ANCHOR_POINTS_M)) \
        + rig.DIMPLE_MOUTH_RADIUS_M
    assert rig.TRAVEL_Z_M > mouths + ARM_PROBE_BALL_RADIUS_M


@pytest.mark.slow
def test_a_touch_seats_the_ball_at_the_bottom_and_leaves_the_arm_free_to_move() -> None:
    """On the emulated rig (seed 0), a touch aimed where the CAD model puts a dimple: the
    as-built arm puts the ball 10 mm off, on the dimple's wall; it comes to rest within
    0.2 mm of the bottom (the plant's truth; the push this replaces left it 3-17 mm up the
    walls), and the move after it reaches its target (after the old push every move
    lagged and ended 20-230 mm off)."""
    emulator = Emulator("arm", seed=0, scene="calibration")
    truth = emulator.scene_parts[0]
    seats: list[float] = []
    dimple = truth.placement.dimples_m()[3]  # type: ignore[attr-defined]

    def seated_readings(arm: touches.TouchingArm) -> np.ndarray:
        readings = real(arm)
        seats.append(float(np.linalg.norm(truth.tip_m - dimple)))  # type: ignore[attr-defined]
        return readings

    real = touches.seated_readings
    with Arm.on(EmulatorTransport(emulator, "arm")) as arm, \
            pytest.MonkeyPatch.context() as patch:
        patch.setattr(touches, "seated_readings", seated_readings)
        arm.torque(True, hold=True)
        arm.home()
        arm.hand = False
        geometry = touches.probe_geometry(arm)
        rpy = touches.ORIENTATIONS[0]
        target = rig.nominal_dimples()[3]
        arm.moveto(list(rig.READY_M), list(rpy), speed=0.4, geometry=geometry, hand=False)
        walk = touches.Walk(arm, geometry, np.array(rig.READY_M), rpy)
        q = walk.touch(target, rpy, "board", axis=touches.BOARD_AXIS)
        assert seats[-1] < 0.0002 and seats[0] > 0.005  # on the wall first
        seated = forward(q, geometry).position
        assert np.linalg.norm(seated - target) < 0.015  # the CAD model's error
        after = arm.moveto(list(rig.READY_M), list(rpy), speed=touches.MOVE_SPEED_RAD_S,
                           tolerance_m=touches.BETWEEN_TOLERANCE_M,
                           settle_timeout=touches.BETWEEN_SETTLE_S, geometry=geometry,
                           hand=False)
    assert after.reached, f"the move after the touch ended {after.position_error * 1000:.0f} mm off"


def test_the_fit_is_made_again_without_a_touch_the_others_disagree_with() -> None:
    """24 touches of the CAD arm where the board says, but one dimple 7 mm from where the
    ball was (a ball left on the board's face would be 10 mm or more): the fit leaves that
    touch out, and only it (the first fit, bent by it, saw others off by 1.3 mm too), and
    then explains the rest."""
    rng = np.random.default_rng(1)
    q = rng.uniform(-0.5, 0.5, (24, 7))
    tips = GEOMETRY.tips(q)
    points = tips - tips[0]
    points[4] += np.array([0.005, -0.005, 0.0])
    data = CalibrationData((BoardTouches(q, points),), np.zeros((0, 7)),
                           tool_m=np.array(ARM_PROBE_TIP_M))
    fitted = touches.fit(data)
    assert fitted.dropped == 1
    assert fitted.result.board_rms_m[1] < 1e-4
    assert calibrate(data).board_rms_m[1] > 5e-4  # with it, the fit could not


def test_ctrl_c_while_seating_leaves_the_arm_where_it_is(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """Interrupted during the pushes, a touch moves nothing more (the push is not taken off,
    the ball not brought back): the arm's ``with`` block holds it.  A ball that did not
    seat is brought back."""
    arm = _Recorder()
    stopped = type("Stopped", (), {"stopped": True})()
    monkeypatch.setattr(touches, "at_rest", lambda _arm: None)
    monkeypatch.setattr(touches, "_guarded", lambda *_a: (stopped, np.zeros(N_STEPPERS)))

    def interrupted(*_a: object, **_k: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(touches, "seat", interrupted)
    with pytest.raises(KeyboardInterrupt):
        touches.touch(arm, rig.nominal_dimples()[0], touches.ORIENTATIONS[0],  # type: ignore[arg-type]
                      GEOMETRY, axis=touches.BOARD_AXIS)
    assert len(arm.targets) == 1  # the approach only

    def not_seated(*_a: object, **_k: object) -> None:
        raise NotSeated("still moving")

    monkeypatch.setattr(touches, "seat", not_seated)
    monkeypatch.setattr(touches, "_release", lambda _arm, _springs: arm.targets.append(([], [])))
    with pytest.raises(NotSeated):
        touches.touch(arm, rig.nominal_dimples()[0], touches.ORIENTATIONS[0],  # type: ignore[arg-type]
                      GEOMETRY, axis=touches.BOARD_AXIS)
    clear = touches.clear_point(rig.nominal_dimples()[0], touches.ORIENTATIONS[0])
    assert arm.targets[-2] == ([], []) and arm.targets[-1][0] == pytest.approx(list(clear))
