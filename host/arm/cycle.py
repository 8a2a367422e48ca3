"""The bytes of the arm's cycles: commands into SYNC_WRITEs, the BULK_READ of the seven
nodes' state, and what encoding them must remember from one cycle to the next.

:class:`CycleWire` is the wire side of :class:`host.arm.facade.Arm` (which owns the bus, the
cycle's schedule and the frames): for the joints discovery found it builds the packets a
cycle sends (:meth:`CycleWire.packets_for`) and decodes what the nodes answer
(:meth:`CycleWire.decode_state`), keeping the goals last sent, the nodes' encoder counts at
power-up, which steppers are unpowered and which the command watchdog stopped.

**Stepper goals** go to each node's *command block* (``command_goal``, in 1/16 counts, so
one microstep can be commanded, and ``deflection_offset``): with every goal the arm tells
the node ``−C·Δq`` (counts; :data:`protocol.robot.ARM_ROUTE_COUPLING`, ``Δq`` the joints
since the nodes' power-up, from the last state read), by how much the belt and cable routes
make the node's own deflection (motor − joint) differ from its elastic element's, so the
node's SLIP/STALLED protection watches the elastic element however the joints before it
moved.

**Torque off, and on again.** An unpowered stepper's rotor turns with its joint (the elastic
element relaxes; a hand moving the arm, a joint coasting on), which the node's step count
cannot follow: its deflection then says the element is wound up, and enabling the torque
would latch STALLED. So when a cycle turns on a stepper's torque that this arm turned off
and whose encoder has moved since (more than :data:`RESYNC_MIN_COUNTS`), it first sends that
node its command block (the goal it has, the coupling offset now) and ``clear_flags``
RESYNC_ROTOR: the node takes the element as relaxed and moves its step origin to match
(``step_count`` moves with it); latches the joint had when its torque went off stay (a node
latches SLIP/STALLED while its coils hold, not once the host turned them off). The joint
then heads for the goal it had, unless :meth:`host.arm.facade.Arm.torque` is told to ``hold`` it where it
is. A stepper found unpowered and without a latch when the arm
opens (power-up, or another program turned it off: ``armctl waypoints record`` then
``play``) is treated the same way. Torque the node turned off itself (an alarm, its latch
set) is not re-synced.

**Keep-alives.**  The arm sets the stepper nodes' command watchdog to be fed by goal writes
only (``watchdog_feed``, :meth:`host.arm.facade.Arm.stream_goals`); a cycle that carries
no goal for a stepper this arm has sent one (a loop that sends a goal once and then reads)
sends it a ``keep_alive`` write instead (one SYNC_WRITE, 6 bytes and 2 a node).

**What a cycle reads** (the least the state needs, as each node answers one contiguous
range): a stepper node's *cycle block* (addresses 76-88: encoder, steps, velocity,
deflection, flags; 13 bytes - mirrors of registers scattered over 26-61, see
:data:`~protocol.control_tables.STEPPER_TABLE`), an RX-64's ``present_position`` ..
``present_load`` (36-41: position, speed, load; 6 bytes), and one cycle in
:data:`SLOW_READ_EVERY` (the first included) on to ``present_temperature`` (voltage and
temperature, 2 bytes more: they drift over seconds; a state reports the last read, at most
9 cycles old); the alarm bits (overheating, input voltage among them) come in every status
packet's error byte.  That is 193 bytes per cycle with the seven goals, 199 on the slow
cycles (~512 cycles/s at 1 Mbaud in fast mode; reading every cycle's 199 bytes gave ~498;
reading ``status_flags`` .. ``step_count`` plus ``deflection`` instead of the cycle block
would cost 18 + 18 bytes more per stepper).
The stepper's goal is not in the block: the state reports the goal this arm last sent
(learnt from the nodes' ``goal_position`` at :meth:`host.arm.facade.Arm.open` and :meth:`host.arm.facade.Arm.read_goals`;
call the latter if anything else writes goals).  Discovery refuses stepper nodes whose
firmware predates the block (``firmware_version`` <
:data:`~protocol.control_tables.STEPPER_CYCLE_BLOCK_FIRMWARE`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Sequence
from typing import Final

from host.arm.bus import Expect
from host.arm.state import (
    N_STEPPERS,
    ArmState,
    Command,
    JointInfo,
    PositionCommand,
    ServoState,
    StepperState,
    TorqueCommand,
)
from protocol.control_tables import (
    GOAL_FINE_PER_COUNT,
    RX64_TABLE,
    STEPPER_COMMAND_BLOCK,
    STEPPER_CYCLE_BLOCK,
    STEPPER_ROTOR_RESYNC_FIRMWARE,
    STEPPER_TABLE,
    StepperClear,
    StepperFlag,
)
from protocol.dynamixel import (
    ErrorBit,
    InstructionPacket,
    make_bulk_read,
    make_sync_write,
    radians_to_rx64_position,
    rpm_to_rx64_speed,
    rx64_load_to_fraction,
    rx64_position_to_radians,
    rx64_present_speed_to_rad_s,
)
from protocol.robot import arm_route_coupling_matrix, series_elastic_torque

_S = STEPPER_TABLE
_R = RX64_TABLE
#: What a cycle reads from a stepper node: its cycle block (see the module docs).
STEPPER_READ_AT: Final = _S[STEPPER_CYCLE_BLOCK[0]].address
STEPPER_READ_LEN: Final = _S[STEPPER_CYCLE_BLOCK[1]].end - STEPPER_READ_AT
#: What a cycle reads from an RX-64: present_position .. present_load ...
SERVO_READ_AT: Final = _R["present_position"].address
SERVO_READ_LEN: Final = _R["present_load"].end - SERVO_READ_AT
#: ... and every :data:`SLOW_READ_EVERY` cycles on to present_temperature (with the voltage).
SERVO_SLOW_READ_LEN: Final = _R["present_temperature"].end - SERVO_READ_AT
#: One cycle in this many (the first included) reads the RX-64s' voltage and temperature.
SLOW_READ_EVERY: Final = 10
_STEPPER_FIELDS = struct.Struct("<iihhB")  # position, steps, velocity, deflection, flags
_SERVO_FIELDS = struct.Struct("<HHH")  # position, speed, load
_SERVO_SLOW_FIELDS = struct.Struct("<BB")  # voltage (0.1 V), temperature (°C)
assert _STEPPER_FIELDS.size == STEPPER_READ_LEN and _SERVO_FIELDS.size == SERVO_READ_LEN
assert SERVO_READ_LEN + _SERVO_SLOW_FIELDS.size == SERVO_SLOW_READ_LEN
_GOAL = _S["command_goal"]
_TORQUE = _S["torque_enable"]
_OFFSET = _S["deflection_offset"]
_KEEP_ALIVE = _S["keep_alive"]
#: The stepper command block (command_goal, deflection_offset): address and length.
COMMAND_AT: Final = _S[STEPPER_COMMAND_BLOCK[0]].address
COMMAND_LEN: Final = _S[STEPPER_COMMAND_BLOCK[1]].end - COMMAND_AT
_ROUTES = [[float(c) for c in row] for row in arm_route_coupling_matrix()]
#: A stepper joint whose encoder moved more than this (counts) while this arm had its
#: torque off gets its rotor re-synced when the torque comes on again (see the module docs).
RESYNC_MIN_COUNTS: Final = 2
#: The latches a stepper node keeps while its coils hold (not once the host turned them off).
LATCHES: Final = StepperFlag.SLIP | StepperFlag.STALLED


class CycleWire:
    """The arm's cycles on the wire for ``joints`` as discovered (J1..J7)."""

    def __init__(self, joints: Sequence[JointInfo]) -> None:
        self.joints = tuple(joints)
        self.steppers = self.joints[:N_STEPPERS]
        self.servos = self.joints[N_STEPPERS:]
        #: Each stepper node's goal (joint encoder counts, in 1/16 steps): what the arm
        #: last sent, learnt from the nodes at open (:meth:`learn_goals`).
        self.stepper_goals = [0.0] * N_STEPPERS
        #: Each stepper node's encoder count in the last state read (None before any).
        self.stepper_counts: list[int] | None = None
        #: Encoder count at each stepper node's power-up (from each cycle's step count,
        #: encoder and deflection).
        self.encoder_at_power_up = [0] * N_STEPPERS
        #: Last commanded RX-64 moving speeds (register units; 0 = maximum).
        self._servo_speed = [0, 0, 0]
        #: Each stepper node's ``velocity_limit`` as this arm last wrote it (rad/s; None:
        #: not written): no motor turns faster.
        self.stepper_speed_limits: list[float | None] = [None] * N_STEPPERS
        #: Stepper joints whose torque is off: joint -> (encoder count, latched
        #: SLIP/STALLED flags) in the state read with that command.
        #: Those found unpowered when the arm opened have no count (None): any move counts.
        self.unpowered: dict[int, tuple[int | None, StepperFlag]] = {}
        #: Stepper joints the last state found stopped by their node's command watchdog
        #: (the host was late): the next cycle sends them the arm's goal again.
        self._watchdog_stopped: set[int] = set()
        #: Stepper joints the arm has sent a goal (not just learnt one at open): only those
        #: are resumed, so a program that only reads (armctl status) changes nothing.
        self._goals_sent: set[int] = set()
        #: Bus IDs of the stepper nodes whose command watchdog only goals and keep-alives
        #: feed (``watchdog_feed`` goals only, as the arm set it): a cycle without a goal for
        #: one this arm has sent a goal sends it a keep-alive.
        self.keep_alive_ids: frozenset[int] = frozenset()
        #: Each RX-64's (voltage 0.1 V, temperature °C) as last read.
        self._servo_slow = [(0, 0)] * len(self.servos)
        entries = [(STEPPER_READ_LEN, j.dxl_id, STEPPER_READ_AT) for j in self.steppers]
        fast = entries + [(SERVO_READ_LEN, j.dxl_id, SERVO_READ_AT) for j in self.servos]
        slow = entries + [(SERVO_SLOW_READ_LEN, j.dxl_id, SERVO_READ_AT) for j in self.servos]
        #: The cycle's BULK_READ and its replies: (every cycle, the slow-register cycles).
        self.bulk_reads = (make_bulk_read(fast), make_bulk_read(slow))
        self.expected_replies = ([Expect(dxl_id, length) for length, dxl_id, _ in fast],
                                 [Expect(dxl_id, length) for length, dxl_id, _ in slow])

    def learn_goals(self, goals: Sequence[int]) -> None:
        """Take each stepper node's ``command_goal`` (1/16 counts) as the goal it has."""
        self.stepper_goals = [g / GOAL_FINE_PER_COUNT for g in goals]

    def found_unpowered(self, torque_on: Sequence[bool], state: ArmState) -> None:
        """Note the stepper joints found with their torque off and no latch in ``state``
        (another program or power-up turned it off; the rotor turned with the joint since):
        enabling one re-syncs its node first."""
        for k, on in enumerate(torque_on):
            # unpowered and not alarmed (a node latches SLIP/STALLED only while its coils
            # hold): whoever turned its torque off, another program or power-up, the rotor
            # turned with the joint since, so enabling it re-syncs the node first
            if not on and not state.steppers[k].flags & LATCHES:
                self.unpowered[k] = (None, StepperFlag(0))

    def took_goals(self, commands: Iterable[Command], *, sent: bool = True) -> None:
        """The nodes took the stepper goals of ``commands`` (the nodes' frame): states
        report them; ``sent`` (a cycle's, not a hold's write) makes them resumable after
        the command watchdog stopped a joint."""
        for c in commands:
            if isinstance(c, PositionCommand) and c.joint < N_STEPPERS:
                if sent:
                    self._goals_sent.add(c.joint)
                self.stepper_goals[c.joint] = (self.joints[c.joint].rad_to_fine(c.angle)
                                               / GOAL_FINE_PER_COUNT)

    def took_torque(self, commands: Iterable[Command], state: ArmState) -> None:
        """Which steppers ``commands`` left unpowered, and since where (``state``, read in
        the same cycle)."""
        counts = self.stepper_counts or [0] * N_STEPPERS
        for c in commands:
            if isinstance(c, TorqueCommand) and c.joint < N_STEPPERS:
                if c.on:
                    self.unpowered.pop(c.joint, None)
                elif c.joint not in self.unpowered:
                    self.unpowered[c.joint] = (counts[c.joint],
                                               state.steppers[c.joint].flags & LATCHES)

    def deflection_offsets(self) -> list[int]:
        """What each stepper node's deflection differs from its elastic element's by, now
        (counts): ``−C·Δq``, ``Δq`` the joints since the nodes' power-up in the last state
        read (0 before any state)."""
        counts = self.stepper_counts
        if counts is None:
            return [0] * N_STEPPERS
        return [-round(turn) for turn in self._route_turns(counts)]

    def _route_turns(self, counts: Sequence[int]) -> list[float]:
        """How far the routes have turned each stepper's capstan (counts, ``C·Δq``) with the
        joints at ``counts`` (encoder counts), ``Δq`` since the nodes' power-up."""
        moved = [c - p for c, p in zip(counts, self.encoder_at_power_up, strict=True)]
        return [sum(c * d for c, d in zip(row, moved, strict=True)) for row in _ROUTES]

    def packets_for(self, commands: Iterable[Command]) -> list[InstructionPacket]:
        """The SYNC_WRITEs that carry ``commands`` (the last command for a joint wins)."""
        torque: dict[int, bytes] = {}
        stepper_goal: dict[int, bytes] = {}
        offsets: list[int] | None = None
        stepper_speed: dict[int, bytes] = {}
        servo: dict[int, PositionCommand] = {}
        for c in commands:
            j = self.joints[c.joint]
            if isinstance(c, TorqueCommand):
                torque[j.dxl_id] = b"\x01" if c.on else b"\x00"
            elif j.kind == "stepper":
                if offsets is None:
                    offsets = self.deflection_offsets()
                offset = max(-32768, min(32767, offsets[c.joint]))
                stepper_goal[j.dxl_id] = (_GOAL.encode(j.rad_to_fine(c.angle))
                                          + _OFFSET.encode(offset))
                if c.speed is not None:
                    counts = min(max(j.rad_to_counts(c.speed), 1), _S["velocity_limit"].maximum
                                 or 1_000_000)
                    stepper_speed[j.dxl_id] = _S["velocity_limit"].encode(counts)
                    self.stepper_speed_limits[c.joint] = j.counts_to_rad(counts)
            else:
                servo[j.dxl_id] = c
        for joint in self._watchdog_stopped & self._goals_sent:
            j = self.joints[joint]
            if j.dxl_id not in stepper_goal and torque.get(j.dxl_id) != b"\x00":
                if offsets is None:
                    offsets = self.deflection_offsets()
                stepper_goal[j.dxl_id] = self._goal_entry(joint, offsets)
        packets = []
        fed = set(stepper_goal)  # the nodes a goal of this cycle feeds
        resync = self._resyncs(torque)
        if resync:  # the command block (offsets), then the re-sync, then the torque
            if offsets is None:
                offsets = self.deflection_offsets()
            for joint in resync:
                j = self.joints[joint]
                if j.dxl_id not in stepper_goal:  # the goal the node has, the offset now
                    stepper_goal[j.dxl_id] = self._goal_entry(joint, offsets)
            packets.append(make_sync_write(COMMAND_AT, COMMAND_LEN, stepper_goal))
            fed.update(stepper_goal)
            stepper_goal = {}
            packets.append(make_sync_write(_S["clear_flags"].address, 1, resync_clears(
                {self.joints[joint].dxl_id: flags for joint, flags in resync.items()})))
        if torque:  # torque_enable is address 24 on both models
            packets.append(make_sync_write(_S["torque_enable"].address, 1, torque))
        if stepper_speed:
            packets.append(make_sync_write(_S["velocity_limit"].address, 4, stepper_speed))
        if stepper_goal:
            packets.append(make_sync_write(COMMAND_AT, COMMAND_LEN, stepper_goal))
        keep = {j.dxl_id: b"\x01" for k, j in enumerate(self.steppers)
                if k in self._goals_sent and j.dxl_id in self.keep_alive_ids
                and j.dxl_id not in fed and torque.get(j.dxl_id) != b"\x00"}
        if keep:  # a joint this arm drives, with no goal this cycle: still this host
            packets.append(make_sync_write(_KEEP_ALIVE.address, _KEEP_ALIVE.size, keep))
        if servo:
            packets.append(self._servo_goals(servo))
        return packets

    def _goal_entry(self, joint: int, offsets: list[int]) -> bytes:
        """A stepper's command block holding the goal this arm last sent it and the
        coupling offset now."""
        return (_GOAL.encode(round(self.stepper_goals[joint] * GOAL_FINE_PER_COUNT))
                + _OFFSET.encode(max(-32768, min(32767, offsets[joint]))))

    def _resyncs(self, torque: dict[int, bytes]) -> dict[int, StepperFlag]:
        """The stepper joints that ``torque`` turns on after this arm turned them off and
        whose encoder moved since (more than :data:`RESYNC_MIN_COUNTS`), or that were
        unpowered and not alarmed when this arm opened, with the SLIP/STALLED latches they
        had when their torque went off."""
        counts = self.stepper_counts
        out: dict[int, StepperFlag] = {}
        if counts is None:
            return out
        for joint, (count, flags) in self.unpowered.items():
            j = self.joints[joint]
            moved = count is None or abs(counts[joint] - count) > RESYNC_MIN_COUNTS
            if (torque.get(j.dxl_id) == b"\x01" and moved
                    and j.firmware_version >= STEPPER_ROTOR_RESYNC_FIRMWARE):
                out[joint] = flags
        return out

    def _servo_goals(self, servo: dict[int, PositionCommand]) -> InstructionPacket:
        goal = _R["goal_position"]
        with_speed = any(c.speed is not None for c in servo.values())
        data: dict[int, bytes] = {}
        for dxl_id, c in servo.items():
            value = goal.encode(radians_to_rx64_position(c.angle))
            if with_speed:
                k = dxl_id - self.servos[0].dxl_id
                if c.speed is not None:
                    self._servo_speed[k] = rpm_to_rx64_speed(c.speed * 60 / (2 * math.pi))
                value += _R["moving_speed"].encode(self._servo_speed[k])
            data[dxl_id] = value
        return make_sync_write(goal.address, 4 if with_speed else 2, data)

    def decode_state(self, t: float, replies: dict[int, tuple[int, bytes]]) -> ArmState:
        """An :class:`ArmState` from each node's ``(error byte, data)`` of a cycle's read."""
        steppers = []
        counts = [0] * N_STEPPERS
        fields = []
        for i, j in enumerate(self.steppers):
            error, data = replies[j.dxl_id]
            position, steps, velocity, deflection, flags = _STEPPER_FIELDS.unpack_from(data)
            counts[i] = position
            fields.append((error, position, steps, velocity, deflection, flags))
            # Where the encoder stood when the step count was 0 (the node's power-up):
            # the motor side in encoder counts is that plus the steps' worth.
            self.encoder_at_power_up[i] = (position + deflection
                                           - round(steps / j.microsteps_per_count))
        # the elements' own deflections: the nodes' plus the routes' turn of the capstans
        routes = self._route_turns(counts)
        for i, j in enumerate(self.steppers):
            error, position, steps, velocity, deflection, flags = fields[i]
            deflection_rad = j.counts_to_rad(deflection)
            element = j.counts_to_rad(deflection + routes[i])
            steppers.append(StepperState(
                joint=j.joint, angle=j.counts_to_rad(position),
                velocity=j.counts_to_rad(velocity),
                motor_angle=j.counts_to_rad(position + deflection),
                step_count=steps, deflection=deflection, deflection_rad=deflection_rad,
                torque=series_elastic_torque(element, j.stiffness), flags=StepperFlag(flags),
                errors=ErrorBit(error), goal=j.counts_to_rad(self.stepper_goals[i])))
        servos = []
        for k, j in enumerate(self.servos):
            error, data = replies[j.dxl_id]
            position, speed, load = _SERVO_FIELDS.unpack_from(data)
            if len(data) >= SERVO_SLOW_READ_LEN:
                self._servo_slow[k] = _SERVO_SLOW_FIELDS.unpack_from(data, SERVO_READ_LEN)
            volts, temperature = self._servo_slow[k]
            servos.append(ServoState(
                joint=j.joint, angle=rx64_position_to_radians(position),
                velocity=rx64_present_speed_to_rad_s(speed), load=rx64_load_to_fraction(load),
                temperature=float(temperature), voltage=volts / 10, errors=ErrorBit(error)))
        self.stepper_counts = counts
        self._watchdog_stopped = {i for i, s in enumerate(steppers)
                                  if s.flags & StepperFlag.WATCHDOG}
        raw = {dxl_id: data for dxl_id, (_, data) in replies.items()}
        return ArmState(t, tuple(steppers), tuple(servos), raw)


def resync_clears(flags: dict[int, StepperFlag]) -> dict[int, bytes]:
    """The ``clear_flags`` values re-syncing the rotors of these stepper nodes (bus ID ->
    the SLIP/STALLED latches each had when its torque went off): RESYNC_ROTOR, and clear the
    latches that came while unpowered (they measured a rotor the step count could not
    follow); latches from before stay for the host to see."""
    reg = _S["clear_flags"]
    out = {}
    for dxl_id, before in flags.items():
        bits = StepperClear.RESYNC_ROTOR
        if not before & StepperFlag.SLIP:
            bits |= StepperClear.SLIP
        if not before & StepperFlag.STALLED:
            bits |= StepperClear.STALL
        out[dxl_id] = reg.encode(int(bits))
    return out
