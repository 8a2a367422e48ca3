"""Homing the hand's fingers from their accelerometers (the dissertation, section 4.4).

The fmcb counts hall transitions from wherever the motors were at power-up, so its joint
angles mean nothing until the host tells it the hall counts of a known pose
(``fmcb.set_home``: the raw counts that are the new zero of each motor).  With the finger
at rest in any pose where no joint axis is near vertical, the accelerometers on F0, F2 and
F3 give the pose in closed form (:mod:`host.estimation.closed_form`); the offsets are then
``raw − joint_to_motor(q)`` (hall counts, :func:`protocol.robot.joint_to_motor`).

A finger is not homed when a joint axis is within
:data:`~host.estimation.closed_form.DEFAULT_MIN_AXIS_TILT_RAD` of vertical (the error names
the joint), when two poses fit the readings equally (move it nearer to straight and retry),
or when it moves while being read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from host.errors import (
    AmbiguousPoseError,
    FingerMovingError,
    HostError,
    UsageError,
    why_no_answer,
)
from host.estimation.closed_form import (
    ACCEL_BOARDS,
    DEFAULT_MIN_AXIS_TILT_RAD,
    InertialEstimate,
    NoAccelerationError,
    UnobservableJointError,
    estimate,
)
from host.estimation.hand_calibration import HandCalibration
from host.hand.interface import HandFinger, LinkedHand
from protocol.robot import joint_to_motor

#: Status samples averaged per estimate, and their spacing (s): the fmcb samples its own
#: accelerometer every 40 ms, the phalanges' arrive every 10 ms.
DEFAULT_SAMPLES: Final = 6
SAMPLE_INTERVAL_S: Final = 0.04
#: A finger is "at rest" while its motors move less than this (hall counts) and its
#: accelerometers' readings spread less than :data:`STILL_ACCEL_COUNTS` (counts, std).
STILL_HALL_COUNTS: Final = 2
STILL_ACCEL_COUNTS: Final = 15.0
#: How long (s, the link's clock) homing reads a finger again while it moves before it
#: refuses (:class:`FingerMovingError`): a hand on the arm is shaken for a second or two after
#: the arm's moves (the wrist servos hunting by a position unit under the hand's weight,
#: ±20-30 mg on the accelerometers), which refused one or two fingers in half the runs of
#: "arm move, then hand home" pasted as the guide gives it.
REST_WAIT_S: Final = 3.0


@dataclass
class InertialReading:
    """Averaged accelerometer readings (counts, each board's axes) of one finger at rest,
    its homing-relative and raw motor positions (hall counts) when read, and the largest
    standard deviation of any accelerometer axis over the samples (counts)."""

    fmcb: np.ndarray
    f2: np.ndarray
    f3: np.ndarray
    hall_pos: list[int]
    spread_counts: float
    hall_moved: int
    samples: int

    def as_dict(self) -> dict[str, np.ndarray]:
        return {"fmcb": self.fmcb, "f2": self.f2, "f3": self.f3}


def accels_from_status(status: dict[str, Any]) -> dict[str, list[int]]:
    """The three accelerometers (counts) in one ``fmcb.status``."""
    return {"fmcb": list(status["fmcb_imu"][:3]), "f2": list(status["pp_imu"][:3]),
            "f3": list(status["dp_imu"][:3])}


def read_at_rest(finger: HandFinger, samples: int = DEFAULT_SAMPLES,
                 interval_s: float = SAMPLE_INTERVAL_S) -> InertialReading:
    """Average ``samples`` status snapshots ``interval_s`` apart (the link's clock)."""
    statuses: list[dict[str, Any]] = []
    session = finger.motor.session
    for k in range(max(1, samples)):
        if k:
            session.sleep(interval_s)
        statuses.append(finger.motor.request("fmcb.status"))
    return averaged(statuses)


def averaged(statuses: Sequence[dict[str, Any]]) -> InertialReading:
    """One finger's ``fmcb.status`` snapshots (at least one) as one averaged reading: the
    accelerometers' means (counts), the last motor positions (hall counts), their spread."""
    rows = [accels_from_status(s) for s in statuses]
    halls = [[int(v) for v in s["hall_pos"]] for s in statuses]
    stacked = {b: np.array([r[b] for r in rows], dtype=float) for b in ("fmcb", "f2", "f3")}
    hall = np.array(halls)
    return InertialReading(
        stacked["fmcb"].mean(axis=0), stacked["f2"].mean(axis=0), stacked["f3"].mean(axis=0),
        halls[-1], max(float(v.std(axis=0).max()) for v in stacked.values()),
        int((hall.max(axis=0) - hall.min(axis=0)).max()), len(rows))


def corrected(finger: int, readings: dict[str, Any],
              calibration: HandCalibration | None) -> dict[str, Any]:
    """``readings`` of finger ``finger`` corrected by ``calibration`` (unchanged without)."""
    return readings if calibration is None else calibration.correct(finger, readings)


def inertial_estimate(finger: HandFinger, samples: int = DEFAULT_SAMPLES,
                      previous: Sequence[float | None] | None = None,
                      min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD,
                      calibration: HandCalibration | None = None) -> InertialEstimate:
    """The finger's joint angles (rad) from its accelerometers now (closed form), their
    readings corrected by ``calibration`` (:mod:`host.estimation.hand_calibration`)."""
    readings = corrected(finger.index, dict(read_at_rest(finger, samples).as_dict()),
                         calibration)
    return estimate(readings, previous, min_tilt_rad)


@dataclass
class HomeResult:
    """One finger's homing: ``homed``, the pose it was homed at (``joints``, rad), the
    offsets sent (raw hall counts), or ``problem`` (why not); ``unobservable`` names the
    joints (0..2) refused because their axes are too close to vertical (turning the hand
    helps, nothing else does)."""

    finger: int
    homed: bool
    joints: tuple[float, float, float] | None = None
    offsets: list[int] = field(default_factory=list)
    problem: str | None = None
    unobservable: tuple[int, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"finger": self.finger, "homed": self.homed,
                "joints": None if self.joints is None else [round(q, 6) for q in self.joints],
                "offsets": list(self.offsets), "problem": self.problem,
                "unobservable": list(self.unobservable)}


def _still(reading: InertialReading) -> bool:
    """Whether ``reading`` was taken at rest (see :data:`STILL_HALL_COUNTS`)."""
    return (reading.hall_moved <= STILL_HALL_COUNTS
            and reading.spread_counts <= STILL_ACCEL_COUNTS)


def home_finger(finger: HandFinger, samples: int = DEFAULT_SAMPLES,
                min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD,
                wait_s: float = REST_WAIT_S,
                calibration: HandCalibration | None = None) -> HomeResult:
    """Home ``finger`` from its accelerometers (corrected by ``calibration`` when given);
    raises (:class:`UnobservableJointError`,
    :class:`AmbiguousPoseError`, :class:`FingerMovingError`) instead of guessing.  A finger
    that moves while being read is read again until it is still, for up to ``wait_s``
    (s, the link's clock)."""
    reading = read_at_rest(finger, samples)
    reads = math.ceil(max(wait_s, 0.0) / (max(1, samples) * SAMPLE_INTERVAL_S))
    for _ in range(reads):
        if _still(reading):
            break
        reading = read_at_rest(finger, samples)
    if not _still(reading):
        raise FingerMovingError(
            f"finger {finger.index} moved while being read (motors {reading.hall_moved} "
            f"hall counts, accelerometers ±{reading.spread_counts:.0f} mg) for "
            f"{wait_s:g} s; let it come to rest (idle it) and home again")
    try:
        found = estimate(corrected(finger.index, dict(reading.as_dict()), calibration), None,
                         min_tilt_rad)
    except NoAccelerationError as exc:
        raise NoAccelerationError(exc.boards, exc.readings,
                                  message=_silent_boards(finger, exc)) from None
    q = found.require(finger.index)
    if found.ambiguous:
        alt = ", ".join(f"J0 {a:+.2f} J1 {b:+.2f}" for a, b in found.candidates)
        raise AmbiguousPoseError(
            f"finger {finger.index}: two poses fit its accelerometers ({alt} rad); move J0 "
            f"and J1 nearer to straight (0) and home again")
    raw = [int(v) for v in finger.motor.request("fmcb.hall_counts", {"raw": 1})["counts"]]
    # The motors stood still while being read, so the raw counts now belong to that pose.
    offsets = [r - round(m) for r, m in zip(raw, joint_to_motor(q), strict=True)]
    finger.set_home(offsets)
    return HomeResult(finger.index, True, q, offsets)


def _silent_boards(finger: HandFinger, exc: NoAccelerationError) -> str:
    """Why ``finger``'s accelerometers in ``exc`` read nothing and what to do: a phalange
    is asked whether it answers (unpowered phalanges are the usual cause after power-up)."""
    nodes = {"f2": finger.proximal, "f3": finger.distal}
    silent: list[tuple[str, str]] = []
    unpolled: list[str] = []
    broken: list[str] = []
    for board in exc.boards:
        name = ACCEL_BOARDS.get(board, board)
        node = nodes.get(board)
        if node is None:
            broken.append(f"the {name} reads {exc.readings.get(board)}")
            continue
        try:
            node.request("ping", retries=0)
            unpolled.append(f"the {name}")
        except HostError as exc_ping:
            silent.append((f"the {name}", why_no_answer(exc_ping)))
    parts = []
    if silent:
        parts.append(" and ".join(name for name, _ in silent)
                     + (" does" if len(silent) == 1 else " do") + " not answer ("
                     + ", ".join(sorted({why for _, why in silent})) + "), so there is no "
                     "acceleration to home from; power the phalanges: `handctl up` "
                     "(Hand.bring_up)")
    if unpolled:
        parts.append(" and ".join(unpolled) + (" answers" if len(unpolled) == 1 else
                                               " answer")
                     + " but the fmcb reads no acceleration from it: switch the fmcb's "
                       "autopoll on: `handctl up` (Hand.bring_up)")
    if broken:
        parts.append(" and ".join(broken) + ": its accelerometer gives no reading")
    return f"finger {finger.index}: " + "; ".join(parts)


def home(hand: LinkedHand, finger: int | None = None, samples: int = DEFAULT_SAMPLES,
         min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD,
         calibration: HandCalibration | None = None) -> list[HomeResult]:
    """Home one finger (errors raised) or every finger (``None``: one :class:`HomeResult`
    each, ``problem`` saying why a finger was not homed); the accelerometers corrected by
    ``calibration`` when given."""
    if finger is not None:
        if not 0 <= finger < len(hand.fingers):
            raise UsageError(f"finger {finger}: the hand has fingers 0..{len(hand.fingers) - 1}")
        return [home_finger(hand.fingers[finger], samples, min_tilt_rad,
                            calibration=calibration)]
    results = []
    for f in hand.fingers:
        try:
            results.append(home_finger(f, samples, min_tilt_rad, calibration=calibration))
        except UnobservableJointError as exc:
            results.append(HomeResult(f.index, False, problem=str(exc),
                                      unobservable=tuple(p.joint for p in exc.problems)))
        except HostError as exc:
            results.append(HomeResult(f.index, False, problem=str(exc)))
    return results


def homed_on_robot(finger: HandFinger) -> bool:
    """Whether the fmcb holds homing offsets (raw and homing-relative counts differ): it
    keeps them until it resets, so another program's homing counts too."""
    raw = finger.motor.request("fmcb.hall_counts", {"raw": 1})["counts"]
    rel = finger.motor.request("fmcb.hall_counts", {"raw": 0})["counts"]
    return list(raw) != list(rel)


__all__ = ["AmbiguousPoseError", "corrected", "FingerMovingError", "HomeResult", "InertialReading",
           "NoAccelerationError", "UnobservableJointError", "home", "home_finger", "homed_on_robot",
           "inertial_estimate", "read_at_rest", "REST_WAIT_S"]
