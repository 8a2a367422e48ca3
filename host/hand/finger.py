"""One finger of the hand as an object: its three boards, its commands as data, its moves.

``hand.fingers[k]`` is a :class:`Finger` with ``.motor`` (fmcb, hop 0), ``.proximal`` (f2,
hop 1) and ``.distal`` (f3, hop 2).  Its commands are data first (:meth:`Finger.make_command`
-> :class:`~host.hand.state.FingerCommand`, joint targets through the hand's joint limits)
and go out through the hand it belongs to (:class:`~host.hand.interface.FingerOwner`: the
hand's :meth:`~host.hand.facade.Hand.send`, one pipelined round for every finger).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from host.errors import HostError, UsageError
from host.hand.interface import FingerOwner
from host.hand.joint_limits import JOINTS_PER_FINGER
from host.hand.node import Node
from host.hand.params import FingerParams
from host.hand.session import Target
from host.hand.state import FingerCommand, FingerState, MoveResult
from protocol.messages.fmcb import ControlMode
from protocol.topology import HOP_NODE, Hop

#: Full effort (1/255 of full PWM).
FULL_EFFORT: Final = 255
#: The fmcb's position deadband (hall counts) assumed when its ``deadband`` parameter cannot
#: be read (a firmware without it): the firmware's default (``firmware_py.fmcb_params``).
FALLBACK_DEADBAND_HALL: Final = 50


class Finger:
    """Finger ``index``: its fmcb (``motor``), proximal (f2) and distal (f3) boards."""

    def __init__(self, hand: FingerOwner, index: int) -> None:
        self.hand = hand
        self.index = index
        session = hand.session
        nodes = [Node(session, Target(index, hop), f"finger {index} {HOP_NODE[hop]}")
                 for hop in Hop]
        self.motor, self.proximal, self.distal = nodes
        self.params = FingerParams(self.motor.request)
        #: The fmcb holds homing offsets (set here, or found on it); moves need it.
        self.homed = False

    def deadband(self) -> int:
        """The fmcb's position deadband (hall counts): its ``deadband`` parameter, read at
        first use and kept; :data:`FALLBACK_DEADBAND_HALL` while the board cannot tell."""
        try:
            return int(self.params.cached("deadband"))
        except HostError:
            return FALLBACK_DEADBAND_HALL

    @property
    def nodes(self) -> list[Node]:
        """fmcb, f2, f3."""
        return [self.motor, self.proximal, self.distal]

    def power(self, state: int | str) -> list[str]:
        """Switch this finger's power (``"off"``, ``"low"``, ``"full"``); every finger's
        power state after."""
        return self.hand.power(self.index, state)

    def status(self) -> FingerState:
        """The fmcb's status now (joints, tactile, currents)."""
        state = FingerState(self.index)
        state.update_from_status(self.motor.request("fmcb.status"))
        return state

    def make_command(self, joints: Sequence[float] | None = None, *,
                     effort: Sequence[int] | int | None = None, relative: bool = False,
                     hall: Sequence[int] | None = None, idle: bool = False) -> FingerCommand:
        """A control command as data: joint targets (rad; ``relative``: deltas) with an
        optional per-joint effort cap (1/255 of full PWM), motor targets ``hall`` (hall
        counts), or ``idle`` (motors off).  Absolute targets pass the joint limits."""
        if idle:
            return FingerCommand(self.index, ControlMode.IDLE, {})
        if hall is not None:
            if len(hall) != JOINTS_PER_FINGER:
                raise UsageError(f"a finger takes {JOINTS_PER_FINGER} motor targets")
            return FingerCommand(self.index, ControlMode.MOTOR,
                                 {"hall_target": [int(h) for h in hall]})
        if joints is None:
            raise UsageError("give joint targets, motor targets or idle")
        if relative:
            target = [float(q) for q in joints]
            if len(target) != JOINTS_PER_FINGER:
                raise UsageError(f"a finger takes {JOINTS_PER_FINGER} joint deltas")
        else:
            target = list(self.hand.limits.apply(self.index, joints))
        if effort is None and not relative:
            return FingerCommand(self.index, ControlMode.JOINT, {"target": target})
        caps = _efforts(FULL_EFFORT if effort is None else effort)
        mode = ControlMode.RELATIVE if relative else ControlMode.JOINT_EFFORT
        return FingerCommand(self.index, mode, {"target": target, "max_effort": caps})

    def command(self, joints: Sequence[float] | None = None, *,
                effort: Sequence[int] | int | None = None, relative: bool = False,
                hall: Sequence[int] | None = None, idle: bool = False,
                unhomed: bool = False) -> None:
        """Send :meth:`make_command` (same arguments) now, without waiting to settle;
        motion for a finger not homed is refused unless ``unhomed``."""
        self.hand.send([self.make_command(joints, effort=effort, relative=relative, hall=hall,
                                          idle=idle)], unhomed=unhomed)

    def idle(self) -> None:
        """Motors off (control mode idle)."""
        self.command(idle=True)

    def move(self, joints: Sequence[float], *, effort: Sequence[int] | int | None = None,
             timeout: float = 3.0, unhomed: bool = False) -> MoveResult:
        """Command joint targets (rad) and wait until the finger settles or ``timeout`` s."""
        return self.hand.move_fingers({self.index: joints}, effort=effort, timeout=timeout,
                                      unhomed=unhomed)

    def set_home(self, offsets: Sequence[int] | None = None) -> None:
        """Make the current pose (or motor ``offsets``, raw hall counts) the zero."""
        if offsets is None:
            offsets = self.motor.request("fmcb.hall_counts", {"raw": 1})["counts"]
        self.motor.request("fmcb.set_home", {"offset": [int(v) for v in offsets]})
        self.homed = True

    def __repr__(self) -> str:
        return f"Finger({self.index})"


def _efforts(effort: Sequence[int] | int) -> list[int]:
    caps = [int(effort)] * JOINTS_PER_FINGER if isinstance(effort, int) else [
        int(e) for e in effort]
    if len(caps) != JOINTS_PER_FINGER or not all(0 <= e <= FULL_EFFORT for e in caps):
        shown = effort if isinstance(effort, int) else caps  # plain ints, never reprs
        raise UsageError(f"efforts are {JOINTS_PER_FINGER} values in 0..{FULL_EFFORT} "
                         f"(1/255 of full PWM), got {shown}")
    return caps
