"""The touch calibration's touches, made by the arm: the probe's ball into the board's
dimples, onto the table and into the anchor dimples, each by a guarded move (§4.4).

One touch of a point ``p`` (m, base frame, where the host expects it), the probe pointing
along ``d`` (the flange's ``−z`` for an orientation ``rpy``), the ball coming from its
:func:`clear_point` (:data:`APPROACH_M` + :data:`CLEAR_M` before ``p`` along ``d``):

1. a Cartesian move of the ball to the approach point, :data:`APPROACH_M` before ``p``,
   then a hold until the arm is at rest (:func:`at_rest`);
2. a guarded move (:meth:`~host.arm.facade.Arm.moveto` with ``until``) at
   :data:`GUARD_SPEED_RAD_S` towards :data:`PRESS_M` past ``p``, stopped once the stepper
   joints' torques, less what gravity makes them carry (:mod:`host.arm.gravity`), have
   differed by :data:`TOUCH_LOAD_NM` (N·m, the norm over J1..J4) from the start's for
   :data:`TOUCH_CYCLES` cycles: the contact seen in the elastic elements' deflections;
3. the joints held where they stopped (the guarded move's end), then the seating
   (:func:`seat`): the stepper motors set so that their springs press the ball with
   :data:`SEAT_FORCE_N` along the dimple's axis more than they carried then
   (:func:`push_torques`, a force, not a displacement, on that baseline,
   :class:`Springs`), again from where each push left it, until one no longer moves it
   (:class:`~host.errors.NotSeated` if :data:`SEAT_PUSHES` do not): the ball has slid down
   the walls to the bottom.  The table is pressed once, along its normal.  The
   joint readings (the encoders, the servos' pots) then, :data:`READINGS` averaged;
4. the push taken off (:func:`_release`, which also gives the nodes back the speed limits
   the joint loop's moves need) and back to the clear point.

Between touches the ball goes straight from one clear point to the next within a group (the
board's dimples, a row of table touches, an anchor's touches), and over the rig at
:data:`~host.arm.calibration_rig.TRAVEL_Z_M` between groups (:func:`travel`): the ball is
the part of the arm the rig stops.

Nothing is read but what the host reads of any arm: joint readings and torques, and the
rig's rough poses (:mod:`host.arm.calibration_rig`).  The board's pose is not known: where
the ball seats in one dimple less where the host aimed is added to the aim of the next (the
CAD model's error and the board's misplacement change slowly over the board), so each lands
inside its dimple's mouth (:data:`~host.arm.calibration_rig.DIMPLE_MOUTH_RADIUS_M`); one
seated further than the mouth from its aim is left out.  :func:`fit` fits the calibration
and fits it again without a board touch the others' distances say is off its dimple.
Every motion is a :meth:`~host.arm.facade.Arm.moveto`, a :meth:`~host.arm.facade.Arm.move`
or a hold: through the arm's gate.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Final, Protocol

import numpy as np

import host.arm.calibration_rig as rig
import host.arm.gravity as arm_gravity
from host.arm.calibration import BoardTouches, CalibrationData, CalibrationResult, calibrate
from host.arm.cartesian import CartesianMove
from host.arm.gate import MOVE_STEPPER_SPEED_RAD_S
from host.arm.geometry import ArmGeometry
from host.arm.hold import Held
from host.arm.joint_loop import JointController
from host.arm.kinematics import forward, jacobian, rpy_to_matrix
from host.arm.rest import RestWatch, servo_setpoint
from host.arm.state import N_STEPPERS, ArmState
from host.errors import NotSeated, TouchMissed, UsageError
from host.transports.base import Transport
from protocol.robot import (
    ARM_PROBE_BALL_RADIUS_M,
    ARM_PROBE_TIP_M,
    SERIES_ELASTIC_STIFFNESS_NM_PER_RAD,
    arm_route_coupling_matrix,
)

#: How far before the expected point a touch starts (m, along the probe) and how far past it
#: the guarded move aims (m).
APPROACH_M: Final = 0.02
PRESS_M: Final = 0.015
#: Speeds (rad/s, fastest joint): between touches, and the guarded approach (~2 cm/s).
MOVE_SPEED_RAD_S: Final = 0.4
GUARD_SPEED_RAD_S: Final = 0.05
#: How far before the approach point (m, along the probe) the ball waits before and after
#: a touch, clear of the dimple's mouth, and from where it goes to the next: a move from one
#: such point to the next, the probe turned by 0.4 rad, dips the ball up to 15 mm below the
#: straight line (the joints interpolated; the CAD model's IK), and at 20 mm it caught a
#: dimple's rim on the emulator.
CLEAR_M: Final = 0.04
#: How near its target a move between touches must come (m) and how long it may settle there
#: (s): a few millimetres do.
BETWEEN_TOLERANCE_M: Final = 0.004
BETWEEN_SETTLE_S: Final = 2.0
#: The approach point, where the guarded move starts, to this (m) and within this long (s):
#: where the ball meets the dimple is where it starts, less the kinematics' error.
APPROACH_TOLERANCE_M: Final = 0.001
APPROACH_SETTLE_S: Final = 4.0
#: How long (s) the arm, held at the approach point, may take to come to rest.
REST_S: Final = 2.0
#: The contact: the stepper torques' change, gravity's taken out (N·m, norm over J1..J4),
#: seen in this many cycles in a row (one cycle's is the encoders' last count flickering:
#: 0.05-0.13 N·m a joint, up to 0.27 N·m together on the emulator).
TOUCH_LOAD_NM: Final = 0.5
TOUCH_CYCLES: Final = 3
#: The seating: the springs press the ball into the dimple along its axis with this force
#: (N) beyond what they carry of the arm's weight, a stepper at most this share of its stall
#: torque (weight and push together; less force where it would be more), the motors moved
#: at this speed (rad/s), each push for at most this long (s) after its motion's own time.
SEAT_FORCE_N: Final = 8.0
SEAT_LOAD_LIMIT: Final = 0.7
SEAT_SPEED_RAD_S: Final = 0.05
SEAT_S: Final = 1.0
#: The pushes, each from where the last left the ball: at most this many; the ball is seated
#: once one moves it less than this (m, by the host's kinematics: about one encoder count
#: at the tip).
SEAT_PUSHES: Final = 24
SEAT_STILL_M: Final = 0.0004
#: A ball the pushes have moved further than this (m, by the host's kinematics) from where
#: the guarded move left it is not in its dimple (whose mouth is 15 mm): it was pushed in
#: free space (a stop short of the surface), and further pushes walk it off along the
#: arm's softest direction.
SEAT_TRAVEL_M: Final = 0.025
#: A dimple seated further than its mouth and this (m) from where it was aimed at is
#: another dimple, or the board's face: not taken, and not aimed by.
AIM_SLACK_M: Final = 0.005
#: After the fit, a board touch is off its dimple when the median of its distances to the
#: other touches, by the fitted kinematics, is off the dimples' by more than this (m): the
#: seated touches' residuals are 0.2 mm rms on the emulator.  (By the CAD model the seated
#: touches' own were up to 6 mm: too much to tell a seat 5 mm off by.)
FIT_CHECK_M: Final = 0.001
#: The most board touches :func:`fit` leaves out.
FIT_DROPS: Final = 3
#: Cycles the motors are held before the readings (the ball seating), and readings averaged.
SEAT_CYCLES: Final = 60
READINGS: Final = 10
#: The probe's orientations (roll, pitch, yaw of the flange, rad): straight down, then tilted
#: about 23° four ways, so each dimple is touched in different arm configurations (the more
#: the wrist turns between touches, the better they tell its geometry: on synthetic touches
#: of the emulated rig, tilts of 0.25 rad left 1.0 mm mean on held-out poses, 0.4 rad
#: 0.8-1.0 mm).
ORIENTATIONS: Final = ((0.0, 0.0, 0.0), (0.4, 0.0, 0.0), (0.0, 0.4, 0.0),
                       (-0.4, 0.0, 0.0), (0.0, -0.4, 0.0))
#: Into the board's dimples (unit vector, base frame: its face's normal as the rig sets it
#: down) and straight down, into the anchor dimples (their axes point up) and the table.
BOARD_AXIS: Final = -rig.board_rotation()[:, 2]
DOWN: Final = np.array([0.0, 0.0, -1.0])
#: Touches per anchor.
ANCHOR_TOUCHES: Final = 4
#: ``armctl calibrate --poses``' default: board touches (each dimple, the orientations in
#: turn).
DEFAULT_POSES: Final = 24

#: Progress: ``(what, done, total)``, ``what`` one of ``"board"``, ``"table"``, ``"anchors"``.
Progress = Callable[[str, int, int], None]


class TouchingArm(Protocol):
    """What the touches use of :class:`~host.arm.facade.Arm`."""

    hand: bool
    geometry: ArmGeometry | None

    def moveto(self, xyz: Sequence[float], rpy: Sequence[float] | None = None, *,
               speed: float = ..., tolerance_m: float = ..., settle_timeout: float = ...,
               controller: JointController | None = None, allow_unhomed: bool = False,
               hand: bool = True, log: None = None,
               until: Callable[[ArmState], bool] | None = None,
               geometry: ArmGeometry | None = None) -> CartesianMove: ...

    def hold(self) -> Held: ...

    def state(self) -> ArmState: ...

    @property
    def transport(self) -> Transport: ...

    def move(self, angles: Sequence[float], *, timeout: float = ...,
             speed: float | None = ..., motors: bool = ...) -> tuple[ArmState, bool]: ...



@dataclass
class Gathered:
    """The touches made: ``data`` for :func:`host.arm.calibration.calibrate`, and how many
    of each kind were made and ``missed``."""

    data: CalibrationData
    counts: dict[str, int] = field(default_factory=dict)
    missed: int = 0


def probe_geometry(arm: TouchingArm) -> ArmGeometry:
    """The kinematics the touches aim with: the arm's (its calibration, or the CAD model)
    with the probe's ball as the point moved."""
    return (arm.geometry or ArmGeometry.nominal()).with_tool(ARM_PROBE_TIP_M)


