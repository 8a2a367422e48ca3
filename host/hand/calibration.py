"""Calibrating the hand's accelerometers on the robot: the poses, the readings, the fit.

Each finger is moved (unhomed, its halls relative) through :data:`CALIBRATION_POSES`,
idled, left to rest and read (:func:`host.hand.homing.read_at_rest`, six samples
averaged), then pushed onto the joint stops of :data:`STOP_TOUCHES` and read resting on
each; :func:`host.estimation.hand_calibration.fit_finger` fits its three boards and its hall
offsets (the model and what it can and cannot observe: that module).  The finger is left
idle near straight (J1 0.2, J2 0.1 rad), where homing sees its joints.  :func:`choose_calibration` is which file a program then uses.  Angles in rad,
readings in counts.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Final, Protocol, TypeVar

import numpy as np

from host.errors import (
    CalibrationError,
    CalibrationFileError,
    HostError,
    RouteError,
    UsageError,
)
from host.estimation.calibration_file import default_path, find
from host.estimation.closed_form import DEFAULT_MIN_AXIS_TILT_RAD, axis_tilt, estimate
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
from host.hand.params import FingerParams
from protocol.messages.palm import RouteStatus
from protocol.robot import FINGER_JOINT_AXES, FINGER_JOINT_STOPS, motor_to_joint

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
#: The mechanical stops a finger is pushed against, after its poses: (joint, which end: 0
#: lower, 1 upper, of :data:`protocol.robot.FINGER_JOINT_STOPS`), the pose it starts from
#: (rad) and the push (rad, relative: past the stop).  J1 back, J2 forward with J1 back
#: (the tip away from the palm), J0 out; J0's only where gravity sees J0 (its axis off
#: vertical).  Pushed with :data:`STOP_EFFORT` for :data:`STOP_PUSH_S`, idled, read: the
#: joint rests on its stop (within 0.05° on the emulator) and the halls still count true.
STOP_TOUCHES: Final = ((1, 0, (0.0, 0.2, 0.1), (0.0, -2.0, 0.0)),
                       (2, 1, (0.0, -0.3, 0.1), (0.0, 0.0, 2.0)),
                       (0, 1, (0.0, 0.2, 0.1), (2.0, 0.0, 0.0)))
STOP_EFFORT: Final = 200
STOP_PUSH_S: Final = 4.0
#: The firmware's joint limits are widened to this (rad) while a stop is touched, then put
#: back.
STOP_LIMIT_RAD: Final = 2.2
#: A joint said to rest on its stop whose uncalibrated estimate is further from the stop
#: than this (rad) did not get there (something in the way): refused.  Generous: at J0's
#: stop the uncalibrated estimate of J0 was seen 7° off (seed 3) on a joint resting there.
STOP_CHECK_RAD: Final = math.radians(15.0)
#: Largest residual (counts RMS) a finger's fit may leave: a few times the readings' noise
#: (about 0.7 counts when the poses are what they say).
MAX_RMS_COUNTS: Final = 5.0

Progress = Callable[[int, int, int], None]


class CalibratingFinger(HandFinger, Protocol):
    """What calibrating uses of a finger: moving it, idling it, its fmcb's parameters."""

    @property
    def params(self) -> FingerParams:
        """The fmcb's parameters (its joint limits)."""
        ...

    def command(self, joints: Sequence[float] | None = None, *,
                effort: Sequence[int] | int | None = None, relative: bool = False,
                hall: Sequence[int] | None = None, idle: bool = False,
                unhomed: bool = False) -> None:
        """Send one control command (``relative``: joint deltas, rad)."""
        ...

    def move(self, joints: Sequence[float], *, effort: Sequence[int] | int | None = None,
             timeout: float = 3.0, unhomed: bool = False) -> Any:
        """Move to ``joints`` (rad) and wait until settled (or ``timeout``, s)."""
        ...

    def idle(self) -> None:
        """Motors off."""
        ...


#: Tries of a request the palm refuses as busy (its queue for the finger full, as after a
#: move that timed out on a loaded link), :data:`BUSY_WAIT_S` apart.
BUSY_TRIES: Final = 5
BUSY_WAIT_S: Final = 0.1
T = TypeVar("T")


def _when_free(finger: CalibratingFinger, call: Callable[[], T]) -> T:
    """``call()``, again while the palm answers that the finger's route is busy."""
    for attempt in range(BUSY_TRIES):
        try:
            return call()
        except RouteError as exc:
            if exc.status != RouteStatus.BUSY or attempt == BUSY_TRIES - 1:
                raise
            finger.motor.session.sleep(BUSY_WAIT_S)
    raise AssertionError("unreachable")


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
        _when_free(finger, finger.idle)
        session.sleep(rest_s)
        reading = _when_free(finger, lambda: read_at_rest(finger))
        samples.append(FingerSample(motor_to_joint(reading.hall_pos),
                                    {b: v.tolist() for b, v in reading.as_dict().items()}))
        if progress is not None:
            progress(finger.index, k + 1, len(poses))
    return samples


