"""The arm's calibration (host.arm.calibration) recovers planted errors from synthetic touches.

The touches come from tools.experiments.arm_calibration's generator: a built arm (planted
zero offsets and body offsets), its flange put on a board's dimples and on a table by its
own kinematics, the readings as the homed host would have them (offsets, quantisation)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from host.arm.calibration import (
    ANCHORED,
    ARM_SECTION,
    GAUGE,
    METHOD,
    PARAMETERS,
    SUMMED,
    TOUCH_SIGMA_M,
    ArmGeometry,
    BoardTouches,
    CalibrationData,
    CalibrationResult,
    arm_section,
    board_residuals,
    calibrate,
    check,
    geometry_of_section,
    plane_distances,
)
from host.errors import CalibrationError
from host.estimation.calibration_file import load, save_section
from tools.experiments.arm_calibration import anchored, held_out_errors, touches

#: Recovery bounds: J2's, J3's and J5's zero offsets within 0.05° of the planted ones (J4's
#: and J6's within 0.15°), and the held-out end-effector error (true gauge) under 0.5 mm
#: mean, 1 mm at most.
ZERO_BOUND_RAD = math.radians(0.05)
MEAN_BOUND_M = 0.0005
MAX_BOUND_M = 0.001


def planted_arm(rng: np.random.Generator) -> tuple[ArmGeometry, np.ndarray]:
    """A built arm's true geometry (zero offsets 0) and its readings' offsets (rad): the
    realistic emulator's sizes (index 0.4°, horns 0.5°, bodies 0.3 mm, tubes 1 mm)."""
    nominal = ArmGeometry.nominal()
    offsets = nominal.joint_offsets_m + rng.normal(0.0, 0.0003, (7, 3))
    offsets[3, 2] -= rng.normal(0.0, 0.001)
    offsets[5, 2] -= rng.normal(0.0, 0.001)
    flange = nominal.flange_offset_m + rng.normal(0.0, 0.0003, 3)
    readings = np.concatenate((rng.normal(0.0, math.radians(0.4), 4),
                               rng.normal(0.0, math.radians(0.5), 3)))
    return ArmGeometry(np.zeros(7), offsets, flange), readings


def test_the_parameters_leave_out_exactly_the_gauge_and_the_summed_offsets() -> None:
    """7 zeros + 21 offsets + 3 flange, less the 5 gauge and 3 summed ones."""
    assert len(PARAMETERS) == 7 + 21 + 3 - len(GAUGE) - len(SUMMED)
    assert not set(PARAMETERS) & (set(GAUGE) | set(SUMMED))


def test_the_nominal_tip_is_the_drawings_flange() -> None:
    """At the kinematic zero the flange hangs 0.68 m below the base plate (0.16 + 0.20 −
    0.08 − 0.47 − 0.08 − 0.32 − 0.05 − 0.04); J2 at 90° swings it forward."""
    g = ArmGeometry.nominal()
    assert g.tips(np.zeros(7))[0] == pytest.approx([0.0, 0.0, -0.68])
    assert g.tips([[0.0, math.pi / 2, 0, 0, 0, 0, 0]])[0] == pytest.approx([1.04, 0.0, 0.36])


def test_a_gauge_motion_changes_no_residual() -> None:
    """J1's zero and a translation of the base move every touch rigidly: the distances and
    the planarity stay as they were (what makes them the gauge)."""
    rng = np.random.default_rng(3)
    q = rng.uniform(-1.0, 1.0, (10, 7))
    board = BoardTouches(q, rng.uniform(0.0, 0.2, (10, 3)))
    g = ArmGeometry.nominal()
    moved_zero = g.zero_offsets_rad.copy()
    moved_zero[0] = 0.3
    shift = np.zeros((7, 3))
    shift[0] = (0.01, -0.02, 0.03)
    shift[1, 2] = 0.02
    moved = ArmGeometry(moved_zero, g.joint_offsets_m + shift, g.flange_offset_m)
    assert board_residuals(moved, [board]) == pytest.approx(board_residuals(g, [board]))
    assert np.abs(plane_distances(moved.tips(q))) == pytest.approx(
        np.abs(plane_distances(g.tips(q))))
    assert not np.allclose(moved.tips(q), g.tips(q))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, pytest.param(12, marks=pytest.mark.long)])