def _load(state: ArmState, hand: bool) -> np.ndarray:
    """The stepper joints' torques less what gravity makes them carry (N·m, J1..J4)."""
    torques = np.array([j.torque for j in state.steppers])
    out: np.ndarray = torques - arm_gravity.spring_torques(state.joints, hand)
    return out


def probe_direction(rpy: Sequence[float]) -> np.ndarray:
    """The probe's direction (unit vector, base frame: the flange's ``−z``) at orientation
    ``rpy`` (rad)."""
    out: np.ndarray = rpy_to_matrix(rpy) @ np.array([0.0, 0.0, -1.0])
    return out


def clear_point(point: np.ndarray, rpy: Sequence[float]) -> np.ndarray:
    """Where the ball waits before and after touching ``point`` (m, base frame) along
    ``rpy``: :data:`APPROACH_M` + :data:`CLEAR_M` before it along the probe."""
    out: np.ndarray = (np.asarray(point, dtype=float)
                       - (APPROACH_M + CLEAR_M) * probe_direction(rpy))
    return out


def _between(arm: TouchingArm, point: np.ndarray, rpy: Sequence[float],
             geometry: ArmGeometry) -> CartesianMove:
    """A move between touches: the ball to ``point`` (m), the probe along ``rpy``."""
    return arm.moveto(np.asarray(point).tolist(), list(rpy), speed=MOVE_SPEED_RAD_S,
                      tolerance_m=BETWEEN_TOLERANCE_M, settle_timeout=BETWEEN_SETTLE_S,
                      geometry=geometry, hand=arm.hand)


