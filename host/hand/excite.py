"""An excitation for identifying a finger: closures against nothing, at two efforts.

Each finger in turn closes to each pose of :data:`CLOSURES` and opens again
(:data:`OPEN`), first at a light effort then at a firm one, with nothing in the way: the
motors' response, the tendons' stretch and the joints' friction show in the halls, the
motors' efforts and the phalanges' accelerometers, and no contact gets in the way.  Every
move goes through :meth:`host.hand.facade.Hand.move_fingers`, which refuses a target outside
the fingers' joint limits before anything moves; the poses are well inside
:data:`protocol.robot.FINGER_JOINT_LIMITS`.  Closures against an object are another
excitation (a scene with a mug), not this one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Protocol

from host.errors import UsageError
from host.hand.state import MoveResult
from protocol.topology import FINGERS

#: The poses each finger closes to (J0 spread, J1, J2; rad), from open each time.
CLOSURES: Final = ((0.0, 0.6, 0.5), (0.0, 0.9, 0.7), (0.2, 0.6, 0.5))
#: Open: where each closure starts and ends (rad).
OPEN: Final = (0.0, 0.0, 0.0)
#: The two efforts (1/255 of full PWM): a light closure and a firm one (below about 150
#: the spread joint J0 may stop short of its target).
EFFORTS: Final = (150, 255)


@dataclass(frozen=True)
class FingerExcitation:
    """Which ``fingers`` (0..3) close, at which ``efforts``, to which ``closures`` (J0, J1,
    J2 poses, rad; default :data:`CLOSURES`), each move given ``timeout_s`` to settle;
    ``unhomed`` moves fingers never homed (angles from their power-up)."""

    fingers: tuple[int, ...] = tuple(range(FINGERS))
    efforts: tuple[int, ...] = EFFORTS
    timeout_s: float = 3.0
    unhomed: bool = False
    closures: tuple[tuple[float, float, float], ...] = CLOSURES

    def __post_init__(self) -> None:
        if not self.fingers or any(not 0 <= f < FINGERS for f in self.fingers):
            raise UsageError(f"fingers must be among 0..{FINGERS - 1}, got {list(self.fingers)}")
        if not self.efforts or any(not 0 < e <= 255 for e in self.efforts):
            raise UsageError(f"efforts must be 1..255, got {list(self.efforts)}")
        if not self.timeout_s > 0:
            raise UsageError(f"timeout {self.timeout_s} s must be > 0")
        if not self.closures or any(len(pose) != 3 for pose in self.closures):
            raise UsageError("closures must be at least one pose of three joint angles")


class MovingHand(Protocol):
    """What :func:`excite_fingers` uses of a hand (:class:`host.hand.facade.Hand`)."""

    def move_fingers(self, targets: dict[int, Sequence[float]], *,
                     effort: Sequence[int] | int | None = None, timeout: float = 3.0,
                     unhomed: bool = False) -> MoveResult:
        """Move fingers to joint targets (rad) and wait until they settle."""
        ...


def moves(plan: FingerExcitation) -> list[tuple[int, int, tuple[float, float, float]]]:
    """The excitation as (finger, effort, pose) moves, in order."""
    return [(finger, effort, pose) for finger in plan.fingers for effort in plan.efforts
            for closure in plan.closures for pose in (closure, OPEN)]


def excite_fingers(hand: MovingHand, plan: FingerExcitation) -> list[MoveResult]:
    """Run every move of ``plan`` (:func:`moves`); returns how each ended (a closure that
    does not settle is kept, not retried: it is data too)."""
    return [hand.move_fingers({finger: pose}, effort=effort, timeout=plan.timeout_s,
                              unhomed=plan.unhomed)
            for finger, effort, pose in moves(plan)]
