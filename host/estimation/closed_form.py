"""Closed-form joint angles of a finger at rest from its three accelerometers.

Point estimates of the dissertation's section 4.3.2 (one set of readings, no filtering):

- **J2 (F2–F3, the 1-DOF case)**: the difference of the arctangents of the two gravity
  vectors projected into the plane orthogonal to the joint axis.
- **J0, J1 (F0–F2, the 2-DOF case)**: with ``b = Rz(−q0)·α0`` the F0 reading turned through
  J0, the F2 reading is ``α2 = Ry(q1)·b`` (eq. 4.10–4.12 in this finger's conventions: J0
  about ``+z``, J1 about ``−y``, so the dissertation's ``θ = q0`` and ``φ = −q1``).  The
  middle row ``α2y = α0y·cos q0 − α0x·sin q0`` has the form ``a cos ψ + b sin ψ = c``
  (eq. 4.4), solved by eq. 4.9 into up to two roots for q0 (eq. 4.13); each gives two roots
  of the top row for q1 (eq. 4.14), of which one also satisfies the bottom row.
  :func:`proximal_candidates` returns every root; the estimate keeps those consistent with
  the whole of eq. 4.12, within the joint's range, nearest the previous estimate.

A joint whose axis is close to vertical (gravity nearly parallel to it) is not observable:
the projection of gravity onto the plane orthogonal to the axis drowns in noise (the
dissertation, section 4.3).  Such a joint is reported as :class:`Unobservable`, with its
name and how far its axis is from vertical, instead of an angle.  J1 and J2 are parallel,
so they become unobservable together; J1 stays observable when J0 is not (the F0–F2
relation then no longer depends on q0).

Readings are 3-vectors in any unit (counts, g) in their *segment's* frame
(:func:`host.estimation.finger_gravity.to_segment`); only their directions matter.  Angles in rad.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from host.errors import HostError, UsageError
from host.estimation.finger_gravity import Vector, to_segment
from protocol.robot import FINGER_JOINT_AXES, FINGER_JOINT_NAMES, FINGER_JOINT_STOPS

if tuple(map(tuple, FINGER_JOINT_AXES)) != ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.0, -1.0, 0.0)):
    raise ImportError("host.estimation.closed_form derives its formulas for J0 about +z and "
                      "J1, J2 about -y; protocol.robot.FINGER_JOINT_AXES changed")

#: Default smallest angle between a joint axis and the vertical for the joint to be
#: estimated (rad): at 20° the projection of gravity is 0.34 g, so 2 mg of noise moves the
#: angle by about 0.3°.
DEFAULT_MIN_AXIS_TILT_RAD: Final = math.radians(20.0)
#: Slack on the joint stops when choosing among roots (rad).
LIMIT_MARGIN_RAD: Final = 0.05
#: A root of eq. 4.9 is kept while ``|c|`` exceeds ``r`` by at most this fraction (noise).
TANGENT_SLACK: Final = 0.02


#: The finger's accelerometers by board, as messages name them.
ACCEL_BOARDS: Final = {"fmcb": "motor module (fmcb)", "f2": "proximal phalange (f2)",
                       "f3": "distal phalange (f3)"}


def plain(vector: Vector | None) -> list[float] | None:
    """``vector`` as a list of plain floats, for messages (never ``np.float64(…)``)."""
    return None if vector is None else [float(v) for v in np.asarray(vector, dtype=float)]


class NoAccelerationError(HostError):
    """Accelerometer readings are missing or zero (no direction): their boards are
    unpowered, do not answer, or are not polled (the robot's state, not the caller's
    mistake).  ``boards`` names them (``"f2"`` …),
    ``readings`` holds what was read (plain floats, None where missing)."""

    def __init__(self, boards: Sequence[str], readings: Mapping[str, list[float] | None],
                 message: str | None = None) -> None:
        parts = [f"the {ACCEL_BOARDS.get(b, b)}"
                 + ("" if readings.get(b) is None else f" ({readings[b]})") for b in boards]
        super().__init__(message or "no acceleration from " + " and ".join(parts))
        self.boards = tuple(boards)
        self.readings = dict(readings)


def has_direction(vector: Vector | None) -> bool:
    """Whether an accelerometer reading is there, finite and not zero."""
    if vector is None:
        return False
    a = np.asarray(vector, dtype=float)
    n = float(np.linalg.norm(a)) if a.size else 0.0
    return n > 0.0 and math.isfinite(n)


def joint_label(joint: int) -> str:
    """``"J1 (proximal)"``: the joint's firmware index and name."""
    return f"J{joint} ({FINGER_JOINT_NAMES[joint]})"


@dataclass(frozen=True)
class Unobservable:
    """Joint ``joint`` (0..2) cannot be estimated: its axis is ``tilt_rad`` from the vertical,
    less than the ``min_tilt_rad`` asked for."""

    joint: int
    tilt_rad: float
    min_tilt_rad: float

    @property
    def name(self) -> str:
        return joint_label(self.joint)

    def __str__(self) -> str:
        return (f"{self.name} is unobservable: its axis is {math.degrees(self.tilt_rad):.1f}° "
                f"from vertical (needs at least {math.degrees(self.min_tilt_rad):.0f}°), so "
                f"gravity says nothing about its angle; turn the hand so this axis is "
                f"closer to horizontal")