def travel(arm: TouchingArm, here: np.ndarray, here_rpy: Sequence[float],
           there: np.ndarray, there_rpy: Sequence[float], geometry: ArmGeometry) -> None:
    """The ball from ``here`` (m, base frame, the probe along ``here_rpy``) to ``there``
    (along ``there_rpy``) over the rig: straight up to :data:`~host.arm.calibration_rig.
    TRAVEL_Z_M`, across at that height, and down.  A joint-space move between two points
    at a dimple's clearance sweeps the ball through the dimples between them, or along
    the table; the ball is the one part of the arm the rig stops."""
    up = np.array([here[0], here[1], max(float(here[2]), rig.TRAVEL_Z_M)])
    over = np.array([there[0], there[1], max(float(there[2]), rig.TRAVEL_Z_M)])
    _between(arm, up, here_rpy, geometry)
    _between(arm, over, there_rpy, geometry)
    _between(arm, there, there_rpy, geometry)


@dataclass(frozen=True)
class Springs:
    """The arm as the guarded move left it, touching: the joint angles (rad, 7), the stepper
    motors' angles (rad at the joint, 4) and the servos' goals (rad, 3: where they drive to,
    :func:`~host.arm.rest.servo_setpoint`).  What the springs carry then (the arm's weight,
    what the host's model of it misses, the touch's light contact) is the baseline each
    push adds to: a
    push from the host's model of what they carry (:meth:`~host.arm.facade.Arm.motor_goals`)
    took the model's errors for a force, up to 16 N sideways on the emulator in a pose far
    from the nodes' power-up one, and walked the ball out of its dimple."""

    joints: np.ndarray
    motors: np.ndarray
    servos: tuple[float, ...]

    @classmethod
    def of(cls, state: ArmState, joints: np.ndarray) -> Springs:
        """The baseline of ``state`` (read after the hold), ``joints`` (rad, 7) its joints'
        averaged readings."""
        return cls(np.asarray(joints, dtype=float), np.array(state.motor_joints),
                   tuple(servo_setpoint(v) for v in state.servos))

    def goals(self, q: Sequence[float] | np.ndarray, torques_nm: np.ndarray) -> list[float]:
        """The joints' goals (rad, 7) that leave the springs carrying the baseline's load
        and ``torques_nm`` (N·m, J1..J4, the springs' own) more at the joint angles ``q``
        (rad): each motor moved with its joint, less what the routes turn its capstan by
        (``(I − C)·Δq``), plus the torque over its spring's stiffness; the servos at their
        baseline goals (given their angles again at each push, they gave way each time)."""
        moved = np.asarray(q, dtype=float)[:N_STEPPERS] - self.joints[:N_STEPPERS]
        follow = (np.eye(N_STEPPERS) - arm_route_coupling_matrix()) @ moved
        motors = (self.motors + follow
                  + np.asarray(torques_nm) / np.array(SERIES_ELASTIC_STIFFNESS_NM_PER_RAD))
        return [*(float(v) for v in motors), *self.servos]


