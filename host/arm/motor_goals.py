"""Where a joint-space move sends the stepper motors so that the *joints* land on their goals.

A stepper node's goal is its motor (steps ÷ reduction, rad at the joint); its joint follows
through the belt and cable routes and the series-elastic element, and lands off the motor by
two things the node cannot see:

* **the routes' coupling**: the belt and cable circuits turn the capstans of J3 and J4 with
  the joints before them (``C·Δq``, :data:`protocol.robot.ARM_ROUTE_COUPLING`, ``Δq`` the
  joints since the nodes' power-up, when each capstan was aligned with its motor).  Shoulder
  lift J2 from 0 to 1.44 rad turns the elbow's capstan by 0.26 rad: a motor sent to 1.5 rad
  left the elbow at 1.75 rad (14° past its goal, and past the joint's range for goals near
  its end) and J3 at −0.18;
* **the spring's static deflection**: the element carries the arm's weight, ``τ/k``
  (:func:`host.arm.gravity.spring_torques`, the hand counted when it is on) within the
  tubes' soft travel of ±4°, much stiffer beyond (:func:`sag`): up to about 0.07 rad (4°,
  115 counts) for the outstretched shoulder.

So a stepper's motor goal for the joint goals ``q`` (rad, seven) is

    m_i = q_i − Σ_j C[i][j]·(q_j − q_ref,j) + δ_i(τ_i(q))

(``q_ref`` the joints at the nodes' power-up, :func:`power_up_angles`; ``δ_i`` the element's
deflection at the spring torque ``τ_i``).  The coupling term is
kinematics and holds on any arm; the gravity term needs the joints' absolute angles, so it is
left out while the arm is not homed, and it is as good as the arm's mass model (a few counts
in most poses, up to about 40 in some; an unmodelled load, a mug in the hand, sags the joint
by its own weight).  The joint loop (:mod:`host.arm.joint_loop`) adds the coupling term to
every goal it sends and leaves the sag to its integral.

A move sends these goals from its start, but the coupling each cancels is the one at the
move's end: J3's motor, which only compensates the shoulder, would get there long before the
shoulder and push J3 off on the way.  So each cycle takes the coupling where the move has
got to (:func:`on_the_way`, :func:`coupled_at`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from host.arm.gravity import spring_torques
from host.arm.state import N_JOINTS, N_STEPPERS, JointCalibration, JointInfo
from host.arm.trajectory import Vector
from protocol.robot import arm_route_coupling_matrix, series_elastic_deflection


def power_up_angles(calibration: JointCalibration | None, steppers: Sequence[JointInfo],
                    encoder_at_power_up: Sequence[int]) -> np.ndarray:
    """Joint angles (rad, seven; J5-J7 0) where the stepper nodes powered up (their encoder
    count then, in the arm's frame: absolute with ``calibration``, else from power-up),
    where each capstan was aligned with its motor."""
    offsets = calibration.offsets if calibration is not None else (0.0,) * N_JOINTS
    q = np.zeros(N_JOINTS)
    for i, j in enumerate(steppers[:N_STEPPERS]):
        q[i] = j.counts_to_rad(encoder_at_power_up[i]) + offsets[i]
    return q


def coupling_feedforward(q_des: Vector, q_ref: Vector) -> np.ndarray:
    """What to add to the stepper goals of J1..J4 (rad, 4) so the capstans end up where the
    goals say although the routes turn them by ``C·(q − q_ref)``: ``−C·(q_des − q_ref)``
    (``q_ref``: joint angles at the nodes' power-up, rad; only J1..J4 are used)."""
    c = arm_route_coupling_matrix()
    dq = np.asarray(q_des, dtype=float)[:N_STEPPERS] - np.asarray(q_ref, dtype=float)[:N_STEPPERS]
    return -(c @ dq)


def sag(q: Vector, steppers: Sequence[JointInfo], hand: bool) -> np.ndarray:
    """The elastic elements' static deflections (rad, J1..J4) holding the arm still at ``q``
    (rad, absolute): ``τ/k`` within the tubes' soft travel, stiffer beyond
    (:func:`protocol.robot.series_elastic_deflection`)."""
    torques = spring_torques(q, hand)
    return np.array([series_elastic_deflection(float(t), j.stiffness)
                     for t, j in zip(torques, steppers[:N_STEPPERS], strict=False)])


def motor_goals(angles: Sequence[float], q_ref: Vector, steppers: Sequence[JointInfo], *,
                gravity: bool, hand: bool) -> list[float]:
    """The seven goals (rad) to send so the joints land on ``angles`` (rad): each stepper's
    motor goal (the module docs; the static deflection only with ``gravity``, for an arm
    whose angles are absolute; ``hand`` on the flange), the servos' ``angles`` as they
    are.  About a millisecond of CPU (the mass model): a move computes it once."""
    q = np.asarray(angles, dtype=float)
    motors = q[:N_STEPPERS] + coupling_feedforward(q, q_ref)
    if gravity:
        motors = motors + sag(q, steppers, hand)
    return [float(m) for m in motors] + [float(a) for a in q[N_STEPPERS:]]


def coupled_at(goals: Sequence[float], angles: Sequence[float],
               way: Sequence[float]) -> list[float]:
    """The stepper motor goals ``goals`` (rad, J1..J4 at least: :func:`motor_goals` of
    ``angles``) with the routes' coupling cancelled at the joints ``way`` (rad, where a move
    has got to: :func:`on_the_way`) instead of at ``angles``: ``goals + C·(angles − way)``,
    J1..J4."""
    c = arm_route_coupling_matrix()
    dq = (np.asarray(angles, dtype=float)[:N_STEPPERS]
          - np.asarray(way, dtype=float)[:N_STEPPERS])
    return [float(g) for g in np.asarray(goals, dtype=float)[:N_STEPPERS] + c @ dq]


def on_the_way(start: Sequence[float], angles: Sequence[float], motors_start: Sequence[float],
               motors_goal: Sequence[float], motors_now: Sequence[float]) -> list[float]:
    """Where a move of the stepper joints from ``start`` to ``angles`` (rad) has got to, by
    each motor's progress from ``motors_start`` towards ``motors_goal`` (rad; now at
    ``motors_now``), J1..J4: the joints the routes' coupling is to be cancelled at while
    the move goes on, so that a joint whose goal is where it is (J3 while the shoulder
    rises) stays there all the way, not only at the end.  A joint whose motor does not
    move is taken as arrived.  Motors, not the joints' encoders: they move smoothly, where
    the links swing about their way."""
    out = []
    for i in range(N_STEPPERS):
        span = motors_goal[i] - motors_start[i]
        done = 1.0 if abs(span) < 1e-9 else (motors_now[i] - motors_start[i]) / span
        done = min(max(done, 0.0), 1.0)
        out.append(start[i] + done * (angles[i] - start[i]))
    return out
