"""Calibrating the hand's accelerometers on the robot: the poses, the readings, the fit.

The fingers are moved together (unhomed, their halls relative) through
:data:`CALIBRATION_POSES`, each pose in its own finger's frame: all commanded, all waited
for until settled, all idled, left to rest and read (six status samples each, averaged as
:func:`host.hand.homing.read_at_rest` does), then pushed together onto the joint stops of
:data:`STOP_TOUCHES` (each push the one a finger alone gets) and read resting on each; :func:`host.estimation.hand_calibration.fit_finger` fits its three boards and its hall
offsets (the model and what it can and cannot observe: that module).  The finger is left
idle near straight (J1 0.2, J2 0.1 rad), where homing sees its joints.  :func:`choose_calibration` is which file a program then uses.  Angles in rad,
readings in counts.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
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
from host.hand.homing import (
    DEFAULT_SAMPLES,
    SAMPLE_INTERVAL_S,
    InertialReading,
    averaged,
)
from host.hand.interface import FingerOwner, HandFinger
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
    """What calibrating uses of a finger: moving it, idling it, its fmcb's parameters, and
    the hand it belongs to (whose :meth:`~host.hand.facade.Hand.wait_settled` waits for
    several fingers at once)."""

    @property
    def hand(self) -> FingerOwner:
        """The hand the finger belongs to."""
        ...

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

    def idle(self) -> None:
        """Motors off."""
        ...


#: Tries of a request the palm refuses as busy (its queue for the finger full, as after a
#: move that timed out on a loaded link), :data:`BUSY_WAIT_S` apart.
BUSY_TRIES: Final = 5
BUSY_WAIT_S: Final = 0.1
#: How long a calibration move waits for the fingers to settle (s, the link's clock).
MOVE_TIMEOUT_S: Final = 2.0
T = TypeVar("T")
Touch = tuple[int, int, Sequence[float], Sequence[float]]


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


def _move_together(fingers: Sequence[CalibratingFinger], pose: Sequence[float]) -> None:
    """Command every finger of ``fingers`` to ``pose`` (rad, unhomed, effort
    :data:`EFFORT`), then wait until all of them settle, or all stop moving, or
    :data:`MOVE_TIMEOUT_S`.  A finger that cannot get there stays where it stopped (its
    halls say where); a refused command does not stop the others' move."""
    for finger in fingers:
        try:
            _when_free(finger, partial(finger.command, pose, effort=EFFORT, unhomed=True))
        except HostError:
            pass
    try:
        fingers[0].hand.wait_settled([f.index for f in fingers], MOVE_TIMEOUT_S)
    except HostError:
        pass


def _idle_all(fingers: Sequence[CalibratingFinger]) -> None:
    """Motors off on every finger of ``fingers``."""
    for finger in fingers:
        _when_free(finger, finger.idle)


def _statuses(fingers: Sequence[CalibratingFinger]) -> list[dict[str, Any]]:
    """One ``fmcb.status`` of each finger, asked in one pipelined round (the palm has a
    queue per finger)."""
    pending = [finger.motor.start("fmcb.status") for finger in fingers]
    out = []
    for finger, p in zip(fingers, pending, strict=True):
        try:
            out.append(finger.motor.session.wait(p))
        except RouteError as exc:
            if exc.status != RouteStatus.BUSY:
                raise
            out.append(_when_free(finger, partial(finger.motor.request, "fmcb.status")))
    return out


def _read_together(fingers: Sequence[CalibratingFinger]) -> list[FingerSample]:
    """Every finger of ``fingers`` read at rest, all at once: :data:`DEFAULT_SAMPLES`
    status rounds :data:`SAMPLE_INTERVAL_S` apart, each finger's averaged as
    :func:`host.hand.homing.read_at_rest` averages them."""
    session = fingers[0].motor.session
    rounds = []
    for k in range(DEFAULT_SAMPLES):
        if k:
            session.sleep(SAMPLE_INTERVAL_S)
        rounds.append(_statuses(fingers))
    return [_sample(averaged([r[n] for r in rounds])) for n in range(len(fingers))]


def _sample(reading: InertialReading, at_stop: tuple[int, float] | None = None
            ) -> FingerSample:
    return FingerSample(motor_to_joint(reading.hall_pos),
                        {b: v.tolist() for b, v in reading.as_dict().items()}, at_stop=at_stop)


