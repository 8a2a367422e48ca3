"""protocol.robot: the robot's conventions against cases worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.control_tables import STEPPER_TABLE
from protocol.dynamixel import radians_to_rx64_position, rx64_position_to_radians
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_JOINT_LIMITS,
    ARM_JOINT_NAMES,
    DEFAULT_HAND_LAYOUT,
    FINGER_JOINT_LIMITS,
    FINGER_JOINT_STOPS,
    HALL_SEQUENCE,
    HALL_STATES_PER_MOTOR_REV,
    HALL_STATES_PER_RAD,
    HAND_LAYOUTS,
    RX64_POSITION_CENTRE,
    RX64_POSITION_MAX,
    RX64_RAD_PER_UNIT,
    RX64_UNITS_PER_RAD,
    STEPPER_DEFAULT_CURRENT_MA,
    STEPPER_HOLDING_MARGIN,
    STEPPER_REDUCTIONS,
    STEPPER_TORQUE_CONSTANT_NM_PER_A,
    encoder_counts_to_rad,
    finger_coupling_matrix,
    finger_coupling_matrix_rad,
    finger_decoupling_matrix,
    joint_to_motor,
    joint_to_motor_rad,
    max_velocity_counts_per_s,
    microsteps_per_encoder_count,
    microsteps_per_rad,
    microsteps_to_rad,
    motor_rad_to_joint,
    motor_to_joint,
    pull_out_fraction,
    rad_to_encoder_counts,
    rad_to_microsteps,
    reduction_x100,
    series_elastic_deflection,
    series_elastic_torque,
)

TURN = 36.0  # hall counts of one motor revolution (36 hall states per rev)


# --- finger: motor ↔ joint ---------------------------------------------------------------------
def test_hall_states_per_revolution() -> None:
    assert HALL_STATES_PER_MOTOR_REV == 36
    assert HALL_STATES_PER_RAD * 2 * math.pi == pytest.approx(36.0, abs=1e-12)
    assert sorted(HALL_SEQUENCE) == [1, 2, 3, 4, 5, 6]
    # 120° sensors: consecutive states differ in exactly one bit (Gray sequence), round trip.
    for a, b in zip(HALL_SEQUENCE, HALL_SEQUENCE[1:] + HALL_SEQUENCE[:1], strict=True):
        assert bin(a ^ b).count("1") == 1


def test_one_turn_of_motor0_moves_only_j0_by_one_over_its_gear() -> None:
    # m = (36, 0, 0): q2 = 0, q1 = 0, q0 = 2π/173.4 = 0.036235 rad
    assert motor_to_joint((TURN, 0.0, 0.0)) == pytest.approx((0.036235, 0.0, 0.0), abs=1e-6)


def test_one_turn_of_motor1_flexes_j1_and_abducts_j0_back() -> None:
    # m = (0, 36, 0): q2 = 0, q1 = 2π/196.7 = 0.031943; m0 = 0 needs g0·q0 = −g1·q1, so
    # q0 = −2π/173.4 = −0.036235 rad.
    assert motor_to_joint((0.0, TURN, 0.0)) == pytest.approx((-0.036235, 0.031943, 0.0),
                                                             abs=1e-6)


def test_one_turn_of_motor2_goes_through_the_tendon_coupling() -> None:
    # m = (0, 0, 36): q2 = 2π/231 = 0.027200; m1 = 0 needs g1·q1 = c·g2·q2 = 0.89·2π, so
    # q1 = 0.89·2π/196.7 = 0.028429; m0 = 0 needs g0·q0 = −(g1·q1 + c·g2·q2) = −2·0.89·2π,
    # so q0 = −2·0.89·2π/173.4 = −0.064499 rad.
    assert motor_to_joint((0.0, 0.0, TURN)) == pytest.approx((-0.064499, 0.028429, 0.027200),
                                                             abs=1e-6)


def test_joint_to_motor_matches_hand_computed_numbers() -> None:
    # q = (0.1, 0.2, 0.3) rad, K = 36/2π = 5.72958: K·g0·q0 = 5.72958·17.34 = 99.35,
    # K·g1·q1 = 5.72958·39.34 = 225.40, K·g2·q2 = 5.72958·69.3 = 397.06,
    # K·c·g2·q2 = 0.89·397.06 = 353.38.
    m0, m1, m2 = joint_to_motor((0.1, 0.2, 0.3))
    assert m2 == pytest.approx(397.06, abs=0.01)
    assert m1 == pytest.approx(225.40 - 353.38, abs=0.02)
    assert m0 == pytest.approx(99.35 + 225.40 + 353.38, abs=0.03)
    assert np.allclose(finger_coupling_matrix() @ np.array([0.1, 0.2, 0.3]), (m0, m1, m2))


def test_shaft_angles_in_rad() -> None:
    # J2 at 2π/231 rad turns motor 2 once (2π rad of shaft) and, through c, the others.
    theta = joint_to_motor_rad((0.0, 0.0, 2 * math.pi / 231.0))
    assert theta == pytest.approx((0.89 * 2 * math.pi, -0.89 * 2 * math.pi, 2 * math.pi))
    assert motor_rad_to_joint(theta) == pytest.approx((0.0, 0.0, 2 * math.pi / 231.0))
    assert np.allclose(finger_coupling_matrix_rad() * HALL_STATES_PER_RAD,
                       finger_coupling_matrix())


def test_decoupling_matrix_is_the_inverse() -> None:
    assert np.allclose(finger_decoupling_matrix() @ finger_coupling_matrix(), np.eye(3))
    # the coupling is upper triangular: motor i never depends on joints below i
    assert np.all(np.tril(finger_coupling_matrix(), -1) == 0.0)


_counts = st.floats(min_value=-20_000.0, max_value=20_000.0, allow_nan=False)
_angles = st.floats(min_value=-1.8, max_value=1.8, allow_nan=False)


@given(st.tuples(_counts, _counts, _counts))
def test_motor_joint_motor_round_trip(m: tuple[float, float, float]) -> None:
    assert joint_to_motor(motor_to_joint(m)) == pytest.approx(m, abs=1e-8)
    assert np.allclose(finger_decoupling_matrix() @ np.array(m), motor_to_joint(m), atol=1e-12)


@given(st.tuples(_angles, _angles, _angles))
def test_joint_motor_joint_round_trip(q: tuple[float, float, float]) -> None:
    assert motor_to_joint(joint_to_motor(q)) == pytest.approx(q, abs=1e-12)
    assert motor_rad_to_joint(joint_to_motor_rad(q)) == pytest.approx(q, abs=1e-12)


def test_default_limits_lie_inside_the_mechanical_stops() -> None:
    assert FINGER_JOINT_LIMITS == ((-1.57, 1.57),) * 3
    for (lo, hi), (stop_lo, stop_hi) in zip(FINGER_JOINT_LIMITS, FINGER_JOINT_STOPS,
                                            strict=True):
        assert stop_lo < lo < 0.0 < hi < stop_hi


# --- hand layouts: joint order and signs -------------------------------------------------------
def test_every_layout_has_four_orthonormal_mounts() -> None:
    assert DEFAULT_HAND_LAYOUT in HAND_LAYOUTS
    assert set(HAND_LAYOUTS) == {"four-finger-thumb", "three-plus-opposed", "two-by-two"}
    for layout in HAND_LAYOUTS.values():
        assert len(layout.mounts) == 4
        for mount in layout.mounts:
            rot = mount.rotation()
            assert np.allclose(rot @ rot.T, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1)


def test_fingers_on_the_distal_edge_flex_about_palm_x() -> None:
    # x_f = +y_p, z_f = +z_p, so y_f = z × x = −x_p: J0 about +z_p, J1 and J2 about −y_f = +x_p.
    for k in range(3):
        axes = HAND_LAYOUTS["three-plus-opposed"].mounts[k].joint_axes()
        assert np.allclose(axes, [[0, 0, 1], [1, 0, 0], [1, 0, 0]])
        assert HAND_LAYOUTS["three-plus-opposed"].mounts[k].position_m[1] == 0.05


def test_opposed_fingers_flex_about_minus_palm_x() -> None:
    # x_f = −y_p, z_f = +z_p, so y_f = z × x = +x_p: J1 and J2 about −x_p, J0 still about +z_p.
    opposed = HAND_LAYOUTS["three-plus-opposed"].mounts[3]
    assert np.allclose(opposed.joint_axes(), [[0, 0, 1], [-1, 0, 0], [-1, 0, 0]])
    two = HAND_LAYOUTS["two-by-two"].mounts
    for k, sign in ((0, 1), (1, 1), (2, -1), (3, -1)):
        assert np.allclose(two[k].joint_axes()[1], [sign, 0, 0])
        assert two[k].position_m[1] == sign * 0.05


def test_thumb_axes() -> None:
    # x_f = +z_p, z_f = (−0.35, 1, 0)/1.05948; y_f = z_f × x_f = (1, 0.35, 0)/1.05948.
    thumb = HAND_LAYOUTS["four-finger-thumb"].mounts[3]
    n = math.sqrt(1 + 0.35 ** 2)
    assert np.allclose(thumb.joint_axes(), [[-0.35 / n, 1 / n, 0], [-1 / n, -0.35 / n, 0],
                                            [-1 / n, -0.35 / n, 0]])


@pytest.mark.parametrize("name", sorted(HAND_LAYOUTS))
def test_positive_flexion_moves_every_fingertip_towards_its_pads(name: str) -> None:
    for mount in HAND_LAYOUTS[name].mounts:
        rot = mount.rotation()
        along, pads = rot[:, 0], rot[:, 2]
        flexion_axis = mount.joint_axes()[1]
        # a small positive rotation about the axis moves the finger's x by axis × x
        assert np.allclose(np.cross(flexion_axis, along), pads)


# --- arm ---------------------------------------------------------------------------------------
def test_arm_joint_order_and_limits() -> None:
    assert ARM_JOINT_NAMES == ("J1", "J2", "J3", "J4", "J5", "J6", "J7")
    assert len(ARM_JOINT_LIMITS) == 7 and all(lo < 0 < hi for lo, hi in ARM_JOINT_LIMITS)
    # the RX-64 joints stop inside the pot's ±150°
    assert all(hi < math.radians(150) for _, hi in ARM_JOINT_LIMITS[4:])


def test_stepper_steps_to_angle_by_hand() -> None:
    # J1: 200 steps × 10 microsteps × 6 = 12 000 microsteps per joint revolution.
    assert microsteps_to_rad(0, 12_000) == pytest.approx(2 * math.pi)
    assert microsteps_per_rad(0) == pytest.approx(12_000 / (2 * math.pi))
    # J3: 200 × 10 × 13 = 26 000 per revolution, so a quarter turn is 6 500 microsteps.
    assert rad_to_microsteps(2, math.pi / 2) == pytest.approx(6_500)
    # microsteps per joint encoder count: 12 000 / 10 000 = 1.2 (J1), 2.0 (J2), 2.6 (J3, J4)
    assert [microsteps_per_encoder_count(j) for j in range(4)] == pytest.approx(
        [1.2, 2.0, 2.6, 2.6])


def test_stepper_torque_speed_curve_by_hand() -> None:
    # flat to the corner (300 full steps/s), then falling as corner / rate
    assert pull_out_fraction(0.0) == pull_out_fraction(-300.0) == 1.0
    assert pull_out_fraction(600.0) == pytest.approx(0.5)
    # the controllers' maximum rate: 4600 microsteps/s = 2300 counts/s of J2 (1.445 rad/s,
    # 1.50 m/s at the outstretched flange, 1.04 m from the J2 axis)
    assert max_velocity_counts_per_s(1) == pytest.approx(2300.0)
    assert encoder_counts_to_rad(max_velocity_counts_per_s(1)) * 1.04 == pytest.approx(
        1.50, abs=0.01)
    # the shoulder's maximum moving torque at the default current: 2.62 × 2 × 10 / 1.6
    k_t = STEPPER_TORQUE_CONSTANT_NM_PER_A[1]
    moving = k_t * STEPPER_DEFAULT_CURRENT_MA / 1000 * STEPPER_REDUCTIONS[1] / 1.6
    assert moving == pytest.approx(32.75)
    assert STEPPER_HOLDING_MARGIN == 1.6


def test_encoder_counts_to_angle_by_hand() -> None:
    assert ARM_ENCODER_COUNTS_PER_REV == 10_000
    assert encoder_counts_to_rad(2_500) == pytest.approx(math.pi / 2)
    assert rad_to_encoder_counts(math.radians(10.0)) == 278  # 10 / 0.036 = 277.8
    assert rad_to_encoder_counts(-math.pi) == -5_000


def test_stepper_table_defaults_are_the_robots() -> None:
    assert STEPPER_REDUCTIONS == (6.0, 10.0, 13.0, 13.0)
    assert [reduction_x100(r) for r in STEPPER_REDUCTIONS] == [600, 1000, 1300, 1300]
    assert STEPPER_TABLE["gear_reduction_x100"].default == 600
    assert STEPPER_TABLE["steps_per_rev"].default == 200
    assert STEPPER_TABLE["microstepping"].default == 10
    assert STEPPER_TABLE["encoder_resolution"].default == 10_000
    # the node's formula: x100 × steps × microsteps / 1 000 000 = microsteps per count
    assert 600 * 200 * 10 / 1_000_000 == microsteps_per_encoder_count(0)


def test_rx64_range_by_hand() -> None:
    assert (RX64_POSITION_CENTRE, RX64_POSITION_MAX) == (512, 1023)
    assert RX64_RAD_PER_UNIT * 1024 == pytest.approx(math.radians(300.0))
    assert RX64_UNITS_PER_RAD == pytest.approx(195.5696, abs=1e-4)  # 1024 / 5.235988
    assert rx64_position_to_radians(512 + 307) == pytest.approx(math.radians(307 * 300 / 1024))
    assert radians_to_rx64_position(math.radians(-150.0)) == 0


def test_a_series_elastic_element_is_soft_for_its_travel_then_solid() -> None:
    """Worked by hand for the shoulder's element (200 N·m/rad, ±4° = 0.0698 rad soft): 10
    N·m is 0.05 rad; 20 N·m is the travel's 13.96 N·m and 6.04 N·m at 2000 N·m/rad more."""
    k, travel = 200.0, math.radians(4.0)
    assert series_elastic_deflection(10.0, k) == pytest.approx(0.05)
    assert series_elastic_deflection(-10.0, k) == pytest.approx(-0.05)
    assert series_elastic_deflection(20.0, k) == pytest.approx(travel + (20.0 - k * travel) / 2000)
    assert series_elastic_deflection(-20.0, k) == pytest.approx(-travel - (20.0 - k * travel) / 2000)
    assert series_elastic_deflection(k * travel, k) == pytest.approx(travel)


@given(st.floats(-200.0, 200.0))
def test_the_element_torque_is_the_inverse_of_its_deflection(torque: float) -> None:
    assert series_elastic_torque(series_elastic_deflection(torque, 86.0), 86.0) == \
        pytest.approx(torque, abs=1e-9)


@given(st.floats(-200.0, 200.0), st.floats(-200.0, 200.0))
def test_a_series_elastic_element_deflects_further_under_more_torque(a: float, b: float) -> None:
    lo, hi = sorted((a, b))
    assert series_elastic_deflection(lo, 86.0) <= series_elastic_deflection(hi, 86.0)
