"""The hand as its helpers see it: small protocols of what each uses of :class:`host.hand.facade.Hand`.

The facade (:mod:`host.hand.facade`) imports its helpers (bring-up, homing, grasps, the recorder,
the view); they never import it back.  Each helper types its ``hand`` (or ``finger``)
argument with the protocol here that names what it calls; :class:`~host.hand.facade.Hand` and
:class:`~host.hand.facade.Finger` satisfy them (mypy checks it where the facade calls a helper).

* :class:`FingerOwner` - what a :class:`~host.hand.finger.Finger` asks of its hand;
* :class:`HandFinger` - one finger's boards and its commands as data;
* :class:`LinkedHand` - the link and the fingers (homing);
* :class:`PoweredHand` - and the palm and the fingers' power (bring-up);
* :class:`MovingHand` - reading and commanding the fingers (grasps);
* :class:`WatchedHand` - the taps a recorder or a view attaches to.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Protocol

from host.hand.joint_limits import JointLimits
from host.hand.node import Node
from host.hand.session import FingerEvent, HandSession
from host.hand.state import FingerCommand, FingerState, HandState, MoveResult


class FingerOwner(Protocol):
    """The hand a finger belongs to: its link, joint limits, power switches, sends and
    waits."""

    @property
    def session(self) -> HandSession:
        """The conversation with the palm."""
        ...

    @property
    def limits(self) -> JointLimits:
        """The joint limits targets pass."""
        ...

    def power(self, finger: int | str, state: int | str, stagger_ms: int = ...) -> list[str]:
        """Switch finger ``finger`` (or ``"all"``) to ``state``; every finger's power state."""
        ...

    def send(self, commands: Sequence[FingerCommand], *, unhomed: bool = False) -> None:
        """Send ``commands`` in one pipelined round."""
        ...

    def move_fingers(self, targets: dict[int, Sequence[float]], *,
                     effort: Sequence[int] | int | None = None,
                     timeout: float = ..., unhomed: bool = False) -> MoveResult:
        """Joint targets (rad) for some fingers; command them, wait until they settle."""
        ...

    def wait_settled(self, fingers: Sequence[int], timeout: float = ...,
                     tolerance_hall: int | None = None) -> MoveResult:
        """Poll the fingers until they settle, stall or ``timeout`` s pass."""
        ...


class HandFinger(Protocol):
    """One finger: its index, its three boards, its commands as data, its homing offsets."""

    @property
    def index(self) -> int:
        """0..3."""
        ...

    @property
    def motor(self) -> Node:
        """The fmcb (hop 0)."""
        ...

    @property
    def proximal(self) -> Node:
        """f2 (hop 1)."""
        ...

    @property
    def distal(self) -> Node:
        """f3 (hop 2)."""
        ...

    @property
    def nodes(self) -> list[Node]:
        """fmcb, f2, f3."""
        ...

    def make_command(self, joints: Sequence[float] | None = None, *,
                     effort: Sequence[int] | int | None = None, relative: bool = False,
                     hall: Sequence[int] | None = None, idle: bool = False) -> FingerCommand:
        """A control command as data (joint targets, rad, pass the joint limits)."""
        ...

    def set_home(self, offsets: Sequence[int] | None = None) -> None:
        """Make the current pose (or motor ``offsets``, raw hall counts) the zero."""
        ...


class LinkedHand(Protocol):
    """The palm's link (its clock: ``now``, ``sleep``) and the four fingers."""

    @property
    def session(self) -> HandSession:
        """The conversation with the palm."""
        ...

    @property
    def fingers(self) -> Sequence[HandFinger]:
        """Fingers 0..3."""
        ...


class PoweredHand(LinkedHand, Protocol):
    """And the palm and the fingers' power switches (bring-up)."""

    @property
    def palm(self) -> Node:
        """The palm's board."""
        ...

    def power(self, finger: int | str, state: int | str, stagger_ms: int = ...) -> list[str]:
        """Switch finger ``finger`` (or ``"all"``) to ``state``; every finger's power state."""
        ...


class MovingHand(LinkedHand, Protocol):
    """Reads and commands the fingers (grasps): joint limits, layout, homing required."""

    @property
    def limits(self) -> JointLimits:
        """The joint limits targets pass."""
        ...

    @property
    def layout(self) -> str:
        """The hand frame's name (:data:`protocol.robot.HAND_LAYOUTS`)."""
        ...

    def finger_states(self, fingers: Sequence[int]) -> dict[int, FingerState]:
        """One ``fmcb.status`` of each of ``fingers``."""
        ...

    def send(self, commands: Sequence[FingerCommand], *, unhomed: bool = False) -> None:
        """Send ``commands`` in one pipelined round."""
        ...

    def wait_settled(self, fingers: Sequence[int], timeout: float = ...,
                     tolerance_hall: int | None = None) -> MoveResult:
        """Poll the fingers until they settle, stall or ``timeout`` s pass."""
        ...

    def require_homed(self, fingers: Sequence[int]) -> None:
        """Raise :class:`~host.errors.NotHomedError` naming the fingers not homed."""
        ...


class WatchedHand(Protocol):
    """What a recorder or a view attaches to: the link's frames and counters, the state and
    finger taps, the finger events; and the states a recorder reads."""

    @property
    def session(self) -> HandSession:
        """The conversation with the palm."""
        ...

    @property
    def state_taps(self) -> list[Callable[[HandState], None]]:
        """Called with every hand state read."""
        ...

    @property
    def finger_taps(self) -> list[Callable[[float, dict[int, FingerState]], None]]:
        """Called with ``(t, states)`` for every finger-states read."""
        ...

    def subscribe(self, callback: Callable[[FingerEvent], None]) -> Callable[[], None]:
        """Call ``callback`` for every finger event; returns the unsubscribe."""
        ...

    def states(self, rate_hz: float, seconds: float | None = None, *,
               fingers: bool = True) -> Iterator[HandState]:
        """The hand's state ``rate_hz`` times a second for ``seconds``."""
        ...
