"""The touch calibration's touches, made by the arm: the probe's ball into the board's
dimples, onto the table and into the anchor dimples, each by a guarded move (§4.4).

One touch of a point ``p`` (m, base frame, where the host expects it), the probe pointing
along ``d`` (the flange's ``−z`` for an orientation ``rpy``):

1. a Cartesian move of the ball to :data:`APPROACH_M` before ``p`` along ``d``;
2. a guarded move (:meth:`~host.arm.facade.Arm.moveto` with ``until``) at
   :data:`GUARD_SPEED_RAD_S` towards :data:`PRESS_M` past ``p``, stopped the cycle the
   stepper joints' torques, less what gravity makes them carry (:mod:`host.arm.gravity`),
   have changed by :data:`TOUCH_LOAD_NM` (N·m, the norm over J1..J4) since it started:
   the contact force seen in the elastic elements' deflections;
3. a hold of the motors where they are (:meth:`~host.arm.facade.Arm.hold`), then the
   motors (not the joints) moved :data:`SEAT_PUSH_M` on along ``d``: the elastic elements
   push the ball, which, no longer held by the joint loop, slides down the dimple's walls to
   its bottom; after :data:`SEAT_CYCLES` cycles the joint readings
   (the encoders, the servos' pots) of :data:`READINGS` more are averaged;
4. back to the approach point.

Nothing is read but what the host reads of any arm: joint readings and torques.  The board's
pose is not known: where the ball seats in one dimple less where the host aimed is added to
the aim of the next (the CAD model's error and the board's misplacement change slowly over
the board), so each lands well inside its dimple's mouth
(:data:`~host.arm.calibration_rig.DIMPLE_MOUTH_RADIUS_M`).  Every motion is a
:meth:`~host.arm.facade.Arm.moveto` or a hold: through the arm's gate.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Final, Protocol

import numpy as np

import host.arm.calibration_rig as rig
import host.arm.gravity as arm_gravity
from host.arm.calibration import BoardTouches, CalibrationData
from host.arm.cartesian import CartesianMove
from host.arm.geometry import ArmGeometry
from host.arm.hold import Held
from host.arm.joint_loop import JointController
from host.arm.kinematics import forward, jacobian, rpy_to_matrix
from host.arm.state import N_STEPPERS, ArmState
from host.errors import TouchMissed, UsageError
from protocol.robot import ARM_PROBE_BALL_RADIUS_M, ARM_PROBE_TIP_M

#: How far before the expected point a touch starts (m, along the probe) and how far past it
#: the guarded move aims (m).
APPROACH_M: Final = 0.02
PRESS_M: Final = 0.015
#: Speeds (rad/s, fastest joint): between touches, and the guarded approach (~2 cm/s).
MOVE_SPEED_RAD_S: Final = 0.4
GUARD_SPEED_RAD_S: Final = 0.05
#: How near the approach point a move between touches must come (m) and how long it may
#: settle there (s): a few millimetres do, the guarded move finds the surface.
BETWEEN_TOLERANCE_M: Final = 0.004
BETWEEN_SETTLE_S: Final = 2.0
#: The contact: the stepper torques' change, gravity's taken out (N·m, norm over J1..J4).
TOUCH_LOAD_NM: Final = 0.5
#: How far past the contact the motors push the ball once the joint loop lets go (m), the
#: motors' speed (rad/s) and how long they may take after it (s).
SEAT_PUSH_M: Final = 0.02
SEAT_SPEED_RAD_S: Final = 0.05
SEAT_S: Final = 1.0
#: Cycles the motors are held before the readings (the ball seating), and readings averaged.
SEAT_CYCLES: Final = 60
READINGS: Final = 10
#: The probe's orientations (roll, pitch, yaw of the flange, rad): straight down, then tilted
#: about 14° four ways, so each dimple is touched in different arm configurations.
ORIENTATIONS: Final = ((0.0, 0.0, 0.0), (0.25, 0.0, 0.0), (0.0, 0.25, 0.0),
                       (-0.25, 0.0, 0.0), (0.0, -0.25, 0.0))
#: Table touches: a grid of this many points a side over the touch square
#: (:data:`~host.arm.calibration_rig.TABLE_TOUCH_HALF_M`); anchor touches per anchor.
TABLE_GRID: Final = 3
ANCHOR_TOUCHES: Final = 2
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


def _between(arm: TouchingArm, point: np.ndarray, rpy: Sequence[float],
             geometry: ArmGeometry) -> None:
    """A move between touches: the ball to ``point`` (m), the probe along ``rpy``."""
    arm.moveto(np.asarray(point).tolist(), list(rpy), speed=MOVE_SPEED_RAD_S,
               tolerance_m=BETWEEN_TOLERANCE_M, settle_timeout=BETWEEN_SETTLE_S,
               geometry=geometry, hand=arm.hand)


def _press(arm: TouchingArm, state: ArmState, direction: np.ndarray,
           geometry: ArmGeometry) -> None:
    """Move the stepper motors (not the joints: the joint loop has let go) so far that their
    elastic elements push the ball :data:`SEAT_PUSH_M` further along ``direction``: held only
    by the springs, it slides down the dimple's walls to the bottom (on the emulator: from
    6 mm off to 0.1 mm).  Through :meth:`~host.arm.facade.Arm.move`, the arm's gate."""
    q = np.array(state.joints)
    j = jacobian(q, geometry)[:3, :N_STEPPERS]
    dq = np.linalg.pinv(j) @ (SEAT_PUSH_M * direction)
    goals = [*(np.array(state.motor_joints) + dq), *q[N_STEPPERS:]]
    arm.move([float(v) for v in goals], motors=True, timeout=SEAT_S, speed=SEAT_SPEED_RAD_S)


