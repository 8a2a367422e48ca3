"""`Arm.move` lands the *joints* on their goals: the stepper motors go where the belt and
cable routes' coupling and the springs' sag leave the joints there (host.arm.motor_goals).

Sent as the motors' goals, the same moves left the elbow up to 18.8° past its goal (521
counts), J3 up to 359 counts off a goal of 0, the shoulder 3.3° under; and J2 2.0 with J4 2.5,
both inside their ranges, drove the elbow into its stop past 2.60 rad, where it latched
STALLED."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.arm.motor_goals import coupled_at, coupling_feedforward, motor_goals, on_the_way
from host.arm.state import JointInfo
from protocol.robot import ARM_JOINT_LIMITS
from tests.ground_truth import arm_joints, planted_of

#: How close (rad) a homed move leaves each stepper joint to its goal, by the plant's truth:
#: the bearings' stiction and the elements' hysteresis (measured: 4 counts or less at every
#: pose below; 13 counts here).  With the elements taken as linear springs the outstretched
#: shoulder, whose tubes are compressed solid, landed 22-26 counts high.
LANDING_TOLERANCE_RAD = 0.008

#: Poses over the joints' ranges, the hand on the flange (rad, J1..J7).
POSES = [
    [0.0, 1.5, 0.0, 1.5, 0.0, 0.2, 0.0],
    [0.5, 0.8, -0.6, 1.2, 0.0, 0.0, 0.0],
    [-0.8, 2.0, 0.5, 0.3, 0.0, -0.3, 0.0],
    [0.0, 2.0, 0.0, 2.5, 0.0, 0.0, 0.0],  # the elbow 0.1 rad inside its stop
    [1.2, 0.4, 1.0, 2.0, 0.5, 0.5, 0.5],
    [0.0, 2.7, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 1.57, 0.0, 0.0, 0.0, 0.0, 0.0],  # outstretched: J2's tubes compressed solid
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.9],
]


def test_the_motor_goals_cancel_the_routes_coupling_by_hand() -> None:
    """From the coupling matrix's rows (J3's capstan turns −0.12 of J2, J4's 0.18 of J2 and
    0.08 of J3), worked by hand: J2 to 1.5 and J3 to 0.5 from a power-up at zero."""
    goals = motor_goals([0.0, 1.5, 0.5, 1.5, 0.1, 0.2, 0.3], np.zeros(7), (),
                        gravity=False, hand=True)
    assert goals == pytest.approx([0.0, 1.5, 0.5 + 0.12 * 1.5, 1.5 - 0.18 * 1.5 - 0.08 * 0.5,
                                   0.1, 0.2, 0.3])
    # the power-up pose is the reference: joints that have not moved since need nothing
    ref = np.array([0.2, 0.7, -0.3, 0.9, 0.0, 0.0, 0.0])
    assert coupling_feedforward(ref, ref) == pytest.approx([0.0] * 4)


def test_on_the_way_the_coupling_is_cancelled_where_the_motors_have_got_to() -> None:
    """Half way by J2's motor (J3's and J4's joints not moving), J3's motor goal lies
    0.12 × the shoulder's remaining 0.75 rad short of its final one, so J3 stays at 0."""
    start, angles = [0.0, 0.0, 0.0, 0.5], [0.0, 1.5, 0.0, 0.5]
    final = motor_goals([*angles, 0.0, 0.0, 0.0], np.zeros(7), (), gravity=False, hand=False)
    way = on_the_way(start, angles, [0.0, 0.0, 0.0, 0.5], final, [0.0, 0.75, 0.1, 0.3])
    assert way == pytest.approx([0.0, 0.75, 0.0, 0.5])
    goals = coupled_at(final, angles, way)
    assert goals[2] == pytest.approx(0.12 * 0.75)
    assert goals[3] == pytest.approx(0.5 - 0.18 * 0.75)
    assert coupled_at(final, angles, angles) == pytest.approx(final[:4])


def test_the_sag_raises_each_motor_by_its_springs_static_deflection() -> None:
    """With gravity the motors go further by τ/k: the outstretched shoulder's spring holds
    the arm up, so J2's motor leads its joint."""
    joints = tuple(JointInfo(i, i + 1, "stepper", 0, 0, 50.0, 200, 5, 10_000, k)
                   for i, k in enumerate((120.0, 200.0, 86.0, 86.0)))
    pose = [0.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0]
    bare = motor_goals(pose, np.zeros(7), joints, gravity=False, hand=False)
    held = motor_goals(pose, np.zeros(7), joints, gravity=True, hand=False)
    assert held[1] - bare[1] > 0.01
    assert held[4:] == bare[4:]


@pytest.mark.slow
def test_a_homed_move_lands_every_stepper_joint_on_its_goal() -> None:
    forget_shared_emulators()
    with Arm.open("emu://full/arm?ready=0&name=lands") as arm:
        arm.torque(True, hold=True)
        arm.home()
        for pose in POSES:
            state, settled = arm.move(pose)
            assert settled, pose
            assert not state.errors, pose
            # where the homed host reads them: the plant's angles less the index marks'
            # mounting errors (the host takes them at their drawn angles)
            q = arm_joints(arm) + planted_of(arm).arm_reading_offsets_rad()
            off = [q[i] - pose[i] for i in range(4)]
            assert max(abs(x) for x in off) <= LANDING_TOLERANCE_RAD, (pose, off)
            assert all(lo <= a <= hi for a, (lo, hi) in zip(q, ARM_JOINT_LIMITS, strict=False))
    forget_shared_emulators()


@pytest.mark.slow
def test_an_unhomed_move_cancels_the_coupling_of_the_joints_before() -> None:
    """Not homed, the sag is not modelled (no absolute angles) but the coupling is
    kinematics: J3 kept at its power-up angle while J2 rises stays there within its own
    spring's few counts, where the motor's goal alone left it 0.12 rad per rad of J2 off."""
    forget_shared_emulators()
    with Arm.open("emu://full/arm?ready=0&name=lands-unhomed") as arm:
        arm.torque(True, hold=True)
        start = arm_joints(arm)
        arm.move([0.0, 1.0, 0.0, 0.5, 0.0, 0.0, 0.0], speed=0.4)
        q = arm_joints(arm)
        assert abs(q[2] - start[2]) <= math.radians(0.5)
    forget_shared_emulators()