def push_torques(q: Sequence[float] | np.ndarray, force_n: np.ndarray,
                 geometry: ArmGeometry, hand: bool = False) -> np.ndarray:
    """The springs' torques (N·m, J1..J4) that press the ball with ``force_n`` (N, base
    frame) at the joint angles ``q`` (rad): ``Jᵀ·F``, the routes passing a spring's torque
    on (:mod:`host.arm.gravity`).  A force, not a displacement: the arm is some 30 times
    stiffer along itself than across, and a motor move along the probe pressed the ball
    34-42° off it, along the dimple's wall rather than into it.  Scaled down where it and
    the arm's weight together (``hand`` on the flange or not) would load a stepper beyond
    :data:`SEAT_LOAD_LIMIT` of its stall torque."""
    qa = np.asarray(q, dtype=float)
    j = jacobian(qa, geometry)[:3, :N_STEPPERS]
    coupling = arm_route_coupling_matrix()
    push = np.linalg.solve(np.eye(N_STEPPERS) - coupling.T, j.T @ np.asarray(force_n))
    weight = arm_gravity.spring_torques(qa, hand)
    room = SEAT_LOAD_LIMIT * arm_gravity.stall_torques() - np.abs(weight)
    scale = min(1.0, *(max(r, 0.0) / abs(t) for r, t in zip(room, push, strict=True)
                       if abs(t) > 1e-9))
    out: np.ndarray = scale * push
    return out


