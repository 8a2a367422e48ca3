"""The 7-DOF arm on one Dynamixel 1.0 bus: discovery, commands as data, one-exchange cycles.

::

    with Arm.open("emu://arm/arm") as arm:            # or "/dev/ttyUSB0", "./robot/arm"
        arm.torque(True)
        state = arm.cycle([arm.make_position(0, 0.3), arm.make_position(5, -0.2)])
        state.joints, state.torques, state.slip

**The cycle.**  :meth:`Arm.cycle` turns a list of commands (:meth:`Arm.make_position`,
:meth:`Arm.make_torque`) into at most a few SYNC_WRITEs (torque enable; stepper speed
limits; stepper goals; servo goals, with speeds when asked) followed by one BULK_READ of
the seven nodes' state, all sent as one write; the nodes answer in turn and the cycle
returns an :class:`~host.arm.state.ArmState`.  Nothing else crosses the bus.

**On the wire** (:mod:`host.arm.cycle`): how the stepper goals carry the routes' coupling
offsets, how a stepper whose rotor turned while unpowered is re-synced before its torque
comes on, and what a cycle reads.

**Fast mode.**  Nodes leave the factory with a return delay of 250 × 2 µs = 0.5 ms, which
costs 3.5 ms per cycle of seven replies.  ``Arm.open(url, return_delay=0)`` (the default)
writes register 5 of every node to the value given (2 µs units; 0-2 is fine on a short
RS-485 bus; the emulator honours it); ``return_delay=None`` leaves the nodes as they are.
The register is in EEPROM: it persists.

**The command watchdog.**  :meth:`open` sets the stepper nodes' ``watchdog_timeout``
(:data:`HOST_WATCHDOG_MS`; the robot CLIs, which run real-time where allowed, give
:func:`host_watchdog_ms`, 50 ms then): a node that hears nothing from this host for that long while it
moves stops and holds (:meth:`set_watchdog`); a cycle that finds one stopped so while this
arm is still cycling sends it its goal again with the next cycle.  It also sets their
``watchdog_feed`` to goals only (:meth:`stream_goals`): this arm streams goals whose
coupling offsets are right only until the next cycle, so another program's READs (a
monitor, ``armctl status``) must not keep a dead host's goals driving the arm; the cycles
feed it with their goals, or an explicit keep-alive when a cycle has none for a joint it
drives.  :meth:`close` gives back what it found.

**Errors.**  Alarms (overheating, input voltage, overload) are reported by name in
:attr:`ArmState.errors` and cleared with :meth:`Arm.clear_errors`: a stepper node's
SLIP/STALLED latch through its ``clear_flags`` register, an RX-64's latched alarms only by
RESET (after which this class restores the return delay it set; torque stays off).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Final

import host.arm.calibration as arm_calibration
import host.arm.cartesian as arm_cartesian
import host.arm.homing as arm_homing
import host.arm.move as arm_move
from host.arm.bus import ARM_BUS_BAUD, DEFAULT_RETRIES, DynamixelBus, Expect
from host.arm.cartesian import (
    MOVETO_SETTLE_S,
    MOVETO_SPEED_RAD_S,
    MOVETO_TOLERANCE_M,
    CartesianMove,
)
from host.arm.cycle import (
    COMMAND_AT,
    COMMAND_LEN,
    RESYNC_MIN_COUNTS,
    SERVO_READ_AT,
    SERVO_READ_LEN,
    SERVO_SLOW_READ_LEN,
    SLOW_READ_EVERY,
    STEPPER_READ_AT,
    STEPPER_READ_LEN,
    CycleWire,
    resync_clears,
)
from host.arm.discovery import discover, open_arm_transport, open_bus
from host.arm.gate import (
    HOLD_TOLERANCE_RAD,
    check_goals,
)
from host.arm.geometry import ArmGeometry
from host.arm.hold import Held, hold
from host.arm.homing import (
    SEARCH_PERIOD_S,
    SEARCH_SPEED_RAD_S,
    SEARCH_STEP_RAD,
    SEARCH_TOLERANCE_RAD,
)
from host.arm.joint_loop import JointController, TrackingLog
from host.arm.move import MOVE_DEFAULT_SPEED, MOVE_MIN_SPEED, UNHOMED_STEPPER_SPEED
from host.arm.rest import RestWatch, off_goal, settled
from host.arm.state import (
    DEFAULT_STIFFNESS_NM_PER_RAD,
    JOINT_IDS,
    JOINT_NAMES,
    N_JOINTS,
    N_STEPPERS,
    ArmState,
    Command,
    JointCalibration,
    JointInfo,
    PositionCommand,
    ServoState,
    StepperState,
    TorqueCommand,
)
from host.arm.stop_model import (
    REST_AHEAD_S,
    rest_deflection_packet,
    rest_deflections,
)
from host.arm.trajectory import (
    MOVE_BRAKE_FLOOR,
    MOVE_RAMP_S,
    SERVO_GOAL_LEAD_S,
    Vector,
    move_speed_limits,
    ramped_speeds,
    servo_lead,
    travel_time,
)
from host.errors import HostError, JointAlarmError, NodeError, ReplyTimeout, UsageError
from host.estimation.calibration_file import serial_of_arm
from host.scheduling import Scheduling
from host.transports.base import Transport, open_transport, url_options, url_scheme
from host.view.live import RobotView, ViewSpec, open_view
from protocol.control_tables import (
    ARM_SERIAL_UNSET,
    STEPPER_TABLE,
    STEPPER_WATCHDOG_DEFAULT_MS,
    STEPPER_WATCHDOG_FEED_FIRMWARE,
    STEPPER_WATCHDOG_FIRMWARE,
    StepperClear,
    WatchdogFeed,
)
from protocol.dynamixel import InstructionPacket, make_reset

_S = STEPPER_TABLE
_GOAL = _S["command_goal"]
_TORQUE = _S["torque_enable"]
#: Fast-mode return delay written at open (2 µs units).
FAST_RETURN_DELAY: Final = 0
#: The stepper nodes' command watchdog this library sets at open (ms; see
#: :meth:`Arm.set_watchdog`): a host that vanishes mid-move leaves the steppers braking
#: after this long, their motors still within about 0.2 s; ten of the 10 ms cycles a move
#: runs.
HOST_WATCHDOG_MS: Final = 100
#: The watchdog (ms) for a host whose cycles run with real-time scheduling
#: (:func:`host_watchdog_ms`): they come within a few ms of their 10 ms even beside
#: CPU-bound processes (through the emulator's ptys beside three: at most 24 ms apart in
#: 5 499 cycles, against 72 ms normally scheduled), so five cycles leave room, and a host
#: that vanishes leaves the steppers braking 50 ms sooner.
HOST_WATCHDOG_REALTIME_MS: Final = 50


def host_watchdog_ms(scheduling: Scheduling) -> int:
    """The stepper watchdog (ms) for a host whose cycles run with ``scheduling``
    (:func:`host.scheduling.current` of the thread that cycles):
    :data:`HOST_WATCHDOG_REALTIME_MS` real-time, else :data:`HOST_WATCHDOG_MS`."""
    return HOST_WATCHDOG_REALTIME_MS if scheduling.realtime else HOST_WATCHDOG_MS


class Arm:
    """The arm's seven joints on ``bus``; use :meth:`open`.  ``joints`` as discovered."""

    def __init__(self, bus: DynamixelBus, joints: Sequence[JointInfo]) -> None:
        if [j.dxl_id for j in joints] != list(JOINT_IDS):
            raise UsageError(f"the arm needs joints at IDs {JOINT_IDS}")
        self.bus = bus
        self.joints = tuple(joints)
        self.return_delay: int | None = None
        #: Absolute joint frames after homing (:mod:`host.arm.homing`); None: the nodes'
        #: frames (angles from power-up), and :attr:`homed` is False.
        self.calibration: JointCalibration | None = None
        #: Called with every cycle's :class:`ArmState` (a recorder, a plot): whoever runs
        #: the cycles (a move, a controller) need not know they are watched.
        self.state_taps: list[Callable[[ArmState], None]] = []
        #: The browser view drawing this arm (:meth:`watch`), if any.
        self.view: RobotView | None = None
        self._owns_view = False
        #: The last state a cycle read (None before any): what a hold starts from.
        self.last_state: ArmState | None = None
        #: The state the cycle before read: with :attr:`last_state`, the motors' speeds
        #: (where a hold lets each motor stop).
        self.previous_state: ArmState | None = None
        #: Cycles run; every :data:`SLOW_READ_EVERY`-th from the first reads the slow registers.
        self.cycles = 0
        #: The cycles' bytes, and what encoding them remembers between cycles.
        self.wire = CycleWire(self.joints)
        #: The hand is on the flange: its weight counts in the model of the arm at rest
        #: that the stepper nodes get with every goal (:mod:`host.arm.stop_model`).
        self.hand = True
        #: The stepper nodes' command watchdog (s) as this arm set it (the nodes' default
        #: until it does).
        self.watchdog_s = STEPPER_WATCHDOG_DEFAULT_MS / 1000
        #: Each stepper node's ``watchdog_feed`` before :meth:`stream_goals` set it (bus ID
        #: -> value): what :meth:`close` gives back.
        self._feed_found: dict[int, int] = {}
        #: The arm's kinematic calibration (zero offsets, link geometry) that Cartesian
        #: moves use (None: the CAD model); :meth:`load_calibration` sets it.
        self.geometry: ArmGeometry | None = None

    # ------------------------------------------------------------------ opening

    @classmethod
    def open(cls, url: str | Transport, *, return_delay: int | None = FAST_RETURN_DELAY,
             retries: int = DEFAULT_RETRIES,
             latency_s: float | None = None,
             stiffness: Sequence[float] = DEFAULT_STIFFNESS_NM_PER_RAD,
             view: ViewSpec = None,
             watchdog_ms: int | None = HOST_WATCHDOG_MS) -> Arm:
        """Open the arm's bus ``url`` (a serial path, by default at 1 Mbaud, any
        transport URL, or an open :class:`~host.transports.base.Transport`), discover the seven joints, set every node's return delay to
        ``return_delay`` (2 µs units; None: leave it), the stepper nodes' command watchdog
        to ``watchdog_ms`` (:meth:`set_watchdog`; None: leave it) and read their goals.
        ``view`` (True, a port, or a :class:`~host.view.live.RobotView` to share): draw every
        cycle in a browser view (:mod:`host.view.live`; its address on stderr), closed with the
        arm unless it was given.

        Raises :class:`~host.errors.TransportError` (no such port),
        :class:`~host.errors.ReplyTimeout` (a joint does not answer) or
        :class:`~host.errors.NodeError` (a node that is not what the arm has there).
        """
        transport = url if isinstance(url, Transport) else open_arm_transport(url)
        try:
            arm = cls.on(transport, return_delay=return_delay, retries=retries,
                         latency_s=latency_s, stiffness=stiffness, watchdog_ms=watchdog_ms)
            arm.watch(view)
            return arm
        except BaseException:
            transport.close()
            raise

    @classmethod
    def on(cls, transport: Transport, *, return_delay: int | None = FAST_RETURN_DELAY,
           retries: int = DEFAULT_RETRIES, latency_s: float | None = None,
           stiffness: Sequence[float] = DEFAULT_STIFFNESS_NM_PER_RAD,
           watchdog_ms: int | None = HOST_WATCHDOG_MS) -> Arm:
        """As :meth:`open`, on a transport already open (e.g. an in-process emulator's
        ``EmulatorTransport(emulator, "arm")``); closing the arm closes it."""
        bus = DynamixelBus(transport, getattr(transport, "baud", ARM_BUS_BAUD),
                           retries=retries, latency_s=latency_s)
        arm = cls(bus, discover(bus, stiffness))
        if return_delay is not None:
            arm.set_return_delay(return_delay)
        if watchdog_ms is not None:
            arm.set_watchdog(watchdog_ms)
        arm.stream_goals()
        arm.read_goals()
        return arm

    @property
    def transport(self) -> Transport:
        """The bus's transport."""
        return self.bus.transport

    def watch(self, view: ViewSpec) -> RobotView | None:
        """Draw this arm's cycles in ``view`` (see :meth:`open`); the view, or None."""
        self.view = open_view(view)
        if self.view is not None:
            self._owns_view = not isinstance(view, RobotView)
            self.view.attach_arm(self)
        return self.view

    def close(self) -> None:
        """Give the stepper nodes back the ``watchdog_feed`` :meth:`stream_goals` found,
        then close the transport (torque is left as it is) and a view this arm opened.  A
        host killed before this leaves the nodes on goals only: safe, and the next clean
        session that found the default gives it back."""
        found, self._feed_found = self._feed_found, {}
        if found and not self.transport.closed:
            try:
                self._write_feed({i: bytes([v]) for i, v in found.items()})
            except HostError:
                pass  # a bus gone: nothing to give back to
        self.bus.transport.close()
        if self.view is not None and self._owns_view:
            self.view.close()

    def __enter__(self) -> Arm:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: object) -> None:
        """Close; when the block raised (Ctrl-C included), first :meth:`hold` the arm where
        it is, and add a note saying what was held (or why not) to the exception."""
        try:
            # a JointAlarmError held the arm at the alarm, and says so
            if exc is not None and not isinstance(exc, JointAlarmError) \
                    and not self.transport.closed:
                note: str | None
                try:
                    held = self.hold()
                    # nothing to hold is news only after Ctrl-C (what did it leave?)
                    note = held.describe() if held.joints or isinstance(
                        exc, KeyboardInterrupt) else None
                except HostError as failed:
                    note = f"could not hold the arm: {failed}"
                if note is not None:
                    exc.add_note(f"the arm: {note}")
        finally:
            self.close()

    def hold(self) -> Held:
        """Stop every joint whose torque is on where it is, torque left on
        (:func:`host.arm.hold.hold`: a stepper's goal := where its motor stops, with the
        coupling offset of the joints as they are; a servo's := its setpoint); what was
        held, and what not."""
        return hold(self)

    @property
    def serial(self) -> str | None:
        """The arm's serial number (``arm-`` and four hex digits,
        :func:`~host.estimation.calibration_file.serial_of_arm`) as J1's stepper node holds
        it in ``arm_serial`` (programmed at assembly, read at discovery); None if the node
        was never given one.  Its calibration file is named by it."""
        value = self.joints[0].arm_serial
        return None if value == ARM_SERIAL_UNSET else serial_of_arm(value)

    def load_calibration(self, choice: str | None = None) -> arm_calibration.ArmCalibrationChoice:
        """Find and use this arm's kinematic calibration (``choice``: None for the default
        file of its :attr:`serial`, ``"none"``, or a path): see
        :func:`host.arm.calibration.choose_calibration`; sets :attr:`geometry`.  Print the
        choice's ``summary()`` and ``warnings``: a missing, another robot's or a stale file
        leaves the CAD model with a warning, never silently."""
        chosen = arm_calibration.choose_calibration(self.serial, choice,
                                                    self.joints[0].firmware_version)
        self.geometry = chosen.geometry
        return chosen

    @property
    def steppers(self) -> tuple[JointInfo, ...]:
        """J1..J4."""
        return self.joints[:N_STEPPERS]

    @property
    def servos(self) -> tuple[JointInfo, ...]:
        """J5..J7."""
        return self.joints[N_STEPPERS:]

    def set_return_delay(self, units: int) -> None:
        """Write every node's return delay (register 5, 2 µs units, 0..254; EEPROM)."""
        if not 0 <= units <= 254:
            raise UsageError(f"return delay {units} outside 0..254 (2 µs units)")
        for j in self.joints:
            self.bus.set_return_delay(j.dxl_id, units)
        self.return_delay = units

    def set_watchdog(self, timeout_ms: int) -> None:
        """Set the stepper nodes' command watchdog (``watchdog_timeout``, ms, 0 = off; RAM,
        back to its default at power-up) on those whose firmware has it (the RX-64s have
        none).  A node that hears nothing from the host for that long while it moves stops
        and holds (StepperFlag.WATCHDOG; nothing latched); every :meth:`cycle` feeds it, so
        a host that cycles (a move, a controller, a recording) is never stopped, and a
        joint at rest is left alone however long the host is idle.  A host that was late
        (a cycle more than the timeout after the last) finds the node stopped
        (``StepperState.watchdog``); the cycle after the one that saw it sends that joint the
        goal this arm last sent it again (a joint it has sent a goal: a program that only
        reads changes nothing), so a loop that sends a goal once and then only reads
        (homing's search) goes on."""
        reg = _S["watchdog_timeout"]
        low, high = reg.minimum or 0, reg.maximum or 0
        if not low <= timeout_ms <= high:
            raise UsageError(f"watchdog timeout {timeout_ms} outside {low}..{high} ms")
        nodes = {j.dxl_id: reg.encode(timeout_ms) for j in self.steppers
                 if j.firmware_version >= STEPPER_WATCHDOG_FIRMWARE}
        if nodes:  # read back: a collision loses a SYNC_WRITE silently
            self.bus.sync_write_confirmed(reg.address, reg.size, nodes)
        self.watchdog_s = timeout_ms / 1000

    def stream_goals(self) -> None:
        """Set the stepper nodes' ``watchdog_feed`` to :attr:`WatchdogFeed.GOALS_ONLY` on
        those whose firmware has it (older ones go on counting any instruction), noting what
        each had for :meth:`close`: only this arm's goals and keep-alives then feed their
        command watchdog, not another program's READs.  The cycles send a keep-alive to a
        stepper this arm has sent a goal when they carry none for it (a loop that sends a
        goal once and then only reads), so such a loop is not stopped."""
        reg = _S["watchdog_feed"]
        ids = [j.dxl_id for j in self.steppers
               if j.firmware_version >= STEPPER_WATCHDOG_FEED_FIRMWARE]
        if not ids:
            return
        replies = self.bus.bulk_read([(reg.size, i, reg.address) for i in ids])
        found = {i: reg.decode(replies[i].params) for i in ids}
        self._write_feed({i: reg.encode(int(WatchdogFeed.GOALS_ONLY)) for i in ids})
        self._feed_found = {**found, **self._feed_found}  # the first found stays
        self.wire.keep_alive_ids = frozenset(ids)

    def _write_feed(self, values: dict[int, bytes]) -> None:
        """SYNC_WRITE ``watchdog_feed`` (bus ID -> its byte), read back until the nodes hold
        it (another program's frame colliding with the write loses it without a word: left
        on any instruction, a node would let that program's READs drive a dead host's
        goals on); the cycles' keep-alives go to the nodes left on goals only."""
        reg = _S["watchdog_feed"]
        self.bus.sync_write_confirmed(reg.address, reg.size, values)
        self.wire.keep_alive_ids = frozenset(
            i for i, v in values.items() if v[0] == int(WatchdogFeed.GOALS_ONLY))

    def read_goals(self) -> None:
        """Learn each stepper node's goal (``command_goal``, 1/16 counts) with one
        BULK_READ, for the states' ``goal`` (a node sets it to its encoder count at
        power-up), then read a state: the coupling offsets sent with goals need it."""
        replies = self.bus.bulk_read([(_GOAL.size, j.dxl_id, _GOAL.address)
                                      for j in self.steppers])
        self.wire.learn_goals([_GOAL.decode(replies[j.dxl_id].params) for j in self.steppers])
        torque = self.bus.bulk_read([(_TORQUE.size, j.dxl_id, _TORQUE.address)
                                     for j in self.steppers])
        state = self.cycle()
        self.wire.found_unpowered([bool(_TORQUE.decode(torque[j.dxl_id].params))
                                   for j in self.steppers], state)

    @property
    def stepper_goals(self) -> list[float]:
        """Each stepper node's goal (joint encoder counts, in 1/16 steps): what this arm
        last sent, learnt from the nodes by :meth:`read_goals`."""
        return self.wire.stepper_goals

    @property
    def stepper_counts(self) -> list[int] | None:
        """Each stepper node's encoder count in the last state read (None before any)."""
        return self.wire.stepper_counts

    @property
    def encoder_at_power_up(self) -> list[int]:
        """Encoder count at each stepper node's power-up (from each cycle's step count,
        encoder and deflection)."""
        return self.wire.encoder_at_power_up

    @property
    def bulk_reads(self) -> tuple[InstructionPacket, InstructionPacket]:
        """The cycle's BULK_READ: (every cycle, the slow-register cycles)."""
        return self.wire.bulk_reads

    @property
    def expected_replies(self) -> tuple[list[Expect], list[Expect]]:
        """The replies to :attr:`bulk_reads`."""
        return self.wire.expected_replies

    def deflection_offsets(self) -> list[int]:
        """What each stepper node's deflection differs from its elastic element's by, now
        (counts; :meth:`host.arm.cycle.CycleWire.deflection_offsets`)."""
        return self.wire.deflection_offsets()

    # ------------------------------------------------------------------ commands as data

    def _joint(self, joint: int | str) -> int:
        if isinstance(joint, str):
            if joint not in JOINT_NAMES:
                raise UsageError(f"no joint {joint!r}; joints are {', '.join(JOINT_NAMES)}")
            return JOINT_NAMES.index(joint)
        if not 0 <= joint < N_JOINTS:
            raise UsageError(f"joint {joint} outside 0..{N_JOINTS - 1} (J1..J7)")
        return joint

    def make_position(self, joint: int | str, angle: float,
                      speed: float | None = None) -> PositionCommand:
        """A command moving ``joint`` (0..6 or ``"J1"``..``"J7"``) to ``angle`` (rad), at
        most ``speed`` (rad/s) if given.  Nothing is sent until :meth:`cycle`."""
        if not math.isfinite(angle):
            raise UsageError(f"joint angle {angle} is not a number")
        if speed is not None and not speed > 0:
            raise UsageError(f"joint speed {speed} must be > 0 rad/s")
        return PositionCommand(self._joint(joint), float(angle), speed)

    def make_torque(self, joint: int | str, on: bool) -> TorqueCommand:
        """A command enabling or disabling ``joint``'s torque."""
        return TorqueCommand(self._joint(joint), bool(on))

    def make_positions(self, angles: Sequence[float],
                       speeds: Sequence[float | None] | None = None) -> list[PositionCommand]:
        """Position commands for all seven joints (rad; speeds rad/s or None each)."""
        if len(angles) != N_JOINTS or (speeds is not None and len(speeds) != N_JOINTS):
            raise UsageError(f"give {N_JOINTS} joint angles (and speeds), J1..J7")
        return [self.make_position(i, a, None if speeds is None else speeds[i])
                for i, a in enumerate(angles)]

    def packets_for(self, commands: Iterable[Command]) -> list[InstructionPacket]:
        """The SYNC_WRITEs that carry ``commands`` (the last command for a joint wins;
        :meth:`host.arm.cycle.CycleWire.packets_for`)."""
        return self.wire.packets_for(commands)

    # ------------------------------------------------------------------ the cycle

    def cycle(self, commands: Iterable[Command] = ()) -> ArmState:
        """Send ``commands`` and read the state of all seven joints in one exchange."""
        commands = list(commands)
        calibration = self.calibration
        if calibration is not None:
            commands = calibration.commands_to_node(commands)
        slow = int(self.cycles % SLOW_READ_EVERY == 0)
        packets = [*self.packets_for(commands), *self._rest_model(commands),
                   self.bulk_reads[slow]]
        replies = self.bus.exchange(packets, self.expected_replies[slow])
        self.cycles += 1
        self.wire.took_goals(commands)  # the nodes took the goals: the state reports them
        state = self.decode_state(self.bus.transport.now(), {s.id: (s.error, s.params)
                                                             for s in replies})
        self.wire.took_torque(commands, state)  # which steppers are unpowered, since where
        if calibration is not None:
            state = calibration.state_from_node(state)
        self.previous_state, self.last_state = self.last_state, state
        for tap in self.state_taps:
            tap(state)
        return state

    def _rest_model(self, commands: list[Command]) -> list[InstructionPacket]:
        """With stepper goals, once homed: the nodes' ``rest_deflection`` from the last
        state (:mod:`host.arm.stop_model`)."""
        state = self.last_state
        if (state is None or self.calibration is None
                or not any(isinstance(c, PositionCommand) and c.joint < N_STEPPERS
                           for c in commands)):
            return []
        values = rest_deflections(self.steppers, state, self.wire.deflection_offsets(),
                                  hand=self.hand, ahead_s=self.watchdog_s + REST_AHEAD_S)
        packet = rest_deflection_packet(self.steppers, values, frozenset(self.wire.unpowered))
        return [] if packet is None else [packet]

    @property
    def stepper_speed_limits(self) -> list[float | None]:
        """Each stepper node's speed limit (rad/s) as this arm last wrote it (None: not
        written since it opened): how fast its motor may turn at most."""
        return self.wire.stepper_speed_limits

    @property
    def unpowered_steppers(self) -> frozenset[int]:
        """The stepper joints (0..3) whose torque this arm turned off, or found off."""
        return frozenset(self.wire.unpowered)

    def send(self, commands: Iterable[Command]) -> None:
        """Send position ``commands`` without reading anything back (no reply is waited
        for): what a hold does first, while the line may still carry the replies of an
        exchange cut short.  The stepper goals go with the coupling offsets of the last
        state read."""
        commands = list(commands)
        if self.calibration is not None:
            commands = self.calibration.commands_to_node(commands)
        self.bus.exchange(self.packets_for(commands))
        self.wire.took_goals(commands, sent=False)

    def decode_state(self, t: float, replies: dict[int, tuple[int, bytes]]) -> ArmState:
        """An :class:`ArmState` from each node's ``(error byte, data)`` of a cycle's read
        (the nodes' frame; :meth:`host.arm.cycle.CycleWire.decode_state`)."""
        return self.wire.decode_state(t, replies)

    # ------------------------------------------------------------------ homing, Cartesian

    @property
    def homed(self) -> bool:
        """True once :meth:`home` (or :func:`host.arm.homing.restore`) fixed the joints'
        absolute angles; until then angles are the nodes' (from power-up)."""
        return self.calibration is not None

    def home(self, *, speed: float = SEARCH_SPEED_RAD_S, step: float = SEARCH_STEP_RAD,
             period: float = SEARCH_PERIOD_S,
             tolerance: float = SEARCH_TOLERANCE_RAD) -> JointCalibration:
        """Find every stepper joint's index mark and fix the joints' absolute angles:
        ``speed`` (rad/s) and ``step`` (rad) shape the search, ``period`` (s) is its polling
        cycle, ``tolerance`` (rad) when a search target counts as reached
        (:func:`host.arm.homing.home`, which raises :class:`~host.errors.HomingError`)."""
        return arm_homing.home(self, speed=speed, step=step, period=period,
                               tolerance=tolerance)

    def moveto(self, xyz: Vector, rpy: Vector | None = None, *,
               speed: float = MOVETO_SPEED_RAD_S, tolerance_m: float = MOVETO_TOLERANCE_M,
               settle_timeout: float = MOVETO_SETTLE_S,
               controller: JointController | None = None, allow_unhomed: bool = False,
               hand: bool = True, log: TrackingLog | None = None,
               until: Callable[[ArmState], bool] | None = None,
               geometry: ArmGeometry | None = None) -> CartesianMove:
        """Move the flange to ``xyz`` (m, base frame), oriented ``rpy`` (rad) if given:
        IK, then an interpolated, feed-forward-compensated joint move at ``speed`` (rad/s,
        fastest joint) until the flange is within ``tolerance_m`` (m) and the arm at rest,
        or ``settle_timeout`` (s) passed (:func:`host.arm.cartesian.moveto`: ``controller``,
        ``allow_unhomed``, ``hand`` on the flange, ``log``; ``until``: a guarded move, held
        where it is the first cycle ``until(state)`` is true; ``geometry``: the kinematics,
        default :attr:`geometry`, the arm's calibration if loaded, else the CAD model); the
        result carries the joint goals."""
        return arm_cartesian.moveto(self, xyz, rpy, speed=speed, tolerance_m=tolerance_m,
                                    settle_timeout=settle_timeout, controller=controller,
                                    allow_unhomed=allow_unhomed, hand=hand, log=log,
                                    until=until,
                                    geometry=self.geometry if geometry is None else geometry)

    # ------------------------------------------------------------------ conveniences

    def state(self) -> ArmState:
        """Read the state of all seven joints (a cycle without commands)."""
        return self.cycle()

    def torque(self, on: bool, joints: Iterable[int | str] | None = None, *,
               hold: bool = False) -> ArmState:
        """Enable or disable the torque of ``joints`` (default: all).

        A joint whose torque comes on heads for the goal its node has, which may be far
        from where the joint now is (a goal sent while its torque was off, the arm moved
        by hand since).  ``hold=True`` (with ``on``) makes each of those joints whose
        torque is off hold where it is instead: its goal becomes its present angle (rad;
        a stepper's joint angle, its elastic element taken as relaxed) in the same cycle."""
        chosen = [self._joint(j) for j in (range(N_JOINTS) if joints is None else joints)]
        commands: list[Command] = []
        if on and hold:
            enabled = self.torque_enabled()
            state = self.cycle()
            commands = [self.make_position(j, state.joints[j]) for j in chosen
                        if not enabled[j]]
        return self.cycle([*commands, *(self.make_torque(j, on) for j in chosen)])

    def torque_enabled(self) -> tuple[bool, ...]:
        """Each joint's ``torque_enable`` register (J1..J7), read with one BULK_READ: False
        where the host turned the torque off, or the node did (a latched alarm)."""
        replies = self.bus.bulk_read([(_TORQUE.size, j.dxl_id, _TORQUE.address)
                                      for j in self.joints])
        return tuple(bool(_TORQUE.decode(replies[j.dxl_id].params)) for j in self.joints)

    def check_limits(self, angles: Sequence[float], present: Sequence[float] | None = None,
                     tolerance: float = HOLD_TOLERANCE_RAD) -> None:
        """Raise :class:`~host.errors.LimitError` (a :class:`~host.errors.UsageError`)
        naming the first goal (rad, J1..J7) that is not finite or outside its joint's range
        (:func:`host.arm.gate.check_goals`: the servos' always, the steppers' once homed,
        before that a stepper goal further from the ``present`` angle than the joint's whole
        range).  A goal within ``tolerance`` (rad) of the joint's ``present`` angle (rad,
        7) passes: a joint already out there may hold where it is."""
        here = list(angles) if present is None else present
        check_goals(angles, here, homed=self.homed, tolerance=tolerance)

    def set_position(self, joint: int | str, angle: float,
                     speed: float | None = None) -> ArmState:
        """Move one joint (rad, rad/s)."""
        return self.cycle([self.make_position(joint, angle, speed)])

    def set_positions(self, angles: Sequence[float],
                      speeds: Sequence[float | None] | None = None) -> ArmState:
        """Move all seven joints at once (rad, rad/s)."""
        return self.cycle(self.make_positions(angles, speeds))

    def motor_goals(self, angles: Sequence[float]) -> list[float]:
        """The goals (rad, seven) :meth:`move` sends so the joints land on ``angles`` (rad):
        each stepper's motor where the routes' coupling and, once homed, its spring's sag
        under the arm's weight (the hand's too while :attr:`hand`) leave its joint on the
        goal (:mod:`host.arm.motor_goals`); the servos' as they are.
        """
        return arm_move.motor_goals_of(self, angles)

    def move(self, angles: Sequence[float], *, duration: float | None = None,
             speed: float | None = None, tolerance: float = 0.02,
             settle_speed: float = 0.05, timeout: float = 10.0, period: float = 0.01,
             rest: RestWatch | None = None,
             unhomed_speed: float | None = UNHOMED_STEPPER_SPEED,
             motors: bool = False) -> tuple[ArmState, bool]:
        """Move all seven joints to ``angles`` (rad) and wait, cycling every ``period``
        (s) with the goals again (so the stepper nodes' coupling offsets follow the joints),
        until the move settled or ``timeout`` (s) passed after the move's own time.  The
        steppers' motors go to :meth:`motor_goals`, where the routes' coupling and (homed)
        the springs' sag leave the joints on ``angles`` (``motors=True``: ``angles`` are
        the stepper motors' goals themselves, as the nodes take them); speeds, durations
        and arrival are the motors'.  Settled: every stepper node
        stopped with its motor within ``tolerance`` (rad) of its motor goal (the joint
        within the arm model's error of ``angles``; an unmodelled load sags it) and its joint slower than
        ``settle_speed`` (rad/s), every servo within ``tolerance`` of its goal, and the
        arm at rest (``rest``, a :class:`~host.arm.rest.RestWatch`: every joint's angle and
        spring deflection still for its window, a second by default; pass one to ask
        it afterwards why a move did not settle).  ``duration`` (s) sets each joint's speed
        so all arrive together, none below :data:`MOVE_MIN_SPEED` (a joint that barely
        moves arrives early and keeps a speed limit it can hold with); ``speed`` (rad/s)
        caps every joint's instead (a stepper's at most
        :data:`~host.arm.gate.MOVE_STEPPER_SPEED_RAD_S` either way); given neither, the joint that moves furthest goes at
        :data:`MOVE_DEFAULT_SPEED` and the others arrive with it; while the arm is not homed (its stops unknown) a stepper joint goes no faster
        than ``unhomed_speed`` (rad/s, None: no such cap; the nodes keep that speed
        limit for later commands without a speed).  The steppers'
        speed limits are raised to those speeds over the first :data:`MOVE_RAMP_S` s and
        lowered again over the last, as each motor nears its goal
        (:func:`move_speed_limits`), so they arrive about that much later than at a
        constant speed.  Returns the last state and whether the move settled.

        ``timeout`` counts from when the slowest joint should have arrived at its speed
        (the move's own time), so a long move at a modest speed is not cut short.

        Before anything moves, the gate (:mod:`host.arm.gate`) raises
        :class:`~host.errors.LimitError` (a :class:`~host.errors.UsageError`) for a goal
        that is not finite or outside its joint's range, a ``duration`` or ``speed`` that
        needs a joint faster than its limit, and a joint to be moved whose torque is off.
        A joint whose node latches an alarm on the way (STALLED, SLIP, an RX-64's
        OVERLOAD ...) stops the move: the arm is held where it is and
        :class:`~host.errors.JointAlarmError` names the joint and the latch."""
        return arm_move.move(self, angles, duration=duration, speed=speed,
                             tolerance=tolerance, settle_speed=settle_speed, timeout=timeout,
                             period=period, rest=rest, unhomed_speed=unhomed_speed,
                             motors=motors)

    def clear_errors(self) -> None:
        """Clear the stepper nodes' SLIP/STALLED latches and RESET the RX-64s that report
        an alarm (restoring the return delay this arm set; their torque stays off)."""
        clear = _S["clear_flags"].encode(int(StepperClear.SLIP | StepperClear.STALL))
        self.bus.sync_write(_S["clear_flags"].address, 1,
                            {j.dxl_id: clear for j in self.steppers})
        state = self.state()
        for j, s in zip(self.servos, state.servos, strict=True):
            if s.errors:
                self.bus.exchange([make_reset(j.dxl_id)], [Expect(j.dxl_id)])
                if self.return_delay is not None:
                    self.bus.set_return_delay(j.dxl_id, self.return_delay)


