"""Joint limits as data, and what to do with a command beyond them.

A :class:`JointLimits` holds each finger's lower and upper limits (rad, joint order J0, J1,
J2) and an ``action``: ``"clamp"`` moves an out-of-range target to the nearest limit,
``"refuse"`` raises :class:`~host.errors.UsageError` before anything is sent.  The fmcb
clamps again to its own parameters, so a host policy can only be tighter than the board's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from host.errors import UsageError
from protocol.robot import FINGER_JOINT_LIMITS, FINGER_JOINT_NAMES
from protocol.topology import FINGERS

ACTIONS: Final = ("clamp", "refuse")
#: Joints (and motors) of a finger module.
JOINTS_PER_FINGER: Final = len(FINGER_JOINT_NAMES)

Limits3 = tuple[float, float, float]
#: The robot's default joint limits (rad): the fmcb's ``joint_lower_*`` / ``joint_upper_*``
#: parameter defaults.
DEFAULT_LOWER: Final[Limits3] = (FINGER_JOINT_LIMITS[0][0], FINGER_JOINT_LIMITS[1][0],
                                 FINGER_JOINT_LIMITS[2][0])
DEFAULT_UPPER: Final[Limits3] = (FINGER_JOINT_LIMITS[0][1], FINGER_JOINT_LIMITS[1][1],
                                 FINGER_JOINT_LIMITS[2][1])


def _four(value: Limits3) -> tuple[Limits3, ...]:
    return tuple(value for _ in range(FINGERS))


@dataclass(frozen=True)
class JointLimits:
    """Per-finger joint limits (rad) and the policy for targets beyond them."""

    lower: tuple[Limits3, ...] = field(default_factory=lambda: _four(DEFAULT_LOWER))
    upper: tuple[Limits3, ...] = field(default_factory=lambda: _four(DEFAULT_UPPER))
    action: str = "refuse"

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise UsageError(f"joint-limit action {self.action!r}: choose one of {ACTIONS}")
        if len(self.lower) != FINGERS or len(self.upper) != FINGERS:
            raise UsageError(f"joint limits need one entry per finger ({FINGERS})")
        for k in range(FINGERS):
            for lo, hi in zip(self.lower[k], self.upper[k], strict=True):
                if not lo <= hi:
                    raise UsageError(f"finger {k}: lower limit {lo} above upper limit {hi}")

    def apply(self, finger: int, target: Sequence[float]) -> Limits3:
        """``target`` (rad, three joints) checked against finger ``finger``'s limits:
        clamped, or :class:`UsageError` under ``"refuse"`` (and for non-finite values)."""
        if len(target) != JOINTS_PER_FINGER:
            raise UsageError(f"a finger takes {JOINTS_PER_FINGER} joint targets, "
                             f"got {len(target)}")
        out = []
        for j, value in enumerate(target):
            v = float(value)
            lo, hi = self.lower[finger][j], self.upper[finger][j]
            if not math.isfinite(v):
                raise UsageError(f"finger {finger} joint {j}: target {value} is not a number")
            if v < lo or v > hi:
                if self.action == "refuse":
                    raise UsageError(
                        f"finger {finger} joint {j}: target {v:.3f} rad is beyond the joint "
                        f"limit [{lo:.3f}, {hi:.3f}] rad; choose a target inside it")
                v = min(max(v, lo), hi)
            out.append(v)
        return (out[0], out[1], out[2])

    def with_action(self, action: str) -> JointLimits:
        """The same limits with another policy."""
        return JointLimits(self.lower, self.upper, action)