def seat(arm: TouchingArm, axis: np.ndarray, geometry: ArmGeometry, *,
         flat: bool = False) -> tuple[np.ndarray, Springs]:
    """Push the ball, which the guarded move left touching the dimple, to its bottom: each
    push :data:`SEAT_FORCE_N` along the dimple's ``axis`` (unit vector into it, base
    frame) on the springs' baseline (:class:`Springs`, :func:`push_torques`), from where the
    last left the ball (held by the springs alone, it slides down the walls until their give
    balances the push), until one moves it less than :data:`SEAT_STILL_M`; the readings
    then (rad, 7, :func:`seated_readings`) and the baseline.  ``flat`` (the table: ``axis``
    its normal): one push, which nothing can move further down (from where the last left
    the ball, pushes would walk it along the surface on any sideways force the host's arm
    model leaves).  :class:`~host.errors.NotSeated` if :data:`SEAT_PUSHES` did not bring it
    to rest, or if they moved it further than :data:`SEAT_TRAVEL_M`.  Through
    :meth:`~host.arm.facade.Arm.move`, the arm's gate."""
    readings = seated_readings(arm)
    springs = Springs.of(arm.state(), readings)
    force = SEAT_FORCE_N * np.asarray(axis, dtype=float)
    start = forward(readings, geometry).position
    here, moved = start, float("inf")
    for _ in range(1 if flat else SEAT_PUSHES):
        arm.move(springs.goals(readings, push_torques(readings, force, geometry, arm.hand)),
                 motors=True, timeout=SEAT_S, speed=SEAT_SPEED_RAD_S)
        readings = seated_readings(arm)
        before, here = here, forward(readings, geometry).position
        moved = float(np.linalg.norm(here - before))
        if float(np.linalg.norm(here - start)) > SEAT_TRAVEL_M:
            raise NotSeated(f"the pushes moved the ball {np.linalg.norm(here - start) * 1000:.0f}"
                            " mm: it is not in the dimple", springs=springs)
        if flat or moved < SEAT_STILL_M:
            return readings, springs
    raise NotSeated(f"the ball did not come to rest in the dimple: the last of {SEAT_PUSHES} "
                    f"pushes moved it {moved * 1000:.1f} mm", springs=springs)


def _release(arm: TouchingArm, springs: Springs | None) -> None:
    """The push taken off the ball before it leaves the dimple: the springs back to their
    baseline (:meth:`Springs.goals` with no torque) at the joints' present angles; else the
    next move's joint loop takes the push for a load to hold (it starts its integral at the
    nodes' goals) and goes on pushing the ball past its targets.  At
    :data:`~host.arm.gate.MOVE_STEPPER_SPEED_RAD_S`: the nodes keep a move's speed limits,
    and the joint loop's moves, which send none, need theirs (after a push at
    :data:`SEAT_SPEED_RAD_S` every later move lagged its path by up to a radian and ended
    10-250 mm from its target, sweeping the ball through the rig).  Without a baseline (no
    push made), where the springs carry the modelled weight
    (:meth:`~host.arm.facade.Arm.move` of the present angles)."""
    joints = list(arm.state().joints)
    if springs is None:
        arm.move(joints, timeout=SEAT_S, speed=MOVE_STEPPER_SPEED_RAD_S)
    else:
        arm.move(springs.goals(joints, np.zeros(N_STEPPERS)), motors=True, timeout=SEAT_S,
                 speed=MOVE_STEPPER_SPEED_RAD_S)


def at_rest(arm: TouchingArm) -> ArmState:
    """Hold the arm where it is (:meth:`~host.arm.facade.Arm.hold`) and read it until it is
    at rest (:class:`~host.arm.rest.RestWatch`), for at most :data:`REST_S`: the guarded
    move's joint loop then takes it over bumplessly, each joint's integral starting at the
    load its node holds.  A move that ended on its settle time with a joint still creeping
    to its goal (its node reporting it moving) gave the new loop a zero integral there, or,
    continued, a step of its goal (J2 3 mrad): the joint's sag or the step changed the
    torques by 0.5-1.1 N·m within 0.1 s, nothing touched, and stopped the guarded move
    before it started.  The last state read."""
    arm.hold()
    watch = RestWatch()
    end = arm.transport.now() + REST_S
    state = arm.state()
    while not watch.update(state) and arm.transport.now() < end:
        state = arm.state()
    return state


def _guarded(arm: TouchingArm, point: np.ndarray, rpy: Sequence[float],
             geometry: ArmGeometry) -> tuple[CartesianMove, np.ndarray]:
    """From where the ball is (the arm at rest, :func:`at_rest`), the ball towards
    :data:`PRESS_M` past ``point`` at :data:`GUARD_SPEED_RAD_S`, stopped once the stepper
    torques less gravity's have differed by :data:`TOUCH_LOAD_NM` from what they were at
    the start for :data:`TOUCH_CYCLES` cycles in a row; the move and that start (N·m,
    J1..J4).  Stopped, the joint loop holds the joints where they were: the push the
    springs had wound up goes (the load at rest is back within 0.15 N·m of the start's), and
    :func:`seat` presses the ball again."""
    direction = probe_direction(rpy)
    control = JointController(arm)  # type: ignore[arg-type]
    start = _load(control.start(), arm.hand)
    seen = [0]  # cycles in a row the load has been over the contact's

    def touched(state: ArmState) -> bool:
        over = float(np.linalg.norm(_load(state, arm.hand) - start)) >= TOUCH_LOAD_NM
        seen[0] = seen[0] + 1 if over else 0
        return seen[0] >= TOUCH_CYCLES

    end = np.asarray(point, dtype=float) + PRESS_M * direction
    move = arm.moveto(end.tolist(), list(rpy), speed=GUARD_SPEED_RAD_S, controller=control,
                      until=touched, settle_timeout=0.5, geometry=geometry, hand=arm.hand)
    return move, start