def test_calibration_recovers_planted_zero_offsets_and_the_end_effector(seed: int) -> None:
    """Synthetic touches of a planted arm (6 placements, 60 table touches), then 3 held-out
    placements.  The default run takes seed 11 only (its touches' IK is most of a CPU
    minute on a loaded machine); seed 12 is ``long``."""
    rng = np.random.default_rng(seed)
    truth, readings = planted_arm(rng)
    train, _ = touches(truth, readings, rng, boards=6, table=60)
    test, test_tips = touches(truth, readings, rng, boards=3, table=0)
    result = calibrate(train)
    assert result.success
    seen = ArmGeometry(-readings, truth.joint_offsets_m, truth.flange_offset_m)
    before = held_out_errors(ArmGeometry.nominal(), seen, test, test_tips)
    after = held_out_errors(result.geometry, seen, test, test_tips)
    # the planted errors were worth millimetres; the calibration leaves tenths
    assert before.mean() > 4 * MEAN_BOUND_M
    assert after.mean() <= MEAN_BOUND_M
    assert after.max() <= MAX_BOUND_M
    # J2..J6's zeros recovered (J1's is the gauge, J7's the flange offset takes): the
    # estimate undoes the readings' offsets; J4's and J6's trade a little with the offsets
    # of the links after them, within the CAD prior
    missed = np.abs(result.geometry.zero_offsets_rad[1:6] + readings[1:6])
    assert missed[[0, 1, 3]] == pytest.approx(np.zeros(3), abs=ZERO_BOUND_RAD)
    assert missed[[2, 4]] == pytest.approx(np.zeros(2), abs=3 * ZERO_BOUND_RAD)
    assert result.board_rms_m[1] < result.board_rms_m[0]
    assert result.board_rms_m[1] < 2 * TOUCH_SIGMA_M
    assert result.table_rms_m[1] < result.table_rms_m[0]
    check(result)  # fit to be written


def test_a_fit_whose_touches_still_disagree_or_that_went_astray_is_refused() -> None:
    """What armctl calibrate refuses to write: touches that still disagree by millimetres
    after the fit (one seated in the wrong dimple), or a parameter moved far beyond what a
    laser-cut build is off by; a build's own errors pass."""
    rng = np.random.default_rng(7)
    built, _readings = planted_arm(rng)
    check(CalibrationResult(built, (0.008, 0.0004), (0.002, 0.0003), 30, True))
    with pytest.raises(CalibrationError, match="still disagree by 7.40 mm"):
        check(CalibrationResult(built, (0.0082, 0.0074), (0.002, 0.0003), 30, True))
    with pytest.raises(CalibrationError, match="table 2.00 mm"):
        check(CalibrationResult(built, (0.008, 0.0004), (0.004, 0.002), 30, True))
    astray = ArmGeometry(np.array([0.0, math.radians(20.0), 0, 0, 0, 0, 0]),
                         built.joint_offsets_m, built.flange_offset_m)
    with pytest.raises(CalibrationError, match="prior widths from the CAD model"):
        check(CalibrationResult(astray, (0.008, 0.0004), (0.002, 0.0003), 30, True))


