"""Arm kinematics: hand-computed poses, limits, the Jacobian against finite differences, IK."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from host.arm import kinematics as K
from protocol.robot import ARM_JOINT_LIMITS

# Lengths (m) along the hanging arm, written out by hand: base → J2 axis 0.36, J2 → elbow
# 0.55, elbow → wrist pitch 0.40, wrist pitch → flange 0.09.
SHOULDER_Z = 0.36
UPPER, FORE, HAND = 0.55, 0.40, 0.09


def test_kinematic_zero_hangs_straight_down() -> None:
    pose = K.forward([0.0] * 7)
    assert pose.position == pytest.approx([0.0, 0.0, SHOULDER_Z - UPPER - FORE - HAND])
    assert pose.position[2] == pytest.approx(-0.68)
    assert pose.rotation == pytest.approx(np.eye(3))


def test_shoulder_lift_of_a_quarter_turn_points_the_arm_forward() -> None:
    pose = K.forward([0.0, math.pi / 2, 0, 0, 0, 0, 0])
    assert pose.position == pytest.approx([UPPER + FORE + HAND, 0.0, SHOULDER_Z])


def test_elbow_bent_a_quarter_turn_puts_the_forearm_forward() -> None:
    pose = K.forward([0.0, 0.0, 0.0, math.pi / 2, 0, 0, 0])
    assert pose.position == pytest.approx([FORE + HAND, 0.0, SHOULDER_Z - UPPER])


def test_pan_turns_the_forward_arm_counter_clockwise_seen_from_above() -> None:
    pose = K.forward([math.pi / 2, math.pi / 2, 0, 0, 0, 0, 0])
    assert pose.position == pytest.approx([0.0, UPPER + FORE + HAND, SHOULDER_Z], abs=1e-12)


def test_wrist_yaw_swings_the_flange_about_x() -> None:
    pose = K.forward([0, 0, 0, 0, 0, 0, math.pi / 2])
    # J7 axis +x, 0.04 m above the flange: R_x(90°)·(0, 0, −0.04) = (0, 0.04, 0)
    assert pose.position == pytest.approx([0.0, 0.04, SHOULDER_Z - UPPER - FORE - 0.05])


def test_rpy_round_trip_and_convention() -> None:
    assert K.rpy_to_matrix((0, 0, math.pi / 2)) @ np.array([1, 0, 0]) == pytest.approx(
        [0, 1, 0], abs=1e-12)
    rpy = (0.3, -0.4, 1.2)
    assert K.matrix_to_rpy(K.rpy_to_matrix(rpy)) == pytest.approx(rpy)


joint_angles = st.tuples(*[st.floats(lo, hi) for lo, hi in ARM_JOINT_LIMITS])


@settings(max_examples=40, deadline=None)
@given(joint_angles)
def test_jacobian_matches_finite_differences(q: tuple[float, ...]) -> None:
    j = K.jacobian(q)
    h = 1e-6
    base = K.forward(q)
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        moved = K.forward(np.add(q, dq))
        assert j[:3, i] == pytest.approx((moved.position - base.position) / h, abs=1e-5)
        omega = K.rotation_error(moved.rotation, base.rotation) / h
        assert j[3:, i] == pytest.approx(omega, abs=1e-5)


@settings(max_examples=15, deadline=None, phases=[Phase.explicit, Phase.generate])
@given(st.tuples(*[st.floats(0.6 * lo, 0.6 * hi) for lo, hi in ARM_JOINT_LIMITS]),
       st.integers(0, 6), st.booleans())
def test_ik_finds_a_reachable_position_within_limits(q: tuple[float, ...], joint: int,
                                                     upper: bool) -> None:
    # One joint at its limit (less the IK's margin): the answer lies on the boundary, and
    # the start, near it as a move's would be, has that joint 0.1 rad beyond the limit.
    at_limit = np.array(q)
    at_limit[joint] = K.UPPER[joint] - K.LIMIT_MARGIN_RAD if upper else \
        K.LOWER[joint] + K.LIMIT_MARGIN_RAD
    start = at_limit + 0.02
    start[joint] = at_limit[joint] + (0.1 if upper else -0.1)
    assert not K.within_limits(start)
    target = K.forward(at_limit).position
    result = K.solve_ik(target, q0=start)
    # (near the straight-arm singularity damping slows the last tenth of a millimetre)
    assert np.linalg.norm(K.forward(result.q).position - target) < 1e-3, result
    assert K.within_limits(result.q)


def test_ik_reaches_a_full_pose_from_nearby() -> None:
    q = np.array([0.4, 0.8, -0.3, 1.1, 0.2, 0.5, -0.3])
    pose = K.forward(q)
    result = K.solve_ik(pose.position, pose.rpy, q0=q + 0.15)
    assert result.converged
    assert K.rotation_error(pose.rotation, K.forward(result.q).rotation) == pytest.approx(
        np.zeros(3), abs=2e-3)


def test_ik_stays_within_limits_for_an_unreachable_target() -> None:
    # The flange at the shoulder: only an arm folded past its stops would get there (the
    # elbow folded to its stop leaves the wrist 0.29 m from the shoulder axis).  IK goes
    # as far as the limits allow, the elbow at its stop, and no further.
    result = K.solve_ik((0.0, 0.0, SHOULDER_Z))
    assert not result.converged and result.position_error > 0.1
    assert K.within_limits(result.q)
    assert result.q[3] == pytest.approx(K.UPPER[3] - K.LIMIT_MARGIN_RAD)


def test_ik_says_a_target_out_of_reach_is_not_reached() -> None:
    result = K.solve_ik((2.0, 0.0, 0.0), max_iterations=60)
    assert not result.converged
    assert result.position_error > 0.9


def test_null_space_term_moves_joints_away_from_limits_without_moving_the_flange() -> None:
    q = np.array([0.0, 0.5, 0.0, 2.55, 0.0, 0.3, 0.0])  # elbow 0.05 rad from its stop
    target = K.forward(q).position
    result = K.solve_ik(target, q0=q, k_limits=0.0, k_singular=0.0)
    shifted = K.solve_ik(target, q0=q, tolerance_m=1e-6, k_limits=0.5)
    assert result.converged and shifted.converged
    assert np.linalg.norm(K.forward(shifted.q).position - target) < 1e-5
    assert abs(shifted.q[3] - 2.60) >= abs(result.q[3] - 2.60)