def seated_readings(arm: TouchingArm) -> np.ndarray:
    """The joint readings (rad, 7) of a seated ball: after :data:`SEAT_CYCLES` cycles, the
    mean of :data:`READINGS` more."""
    for _ in range(SEAT_CYCLES):
        arm.state()
    out: np.ndarray = np.mean([arm.state().joints for _ in range(READINGS)], axis=0)
    return out


def touch(arm: TouchingArm, point: np.ndarray, rpy: Sequence[float],
          geometry: ArmGeometry, *, axis: np.ndarray, flat: bool = False) -> np.ndarray:
    """Touch ``point`` (m, base frame: the ball's centre expected there) with the probe along
    orientation ``rpy`` (see the module docs), from and back to its :func:`clear_point`
    (the ball there already); the joint readings seated (rad, 7): pushed along ``axis``
    (unit vector into the dimple, base frame) to its bottom, or, ``flat``, onto the surface
    (:func:`seat`).  :class:`TouchMissed` if
    nothing was felt, :class:`~host.errors.NotSeated` if the ball did not seat,
    :class:`~host.errors.UsageError` if a pose is out of reach; the ball is back at its
    clear point in every case but the last."""
    direction = probe_direction(rpy)
    clear = clear_point(point, rpy)
    arm.moveto((np.asarray(point, dtype=float) - APPROACH_M * direction).tolist(), list(rpy),
               speed=MOVE_SPEED_RAD_S, tolerance_m=APPROACH_TOLERANCE_M,
               settle_timeout=APPROACH_SETTLE_S, geometry=geometry, hand=arm.hand)
    at_rest(arm)
    guarded, _ = _guarded(arm, point, rpy, geometry)
    if not guarded.stopped:
        _between(arm, clear, rpy, geometry)
        raise TouchMissed(f"nothing felt within {PRESS_M * 1000:.0f} mm past "
                          f"{tuple(round(float(v), 3) for v in point)} m")
    try:
        readings, springs = seat(arm, axis, geometry, flat=flat)
    except NotSeated as exc:  # the push off, back: anything else (Ctrl-C) leaves it held
        _release(arm, exc.springs if isinstance(exc.springs, Springs) else None)
        _between(arm, clear, rpy, geometry)
        raise
    _release(arm, springs)
    _between(arm, clear, rpy, geometry)
    return readings


def board_plan(poses: int) -> list[tuple[int, tuple[float, float, float]]]:
    """The board touches in order: ``(dimple index, orientation)``, the dimples in turn and
    the orientations of :data:`ORIENTATIONS` in turn (12 dimples, 5 orientations: a dimple
    touched again is touched in another orientation)."""
    n = len(rig.dimple_points())
    return [(k % n, ORIENTATIONS[k % len(ORIENTATIONS)]) for k in range(poses)]