@settings(deadline=None, max_examples=20)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.05, 0.05))
def test_planarity_is_invariant_to_the_tables_pose(tilt: float, yaw: float, height: float
                                                   ) -> None:
    """Points on any plane have zero plane distances; lifting one by d gives it about d
    (less its share of the fit)."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.3, 0.3, (30, 2))
    flat = np.column_stack((xy, np.full(30, height)))
    c, s = math.cos(tilt), math.sin(tilt)
    rot_x = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = math.cos(yaw), math.sin(yaw)
    rot_z = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    points = flat @ (rot_z @ rot_x).T
    assert np.abs(plane_distances(points)).max() < 1e-12
    lifted = points.copy()
    lifted[0] += 0.001 * (rot_z @ rot_x)[:, 2]
    assert 0.0008 < abs(plane_distances(lifted)[0]) <= 0.001 + 1e-12


def test_calibration_refuses_too_few_touches() -> None:
    with pytest.raises(ValueError, match="at least one board"):
        calibrate(CalibrationData((), np.zeros((0, 7))))


def test_a_geometry_survives_its_json_form() -> None:
    rng = np.random.default_rng(5)
    g = ArmGeometry(rng.normal(0, 0.01, 7), rng.normal(0, 0.3, (7, 3)), rng.normal(0, 0.1, 3))
    back = ArmGeometry.from_dict(g.as_dict())
    assert back.tips(np.ones((2, 7))) == pytest.approx(g.tips(np.ones((2, 7))))
    with pytest.raises(ValueError, match="7 zero offsets"):
        ArmGeometry.from_dict({**g.as_dict(), "zero_offsets_rad": [0.0] * 6})


def test_the_arm_section_round_trips_through_the_calibration_file(tmp_path: Path) -> None:
    """A calibration saved as the file's "arm" section gives back the same geometry."""
    rng = np.random.default_rng(6)
    geometry = ArmGeometry(rng.normal(0, 0.01, 7), ArmGeometry.nominal().joint_offsets_m
                           + rng.normal(0, 0.001, (7, 3)), ArmGeometry.nominal().flange_offset_m)
    result = CalibrationResult(geometry, (0.004, 0.0002), (0.003, 0.0001), 40, True)
    path = tmp_path / "arm.json"
    save_section(path, "00002000", ARM_SECTION, arm_section(result))
    section = load(path).section(ARM_SECTION)
    assert section is not None and section["method"] == METHOD
    back = geometry_of_section(section)
    q = rng.uniform(-1, 1, (5, 7))
    assert back.tips(q) == pytest.approx(geometry.tips(q), abs=1e-12)
    with pytest.raises(ValueError, match="no geometry"):
        geometry_of_section({"method": METHOD})


@pytest.mark.slow
@pytest.mark.long
def test_anchor_touches_make_j1s_zero_and_the_base_seen() -> None:
    """With two dimples drawn in the base frame touched too, J1's index error is recovered
    and the held-out flange positions are right without being given the gauge.  Long (the
    same synthetic touch set as above, a second time: minutes on a loaded machine)."""
    rng = np.random.default_rng(13)
    truth, readings = planted_arm(rng)
    train, _ = touches(truth, readings, rng, boards=6, table=60)
    test, test_tips = touches(truth, readings, rng, boards=3, table=0)
    with_anchors = anchored(train, truth, readings, rng)
    assert with_anchors.parameters()[:len(ANCHORED)] == ANCHORED
    geometry = calibrate(with_anchors).geometry
    est = np.concatenate([geometry.tips(b.joints) for b in test.boards])
    errors = np.linalg.norm(est - np.concatenate(test_tips), axis=1)
    assert errors.mean() <= MEAN_BOUND_M and errors.max() <= MAX_BOUND_M, errors
    # J1's zero itself within 0.25°: with two anchors it still trades a little with J1's
    # and J2's body offsets (the flange is right, as above)
    assert abs(geometry.zero_offsets_rad[0] + readings[0]) <= 5 * ZERO_BOUND_RAD
    # without them the same touches leave J1's error in: millimetres at the board
    plain = calibrate(train).geometry
    est = np.concatenate([plain.tips(b.joints) for b in test.boards])
    assert np.linalg.norm(est - np.concatenate(test_tips), axis=1).mean() > 2 * MEAN_BOUND_M
