"""The hand as objects: the palm, four fingers, each finger's three boards.

::

    with Hand.open("/dev/ttyACM0") as hand:          # or "emu://hand/palm", "socket://…"
        found = hand.discover()                       # 13 NodeInfo: who answers, versions
        hand.power("all", "full")
        hand.fingers[1].move((0.3, 0.6, 0.4))         # rad, waits until it settles
        for state in hand.states(rate_hz=50, seconds=1.0):
            print(state.joints)

``hand.palm`` is a :class:`Node`; ``hand.fingers[k]`` a :class:`Finger` with ``.motor``
(fmcb, hop 0), ``.proximal`` (f2, hop 1) and ``.distal`` (f3, hop 2).  Commands are data
first (:meth:`Finger.make_command` → :class:`FingerCommand`) and sent by
:meth:`Hand.send` (all fingers in one pipelined round) or :meth:`Finger.command`.  Joint
targets pass the hand's :class:`~host.hand.joint_limits.JointLimits` (clamp or refuse) first.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import host.hand.bring_up as hand_bring_up
import host.hand.calibration as hand_calibration
import host.hand.grasp as grasping
import host.hand.homing as hand_homing
from host.code_names import code_name
from host.errors import HostError, NotHomedError, UsageError, why_no_answer
from host.estimation.calibration_file import serial_of_uid
from host.estimation.closed_form import DEFAULT_MIN_AXIS_TILT_RAD
from host.estimation.hand_calibration import HandCalibration
from host.hand.bring_up import BOOT_TIMEOUT_S, bring_up
from host.hand.finger import FALLBACK_DEADBAND_HALL, FULL_EFFORT, Finger
from host.hand.grasp import GRASP_TIMEOUT_S
from host.hand.homing import DEFAULT_SAMPLES, HomeResult
from host.hand.joint_limits import JOINTS_PER_FINGER, JointLimits
from host.hand.node import Node
from host.hand.params import FingerParams
from host.hand.session import LINK_NODE, FingerEvent, HandSession, PendingReply, Target, Timeouts
from host.hand.state import (
    FingerCommand,
    FingerState,
    FingerUp,
    GraspResult,
    HandState,
    MoveResult,
    NodeInfo,
)
from host.hand.synergies import BLEND_PERIOD_S, DEFAULT_SPEED_RAD_S
from host.transports.base import Transport, open_transport
from host.view.live import RobotView, ViewSpec, open_view
from protocol.messages.fmcb import ControlMode
from protocol.messages.palm import ALL_FINGERS, FingerPower
from protocol.robot import DEFAULT_HAND_LAYOUT, HandLayout
from protocol.topology import FINGERS

#: Default stagger between fingers when all are switched (ms).
POWER_STAGGER_MS: Final = 5
#: Longest further wait (s), after ``(FINGERS - 1) × stagger``, for the palm to report
#: every finger switched when all are (its clock may lag the host's).
POWER_SETTLE_S: Final = 0.25
#: Status polling period while waiting for a move to settle (s).
SETTLE_POLL_S: Final = 0.02
#: A finger whose motors moved less than this (hall counts) in :data:`STALL_S` has stopped.
STALL_COUNTS: Final = 3
STALL_S: Final = 0.2
#: Highest rate the palm polls fingers at (Hz).
MAX_POLL_HZ: Final = 200
#: A motor within its fmcb's deadband plus this many hall counts of its target has settled.
SETTLE_MARGIN_HALL: Final = 15


@dataclass
class StatusRead:
    """A :meth:`Hand.status` read in flight (:meth:`Hand.start_status`), started at ``t``
    (s, the link's clock)."""

    hand: Hand
    t: float
    summary: PendingReply
    polls: list[PendingReply]

    @property
    def ready(self) -> bool:
        """Every reply is in (or refused): :meth:`finish` will not wait."""
        return self.summary.done and all(p.done for p in self.polls)

    def finish(self) -> HandState:
        """Wait for what has not come yet and return the state (the hand's state taps see
        it); a finger that did not answer keeps the palm's summary, with its problem."""
        hand = self.hand
        state = HandState(self.t, [FingerState(k) for k in range(FINGERS)])
        state.update_from_hand_status(hand.session.wait(self.summary))
        for finger, p in zip(state.fingers, self.polls, strict=False):
            finger.present = False
            try:
                finger.update_from_status(hand.session.wait(p))
            except HostError as exc:  # unpowered, booting or gone: the palm's summary stands
                finger.problem = why_no_answer(exc)
        for tap in list(hand.state_taps):
            tap(state)
        return state


class Hand:
    """A hand behind its palm link.  A context manager; :meth:`close` closes the link."""

    def __init__(self, session: HandSession, limits: JointLimits | None = None,
                 layout: str = DEFAULT_HAND_LAYOUT) -> None:
        if session.link != "palm":
            raise UsageError("Hand needs the palm's link; a loose finger is driven with "
                             "HandSession(transport, link='finger')")
        self.session = session
        self.limits = limits or JointLimits()
        #: The hand frame's name (:data:`protocol.robot.HAND_LAYOUTS`): which module is the
        #: thumb or opposed, where each spreads (grasps read it).
        self.layout = layout
        self.palm = Node(session, LINK_NODE, "palm")
        self.fingers = [Finger(self, k) for k in range(FINGERS)]
        #: The accelerometers' calibration the estimates and homing use (None: their
        #: nominal mounting); :meth:`load_calibration` sets it.
        self.calibration: HandCalibration | None = None
        #: Called with every :class:`HandState` read (:meth:`status`, streams): a view, a
        #: plot, a recorder; whoever reads the hand need not know it is watched.
        self.state_taps: list[Callable[[HandState], None]] = []
        #: Called with ``(t, states)`` for every :meth:`finger_states` read (``t``: the
        #: link's clock after it, s; finger index → :class:`FingerState`).
        self.finger_taps: list[Callable[[float, dict[int, FingerState]], None]] = []
        #: The browser view drawing this hand (:meth:`watch`), if any.
        self.view: RobotView | None = None
        self._owns_view = False

    @classmethod
    def open(cls, url: str | Transport, *, limits: JointLimits | None = None,
             timeouts: Timeouts | None = None, retries: int = 2,
             layout: str = DEFAULT_HAND_LAYOUT, view: ViewSpec = None) -> Hand:
        """Open the palm link ``url`` (a path, any transport URL, or an open Transport) of
        a hand built as ``layout``.  ``view`` (True, a port, or a
        :class:`~host.view.live.RobotView` to share): draw every state read and every finger
        event in a browser view (:mod:`host.view.live`; its address on stderr), closed with the
        hand unless it was given."""
        transport = open_transport(url) if isinstance(url, str) else url
        hand = cls(HandSession(transport, timeouts=timeouts, retries=retries), limits,
                   layout)
        try:
            hand.watch(view)
        except BaseException:
            hand.close()
            raise
        return hand

    def watch(self, view: ViewSpec) -> RobotView | None:
        """Draw this hand's states and events in ``view`` (see :meth:`open`); the view, or
        None."""
        self.view = open_view(view, layout=self.layout)
        if self.view is not None:
            self._owns_view = not isinstance(view, RobotView)
            self.view.attach_hand(self)
        return self.view

    def close(self) -> None:
        """Close the link (idempotent) and a view this hand opened."""
        self.session.close()
        if self.view is not None and self._owns_view:
            self.view.close()

    def __enter__(self) -> Hand:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: object) -> None:
        """Close; when the block raised (Ctrl-C included), first :meth:`hold` every finger
        where it is, and add a note saying which (or why not) to the exception."""
        try:
            if exc is not None and not self.session.transport.closed:
                note: str | None
                try:
                    held = self.hold()
                    # nothing to hold is news only after Ctrl-C (what did it leave?)
                    note = (f"finger(s) {', '.join(map(str, held))} held where they were, "
                            "motors on" if held else "no finger was moving"
                            if isinstance(exc, KeyboardInterrupt) else None)
                except HostError as failed:
                    note = f"could not hold the fingers: {failed}"
                if note is not None:
                    exc.add_note(f"the hand: {note}")
        finally:
            self.close()

    def hold(self, fingers: Sequence[int] | None = None) -> list[int]:
        """Stop ``fingers`` (default: every finger) where they are: each one's motor targets
        := its present motor positions (hall counts, :attr:`ControlMode.MOTOR`: the same
        joint angles, with no limit or homing to refuse them), the motors left on.  A finger
        whose targets already are where it is (idle: its fmcb keeps them there; or holding)
        is left as it is, and so is one that does not answer (unpowered, booting, gone);
        returns the fingers held."""
        chosen = list(range(FINGERS)) if fingers is None else list(fingers)
        pending = []
        for k in chosen:
            try:
                pending.append((k, self.fingers[k].motor.start("fmcb.status", retries=0)))
            except HostError:
                continue
        present: dict[int, list[int]] = {}
        for k, p in pending:
            try:
                state = FingerState(k)
                state.update_from_status(self.session.wait(p))
            except HostError:
                continue
            if state.targets_hall != state.joints_hall:
                present[k] = list(state.joints_hall)
        commands = [self.fingers[k].make_command(hall=hall) for k, hall in present.items()]
        held = []
        replies = []
        for c in commands:
            try:
                replies.append((c.finger, self.fingers[c.finger].motor.start("fmcb.control",
                                                                             c.fields)))
            except HostError:
                continue
        for k, p in replies:
            try:
                self.session.wait(p)
                held.append(k)
            except HostError:
                continue
        return held

    # --- discovery and power ---------------------------------------------------------------
    def discover(self) -> list[NodeInfo]:
        """Ask every place (palm, then each finger's fmcb, f2, f3) who answers there; one
        :class:`NodeInfo` each, in that order, with ``problem`` where nothing answered."""
        nodes = [self.palm, *(n for f in self.fingers for n in f.nodes)]
        pending: list[tuple[Node, PendingReply | HostError]] = []
        for node in nodes:
            try:
                pending.append((node, node.start("identify")))
            except HostError as exc:
                pending.append((node, exc))
        found = []
        for node, p in pending:
            try:
                if isinstance(p, HostError):
                    raise p
                found.append(node._info(self.session.wait(p)))
            except HostError as exc:
                hop = None if node is self.palm else node.target.hop
                found.append(NodeInfo(node.where, node.target.finger, hop, False,
                                      problem=why_no_answer(exc)))
        return found

    def power(self, finger: int | str, state: int | str,
              stagger_ms: int = POWER_STAGGER_MS) -> list[str]:
        """Switch finger ``finger`` (0..3, or ``"all"``, ``stagger_ms`` apart) to ``state``
        (``"off"``, ``"low"``, ``"full"``); every finger's power state as the palm reports.

        The palm switches ``"all"`` one finger every ``stagger_ms`` ms and answers at the
        first switch, so for ``"all"`` this waits out the stagger on the link's clock and
        reports the states the palm's ``palm.hand_status`` gives afterwards: what the palm
        does, not the moment in between.  Fingers switched on boot for their autoboot window
        (:data:`~protocol.messages.boot_program.AUTOBOOT_WINDOW_US`) before their fmcb answers; :meth:`bring_up` waits for them."""
        try:
            code = FingerPower[state.upper()] if isinstance(state, str) else FingerPower(state)
        except (KeyError, ValueError) as exc:
            raise UsageError(f"power state {state!r}: choose off, low or full") from exc
        index = ALL_FINGERS if finger == "all" else int(finger)
        if index != ALL_FINGERS and not 0 <= index < FINGERS:
            raise UsageError(f"finger {finger}: the hand has fingers 0..{FINGERS - 1}")
        reply = self.palm.request("palm.finger_power",
                                  {"finger": index, "state": code, "stagger_ms": stagger_ms})
        states = list(reply["states"])
        if index == ALL_FINGERS and stagger_ms > 0:
            # The palm's timers started before it replied, so on its clock this is past the
            # last switch; a palm whose clock lags the host's (an emulator behind the wall
            # clock) is given up to POWER_SETTLE_S more.
            stagger_s = stagger_ms / 1000
            self.session.sleep((FINGERS - 1) * stagger_s)
            deadline = self.session.now() + POWER_SETTLE_S
            while True:
                states = [f["power"] for f in self.palm.request("palm.hand_status")["fingers"]]
                if all(s == code for s in states) or self.session.now() >= deadline:
                    break
                self.session.sleep(stagger_s)
        return [code_name(FingerPower, s, "power") for s in states]

    def bring_up(self, fingers: int | str | Sequence[int] = "all",
                 timeout: float = BOOT_TIMEOUT_S,
                 on_progress: Callable[[str], None] | None = None) -> list[FingerUp]:
        """Power ``fingers`` full, wait for each fmcb to boot, power its phalanges, wait for
        f2 and f3, switch the fmcb's autopoll on (about 10 s on the link's clock): see
        :func:`host.hand.bring_up.bring_up`.  One :class:`~host.hand.state.FingerUp`
        per finger, saying what came up and, for what did not, why.  ``timeout`` (s)
        bounds each board's boot after its power is switched on."""
        return hand_bring_up.bring_up(self, fingers, timeout, on_progress)

    # --- state -------------------------------------------------------------------------------
    def finger_states(self, fingers: Sequence[int]) -> dict[int, FingerState]:
        """One ``fmcb.status`` of each of ``fingers``, the requests in flight together;
        finger index → :class:`FingerState`."""
        pending = {k: self.fingers[k].motor.start("fmcb.status") for k in fingers}
        states = {}
        for k, p in pending.items():
            state = FingerState(k)
            state.update_from_status(self.session.wait(p))
            states[k] = state
        if self.finger_taps:
            now = self.session.now()
            for tap in list(self.finger_taps):
                tap(now, states)
        return states

    def status(self, fingers: bool = True) -> HandState:
        """The hand now: the palm's summary and (``fingers``) each answering finger's fmcb
        status; requests go out together, so this costs about one finger round trip."""
        return self.start_status(fingers).finish()

    def start_status(self, fingers: bool = True) -> StatusRead:
        """Send :meth:`status`'s requests and return without waiting: the
        :class:`StatusRead` is ``ready`` once the link has brought every reply in (after
        ``session.pump``), and ``finish()`` gives the :class:`HandState`."""
        summary = self.palm.start("palm.hand_status")
        polls = [f.motor.start("fmcb.status", retries=0) for f in self.fingers] if fingers else []
        return StatusRead(self, self.session.now(), summary, polls)

    def set_poll_rate(self, rate_hz: int) -> None:
        """Have the palm poll every powered finger's status at ``rate_hz`` (0: off)."""
        self.palm.request("palm.poll", {"rate_hz": max(0, min(MAX_POLL_HZ, int(rate_hz)))})

    def states(self, rate_hz: float, seconds: float | None = None, *,
               fingers: bool = True) -> Generator[HandState, None, None]:
        """Yield the hand's state ``rate_hz`` times a second (the link's clock) for
        ``seconds`` (None: forever).  ``fingers`` False reads only the palm's summary (the
        palm polls the fingers at that rate, and goes back to the rate it had when the
        stream ends or is closed; cheapest); events arrive meanwhile."""
        if rate_hz <= 0:
            raise UsageError(f"rate {rate_hz} Hz: give a positive rate")
        restore: int | None = None
        if not fingers:
            restore = self.status(fingers=False).poll_hz
            self.set_poll_rate(int(min(MAX_POLL_HZ, max(1, round(rate_hz)))))
        try:
            start = self.session.now()
            tick = 0
            while seconds is None or tick / rate_hz <= seconds:
                due = start + tick / rate_hz
                wait = due - self.session.now()
                if wait > 0:
                    self.session.sleep(wait)
                yield self.status(fingers=fingers)
                tick += 1
        finally:
            if restore is not None and not self.session.transport.closed:
                try:
                    self.set_poll_rate(restore)
                except HostError:
                    pass  # the link is gone: what raised in the loop says so

    def stream(self, rate_hz: float, on_state: Callable[[HandState], None],
               seconds: float | None = None, *, fingers: bool = True) -> None:
        """Call ``on_state`` with :meth:`states` until ``seconds`` have passed."""
        for state in self.states(rate_hz, seconds, fingers=fingers):
            on_state(state)

    # --- events --------------------------------------------------------------------------------
    def subscribe(self, callback: Callable[[FingerEvent], None]) -> Callable[[], None]:
        """Call ``callback`` for every finger event (lost, returned, breaker trip, …)."""
        return self.session.subscribe(callback)

    def next_event(self, timeout: float = 0.0) -> FingerEvent | None:
        """The oldest finger event not yet taken, waiting up to ``timeout`` s."""
        return self.session.next_event(timeout)

    # --- commands and moves -----------------------------------------------------------------
    def make_commands(self, joints: Sequence[float], *,
                      effort: Sequence[int] | int | None = None) -> list[FingerCommand]:
        """Commands for all 12 joints (rad, finger by finger); ``effort`` one cap for all,
        or 12 (1/255 of full PWM)."""
        n = FINGERS * JOINTS_PER_FINGER
        if len(joints) != n:
            raise UsageError(f"the hand takes {n} joint targets, got {len(joints)}")
        per_finger: list[Any]
        if effort is None or isinstance(effort, int):
            per_finger = [effort] * FINGERS
        elif len(effort) != n:
            raise UsageError(f"give one effort or {n}, got {len(effort)}")
        else:
            per_finger = [list(effort[3 * k: 3 * k + 3]) for k in range(FINGERS)]
        out = []
        for k, f in enumerate(self.fingers):
            q = joints[3 * k: 3 * k + 3]
            out.append(f.make_command(q, effort=per_finger[k]))
        return out

    def send(self, commands: Sequence[FingerCommand], *, unhomed: bool = False) -> None:
        """Send ``commands`` in one pipelined round (each finger has its own palm queue).
        Motion for a finger not homed is refused (:class:`NotHomedError`) unless
        ``unhomed``."""
        if not unhomed:
            self.require_homed([c.finger for c in commands if c.mode != ControlMode.IDLE])
        pending = [self.fingers[c.finger].motor.start("fmcb.control", c.fields)
                   for c in commands]
        errors = []
        for p in pending:
            try:
                self.session.wait(p)
            except HostError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]

    def move(self, joints: Sequence[float], *, effort: Sequence[int] | int | None = None,
             timeout: float = 3.0, unhomed: bool = False) -> MoveResult:
        """All 12 joints (rad): command, then wait until every finger settles."""
        commands = self.make_commands(joints, effort=effort)
        self.send(commands, unhomed=unhomed)
        return self.wait_settled([c.finger for c in commands], timeout)

    def move_fingers(self, targets: dict[int, Sequence[float]], *,
                     effort: Sequence[int] | int | None = None,
                     timeout: float = 3.0, unhomed: bool = False) -> MoveResult:
        """Joint targets (rad) for some fingers; command them, then wait until they settle."""
        self.send([self.fingers[k].make_command(q, effort=effort) for k, q in targets.items()],
                  unhomed=unhomed)
        return self.wait_settled(list(targets), timeout)

    def grasp(self, name: str, amount: float = 1.0, *, speed: float = DEFAULT_SPEED_RAD_S,
              fingers: Sequence[int] | None = None, until_contact: bool = False,
              effort: Sequence[int] | int | None = None, timeout: float = GRASP_TIMEOUT_S,
              squeeze_rad: float = 0.0, unhomed: bool = False,
              layout: str | HandLayout | None = None, period: float = BLEND_PERIOD_S,
              on_states: Callable[[float, Mapping[int, FingerState]], None] | None = None
              ) -> GraspResult:
        """Blend ``fingers`` (default: all four) towards grasp or pose ``name`` at ``amount``
        (0..1) at ``speed`` rad/s, every ``period`` s, stopping a finger at contact with
        ``until_contact``, then wait up to ``timeout`` s for them to settle and squeeze by
        ``squeeze_rad`` (rad of J1) with ``effort`` (1/255 of full PWM); ``layout`` other
        than the hand's, ``unhomed`` fingers allowed, ``on_states`` told every status read:
        see :func:`host.hand.grasp.grasp`."""
        return grasping.grasp(self, name, amount, speed=speed, fingers=fingers,
                              until_contact=until_contact, effort=effort, timeout=timeout,
                              squeeze_rad=squeeze_rad, unhomed=unhomed, layout=layout,
                              period=period, on_states=on_states)

    # --- homing (host.hand.homing) ---------------------------------------------------------
    def home(self, finger: int | None = None, samples: int = DEFAULT_SAMPLES,
             min_tilt_rad: float = DEFAULT_MIN_AXIS_TILT_RAD) -> list[HomeResult]:
        """Home ``finger`` (or every finger) from its accelerometers, averaging ``samples``
        status reads, refusing a joint whose axis is within ``min_tilt_rad`` of vertical:
        see :func:`host.hand.homing.home`."""
        return hand_homing.home(self, finger, samples, min_tilt_rad,
                                calibration=self.calibration)

    # --- calibration (host.hand.calibration) ---------------------------------------------
    def serial(self) -> str:
        """The robot's serial number: the palm's ``uid`` as eight hex digits."""
        info = self.palm.identify()
        if info.uid is None:
            raise HostError(f"the palm did not say its uid: {info.problem}")
        return serial_of_uid(info.uid)

    def load_calibration(self, choice: str | None = None
                         ) -> hand_calibration.CalibrationChoice:
        """Find and use this robot's accelerometer calibration (``choice``: None for the
        default file of its serial, ``"none"``, or a path): see
        :func:`host.hand.calibration.choose_calibration`.  Print its ``summary()`` and
        ``warnings``."""
        info = self.palm.identify()
        if info.uid is None:
            raise HostError(f"the palm did not say its uid: {info.problem}")
        chosen = hand_calibration.choose_calibration(serial_of_uid(info.uid), choice,
                                                     info.fw_version)
        self.calibration = chosen.calibration
        return chosen

    def require_homed(self, fingers: Sequence[int]) -> None:
        """Raise :class:`~host.errors.NotHomedError` naming those of ``fingers`` whose fmcb
        holds no homing offsets (asked of the fmcb for a finger not homed here: another
        program's homing counts too)."""
        for k in sorted(set(fingers)):
            finger = self.fingers[k]
            if not finger.homed:
                finger.homed = hand_homing.homed_on_robot(finger)
        missing = [k for k in sorted(set(fingers)) if not self.fingers[k].homed]
        if missing:
            raise NotHomedError(
                f"finger(s) {missing} not homed: their joint angles are only hall counts "
                f"since power-up. Home them (Hand.home, `handctl home`) or pass "
                f"unhomed=True (handctl: --unhomed) to move anyway", fingers=missing)

    def wait_settled(self, fingers: Sequence[int], timeout: float = 3.0,
                     tolerance_hall: int | None = None) -> MoveResult:
        """Poll the fingers' status until every motor is within ``tolerance_hall`` counts
        of its target (settled), or none moved for 0.2 s (stalled), or ``timeout`` s.
        ``tolerance_hall`` defaults to each finger's fmcb deadband (:meth:`Finger.deadband`)
        plus :data:`SETTLE_MARGIN_HALL`."""
        tolerance = {k: (self.fingers[k].deadband() + SETTLE_MARGIN_HALL
                         if tolerance_hall is None else tolerance_hall) for k in fingers}
        start = self.session.now()
        last_move = {k: start for k in fingers}
        last_pos: dict[int, list[int]] = {}
        first: tuple[float, dict[int, FingerState]] | None = None
        while True:
            # First wait: the fmcb refreshes its status snapshot every 5 ms, so a status
            # read at once may still show the old target.
            self.session.sleep(SETTLE_POLL_S)
            states = self.finger_states(fingers)
            now = self.session.now()
            if first is None:
                first = (now, states)
            near, stalled = [], []
            for k, s in states.items():
                tgt = s.targets_hall or s.joints_hall
                near.append(max(abs(a - b) for a, b in zip(s.joints_hall, tgt, strict=True))
                            <= tolerance[k])
                prev = last_pos.get(k)
                if prev is None or max(abs(a - b) for a, b in zip(s.joints_hall, prev,
                                                                  strict=True)) > STALL_COUNTS:
                    last_move[k] = now
                    last_pos[k] = list(s.joints_hall)
                elif now - last_move[k] >= STALL_S:
                    stalled.append(k)
            settled = all(near)
            if settled or len(stalled) == len(states) or now - start >= timeout:
                errors = {k: _joint_error(s) for k, s in states.items()}
                return MoveResult(settled, [] if settled else stalled, errors, states,
                                  now - start, _robot_rate(first, now, states))