def gather(arm: TouchingArm, poses: int = DEFAULT_POSES,
           progress: Progress | None = None) -> Gathered:
    """Make the calibration's touches (module docs): ``poses`` board touches (the dimples in
    turn, each orientation of :data:`ORIENTATIONS` in turn), the table touches
    (:func:`~host.arm.calibration_rig.table_points`), :data:`ANCHOR_TOUCHES` per anchor.  A
    touch that feels nothing, cannot be reached, does not seat, or seats off its aim is
    left out (counted in ``missed``); :class:`~host.errors.UsageError` if fewer than 6
    board touches were made."""
    if poses < 6:
        raise UsageError(f"--poses {poses}: the board needs at least 6 touches")
    geometry = probe_geometry(arm)
    ready = np.array(rig.READY_M)
    arm.moveto(ready.tolist(), list(ORIENTATIONS[0]), speed=MOVE_SPEED_RAD_S,
               geometry=geometry, hand=arm.hand)
    tell = progress or (lambda _what, _done, _total: None)
    walk = Walk(arm, geometry, ready, ORIENTATIONS[0])
    joints, touched_points, missed = _touch_board(walk, poses, tell)
    if len(joints) < 6:
        raise UsageError(f"only {len(joints)} of {poses} board touches found a dimple: is the "
                         "board where the calibration rig says?")
    table = _touch_table(walk, tell)
    anchor_q, anchor_p, anchor_missed = _touch_anchors(walk, tell)
    missed += len(rig.table_points()) - len(table) + anchor_missed
    walk.to(ready, ORIENTATIONS[0], group="ready")
    data = CalibrationData((BoardTouches(np.array(joints), np.array(touched_points)),),
                           np.array(table).reshape(-1, 7), anchor_q, anchor_p,
                           np.array(ARM_PROBE_TIP_M, dtype=float))
    return Gathered(data, {"board": len(joints), "table": len(table),
                           "anchors": len(anchor_q)}, missed)


class Walk:
    """Where the ball is between touches (m, base frame, at a touch's :func:`clear_point` or
    at the ready point), and how it gets to the next: straight to another point of the same
    group (one board's dimples, one row of table touches, one anchor), else by
    :func:`travel` over the rig."""

    def __init__(self, arm: TouchingArm, geometry: ArmGeometry, here: np.ndarray,
                 rpy: Sequence[float]) -> None:
        self.arm = arm
        self.geometry = geometry
        self.here = np.asarray(here, dtype=float)
        self.rpy = tuple(rpy)
        self.group = "ready"

    def to(self, there: np.ndarray, rpy: Sequence[float], group: str) -> None:
        """Bring the ball to ``there`` (m) along ``rpy``: straight, or over the rig when the
        group changes."""
        if group != self.group:
            travel(self.arm, self.here, self.rpy, np.asarray(there, dtype=float), rpy,
                   self.geometry)
        else:
            _between(self.arm, there, rpy, self.geometry)
        self.here, self.rpy, self.group = np.asarray(there, dtype=float), tuple(rpy), group

    def touch(self, point: np.ndarray, rpy: Sequence[float], group: str, axis: np.ndarray,
              flat: bool = False) -> np.ndarray:
        """:func:`touch` ``point`` (m) along ``rpy``, the ball brought to its clear point
        first; the ball is left there."""
        self.to(clear_point(point, rpy), rpy, group)
        return touch(self.arm, point, rpy, self.geometry, axis=axis, flat=flat)


