"""The hand's accelerometer calibration on the emulated robot as built (realistic sensors):
what it recovers of the planted chips, what it says it cannot, and its use by estimates."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.imperfections import AccelTruth
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.estimation.finger_gravity import JOINTS_BEFORE
from host.estimation.hand_calibration import BoardCalibration, FingerFit
from host.hand.calibration import calibrate_fingers
from host.hand.facade import Hand
from protocol.robot import FINGER_JOINT_AXES, accel_mount_rotation

THUMB = 3
#: Bounds the calibration is held to on the thumb (every joint axis observable, palm up):
#: the phalanges' rotation (deg; about their joint axis, known through the stops the finger
#: touches, and across it) and their bias (mg per axis).
ROTATION_BOUND_DEG = 0.3
BIAS_BOUND_MG = 3.0


def rotation_error(fit: BoardCalibration, truth: AccelTruth, board: str) -> tuple[float, float]:
    """(about the board's joint axis, perpendicular to it), deg: the rotation left between
    the fitted chip and the planted one (the antisymmetric part of ``M_fit⁻¹·M_true``)."""
    e = np.linalg.solve(fit.matrix(), truth.matrix() * 1000.0) - np.eye(3)
    w = np.array([e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1]]) / 2.0
    axis = accel_mount_rotation(board).T @ np.asarray(FINGER_JOINT_AXES[JOINTS_BEFORE[board] - 1])
    along = float(w @ axis)
    return math.degrees(along), math.degrees(float(np.linalg.norm(w - along * axis)))


#: The runs: seed 1 calibrates the four fingers together (moved, settled and read at once),
#: seed 2 the thumb alone; the thumb is held to the same bounds in both.
RUNS = {1: (0, 1, 2, 3), 2: (THUMB,)}


@pytest.fixture(scope="module", params=sorted(RUNS), ids=lambda s: f"seed{s}")
def calibrated_hand(request: pytest.FixtureRequest
                    ) -> Iterator[tuple[Emulator, dict[int, FingerFit]]]:
    emulator = Emulator("hand", seed=request.param, can="none", sensors="realistic")
    bring_up(emulator)
    with Hand.open(EmulatorTransport(emulator, "palm")) as hand:
        _, fits = calibrate_fingers([hand.fingers[k] for k in RUNS[request.param]])
    yield emulator, fits
    emulator.close()


@pytest.fixture
def calibrated(calibrated_hand: tuple[Emulator, dict[int, FingerFit]]
               ) -> tuple[Emulator, FingerFit]:
    emulator, fits = calibrated_hand
    return emulator, fits[THUMB]


@pytest.mark.slow
def test_every_finger_calibrated_together_holds_its_poses(
        calibrated_hand: tuple[Emulator, dict[int, FingerFit]]) -> None:
    emulator, fits = calibrated_hand
    assert emulator.planted is not None
    assert sorted(fits) == sorted(RUNS[emulator.seed])
    for k, fit in fits.items():
        # residuals at the sensors' noise: no finger met another while they moved together
        assert fit.rms_counts < 2.0, k
        # 27 poses and the stops: J0's only for the thumb (the others' J0 axis is vertical)
        assert fit.poses == (30 if k == THUMB else 29), k
        for board in ("f2", "f3"):
            truth = emulator.planted.accels[f"finger{k}.{board}"]
            # whatever its J0's observability, each phalange's bias is recovered
            assert np.all(np.abs(fit.boards[board].bias - truth.bias_mg) <= BIAS_BOUND_MG), k


@pytest.mark.slow
@pytest.mark.parametrize("board", ["f2", "f3"])
def test_calibration_recovers_the_planted_rotation_and_bias(
        calibrated: tuple[Emulator, FingerFit], board: str) -> None:
    emulator, fit = calibrated
    assert emulator.planted is not None
    truth = emulator.planted.accels[f"finger{THUMB}.{board}"]
    along, across = rotation_error(fit.boards[board], truth, board)
    assert math.hypot(along, across) <= ROTATION_BOUND_DEG
    assert np.all(np.abs(fit.boards[board].bias - truth.bias_mg) <= BIAS_BOUND_MG)
    # without the calibration (the nominal chip) the same measure is off by the planted tilt
    assert math.hypot(*rotation_error(BoardCalibration.nominal(), truth, board)) > math.hypot(
        along, across)


@pytest.mark.slow
def test_the_fit_says_what_it_could_not_observe(calibrated: tuple[Emulator, FingerFit]) -> None:
    _, fit = calibrated
    unobservable = fit.unobservable()
    # with the palm fixed the fmcb sees one direction of gravity
    assert "fmcb.rotation[x]" in unobservable
    # a phalange's tilt about its joint axis (-y), the same as its joint's hall offset,
    # is known once the joint has rested against its stop
    assert "f2.rotation[y]" not in unobservable and "f3.rotation[y]" not in unobservable
    assert "f2.bias[x]" not in unobservable and "f3.rotation[x]" not in unobservable
    assert fit.rms_counts < 2.0
