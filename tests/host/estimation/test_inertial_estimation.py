"""Inertial joint estimation against hand-computed cases and the forward model: the closed
forms (1-DOF J2, 2-DOF J0/J1 of eq. 4.12-4.14 with their multiple roots, unobservable
poses), the joint EKF on synthetic trajectories, and accelerometer calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from host.errors import UsageError
from host.estimation.accel_calibration import calibrate
from host.estimation.closed_form import (
    UnobservableJointError,
    distal_angle,
    eq_4_12_residual,
    eq_4_13_roots,
    eq_4_14_roots,
    estimate,
    proximal_candidates,
    solve_trig,
)
from host.estimation.ekf import JointEkf, fuse_snapshot
from host.estimation.finger_gravity import axis_rotation, predict_readings, segment_rotations
from protocol.robot import accel_mount_rotation, joint_to_motor, motor_to_joint

# The thumb's pose on the hand: finger along up, pads horizontal (F0 reads +x up).
UP_ALONG_X = (1.0, 0.0, 0.0)


def test_solve_trig_gives_two_one_or_no_roots() -> None:
    # cos ψ + 0·sin ψ = 0.5 → ψ = ±60°
    assert sorted(solve_trig(1.0, 0.0, 0.5)) == pytest.approx([-math.pi / 3, math.pi / 3])
    assert solve_trig(1.0, 0.0, 1.0) == pytest.approx([0.0])     # tangent: one root
    assert solve_trig(1.0, 0.0, 1.5) == []                       # |c| > r: none
    assert solve_trig(0.0, 0.0, 0.0) == []


def test_distal_angle_by_hand() -> None:
    # F2 points up (+x up): F3 flexed by 30° about -y reads up at (cos 30°, 0, -sin 30°)...
    a2 = (1.0, 0.0, 0.0)
    a3 = (math.cos(math.radians(30)), 0.0, -math.sin(math.radians(30)))
    # a2 = R(-y, q2)·a3: rotating (c, 0, -s) by +30° about -y gives (1, 0, 0)
    assert distal_angle(a2, a3) == pytest.approx(math.radians(30))
    assert distal_angle(a3, a2) == pytest.approx(math.radians(-30))


def test_distal_axis_vertical_is_unobservable_and_named() -> None:
    found = distal_angle((0.05, 1.0, 0.0), (0.0, 1.0, 0.05))
    assert not isinstance(found, float)
    assert found.joint == 2 and "J2 (distal)" in str(found) and "vertical" in str(found)


def test_eq_4_13_has_two_roots_and_eq_4_14_two_per_root_of_which_one_is_exact() -> None:
    q = (0.4, 0.7, 0.0)
    up = np.array([0.3, 0.5, 0.81])
    up /= np.linalg.norm(up)
    r = predict_readings(q, up)
    roots0 = eq_4_13_roots(r["fmcb"], r["f2"])
    assert len(roots0) == 2 and min(abs(x - 0.4) for x in roots0) < 1e-9
    roots1 = eq_4_14_roots(r["fmcb"], r["f2"], 0.4)
    assert len(roots1) == 2 and min(abs(x - 0.7) for x in roots1) < 1e-9
    cands = proximal_candidates(r["fmcb"], r["f2"])
    assert len(cands) == 4
    exact = [(a, b) for a, b, res in cands if res < 1e-9]
    assert len(exact) == 2                         # both roots of 4.13 are exact solutions
    assert any(abs(a - 0.4) < 1e-9 and abs(b - 0.7) < 1e-9 for a, b in exact)
    for a, b, res in cands:
        assert res == pytest.approx(eq_4_12_residual(r["fmcb"], r["f2"], a, b))


def test_roots_are_chosen_by_joint_limits_then_by_continuity() -> None:
    # The thumb: F0 reads +x up, so α2y = -sin q0: roots q0 and π - q0, one in the stops.
    q = (0.5, -0.3, 0.6)
    found = estimate(predict_readings(q, UP_ALONG_X))
    assert found.q == pytest.approx(q) and not found.ambiguous
    assert len(eq_4_13_roots(UP_ALONG_X, predict_readings(q, UP_ALONG_X)["f2"])) == 2
    # Tilted base: both roots within the stops; the previous estimate chooses.
    up = np.array([0.2, 0.6, 0.77])
    up /= np.linalg.norm(up)
    q = (0.3, 0.4, -0.2)
    r = predict_readings(q, up)
    free = estimate(r)
    assert len(free.candidates) == 2 and free.ambiguous
    other = next(c for c in free.candidates if abs(c[0] - 0.3) > 0.1)
    assert estimate(r, previous=q).q == pytest.approx(q)
    assert estimate(r, previous=(other[0], other[1], 0.0)).q[:2] == pytest.approx(other)


def test_vertical_j0_is_reported_but_j1_j2_still_estimated() -> None:
    # Fingers 0-2 on the hand's stand: F0's z (J0's axis) is up.
    q = (0.7, 0.5, 0.3)
    found = estimate(predict_readings(q, (0.0, 0.0, 1.0)))
    assert [p.joint for p in found.unobservable] == [0]
    assert found.q[0] is None and found.q[1:] == pytest.approx((0.5, 0.3))
    with pytest.raises(UnobservableJointError, match=r"finger 2: J0 \(abduction\)"):
        found.require(2)


def test_horizontal_j1_axis_along_gravity_makes_j1_and_j2_unobservable() -> None:
    # Up along F0's -y (J1 and J2 axes vertical whatever q0 = 0).
    found = estimate(predict_readings((0.0, 0.4, 0.4), (0.0, -1.0, 0.0)))
    assert sorted(p.joint for p in found.unobservable) == [1, 2]
    assert found.q[0] == pytest.approx(0.0, abs=1e-9)
    assert found.q[1] is None and found.q[2] is None


@settings(max_examples=150, deadline=None)
@given(q=st.tuples(*[st.floats(-1.5, 1.5)] * 3),
       up=st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 0.2))
def test_closed_form_inverts_the_forward_model(q: tuple[float, float, float],
                                               up: tuple[float, float, float]) -> None:
    r = predict_readings(q, np.asarray(up) / np.linalg.norm(up))
    found = estimate(r, previous=q)
    for j, value in enumerate(found.q):
        if value is not None:
            assert value == pytest.approx(q[j], abs=1e-6)
    unobs = {p.joint for p in found.unobservable}
    assert all(found.q[j] is not None for j in range(3) if j not in unobs)


def _trajectory(t: np.ndarray) -> np.ndarray:
    return np.stack([0.4 * np.sin(1.3 * t), 0.6 + 0.5 * np.sin(2.1 * t + 0.3),
                     0.5 + 0.6 * np.sin(1.7 * t + 1.0)], axis=1)


@pytest.mark.slow
def test_ekf_tracks_a_synthetic_trajectory_from_accelerometers_alone() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 4.0, 0.01)
    q = _trajectory(t)
    ekf = JointEkf(q0=(0.0, 0.5, 0.4), q0_sigma=0.3)
    errors = []
    for k, tk in enumerate(t):
        r = predict_readings(q[k], UP_ALONG_X)
        noisy = {b: v + rng.normal(0.0, 0.002, 3) for b, v in r.items()}
        ekf.predict(float(tk))
        ekf.update_accels(noisy["fmcb"], noisy["f2"], noisy["f3"], float(tk))
        if tk > 0.5:
            errors.append(ekf.q - q[k])
    rms = np.degrees(np.sqrt(np.mean(np.square(errors), axis=0)))
    assert np.all(rms < 1.0), rms


def test_ekf_with_halls_follows_a_vertical_j0_the_accelerometers_cannot_see() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 2.0, 0.01)
    q = _trajectory(t)
    ekf = JointEkf()
    for k, tk in enumerate(t):
        r = predict_readings(q[k], (0.0, 0.0, 1.0))
        noisy = {b: v + rng.normal(0.0, 0.002, 3) for b, v in r.items()}
        ekf.predict(float(tk))
        ekf.update_accels(noisy["fmcb"], noisy["f2"], noisy["f3"], float(tk))
        ekf.update_halls([round(m) for m in joint_to_motor(q[k])])
    assert ekf.q == pytest.approx(q[-1], abs=0.01)


def test_fuse_snapshot_agrees_with_halls_and_accels() -> None:
    q = (0.2, 0.5, 0.3)
    r = predict_readings(q, UP_ALONG_X)
    counts = {b: list(np.round(v * 1000)) for b, v in r.items()}
    hall = [round(m) for m in joint_to_motor(q)]
    assert fuse_snapshot(hall, counts) == pytest.approx(q, abs=0.005)


def test_calibration_recovers_bias_scale_and_misalignment() -> None:
    rng = np.random.default_rng(6)
    true_rot = axis_rotation((0.3, -0.5, 0.8), math.radians(4.0))
    bias = np.array([12.0, -30.0, 7.0])
    scale = np.array([1012.0, 985.0, 1003.0])
    ups = rng.normal(size=(20, 3))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    readings = (ups @ true_rot) * scale + bias + rng.normal(0.0, 2.0, (20, 3))
    cal = calibrate(readings, ups)
    assert cal.bias == pytest.approx(bias, abs=3.0)
    assert cal.scale == pytest.approx(scale, abs=3.0)
    assert math.degrees(cal.misalignment_rad()) == pytest.approx(4.0, abs=0.2)
    assert math.degrees(cal.misalignment_rad(true_rot)) < 0.2
    assert cal.rms_counts < 3.0
    assert cal.to_segment(readings[0]) == pytest.approx(ups[0], abs=0.01)


def test_calibration_refuses_coplanar_poses() -> None:
    ups = np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0], [0.7, 0.7, 0]])
    with pytest.raises(UsageError, match="not all in one plane"):
        calibrate(ups * 1000, ups)


@pytest.mark.slow
def test_ekf_with_halls_learns_a_homing_offset_from_the_accelerometers() -> None:
    # The halls read 0.9° high on J1 and low on J2 (an imperfect homing); while the finger
    # moves, the halls carry the motion and the accelerometers find the offset.
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 6.0, 0.01)
    q = _trajectory(t)
    offset = np.array([0.0, 0.016, -0.016])
    ekf = JointEkf()
    errors = []
    for k, tk in enumerate(t):
        r = predict_readings(q[k], UP_ALONG_X)
        counts = {b: np.round((v + rng.normal(0.0, 0.002, 3)) * 1000) for b, v in r.items()}
        hall = [round(m) for m in joint_to_motor(q[k] + offset)]
        ekf.update_status(float(tk), counts, hall)
        if tk > 4.0:
            errors.append(ekf.q - q[k])
    assert ekf.hall_offsets[1:] == pytest.approx(offset[1:], abs=0.005)
    rms = np.degrees(np.sqrt(np.mean(np.square(errors), axis=0)))
    assert np.all(rms < 0.4), rms


def _jolting_moves(rng: np.random.Generator, dt: float, accel: float,
                   speed: float) -> np.ndarray:
    """Joint angles (rad) every ``dt`` s of a finger driven hard from rest to random targets
    and back to rest: each move accelerates at up to ``accel`` rad/s² from a standstill (a
    jolt), cruises at up to ``speed`` rad/s and brakes as hard."""
    q, qd = np.array([0.1, 0.5, 0.4]), np.zeros(3)
    out = []
    for _ in range(6):
        target = np.array([rng.uniform(-0.6, 0.6), rng.uniform(0.0, 1.2), rng.uniform(0.0, 1.2)])
        for _ in range(round(0.8 / dt)):
            v_want = np.clip(8.0 * (target - q), -speed, speed)
            qd = qd + np.clip(v_want - qd, -accel * dt, accel * dt)
            q = q + qd * dt
            out.append(q.copy())
    return np.array(out)


def _accels_in_motion(q: np.ndarray, dt: float) -> dict[str, np.ndarray]:
    """Accelerometer readings (g, board axes; rows follow ``q``) of a finger moving through
    ``q`` (rad, one row every ``dt`` s) with F0 still and up along its x axis: gravity and
    the accelerations of motion of boards 3 cm (F2, mid proximal phalanx) and 6 + 2 cm (F3)
    out from the knuckle."""
    pos: dict[str, list[np.ndarray]] = {"f2": [], "f3": []}
    rots: dict[str, list[np.ndarray]] = {"f2": [], "f3": []}
    for qk in q:
        r = segment_rotations(qk)
        pos["f2"].append(r["f2"] @ np.array([0.03, 0.0, 0.0]))
        pos["f3"].append(r["f2"] @ np.array([0.06, 0.0, 0.0]) + r["f3"] @ np.array([0.02, 0, 0]))
        for b in rots:
            rots[b].append(r[b])
    up = np.asarray(UP_ALONG_X)
    out = {"fmcb": np.tile(accel_mount_rotation("fmcb").T @ up, (len(q), 1))}
    for b in ("f2", "f3"):
        p = np.array(pos[b])
        acc = np.gradient(np.gradient(p, dt, axis=0), dt, axis=0) / 9.81  # g, F0 frame
        out[b] = np.array([accel_mount_rotation(b).T @ (rot.T @ (up - a))
                           for rot, a in zip(rots[b], acc, strict=True)])
    return out


def _fused_against_exact_halls(q: np.ndarray, dt: float) -> tuple[np.ndarray, float]:
    """Run the EKF over ``q`` (rad, a row every ``dt`` s) with exact halls and readings that
    carry the accelerations of motion (a status every 20 ms, the fmcb's IMU refreshed every
    40 ms): the largest |fused − halls| per joint (deg) and the largest part of a reading
    that is motion, not gravity (g)."""
    readings = _accels_in_motion(q, dt)
    every = round(0.02 / dt)
    ekf = JointEkf(q0=q[0], q0_sigma=0.05)
    worst_dynamic = 0.0
    errors = []
    for k in range(0, len(q), every):
        held = k - k % (2 * every)
        counts = {b: np.round(v[held] * 1000) for b, v in readings.items()}
        static = predict_readings(q[held], UP_ALONG_X)
        worst_dynamic = max(worst_dynamic, *(float(np.max(np.abs(readings[b][held] - static[b])))
                                             for b in ("f2", "f3")))
        hall = [round(m) for m in joint_to_motor(q[k])]
        ekf.update_status(k * dt, counts, hall)
        errors.append(ekf.q - np.asarray(motor_to_joint(hall)))
    return np.degrees(np.abs(np.asarray(errors))).max(axis=0), worst_dynamic


@pytest.mark.parametrize(("accel", "speed"), [(150.0, 1.5), (40.0, 3.0)])
def test_ekf_fused_with_exact_halls_stays_on_them_through_jolting_moves(accel: float,
                                                                        speed: float) -> None:
    # Halls exact (the finger homed perfectly), accelerometers read the motion's own
    # accelerations (a jolt of a g or more as the motors start and stop, or a third of a g
    # for 75 ms): the fused estimate must follow the halls, never be dragged off by the
    # readings into the offsets.
    dt = 0.001
    err, worst_dynamic = _fused_against_exact_halls(
        _jolting_moves(np.random.default_rng(11), dt, accel, speed), dt)
    assert worst_dynamic > 0.25  # the accelerations of motion are large
    assert np.all(err < 1.0), err


def test_ekf_fused_with_exact_halls_stays_on_them_through_a_tremor() -> None:
    # A 6 Hz tremor of ±0.9° keeps the readings off gravity (by 0.1 g) for seconds while the
    # joints move: a disagreement that lasts, but not one to believe over the halls.
    dt = 0.001
    t = np.arange(0.0, 3.0, dt)
    q = np.stack([0.1 + 0.015 * np.sin(40.0 * t + p) for p in (0.0, 1.0, 2.0)], axis=1)
    q[:, 1:] += (0.4, 0.3)
    err, worst_dynamic = _fused_against_exact_halls(q, dt)
    assert worst_dynamic > 0.1
    assert np.all(err < 1.0), err


def test_ekf_believes_accelerometers_that_keep_disagreeing_with_the_halls() -> None:
    # The finger rests while its halls read 12° off on J0 and J1 (lost hall counts, a bad
    # homing): unlike a jolt, the disagreement persists, so the accelerometers win and the
    # offsets take it up.
    q = np.array([0.3, 0.7, 0.5])
    r = predict_readings(q, UP_ALONG_X)
    counts = {b: np.round(v * 1000) for b, v in r.items()}
    wrong = q + np.radians([12.0, 12.0, 0.0])
    hall = [round(m) for m in joint_to_motor(wrong.tolist())]
    ekf = JointEkf(q0=wrong, q0_sigma=0.05)
    for k in range(10):  # 0.2 s of status at 50 Hz, a fresh IMU sample every 40 ms
        ekf.update_status(0.02 * k, {b: v + (k // 2) % 2 for b, v in counts.items()}, hall)
    assert np.degrees(np.abs(ekf.q - q)).max() < 0.5