def touch(arm: TouchingArm, point: np.ndarray, rpy: Sequence[float],
          geometry: ArmGeometry, *, seat: bool = True) -> np.ndarray:
    """Touch ``point`` (m, base frame: the ball's centre expected there) with the probe along
    orientation ``rpy`` (see the module docs); the joint readings seated (rad, 7).  ``seat``
    False (a flat surface: the table): no push after the contact (it would only wind up the
    elastic elements until a node latches STALLED).
    :class:`TouchMissed` if nothing was felt, :class:`~host.errors.UsageError` if a pose is
    out of reach."""
    direction = rpy_to_matrix(rpy) @ np.array([0.0, 0.0, -1.0])
    above = np.asarray(point, dtype=float) - APPROACH_M * direction
    _between(arm, above, rpy, geometry)
    control = JointController(arm)  # type: ignore[arg-type]
    start = _load(control.start(), arm.hand)

    def touched(state: ArmState) -> bool:
        return float(np.linalg.norm(_load(state, arm.hand) - start)) >= TOUCH_LOAD_NM

    end = np.asarray(point, dtype=float) + PRESS_M * direction
    guarded = arm.moveto(end.tolist(), list(rpy), speed=GUARD_SPEED_RAD_S, controller=control,
                         until=touched, settle_timeout=0.5, geometry=geometry, hand=arm.hand)
    if not guarded.stopped:
        _between(arm, above, rpy, geometry)
        raise TouchMissed(f"nothing felt within {PRESS_M * 1000:.0f} mm past "
                          f"{tuple(round(float(v), 3) for v in point)} m")
    arm.hold()
    if seat:
        _press(arm, arm.state(), direction, geometry)
    for _ in range(SEAT_CYCLES):
        arm.state()
    readings = np.mean([arm.state().joints for _ in range(READINGS)], axis=0)
    _between(arm, above, rpy, geometry)
    out: np.ndarray = readings
    return out