class UnobservableJointError(UsageError):
    """An estimate was required of a joint whose axis is too close to vertical."""

    def __init__(self, finger: int | None, problems: Sequence[Unobservable]) -> None:
        where = "" if finger is None else f"finger {finger}: "
        super().__init__(where + "; ".join(str(p) for p in problems))
        self.finger = finger
        self.problems = tuple(problems)


@dataclass(frozen=True)
class InertialEstimate:
    """Joint angles (rad, J0 J1 J2; None where unobservable) from one set of readings.

    ``unobservable`` names the joints that could not be estimated; ``candidates`` every
    (q0, q1) pair satisfying eq. 4.12 within the joint stops; ``ambiguous`` when more than
    one was left and no previous estimate chose between them (the one nearest zero is
    given)."""

    q: tuple[float | None, float | None, float | None]
    unobservable: tuple[Unobservable, ...] = ()
    candidates: tuple[tuple[float, float], ...] = ()
    ambiguous: bool = False
    tilt_rad: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))

    @property
    def observable(self) -> bool:
        """Every joint has an angle."""
        return not self.unobservable

    def require(self, finger: int | None = None) -> tuple[float, float, float]:
        """All three angles (rad), or :class:`UnobservableJointError` naming the joints."""
        if self.unobservable:
            raise UnobservableJointError(finger, self.unobservable)
        q0, q1, q2 = self.q
        assert q0 is not None and q1 is not None and q2 is not None
        return (q0, q1, q2)


def wrap(angle: float) -> float:
    """``angle`` (rad) in (−π, π]."""
    return math.atan2(math.sin(angle), math.cos(angle))


def solve_trig(a: float, b: float, c: float, slack: float = TANGENT_SLACK) -> list[float]:
    """Every ψ (rad, wrapped) with ``a cos ψ + b sin ψ = c`` (the dissertation, eq. 4.4–4.9).

    ``r = √(a² + b²)``; no root when ``|c| > r·(1 + slack)`` (or r = 0), one when
    ``|c| ≥ r`` (clamped: noise pushed a tangent root over), two otherwise.
    """
    r = math.hypot(a, b)
    if r == 0.0 or abs(c) > r * (1.0 + slack):
        return []
    c = max(-r, min(r, c))
    gamma = math.atan2(a, b)
    root = math.sqrt(max(0.0, r * r - c * c))
    first = wrap(math.atan2(c, root) - gamma)
    if root == 0.0:
        return [first]
    return [first, wrap(math.atan2(c, -root) - gamma)]


def _unit(v: Vector) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(a))
    if n == 0.0 or not math.isfinite(n):
        raise UsageError(f"an accelerometer reading of {plain(a)} has no direction")
    return a / n


def axis_tilt(up: np.ndarray, axis: Vector) -> float:
    """Angle (rad, 0..π/2) between a joint axis and the vertical, both in one frame."""
    cos = abs(float(np.dot(up, _unit(axis))))
    return math.acos(min(1.0, cos))


def distal_angle(a2: Vector, a3: Vector,
                 min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD) -> float | Unobservable:
    """J2 (rad) from the F2 and F3 readings (segment frames): the 1-DOF closed form.

    J2 turns F3 about ``u = −y`` of F2, so ``α2 = R(u, q2)·α3``; q2 is the angle from α3's
    projection onto the plane ⟂ u to α2's, i.e. the difference of their arctangents in the
    x–z plane.
    """
    u2, u3 = _unit(a2), _unit(a3)
    tilt = axis_tilt(u2, FINGER_JOINT_AXES[2])
    if tilt < min_tilt_rad:
        return Unobservable(2, tilt, min_tilt_rad)
    return wrap(math.atan2(u2[2], u2[0]) - math.atan2(u3[2], u3[0]))


def eq_4_13_roots(a0: Vector, a2: Vector) -> list[float]:
    """The up to two q0 (rad) of eq. 4.13: middle row of eq. 4.12, ``a = α0y``,
    ``b = −α0x``, ``c = α2y`` (unit readings, segment frames)."""
    u0, u2 = _unit(a0), _unit(a2)
    return solve_trig(float(u0[1]), float(-u0[0]), float(u2[1]))


def eq_4_14_roots(a0: Vector, a2: Vector, q0: float) -> list[float]:
    """The up to two q1 (rad) of eq. 4.14 for a given q0: top row of eq. 4.12,
    ``α2x = bx·cos q1 + bz·sin q1`` with ``b = Rz(−q0)·α0``."""
    u0, u2 = _unit(a0), _unit(a2)
    bx = math.cos(q0) * u0[0] + math.sin(q0) * u0[1]
    return solve_trig(float(bx), float(u0[2]), float(u2[0]))


