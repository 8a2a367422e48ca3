"""Calibrating the hand's accelerometers on the robot: the poses, the readings, the fit.

Each finger is moved (unhomed, its halls relative) through :data:`CALIBRATION_POSES`,
idled, left to rest and read (:func:`host.hand.homing.read_at_rest`, six samples
averaged); then :func:`host.estimation.hand_calibration.fit_finger` fits its three boards
and its hall offsets (the model and what it can and cannot observe: that module).  The
finger is left idle at the last pose.  Angles in rad, readings in counts.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np

from host.errors import CalibrationError, CalibrationFileError, HostError, UsageError
from host.estimation.calibration_file import default_path, find
from host.estimation.closed_form import estimate
from host.estimation.finger_gravity import to_segment
from host.estimation.hand_calibration import (
    FingerFit,
    FingerSample,
    HandCalibration,
    board_key,
    fit_finger,
)
from host.hand.homing import read_at_rest
from host.hand.interface import HandFinger
from protocol.robot import motor_to_joint

#: The poses (J0, J1, J2; rad) a finger calibrates in: J0 swung both ways, J1 from bent
#: back a little to bent, J2 from straight to well bent, so each phalange sees gravity from
#: many directions.  J2 bends far only while J1 is low, and J1 stays below 1 rad: beyond,
#: the thumb's tip meets the palm (a collision pushes J0 aside and the halls lose counts).
CALIBRATION_POSES: Final = tuple(
    (j0, j1, j2) for j0 in (-0.7, 0.0, 0.7)
    for j1, j2 in ((-0.3, 0.1), (0.0, 0.1), (0.0, 0.8), (0.0, 1.4), (0.45, 0.1),
                   (0.45, 0.8), (0.45, 1.4), (0.9, 0.1), (0.9, 0.8)))
#: Rest after each move before reading (s, the link's clock).
REST_S: Final = 0.3
#: Effort cap of the calibration's moves (1/255 of full PWM).
EFFORT: Final = 200
#: Largest residual (counts RMS) a finger's fit may leave: a few times the readings' noise
#: (about 0.7 counts when the poses are what they say).
MAX_RMS_COUNTS: Final = 5.0

Progress = Callable[[int, int, int], None]


class CalibratingFinger(HandFinger, Protocol):
    """What calibrating uses of a finger: moving it and idling it."""

    def move(self, joints: Sequence[float], *, effort: Sequence[int] | int | None = None,
             timeout: float = 3.0, unhomed: bool = False) -> Any:
        """Move to ``joints`` (rad) and wait until settled (or ``timeout``, s)."""
        ...

    def idle(self) -> None:
        """Motors off."""
        ...


def gather_finger(finger: CalibratingFinger, poses: Sequence[Sequence[float]] = CALIBRATION_POSES,
                  progress: Progress | None = None,
                  rest_s: float = REST_S) -> list[FingerSample]:
    """Move ``finger`` through ``poses`` and read it at rest at each; ``progress(finger,
    done, total)`` after each pose.  A pose the finger cannot reach is read where it
    stopped (the halls say where that is)."""
    session = finger.motor.session
    samples = []
    for k, pose in enumerate(poses):
        try:
            finger.move(pose, effort=EFFORT, timeout=2.0, unhomed=True)
        except HostError:
            pass
        finger.idle()
        session.sleep(rest_s)
        reading = read_at_rest(finger)
        samples.append(FingerSample(motor_to_joint(reading.hall_pos),
                                    {b: v.tolist() for b, v in reading.as_dict().items()}))
        if progress is not None:
            progress(finger.index, k + 1, len(poses))
    return samples


def _guesses(samples: Sequence[FingerSample]) -> tuple[list[float], list[float]]:
    """The start of the fit: the offsets a nominal homing at the first pose would give and
    the fmcb's mean nominal reading as the up direction."""
    first = samples[0]
    offsets = [0.0, 0.0, 0.0]
    try:
        found = estimate(first.readings)
        offsets = [0.0 if q is None else q - h for q, h in zip(found.q, first.q_hall,
                                                               strict=True)]
    except HostError:
        pass
    up = np.mean([to_segment("fmcb", s.readings["fmcb"]) for s in samples], axis=0)
    return offsets, (up / np.linalg.norm(up)).tolist()


def fit_samples(samples: Sequence[FingerSample]) -> FingerFit:
    """:func:`fit_finger` on one orientation's samples, started from :func:`_guesses`."""
    offsets, up = _guesses(samples)
    return fit_finger(samples, offsets_guess=offsets, up_guess={0: up})


def calibrate_fingers(fingers: Sequence[CalibratingFinger], progress: Progress | None = None,
                      poses: Sequence[Sequence[float]] = CALIBRATION_POSES
                      ) -> tuple[HandCalibration, dict[int, FingerFit]]:
    """Gather and fit each finger of ``fingers``; the hand's calibration and each fit.
    Raises :class:`~host.errors.CalibrationError` for a fit worse than
    :data:`MAX_RMS_COUNTS`."""
    cal = HandCalibration(source="this run")
    fits: dict[int, FingerFit] = {}
    for finger in fingers:
        fit = fit_samples(gather_finger(finger, poses, progress))
        if not fit.rms_counts <= MAX_RMS_COUNTS:
            raise CalibrationError(
                f"finger {finger.index}: the fit leaves {fit.rms_counts:.1f} mg RMS (the "
                f"sensors' noise is under 1 mg): the finger did not hold the poses (met "
                f"something, or its halls lost counts); clear its way and calibrate again",
                finger=finger.index)
        fits[finger.index] = fit
        for board, board_cal in fit.boards.items():
            cal.boards[board_key(finger.index, board)] = board_cal
    return cal, fits


@dataclass
class CalibrationChoice:
    """Which calibration a program uses: ``calibration`` (None: the nominal mounting),
    ``path`` it came from, and the ``warnings`` its user must see (one line each)."""

    calibration: HandCalibration | None
    path: Path | None
    warnings: list[str] = field(default_factory=list)
    created_utc: str | None = None

    def summary(self) -> str:
        """The one line a program prints: which calibration its estimates use."""
        if self.calibration is None:
            return "calibration: none (accelerometers on their nominal mounting)"
        boards = len(self.calibration.boards)
        return (f"calibration: {self.path} (hand, {boards} boards, made "
                f"{self.created_utc})")


#: ``--calibration none``: no file, no warning.
NO_CALIBRATION: Final = "none"


def choose_calibration(robot_serial: str, choice: str | os.PathLike[str] | None = None,
                       firmware: str | None = None) -> CalibrationChoice:
    """The hand calibration to use for robot ``robot_serial``: ``choice`` None (the file
    at :func:`~host.estimation.calibration_file.default_path`), ``"none"`` (the nominal
    mounting, asked for: no warning) or a file's path.  Missing, another robot's, an older
    format or made on older firmware than ``firmware``: a warning (another robot's file is
    not used).  A file that is not one raises :class:`~host.errors.CalibrationFileError`."""
    if choice is not None and str(choice) == NO_CALIBRATION:
        return CalibrationChoice(None, None)
    path = default_path(robot_serial) if choice is None else Path(choice)
    found, warnings = find(robot_serial, path, section="hand", firmware=firmware)
    section = None if found is None else found.section("hand")
    if found is None or section is None:
        return CalibrationChoice(None, path, warnings)
    try:
        cal = HandCalibration.from_section(section, str(path))
    except UsageError as exc:
        raise CalibrationFileError(str(exc), path=path) from None  # names the file
    return CalibrationChoice(cal, path, warnings, str(section.get("created_utc")))