def gather(arm: TouchingArm, poses: int = DEFAULT_POSES,
           progress: Progress | None = None) -> Gathered:
    """Make the calibration's touches (module docs): ``poses`` board touches (the dimples in
    turn, each orientation of :data:`ORIENTATIONS` in turn), :data:`TABLE_GRID`² table
    touches, :data:`ANCHOR_TOUCHES` per anchor.  A touch that feels nothing or cannot be
    reached is left out (counted in ``missed``); :class:`~host.errors.UsageError` if fewer
    than 6 board touches were made."""
    if poses < 6:
        raise UsageError(f"--poses {poses}: the board needs at least 6 touches")
    geometry = probe_geometry(arm)
    arm.moveto(list(rig.READY_M), list(ORIENTATIONS[0]), speed=MOVE_SPEED_RAD_S,
               geometry=geometry, hand=arm.hand)
    dimples = rig.nominal_dimples()
    points = rig.dimple_points()
    aim = np.zeros(3)  # where the last dimple seated less where it was aimed at (m)
    joints: list[np.ndarray] = []
    touched_points: list[np.ndarray] = []
    missed = 0
    tell = progress or (lambda _what, _done, _total: None)
    for k in range(poses):
        dimple = k % len(dimples)
        rpy = ORIENTATIONS[(k // len(dimples)) % len(ORIENTATIONS)]
        target = dimples[dimple] + aim
        try:
            q = touch(arm, target, rpy, geometry)
        except (TouchMissed, UsageError):
            missed += 1
        else:
            seated = forward(q, geometry).position
            if np.linalg.norm(seated - target) > rig.DIMPLE_MOUTH_RADIUS_M + 0.005:
                missed += 1  # seated in another dimple, or on the board: not this one
            else:
                joints.append(q)
                touched_points.append(points[dimple])
                aim = seated - dimples[dimple]
        tell("board", k + 1, poses)
    if len(joints) < 6:
        raise UsageError(f"only {len(joints)} of {poses} board touches found a dimple: is the "
                         "board where the calibration rig says?")
    table = _touch_table(arm, geometry, tell)
    anchor_q, anchor_p, anchor_missed = _touch_anchors(arm, geometry, tell)
    missed += TABLE_GRID ** 2 - len(table) + anchor_missed
    arm.moveto(list(rig.READY_M), list(ORIENTATIONS[0]), speed=MOVE_SPEED_RAD_S,
               geometry=geometry, hand=arm.hand)
    data = CalibrationData((BoardTouches(np.array(joints), np.array(touched_points)),),
                           np.array(table).reshape(-1, 7), anchor_q, anchor_p,
                           np.array(ARM_PROBE_TIP_M, dtype=float))
    return Gathered(data, {"board": len(joints), "table": len(table),
                           "anchors": len(anchor_q)}, missed)


def _touch_table(arm: TouchingArm, geometry: ArmGeometry, tell: Progress) -> list[np.ndarray]:
    cx, cy = rig.TABLE_TOUCH_CENTRE_XY_M
    steps = np.linspace(-rig.TABLE_TOUCH_HALF_M, rig.TABLE_TOUCH_HALF_M, TABLE_GRID)
    out: list[np.ndarray] = []
    total = TABLE_GRID ** 2
    for k, (dx, dy) in enumerate((x, y) for x in steps for y in steps):
        point = np.array([cx + dx, cy + dy, rig.TABLE_TOP_Z_M + ARM_PROBE_BALL_RADIUS_M])
        rpy = ORIENTATIONS[k % len(ORIENTATIONS)]
        try:
            out.append(touch(arm, point, rpy, geometry, seat=False))
        except (TouchMissed, UsageError):
            pass
        tell("table", k + 1, total)
    return out


def _touch_anchors(arm: TouchingArm, geometry: ArmGeometry, tell: Progress
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    joints: list[np.ndarray] = []
    points: list[np.ndarray] = []
    total = len(rig.ANCHOR_POINTS_M) * ANCHOR_TOUCHES
    done = 0
    for drawn in rig.ANCHOR_POINTS_M:
        for t in range(ANCHOR_TOUCHES):
            try:
                joints.append(touch(arm, np.array(drawn), ORIENTATIONS[t % len(ORIENTATIONS)],
                                    geometry))
                points.append(np.array(drawn))
            except (TouchMissed, UsageError):
                pass
            done += 1
            tell("anchors", done, total)
    return (np.array(joints).reshape(-1, 7), np.array(points).reshape(-1, 3),
            total - len(joints))