#: The arm's API: :class:`Arm`, the constants of its cycle, and (from the modules they live
#: in) the free functions and types its users import from here.
__all__ = [
    "COMMAND_AT", "COMMAND_LEN", "FAST_RETURN_DELAY", "HOST_WATCHDOG_MS",
    "HOST_WATCHDOG_REALTIME_MS", "host_watchdog_ms", "MOVE_DEFAULT_SPEED", "MOVE_MIN_SPEED",
    "MOVE_BRAKE_FLOOR", "MOVE_RAMP_S", "move_speed_limits", "ramped_speeds", "travel_time",
    "RESYNC_MIN_COUNTS", "SERVO_GOAL_LEAD_S", "servo_lead", "SERVO_READ_AT", "SERVO_READ_LEN", "SERVO_SLOW_READ_LEN",
    "SLOW_READ_EVERY", "STEPPER_READ_AT", "STEPPER_READ_LEN", "Arm", "resync_clears",
    # moved out, importable here as before
    "discover", "open_arm_transport", "open_bus", "off_goal", "settled",
    "CartesianMove", "Held", "JointCalibration", "JointController", "TrackingLog",
    "ARM_BUS_BAUD", "DEFAULT_STIFFNESS_NM_PER_RAD", "HOLD_TOLERANCE_RAD", "JOINT_IDS",
    "JOINT_NAMES", "N_JOINTS", "N_STEPPERS", "ArmState", "Command", "JointInfo",
    "PositionCommand", "ServoState", "StepperState", "TorqueCommand",
    # other host modules' names this module once imported, kept for programs that used them
    "NodeError", "ReplyTimeout", "open_transport", "url_options", "url_scheme",
]