def _robot_rate(first: tuple[float, dict[int, FingerState]], now: float,
                states: dict[int, FingerState]) -> float | None:
    """Robot seconds (an fmcb's status clock, µs, wrapping at 2³²) per link second between
    the ``first`` status read and the last; None when no finger tells or no time passed."""
    t0, before = first
    if now - t0 <= 0:
        return None
    for k, s in states.items():
        was = before[k].fmcb_time_us if k in before else None
        if was is not None and s.fmcb_time_us is not None:
            return ((s.fmcb_time_us - was) % (1 << 32)) / 1e6 / (now - t0)
    return None


def _joint_error(state: FingerState) -> tuple[float, float, float]:
    target = state.joint_targets or state.joints
    return (target[0] - state.joints[0], target[1] - state.joints[1],
            target[2] - state.joints[2])


#: The hand's API: :class:`Hand`, :class:`Finger` and the constants of their moves, and
#: (from the modules they live in) the types and names its users import from here.
__all__ = [
    "MAX_POLL_HZ", "POWER_SETTLE_S", "POWER_STAGGER_MS", "SETTLE_MARGIN_HALL",
    "SETTLE_POLL_S", "STALL_COUNTS", "STALL_S", "Hand", "StatusRead",
    # moved out, importable here as before
    "FALLBACK_DEADBAND_HALL", "FULL_EFFORT", "Finger",
    "FingerCommand", "FingerUp", "GraspResult", "HomeResult", "MoveResult", "Node",
    "NodeInfo", "FingerState", "HandState", "FingerEvent", "HandSession", "PendingReply",
    "Target", "Timeouts", "LINK_NODE", "BOOT_TIMEOUT_S", "JOINTS_PER_FINGER", "JointLimits",
    "FingerParams", "bring_up",
]
