"""The finger module's control law, in one tested place.

The robot's conventions (joint order, hall counts, the tendon coupling, joint limits) are
:mod:`protocol.robot`'s.  Efforts in 1/255 of full PWM (signed, the original's 8-bit PWM),
positions in hall counts, velocities in hall counts/s.

Hall sign convention: a transition forward along :data:`~protocol.robot.HALL_SEQUENCE`
counts +1, and a positive duty drives the motor forward (the plant implements the same
convention).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from protocol.robot import HALL_SEQUENCE

#: Largest effort magnitude (full PWM).
EFFORT_FULL: Final = 255

_HALL_INDEX: Final = {state: i for i, state in enumerate(HALL_SEQUENCE)}

Vec3 = tuple[float, float, float]


class HallCounter:
    """Counts hall transitions of one motor.

    ``update(state)`` takes the 3-bit hall state: a step forward along
    :data:`HALL_SEQUENCE` counts +1, a step back −1; a jump of two or three positions or an
    invalid state (0 or 7) is not counted and increments ``invalid`` (the reference state is
    kept, so counting resumes from the next valid neighbour).
    """

    __slots__ = ("count", "invalid", "_index", "_valid")

    def __init__(self) -> None:
        self.count = 0
        self.invalid = 0
        self._index: int | None = None
        self._valid = False

    def holds(self) -> bool:
        """True when the last state read was valid and counted (a reference is set): reading
        the same state again changes nothing."""
        return self._index is not None and self._valid

    def update(self, state: int) -> int:
        """Account for the hall ``state`` read now; returns the count (hall counts)."""
        idx = _HALL_INDEX.get(state & 7)
        if idx is None:
            self.invalid += 1
            self._valid = False
            return self.count
        if self._index is None:
            self._index = idx
            self._valid = True
            return self.count
        step = (idx - self._index) % 6
        if step == 1:
            self.count += 1
        elif step == 5:
            self.count -= 1
        elif step != 0:
            self.invalid += 1
            self._valid = False
            return self.count
        self._index = idx
        self._valid = True
        return self.count


def min_cap(*caps: int) -> int:
    """The effective effort cap (1/255 PWM): the smallest of all caps, within 0..255."""
    return max(0, min(EFFORT_FULL, *caps))


def clamp_effort(effort: float, cap: int) -> int:
    """``effort`` rounded and clamped to ±``cap`` (1/255 PWM)."""
    e = int(round(effort))
    return cap if e > cap else -cap if e < -cap else e


def pd_effort(error: float, velocity: float, kp: float, kd: float, deadband: float,
              cap: int) -> int:
    """PD on hall counts: effort (1/255 PWM) for a position error and velocity.

    ``error`` = target − position (hall counts), ``velocity`` in hall counts/s; inside the
    deadband (|error| ≤ ``deadband``) the effort is 0, so the motor stops; otherwise
    ``kp·error − kd·velocity`` clamped to ±``cap``.
    """
    if abs(error) <= deadband:
        return 0
    return clamp_effort(kp * error - kd * velocity, cap)


def clamp_joints(q: Sequence[float], lower: Sequence[float], upper: Sequence[float]) -> Vec3:
    """Joint angles (rad) clamped into [lower, upper] per joint."""
    out = [min(max(float(v), lo), hi) for v, lo, hi in zip(q, lower, upper, strict=True)]
    return (out[0], out[1], out[2])