def touch_stops(finger: CalibratingFinger, progress: Progress | None = None,
                touches: Sequence[tuple[int, int, Sequence[float], Sequence[float]]]
                = STOP_TOUCHES, j0_observable: bool = True) -> list[FingerSample]:
    """Push ``finger`` against each stop of ``touches`` (J0's only if ``j0_observable``),
    its firmware joint limits widened meanwhile and restored after; one sample resting
    against each (``at_stop`` set)."""
    session = finger.motor.session
    chosen = [t for t in touches if j0_observable or t[0] != 0]
    names = [f"joint_{end}_{j}" for j in range(3) for end in ("lower", "upper")]
    saved = {n: finger.params.get(n) for n in names}
    samples = []
    try:
        for n in names:
            finger.params.set(n, STOP_LIMIT_RAD if "upper" in n else -STOP_LIMIT_RAD)
        for k, (joint, end, start, push) in enumerate(chosen):
            try:
                finger.move(start, effort=EFFORT, timeout=2.0, unhomed=True)
            except HostError:
                pass
            _when_free(finger, partial(finger.command, push, relative=True, effort=STOP_EFFORT,
                                       unhomed=True))
            session.sleep(STOP_PUSH_S)
            _when_free(finger, finger.idle)
            session.sleep(REST_S)
            reading = _when_free(finger, lambda: read_at_rest(finger))
            stop = FINGER_JOINT_STOPS[joint][end]
            _check_on_stop(finger.index, joint, stop, reading.as_dict())
            samples.append(FingerSample(motor_to_joint(reading.hall_pos),
                                        {b: v.tolist() for b, v in reading.as_dict().items()},
                                        at_stop=(joint, stop)))
            if progress is not None:
                progress(finger.index, k + 1, len(chosen))
        try:  # off the last stop, back where homing sees every joint
            finger.move(chosen[0][2], effort=EFFORT, timeout=2.0, unhomed=True)
        except HostError:
            pass
    finally:
        _when_free(finger, finger.idle)
        for n, v in saved.items():
            finger.params.set(n, v)
    return samples


def _check_on_stop(finger: int, joint: int, stop: float, readings: dict[str, Any]) -> None:
    """Refuse a stop the joint did not reach: its nominal estimate is within
    :data:`STOP_CHECK_RAD` of the stop if it did."""
    try:
        q = estimate(readings).q[joint]
    except HostError:
        return
    if q is not None and abs(q - stop) > STOP_CHECK_RAD:
        raise CalibrationError(
            f"finger {finger}: J{joint} did not reach its stop at {math.degrees(stop):.0f}° "
            f"(its accelerometers say {math.degrees(q):.0f}°): clear its way and calibrate "
            "again", finger=finger)


def _j0_observable(samples: Sequence[FingerSample]) -> bool:
    """Whether gravity sees the finger's J0 (its axis off vertical by 20° or more)."""
    up = np.mean([to_segment("fmcb", s.readings["fmcb"]) for s in samples], axis=0)
    return bool(axis_tilt(up / np.linalg.norm(up), FINGER_JOINT_AXES[0])
                >= DEFAULT_MIN_AXIS_TILT_RAD)


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
                      poses: Sequence[Sequence[float]] = CALIBRATION_POSES, *,
                      stops: bool = True) -> tuple[HandCalibration, dict[int, FingerFit]]:
    """Gather and fit each finger of ``fingers`` (its poses, then, with ``stops``, its
    :data:`STOP_TOUCHES`); the hand's calibration and each fit.
    Raises :class:`~host.errors.CalibrationError` for a fit worse than
    :data:`MAX_RMS_COUNTS`."""
    cal = HandCalibration(source="this run")
    fits: dict[int, FingerFit] = {}
    total = len(poses) + (len(STOP_TOUCHES) if stops else 0)

    def told(first: int) -> Progress | None:
        if progress is None:
            return None
        report = progress
        return lambda f, done, _n: report(f, first + done, total)

    for finger in fingers:
        samples = gather_finger(finger, poses, told(0))
        if stops:
            touched = touch_stops(finger, told(len(poses)),
                                  j0_observable=_j0_observable(samples))
            samples += touched
            if progress is not None and len(touched) < len(STOP_TOUCHES):
                progress(finger.index, total, total)
        fit = fit_samples(samples)
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