def distance_errors(tips: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
    """``|tip_k − tip_j| − |p_k − p_j|`` (m) for every other touch ``j``: ``tips`` where the
    host's kinematics put the ball (n×3, m), ``points`` the dimples touched (n×3, m)."""
    others = np.arange(len(tips)) != k
    out: np.ndarray = (np.linalg.norm(tips[others] - tips[k], axis=1)
                       - np.linalg.norm(points[others] - points[k], axis=1))
    return out


def distance_medians(tips: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each board touch's median ``|distance error|`` to the others (m, n;
    :func:`distance_errors`): how far off its dimple the others see it.  Zeros for fewer
    than three touches (two cannot tell which of them is off)."""
    if len(tips) < 3:
        return np.zeros(len(tips))
    return np.array([float(np.median(np.abs(distance_errors(tips, points, k))))
                     for k in range(len(tips))])


@dataclass(frozen=True)
class Fitted:
    """:func:`fit`'s outcome: the calibration's ``result`` and how many board touches were
    ``dropped`` (off their dimples)."""

    result: CalibrationResult
    dropped: int


def fit(data: CalibrationData) -> Fitted:
    """:func:`host.arm.calibration.calibrate` on the touches made; then, while the board
    touch the others disagree with most (:func:`distance_medians`, by the fitted
    kinematics) is off by more than :data:`FIT_CHECK_M`, the fit again without it (at most
    :data:`FIT_DROPS` times): a ball left where no push moved it (a flat spot: the board's
    face) passes :func:`seat`, not its distances to the others.  One at a time: a touch far
    off bends the first fit enough that the others' medians grow too."""
    result = calibrate(data)
    dropped = 0
    while len(data.boards) == 1 and dropped < FIT_DROPS:
        board = data.boards[0]
        points = np.asarray(board.points_m, dtype=float)
        tips = result.geometry.with_tool(np.asarray(data.tool_m)).tips(board.joints)
        medians = distance_medians(tips, points)
        worst = int(np.argmax(medians)) if len(medians) else 0
        if not len(medians) or medians[worst] <= FIT_CHECK_M:
            break
        kept = np.arange(len(points)) != worst
        data = replace(data, boards=(BoardTouches(board.joints[kept], points[kept]),))
        result = calibrate(data)
        dropped += 1
    return Fitted(result, dropped)


def _aimed_touch(walk: Walk, target: np.ndarray, rpy: Sequence[float], group: str,
                 axis: np.ndarray) -> np.ndarray | None:
    """:meth:`Walk.touch` of a dimple aimed at ``target`` (m): the readings (rad, 7), or
    None if nothing was felt, the ball did not seat, the pose was out of reach, or it
    seated further than the dimple's mouth (and :data:`AIM_SLACK_M`) from the aim: in
    another dimple, or on the board."""
    try:
        q = walk.touch(target, rpy, group, axis=axis)
    except (TouchMissed, UsageError):
        return None
    seated = forward(q, walk.geometry).position
    if np.linalg.norm(seated - target) > rig.DIMPLE_MOUTH_RADIUS_M + AIM_SLACK_M:
        return None
    return q


def _touch_board(walk: Walk, poses: int, tell: Progress
                 ) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """The board touches (:func:`board_plan`): their readings (rad, 7 each), the dimples'
    points (m, board frame) and how many were left out (:func:`_aimed_touch`).  Each kept
    touch's seat less its aim moves the next aim."""
    dimples = rig.nominal_dimples()
    points = rig.dimple_points()
    aim = np.zeros(3)  # where the last dimple seated less where it was aimed at (m)
    joints: list[np.ndarray] = []
    touched_points: list[np.ndarray] = []
    for k, (dimple, rpy) in enumerate(board_plan(poses)):
        target = dimples[dimple] + aim
        q = _aimed_touch(walk, target, rpy, "board", BOARD_AXIS)
        tell("board", k + 1, poses)
        if q is not None:
            joints.append(q)
            touched_points.append(points[dimple])
            aim = forward(q, walk.geometry).position - dimples[dimple]
    return joints, touched_points, poses - len(joints)


def _touch_table(walk: Walk, tell: Progress) -> list[np.ndarray]:
    """The table touches (:func:`~host.arm.calibration_rig.table_points`, no push): their
    readings (rad, 7 each)."""
    points = rig.table_points()
    out: list[np.ndarray] = []
    for k, (x, y, row) in enumerate(points):
        point = np.array([x, y, rig.TABLE_TOP_Z_M + ARM_PROBE_BALL_RADIUS_M])
        try:
            out.append(walk.touch(point, ORIENTATIONS[0], f"table{row}", DOWN,
                                  flat=True))
        except (TouchMissed, UsageError):
            pass
        tell("table", k + 1, len(points))
    return out


def _touch_anchors(walk: Walk, tell: Progress) -> tuple[np.ndarray, np.ndarray, int]:
    """:data:`ANCHOR_TOUCHES` touches of each anchor dimple, each in another orientation:
    their readings (rad, k×7), the anchors' drawn points (m, k×3), how many were missed.
    As on the board, where one seated less where it was aimed at moves the next aim."""
    joints: list[np.ndarray] = []
    points: list[np.ndarray] = []
    total = len(rig.ANCHOR_POINTS_M) * ANCHOR_TOUCHES
    aim = np.zeros(3)
    done = 0
    for a, drawn in enumerate(rig.ANCHOR_POINTS_M):
        for t in range(ANCHOR_TOUCHES):
            target = np.array(drawn) + aim
            q = _aimed_touch(walk, target, ORIENTATIONS[t % len(ORIENTATIONS)], f"anchor{a}",
                             DOWN)
            done += 1
            tell("anchors", done, total)
            if q is not None:
                joints.append(q)
                points.append(np.array(drawn))
                aim = forward(q, walk.geometry).position - np.array(drawn)
    return (np.array(joints).reshape(-1, 7), np.array(points).reshape(-1, 3),
            total - len(joints))