def _proximal_q1(u0: np.ndarray, u2: np.ndarray, q0: float) -> float:
    """q1 (rad) for a given q0 from the top and bottom rows of eq. 4.12 together (the root
    of eq. 4.14 consistent with the bottom row, least squares under noise)."""
    bx = math.cos(q0) * u0[0] + math.sin(q0) * u0[1]
    return wrap(math.atan2(u0[2], bx) - math.atan2(u2[2], u2[0]))


def eq_4_12_residual(a0: Vector, a2: Vector, q0: float, q1: float) -> float:
    """``|α2 − Ry(q1)·Rz(−q0)·α0|`` for unit readings: 0 for an exact root of eq. 4.12."""
    u0, u2 = _unit(a0), _unit(a2)
    c0, s0, c1, s1 = math.cos(q0), math.sin(q0), math.cos(q1), math.sin(q1)
    bx, by, bz = c0 * u0[0] + s0 * u0[1], -s0 * u0[0] + c0 * u0[1], u0[2]
    pred = np.array([c1 * bx + s1 * bz, by, -s1 * bx + c1 * bz])
    return float(np.linalg.norm(u2 - pred))


def proximal_candidates(a0: Vector, a2: Vector
                        ) -> list[tuple[float, float, float]]:
    """Every root (q0, q1, residual of eq. 4.12) of eq. 4.13 × eq. 4.14: up to four, of
    which the exact solutions have a residual near zero."""
    out = []
    for q0 in eq_4_13_roots(a0, a2):
        for q1 in eq_4_14_roots(a0, a2, q0):
            out.append((q0, q1, eq_4_12_residual(a0, a2, q0, q1)))
    return out


def _within(q: float, joint: int) -> bool:
    lo, hi = FINGER_JOINT_STOPS[joint]
    return lo - LIMIT_MARGIN_RAD <= q <= hi + LIMIT_MARGIN_RAD


def estimate(readings: Mapping[str, Vector],
             previous: Sequence[float | None] | np.ndarray | None = None,
             min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD) -> InertialEstimate:
    """Joint angles from the boards' readings at rest (``"fmcb"``, ``"f2"``, ``"f3"``: each
    board's own axes, any unit; the mounting of :func:`protocol.robot.accel_mount_rotation`
    is undone here).  ``previous`` (rad, None entries allowed) picks among roots
    (continuity) and stands in for an unobservable J0 when computing J1.  A reading that is
    missing or zero raises :class:`NoAccelerationError` naming its boards.
    """
    silent = [b for b in ACCEL_BOARDS if not has_direction(readings.get(b))]
    if silent:
        raise NoAccelerationError(silent, {b: plain(readings.get(b)) for b in silent})
    u0 = _unit(to_segment("fmcb", readings["fmcb"]))
    u2 = _unit(to_segment("f2", readings["f2"]))
    u3 = _unit(to_segment("f3", readings["f3"]))
    prev = list(previous) if previous is not None else [None, None, None]
    tilts = (axis_tilt(u0, FINGER_JOINT_AXES[0]), axis_tilt(u2, FINGER_JOINT_AXES[1]),
             axis_tilt(u2, FINGER_JOINT_AXES[2]))
    problems: list[Unobservable] = []
    q: list[float | None] = [None, None, None]
    candidates: list[tuple[float, float]] = []
    ambiguous = False
    j1_observable = tilts[1] >= min_tilt_rad
    if tilts[0] < min_tilt_rad:
        problems.append(Unobservable(0, tilts[0], min_tilt_rad))
        if j1_observable:
            q0_guess = prev[0] if prev[0] is not None else 0.0
            q1 = _proximal_q1(u0, u2, q0_guess)
            candidates = [(q0_guess, q1)]
            q[1] = q1
    else:
        roots = [(q0, _proximal_q1(u0, u2, q0)) for q0 in eq_4_13_roots(u0, u2)]
        candidates = [(q0, q1) for q0, q1 in roots if _within(q0, 0) and _within(q1, 1)]
        if not candidates:
            candidates = roots  # nothing fits the stops (miscalibration?): keep them all
        if candidates:
            if prev[0] is not None:
                p0, p1 = prev[0], prev[1] if prev[1] is not None else 0.0
                best = min(candidates, key=lambda c: abs(wrap(c[0] - p0))
                           + abs(wrap(c[1] - p1)))
            else:
                best = min(candidates, key=lambda c: abs(c[0]))
                ambiguous = len(candidates) > 1 and abs(
                    wrap(candidates[0][0] - candidates[1][0])) > 2 * LIMIT_MARGIN_RAD
            q[0] = best[0]
            q[1] = best[1] if j1_observable else None
    if not j1_observable:
        problems.append(Unobservable(1, tilts[1], min_tilt_rad))
    d = distal_angle(u2, u3, min_tilt_rad)
    if isinstance(d, Unobservable):
        problems.append(d)
    else:
        q[2] = d
    return InertialEstimate((q[0], q[1], q[2]), tuple(problems), tuple(candidates),
                            ambiguous, tilts)