def gather_fingers(fingers: Sequence[CalibratingFinger],
                   poses: Sequence[Sequence[float]] = CALIBRATION_POSES,
                   progress: Progress | None = None,
                   rest_s: float = REST_S) -> dict[int, list[FingerSample]]:
    """Move ``fingers`` (of one hand) through ``poses`` together and read each at rest at
    each pose (the fingers are independent: each takes the pose in its own frame); each
    finger's samples by its index.  ``progress(finger, done, total)`` after each pose.  A
    pose a finger cannot reach is read where it stopped (the halls say where)."""
    samples: dict[int, list[FingerSample]] = {f.index: [] for f in fingers}
    if not fingers:
        return samples
    session = fingers[0].motor.session
    for k, pose in enumerate(poses):
        _move_together(fingers, pose)
        _idle_all(fingers)
        session.sleep(rest_s)
        for finger, sample in zip(fingers, _read_together(fingers), strict=True):
            samples[finger.index].append(sample)
            if progress is not None:
                progress(finger.index, k + 1, len(poses))
    return samples


def gather_finger(finger: CalibratingFinger, poses: Sequence[Sequence[float]] = CALIBRATION_POSES,
                  progress: Progress | None = None,
                  rest_s: float = REST_S) -> list[FingerSample]:
    """:func:`gather_fingers` of one finger."""
    return gather_fingers([finger], poses, progress, rest_s)[finger.index]


#: The fmcb parameters of the joint limits a stop touch widens.
_LIMIT_PARAMS: Final = tuple(f"joint_{end}_{j}" for j in range(3) for end in ("lower", "upper"))


def touch_stops_together(fingers: Sequence[CalibratingFinger], progress: Progress | None = None,
                         touches: Sequence[Touch] = STOP_TOUCHES,
                         j0_observable: Mapping[int, bool] | None = None
                         ) -> dict[int, list[FingerSample]]:
    """Push ``fingers`` against each stop of ``touches`` together (J0's only for the
    fingers ``j0_observable`` says; default all), each finger's firmware joint limits
    widened meanwhile and restored after; one sample of each finger resting against each
    stop it touched (``at_stop`` set), by finger index.  Each push is the one a finger
    alone gets: :data:`STOP_EFFORT` for :data:`STOP_PUSH_S`, then idle."""
    observable = j0_observable or {}
    chosen = {f.index: [t for t in touches if observable.get(f.index, True) or t[0] != 0]
              for f in fingers}
    samples: dict[int, list[FingerSample]] = {f.index: [] for f in fingers}
    if not fingers:
        return samples
    session = fingers[0].motor.session
    saved = {f.index: {n: f.params.get(n) for n in _LIMIT_PARAMS} for f in fingers}
    try:
        for f in fingers:
            for n in _LIMIT_PARAMS:
                f.params.set(n, STOP_LIMIT_RAD if "upper" in n else -STOP_LIMIT_RAD)
        for touch in touches:
            joint, end, start, push = touch
            group = [f for f in fingers if touch in chosen[f.index]]
            if not group:
                continue
            _move_together(group, start)
            for f in group:
                _when_free(f, partial(f.command, push, relative=True, effort=STOP_EFFORT,
                                      unhomed=True))
            session.sleep(STOP_PUSH_S)
            _idle_all(group)
            session.sleep(REST_S)
            stop = FINGER_JOINT_STOPS[joint][end]
            for f, sample in zip(group, _read_together(group), strict=True):
                _check_on_stop(f.index, joint, stop, sample.readings)
                samples[f.index].append(replace(sample, at_stop=(joint, stop)))
                if progress is not None:
                    progress(f.index, len(samples[f.index]), len(chosen[f.index]))
        # off the last stop, back where homing sees every joint (each finger's first start)
        back: dict[tuple[float, ...], list[CalibratingFinger]] = {}
        for f in fingers:
            if chosen[f.index]:
                back.setdefault(tuple(chosen[f.index][0][2]), []).append(f)
        for pose, group in back.items():
            _move_together(group, pose)
    finally:
        _idle_all(fingers)
        for f in fingers:
            for n, v in saved[f.index].items():
                f.params.set(n, v)
    return samples


def touch_stops(finger: CalibratingFinger, progress: Progress | None = None,
                touches: Sequence[Touch] = STOP_TOUCHES,
                j0_observable: bool = True) -> list[FingerSample]:
    """:func:`touch_stops_together` of one finger."""
    return touch_stops_together([finger], progress, touches,
                                {finger.index: j0_observable})[finger.index]


def _check_on_stop(finger: int, joint: int, stop: float, readings: Mapping[str, Any]) -> None:
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
    """Gather ``fingers`` (of one hand) together (the poses, then, with ``stops``,
    :data:`STOP_TOUCHES`: every finger moved, settled, idled and read at once, so four take
    the time of one) and fit each; the hand's calibration and each fit.
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

    gathered = gather_fingers(fingers, poses, told(0))
    if stops:
        observable = {k: _j0_observable(v) for k, v in gathered.items()}
        touched = touch_stops_together(fingers, told(len(poses)), j0_observable=observable)
        for finger in fingers:
            gathered[finger.index] += touched[finger.index]
            if progress is not None and len(touched[finger.index]) < len(STOP_TOUCHES):
                progress(finger.index, total, total)
    for finger in fingers:
        fit = fit_samples(gathered[finger.index])
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
