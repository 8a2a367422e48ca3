"""The arm's stepper joint node (bus IDs 1-4): a series-elastic joint on a Dynamixel 1.0 bus.

A stepper motor drives the joint through a reduction and an elastic element; a joint encoder
with an index mark measures the joint.  The node exposes :data:`STEPPER_TABLE`:

* A 1 kHz control tick generates steps toward ``goal_position`` (joint encoder counts) with a
  trapezoidal profile: the commanded motor position (in joint counts) moves with a velocity
  never above ``velocity_limit`` and changed by at most ``acceleration_limit`` / 1000 per
  tick, slowing so as to stop at the goal.  Microsteps per joint count =
  ``gear_reduction_x100 * steps_per_rev * microstepping / 1 000 000`` (0.01 × reduction ×
  steps per motor rev × microsteps per step / 10 000 counts per joint rev).
* ``goal_position`` starts at the encoder count at power-up, so enabling torque holds still.
  ``command_goal`` is the same goal in 1/16 counts (:data:`GOAL_FINE_PER_COUNT`): writing
  either sets the other (``goal_position`` to the nearest count), and the node steps towards
  the finer one, so a host can command single microsteps.
* The step generator never runs faster than the controller's maximum step rate
  (:data:`protocol.robot.STEPPER_MAX_STEP_RATE` microsteps/s), whatever ``velocity_limit``
  says.
* ``step_count`` = hardware step counter since power-up, minus the offset recorded by
  ``clear_flags`` ZERO_STEP_COUNT.  ``present_position`` = encoder count.
* ``deflection`` = motor angle after the reduction minus joint angle, both relative to
  power-up, in joint counts: ``round(steps_since_power_up / microsteps_per_count) -
  (encoder - encoder_at_power_up)``, clamped to int16 (ZERO_STEP_COUNT does not change it).
* |deflection − deflection_offset| > ``slip_threshold`` latches SLIP (the motor could not
  have followed its own steps); the same over ``deflection_limit`` latches STALLED, reported
  as the OVERLOAD alarm bit.  ``deflection_offset`` (counts) is what the host knows the
  node's deflection differs from the elastic element's by: the belt and cable routes turn
  the capstan by ``C·Δq`` of the joints before it, which the node cannot see (the host
  writes ``−C·Δq`` every cycle with the goal, in the command block; 0 = none).  Over-temperature (sensor ``temperature``, 0.1 °C) and supply (``supply_mv``) outside
  the voltage limits are live alarm bits.  An alarm in ``alarm_shutdown`` turns the torque
  off (``torque_enable`` := 0); the host clears the cause and enables it again.
* A STALLED latch with torque on (``alarm_shutdown`` without OVERLOAD, the factory setting)
  stops the step generator at once and holds the motor where it stands (the goal registers
  say where); goals do not move it until the host clears STALL, and the clear holds it there.
  A clear made while the deflection is still over ``deflection_limit`` (a joint against a
  stop, a rotor that slipped) does not latch again at once: from then on SLIP and STALLED
  latch only beyond the least deviation seen since the clear plus a quarter of
  ``deflection_limit``, until the deviation is back within the limit, so the host can
  unwind the spring with a goal back.
* ``clear_flags`` RESYNC_ROTOR, with torque off only (a powered rotor does not turn with
  the joint, and a stall must stay one): the rotor turned with the joint while unpowered,
  so the step counter no longer says where it is; the node takes the elastic element as
  relaxed and moves its step origin so that ``deflection`` = ``deflection_offset``
  (``step_count`` moves by the same microsteps).  Ignored with torque on.
* The first index pulse after power-up (or after REARM_INDEX) latches ``index_step_count``
  and ``index_encoder_count`` and sets ``index_seen`` and INDEX_SEEN, so the host can
  calibrate the encoder offset; later pulses leave the latch alone.
* The cycle block (``cycle_present_position`` .. ``cycle_status_flags``, addresses 76-88)
  mirrors ``present_position``, ``step_count``, ``present_velocity`` (saturated to int16),
  ``deflection`` and ``status_flags``, written together with them, so one contiguous read
  gets a cycle's state.
* Torque off: current 0 and no steps; on: ``run_current`` while moving, ``holding_current``
  at standstill, both capped by ``max_current``.
* Command watchdog: what ``watchdog_feed`` names restarts a count of ticks (ms): with 0
  (power-up) every instruction addressed to the node (:meth:`host_heard`: PING, READ, WRITE,
  a SYNC_WRITE entry, a BULK_READ naming it, ...); with 1 only a write of a goal
  (``goal_position``, ``command_goal``) or of ``keep_alive`` (:meth:`after_write`), so that
  another program's READs do not keep a streaming host's stale goals driving the joint.
  When the count passes ``watchdog_timeout`` (0 = off) while the step generator moves, the
  node stops the move: its goal becomes the point where braking at ``acceleration_limit``
  from the present motor speed ends (``goal_position`` and ``command_goal`` say so), and it
  sets StepperFlag.WATCHDOG.  It holds the *motor* there, not the joint angle: the elastic
  element keeps the deflection that carries the load, and the route coupling is not taken for
  deflection.  Torque stays on and nothing latches; the next goal clears the flag and moves
  on.  A node at rest is left alone whatever the count.
* Stale goals near the stall limit (whatever feeds the watchdog): while the node steps on
  a goal written more than ``watchdog_timeout`` ago, and its element (|deflection −
  ``deflection_offset``|) is winding up so that braking from the present speed - the joint
  going on at its own speed meanwhile - would leave it within
  :data:`STALE_GUARD_SHARE` of ``deflection_limit``, the node stops as the watchdog does
  (WATCHDOG, braking, holding the motor; no settling) instead of driving on into a STALLED
  latch: the routes' coupling offset that came with the goal is as stale as the goal.
* Settling after a watchdog stop (:mod:`firmware_py.stepper_settle`): the link swings on
  about the hold on its elastic element.  For :data:`SETTLE_TICKS` after the stop, at most
  ``STEPPER_SETTLE_CORRECTIONS`` times, when the encoder says the link is about to turn, the
  node moves its goal so the element carries at the turn the deflection that holds the link
  still there (a posicast): within ``STEPPER_SETTLE_MAX_CHANGE_COUNTS`` of the hold
  (``STEPPER_SETTLE_MAX_BACK_COUNTS`` against the way it went), at
  ``STEPPER_SETTLE_ACCEL_COUNTS_S2`` and up to the maximum step rate
  (:mod:`protocol.robot`).  A goal, a latch, an alarm's torque-off or torque off ends it.
  The deflection that holds the link still there is the host's ``rest_deflection`` (its
  model, written with every goal; −32768 = not given), clamped to the deflections seen since
  the stop, else identified from the swing.
  Only a stop that cut a move short settles (the goal further on than the braking's end by
  more than that bound): a node still finishing a short way to its goal when its host went
  quiet (a host's hold, then the host's exit) holds as before.

Implementation notes (the emulator runs four of these at 1 kHz): the tick reads the encoder,
the step counter and the sensors once and derives everything from those readings; the
registers it needs are kept in attributes (:meth:`reload_registers`, with the microsteps per
count derived from the EEPROM) and the read-only registers are packed into the image with
precompiled structs at the same moments as before (every tick, before every READ/BULK_READ,
after a host write, at the index pulse), so the image - and :meth:`get` - are what they
always were.  Flags are plain ints inside.
"""

from __future__ import annotations

import math
import struct
from collections import deque

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.hal import Hal
from firmware_py.stepper_settle import SwingSettler
from protocol.control_tables import (
    GOAL_FINE_PER_COUNT,
    REST_DEFLECTION_UNKNOWN,
    STEPPER_TABLE,
    Register,
    StepperClear,
    StepperFlag,
    WatchdogFeed,
)
from protocol.dynamixel import ErrorBit
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    STEPPER_MAX_STEP_RATE,
    STEPPER_SETTLE_ACCEL_COUNTS_S2,
    STEPPER_SETTLE_MAX_BACK_COUNTS,
    STEPPER_SETTLE_MAX_CHANGE_COUNTS,
)

#: Control tick period (µs): 1 kHz.
TICK_US = 1_000
#: Window over which present_velocity is measured (ticks).
VELOCITY_WINDOW = 10
_INT16 = 32767
_INT16_MIN = -32768
_DT = TICK_US / 1e6  # tick period (s)
#: gear_reduction_x100 × steps × microsteps over this = microsteps per joint encoder count.
_X100_COUNTS_PER_REV = 100 * ARM_ENCODER_COUNTS_PER_REV
#: Ticks after a watchdog stop during which the node settles its link (3 s).
SETTLE_TICKS = 3_000
#: A correction's goal keeps the deflection at the link's present position within this share
#: of ``deflection_limit``.
SETTLE_DEFLECTION_SHARE = 0.75
#: A node stepping on stale goals stops when braking would leave its element within this
#: share of ``deflection_limit`` of it (see the module docs): an eighth, 19 counts (0.7°) of
#: the factory 150.
STALE_GUARD_SHARE = 0.125

# Plain-int bits for the hot path (IntFlag arithmetic is slow).
_MOVING = int(StepperFlag.MOVING)
_SLIP = int(StepperFlag.SLIP)
_INDEX_SEEN = int(StepperFlag.INDEX_SEEN)
_STALLED = int(StepperFlag.STALLED)
_HARDWARE_ERROR = int(StepperFlag.HARDWARE_ERROR)
_WATCHDOG = int(StepperFlag.WATCHDOG)
_GOALS_ONLY = int(WatchdogFeed.GOALS_ONLY)
_GOAL_REGISTERS = frozenset({"goal_position", "command_goal"})
_OVERHEATING = int(ErrorBit.OVERHEATING)
_INPUT_VOLTAGE = int(ErrorBit.INPUT_VOLTAGE)
_OVERLOAD = int(ErrorBit.OVERLOAD)
_CLEAR_SLIP = int(StepperClear.SLIP)
_CLEAR_STALL = int(StepperClear.STALL)
_CLEAR_ZERO = int(StepperClear.ZERO_STEP_COUNT)
_CLEAR_REARM = int(StepperClear.REARM_INDEX)
_CLEAR_RESYNC = int(StepperClear.RESYNC_ROTOR)


def _packer(*names: str) -> tuple[struct.Struct, int]:
    """A struct packing the adjacent registers ``names`` in one go, and their address."""
    regs = [STEPPER_TABLE[n] for n in names]
    for a, b in zip(regs, regs[1:], strict=False):
        assert a.end == b.address, f"{a.name} and {b.name} are not adjacent"
    codes = "".join({1: "b", 2: "h", 4: "i"}[r.size] if r.signed
                    else {1: "B", 2: "H", 4: "I"}[r.size] for r in regs)
    return struct.Struct("<" + codes), regs[0].address


# The read-only registers, in the order the node has always written them.
_POS_VEL_STEPS, _POS_VEL_STEPS_AT = _packer("present_position", "present_velocity", "step_count")
_POS_VEL_STEPS_END = _POS_VEL_STEPS_AT + _POS_VEL_STEPS.size
_DEFLECTION, _DEFLECTION_AT = _packer("deflection")
_FLAGS, _FLAGS_AT = _packer("status_flags")
_HW_VOLT_TEMP, _HW_VOLT_TEMP_AT = _packer("hardware_error_status", "present_voltage",
                                          "present_temperature")
# The cycle block: mirrors of the above in one range, written with them.
_CYCLE_BLOCK, _CYCLE_BLOCK_AT = _packer("cycle_present_position", "cycle_step_count",
                                        "cycle_velocity", "cycle_deflection",
                                        "cycle_status_flags")


class StepperNodeApp(DynamixelSlave):
    """The stepper joint node's application on ``hal`` (factory bus ID ``dxl_id``)."""

    CACHED_REGISTERS = frozenset({
        "gear_reduction_x100", "steps_per_rev", "microstepping", "temperature_limit",
        "min_voltage_limit", "max_voltage_limit", "max_current", "alarm_shutdown",
        "torque_enable", "goal_position", "velocity_limit", "acceleration_limit",
        "slip_threshold", "deflection_limit", "run_current", "holding_current",
        "command_goal", "deflection_offset", "watchdog_timeout", "rest_deflection",
        "watchdog_feed",
    })

    def __init__(self, hal: Hal, dxl_id: int = 1) -> None:
        super().__init__(hal, STEPPER_TABLE, {"id": dxl_id, "baud_rate": 1})
        self.stepper = hal.stepper()
        self.encoder = hal.encoder()
        self._hw_steps0 = 0  # hardware counter at power-up (moved by RESYNC_ROTOR)
        self._step_offset = 0  # hardware counter at the last ZERO_STEP_COUNT (ditto)
        self._enc0 = 0  # encoder at power-up
        self._velocity = 0.0  # commanded joint velocity (counts/s)
        self._flags = 0  # latched StepperFlag bits (SLIP, STALLED, INDEX_SEEN), plain int
        self._enc_history: deque[int] = deque(maxlen=VELOCITY_WINDOW + 1)
        # Registers kept in attributes (reload_registers: from the image at every boot).
        self._mpc = 0.0
        self._temperature_limit = self._min_voltage = self._max_voltage = 0
        self._max_current = self._alarm_shutdown = self._torque_enable = 0
        self._goal = 0.0  # counts (command_goal / 16)
        self._velocity_limit = self._acceleration_limit = 0
        self._slip_threshold = self._deflection_limit = self._deflection_offset = 0
        self._run_current = self._holding_current = 0
        self._watchdog_timeout = 0  # ms (ticks); 0 = off
        self._rest_deflection = REST_DEFLECTION_UNKNOWN  # counts, the host's model
        self._quiet_ticks = 0  # ticks since the watchdog was last fed
        self._goals_feed = False  # watchdog_feed = GOALS_ONLY: only goal/keep_alive writes feed
        self._goal_age = 0  # ticks since the last goal written (by a host)
        #: |deflection − offset| (counts) at a clear made while over deflection_limit, then
        #: the least since; 0 once back within it (see the module docs)
        self._allowance = 0
        #: The tick sleeps (see :meth:`_tick`) only on a board whose encoder and
        #: temperature and supply inputs interrupt on a change.
        self._can_sleep = False
        #: True while a tick would change nothing: it returns at once until woken.
        self.asleep = False
        #: Wake-ups so far (a wake-up during a tick keeps it from going to sleep after it).
        self._wakes = 0
        #: The last tick's encoder, step counter, temperature and supply readings.
        self._last_inputs = (0, 0, 0, 0)
        #: after a watchdog stop: what settles the link's swing (None: nothing to settle)
        self._settler: SwingSettler | None = None
        self._settle_ticks = 0  # ticks the settler has still to run
        self._settling_move = False  # the motor moves with the settling profile

    # ------------------------------------------------------------------ hooks

    def reload_registers(self) -> None:
        self._wake()  # a register the tick reads may have changed
        get = self.get
        self._mpc = (get("gear_reduction_x100") * get("steps_per_rev")
                     * get("microstepping") / _X100_COUNTS_PER_REV)
        self._temperature_limit = get("temperature_limit")
        self._min_voltage = get("min_voltage_limit")
        self._max_voltage = get("max_voltage_limit")
        self._max_current = get("max_current")
        self._alarm_shutdown = get("alarm_shutdown")
        self._torque_enable = get("torque_enable")
        # The finer goal unless goal_position was changed alone (then it rules; after_write
        # brings command_goal along for host writes).
        goal, fine = get("goal_position"), get("command_goal") / GOAL_FINE_PER_COUNT
        self._goal = fine if _round_half_away(fine) == goal else float(goal)
        self._deflection_offset = get("deflection_offset")
        self._velocity_limit = get("velocity_limit")
        self._acceleration_limit = get("acceleration_limit")
        self._slip_threshold = get("slip_threshold")
        self._deflection_limit = get("deflection_limit")
        self._run_current = get("run_current")
        self._holding_current = get("holding_current")
        self._watchdog_timeout = get("watchdog_timeout")
        self._rest_deflection = get("rest_deflection")
        self._goals_feed = get("watchdog_feed") == _GOALS_ONLY

    def power_up(self) -> None:
        wake = self._wake
        sensors = self.hal.sensors
        self._can_sleep = all([self.encoder.set_change_interrupt(wake),
                               sensors.watch_channel("temperature", wake),
                               sensors.watch_channel("supply_mv", wake)])
        self._wake()
        self._hw_steps0 = self._step_offset = self.stepper.step_count()
        self._enc0 = self.encoder.count()
        self._velocity = 0.0
        self._flags = 0
        self._quiet_ticks = 0
        self._goal_age = 0
        self._allowance = 0
        self._end_settling()
        self._enc_history = deque([self._enc0], maxlen=VELOCITY_WINDOW + 1)
        self._set_goal_counts(self._enc0)
        self.stepper.set_step_rate(0.0)
        self.stepper.set_current(0)
        self.encoder.set_index_callback(self._on_index)
        self._refresh()
        self.hal.clock.call_every(TICK_US, self._tick)

    def before_read(self) -> None:
        self._refresh()

    def host_heard(self) -> None:
        if not self._goals_feed:  # any instruction feeds the watchdog
            self._quiet_ticks = 0

    def after_write(self, touched: list[Register]) -> None:
        self._wake()
        names = {r.name for r in touched}
        if not names.isdisjoint(_GOAL_REGISTERS):
            self._flags &= ~_WATCHDOG  # a new goal: the host is back in charge
            self._end_settling()
            self._quiet_ticks = self._goal_age = 0  # feeds the watchdog in either mode
        if "keep_alive" in names:
            self._quiet_ticks = 0
            self.set("keep_alive", 0)
        if "command_goal" in names:
            fine = self.get("command_goal")
            self.set("goal_position", _round_half_away(fine / GOAL_FINE_PER_COUNT))
            self._goal = fine / GOAL_FINE_PER_COUNT
        elif "goal_position" in names:
            self._set_goal_counts(self.get("goal_position"))
        if "clear_flags" in names:
            self._clear(self.get("clear_flags"))
            self.set("clear_flags", 0)
        if "torque_enable" in names and not self._torque_enable:
            self._end_settling()
            self._velocity = 0.0
            self.stepper.set_step_rate(0.0)
        self._refresh()

    def alarm_bits(self) -> int:
        return self._hardware_errors()

    def _set_goal_counts(self, counts: int) -> None:
        """``goal_position`` := ``counts`` and ``command_goal`` with it (1/16 counts)."""
        self.set("goal_position", counts)
        fine = STEPPER_TABLE["command_goal"]
        low, high = fine.encodable
        self.set("command_goal", max(low, min(high, counts * GOAL_FINE_PER_COUNT)))

    # ------------------------------------------------------------------ quantities

    @property
    def microsteps_per_count(self) -> float:
        """Motor microsteps per joint encoder count."""
        return self._mpc

    def motor_position(self) -> float:
        """Commanded motor angle after the reduction, in joint counts, in the encoder's frame
        (equal to the encoder count when the elastic element is relaxed)."""
        steps = self.stepper.step_count() - self._hw_steps0
        return self._enc0 + steps / self._mpc

    def deflection(self) -> int:
        """Motor angle after the reduction minus joint angle since power-up (counts, int16)."""
        return self._deflection(self.stepper.step_count(), self.encoder.count())

    def _deflection(self, hw_steps: int, enc: int) -> int:
        value = round((hw_steps - self._hw_steps0) / self._mpc) - (enc - self._enc0)
        return _INT16_MIN if value < _INT16_MIN else _INT16 if value > _INT16 else value

    def _hardware_errors(self) -> int:
        return self._errors(self.sensor("temperature"), self.sensor("supply_mv"))

    def _errors(self, temperature: int, supply_mv: int) -> int:
        """The live ErrorBit alarms for these sensor readings and the latched flags."""
        bits = 0
        if temperature // 10 > self._temperature_limit:
            bits |= _OVERHEATING
        decivolts = supply_mv // 100
        if not self._min_voltage <= decivolts <= self._max_voltage:
            bits |= _INPUT_VOLTAGE
        if self._flags & _STALLED:
            bits |= _OVERLOAD
        return bits

    # ------------------------------------------------------------------ events

    def _on_index(self, encoder_count: int) -> None:
        self._wake()
        if self._flags & _INDEX_SEEN:
            return
        self._flags |= _INDEX_SEEN
        self.set("index_step_count", self.stepper.step_count() - self._step_offset)
        self.set("index_encoder_count", encoder_count)
        self.set("index_seen", 1)
        self._refresh()

    def _wake(self) -> None:
        """An encoder count change, a temperature or supply change, a host write, an index
        pulse: the next tick runs."""
        self.asleep = False
        self._wakes += 1

    def _clear(self, bits: int) -> None:
        if bits & (_CLEAR_SLIP | _CLEAR_STALL) and self._torque_enable:
            size = abs(self.deflection() - self._deflection_offset)
            if size > self._deflection_limit:
                self._allowance = size
        if bits & _CLEAR_SLIP:
            self._flags &= ~_SLIP
        if bits & _CLEAR_STALL and self._flags & _STALLED:
            self._end_settling()
            self._flags &= ~_STALLED
            if self._torque_enable:  # hold where the motor stands: clearing starts no move
                self._hold_at(self.motor_position())
        if bits & _CLEAR_ZERO:
            self._step_offset = self.stepper.step_count()
        if bits & _CLEAR_REARM:
            self._flags &= ~_INDEX_SEEN
            for name in ("index_step_count", "index_encoder_count", "index_seen"):
                self.set(name, 0)
        if bits & _CLEAR_RESYNC and not self._torque_enable:
            self._resync_rotor()

    def _resync_rotor(self) -> None:
        """RESYNC_ROTOR: an unpowered rotor turns with the joint (the elastic element
        relaxes), which the step counter cannot see.  Take the element as relaxed: move the
        step origin (microsteps) so that ``deflection`` = ``deflection_offset``, and
        ``step_count`` with it (``step_count`` − ``deflection`` × microsteps per count, the
        power-up reference a host derives, stays).  The goal stays where it is, in the
        joint's frame: enabling torque heads there."""
        hw_steps = self.stepper.step_count()
        slid = self._deflection(hw_steps, self.encoder.count()) - self._deflection_offset
        shift = round(slid * self._mpc)
        self._hw_steps0 += shift
        self._step_offset += shift

    def _tick(self) -> None:
        """The 1 kHz control tick: alarms, trajectory, step rate, current, registers.

        One reading of the encoder, the step counter and the sensors serves the whole tick
        (nothing else runs within it, and setting the step rate leaves the count as it is).

        It goes to sleep (returns at once from the next tick on, counting only the
        watchdog's quiet ticks) when a tick changed nothing: the motor at rest before and
        after it, the same readings as the tick before, the velocity window full of one
        count, the latches, the allowance and the torque as they were; the next ticks would
        then read the same inputs and write the same outputs and registers, until an
        encoder count change, a temperature or supply change (the HAL's interrupts), a host
        write or an index pulse wakes it.  The timer keeps its phase meanwhile, so a woken
        tick runs exactly when it would have.  A node at rest ignores the watchdog count."""
        if self.asleep:
            self._quiet_ticks += 1
            self._goal_age += 1
            return
        wakes = self._wakes
        flags_before, allowance_before = self._flags, self._allowance
        torque_before, velocity_before = self._torque_enable, self._velocity
        stepper = self.stepper
        enc = self.encoder.count()
        self._enc_history.append(enc)
        hw_steps = stepper.step_count()
        mpc = self._mpc
        # deflection: SLIP and STALLED latch while the coils hold, or while a latch set
        # then stands (its alarm cut the coils: a shove goes on).  Turned off by the host
        # with no latch, the rotor turns with the joint and the step count cannot follow:
        # a deflection then is no load and no lost step.
        value = round((hw_steps - self._hw_steps0) / mpc) - (enc - self._enc0)
        deflection = _INT16_MIN if value < _INT16_MIN else _INT16 if value > _INT16 else value
        if self._torque_enable or self._flags & (_SLIP | _STALLED):
            size = deflection - self._deflection_offset
            if size < 0:
                size = -size
            allowance = self._allowance
            if allowance:  # cleared while over: only a deflection growing again latches
                if size <= self._deflection_limit:
                    allowance = self._allowance = 0
                elif size < allowance:
                    allowance = self._allowance = size
                allowance += self._deflection_limit >> 2
            if size > self._slip_threshold and size > allowance:
                self._flags |= _SLIP
            if (size > self._deflection_limit and size > allowance
                    and not self._flags & _STALLED):
                self._flags |= _STALLED
                if self._torque_enable:  # stop stepping: hold the motor where it is
                    self._end_settling()
                    self._velocity = 0.0
                    self._hold_at(self._enc0 + (hw_steps - self._hw_steps0) / mpc)
        # live alarms; a shutdown one turns the torque off
        read = self.hal.sensors.read
        temperature = read("temperature")
        if type(temperature) is not int:
            temperature = self.sensor("temperature")
        supply_mv = read("supply_mv")
        if type(supply_mv) is not int:
            supply_mv = self.sensor("supply_mv")
        errors = self._errors(temperature, supply_mv)
        if errors & self._alarm_shutdown and self._torque_enable:
            self.set("torque_enable", 0)
            self._end_settling()
        quiet = self._quiet_ticks + 1
        self._quiet_ticks = quiet
        self._goal_age += 1
        if self._torque_enable:
            timeout = self._watchdog_timeout
            if timeout and self._velocity != 0.0 and not self._flags & (_WATCHDOG | _STALLED):
                if quiet > timeout:
                    self._watchdog_stop(hw_steps, mpc)
                elif self._goal_age > timeout and self._stale_winding(deflection):
                    self._watchdog_stop(hw_steps, mpc, settle=False)
            if self._settler is not None:
                self._settle(enc, hw_steps, mpc)
            if self._flags & _STALLED:  # held until the host clears the latch
                velocity = self._velocity = 0.0
            else:
                velocity = self._velocity = self._next_velocity_at(hw_steps, mpc)
            stepper.set_step_rate(velocity * mpc)
            current = self._run_current if velocity != 0.0 else self._holding_current
            cap = self._max_current
            stepper.set_current(cap if cap < current else current)
        else:
            velocity = self._velocity = 0.0
            stepper.set_step_rate(0.0)
            stepper.set_current(0)
        self._publish(enc, hw_steps, deflection, errors, velocity, temperature, supply_mv)
        inputs = (enc, hw_steps, temperature, supply_mv)
        if (self._can_sleep and velocity == 0.0 and velocity_before == 0.0
                and self._settler is None  # settling reads every tick's encoder
                and inputs == self._last_inputs and self._wakes == wakes
                and self._flags == flags_before and self._allowance == allowance_before
                and self._torque_enable == torque_before
                and self._enc_history.count(enc) == VELOCITY_WINDOW + 1):
            self.asleep = True
        self._last_inputs = inputs

    def _stale_winding(self, deflection: int) -> bool:
        """Stepping on stale goals, would braking now leave the element (|``deflection`` −
        ``deflection_offset``|, counts) within :data:`STALE_GUARD_SHARE` of
        ``deflection_limit``, it winding up?  Braking from the motor's speed ``v``
        (counts/s) at ``acceleration_limit`` ``a`` takes ``|v|/a`` s and ``v²/2a`` counts;
        the joint goes on meanwhile at its speed over the velocity window."""
        element = deflection - self._deflection_offset
        history = self._enc_history
        span = len(history) - 1
        joint = (history[-1] - history[0]) / (span * _DT) if span else 0.0
        velocity = self._velocity
        if element == 0 or (velocity - joint) * element <= 0:
            return False  # relaxed, or unwinding
        accel = float(self._acceleration_limit)
        braking = abs(velocity) / accel
        more = (math.copysign(velocity * velocity / (2.0 * accel), velocity)
                - joint * braking)
        if more * element < 0:
            more = 0.0
        limit = self._deflection_limit
        return abs(element) + abs(more) >= limit - STALE_GUARD_SHARE * limit

    def _watchdog_stop(self, hw_steps: int, mpc: float, *, settle: bool = True) -> None:
        """No instruction within ``watchdog_timeout`` while moving (or stale goals winding
        the element up to the stall limit, ``settle`` False): the goal becomes where the
        motor stops braking at ``acceleration_limit`` (the motor's frame, so the load's
        deflection stays in the element), and the WATCHDOG flag is set; a stop that cut a
        move short settles the link's swing when ``settle``."""
        velocity = self._velocity
        motor = self._enc0 + (hw_steps - self._hw_steps0) / mpc
        accel = float(self._acceleration_limit)
        stop = motor + math.copysign(velocity * velocity / (2.0 * accel), velocity)
        cut_short = (self._goal - stop) * velocity > STEPPER_SETTLE_MAX_CHANGE_COUNTS * abs(velocity)
        self._hold_at(stop)
        self._flags |= _WATCHDOG
        if not cut_short or not settle:
            # the goal lay within the settling's reach: the node was finishing a short way
            # (a host's hold); it holds as it always did
            return
        model = self._rest_deflection
        self._settler = SwingSettler(self._goal, motor - self._enc_history[-1],
                                     float(STEPPER_SETTLE_MAX_CHANGE_COUNTS),
                                     float(STEPPER_SETTLE_ACCEL_COUNTS_S2),
                                     STEPPER_MAX_STEP_RATE / mpc, velocity,
                                     float(STEPPER_SETTLE_MAX_BACK_COUNTS),
                                     None if model == REST_DEFLECTION_UNKNOWN else float(model))
        self._settle_ticks = SETTLE_TICKS

    def _settle(self, enc: int, hw_steps: int, mpc: float) -> None:
        """One tick of settling the link after a watchdog stop (:mod:`firmware_py.stepper_settle`):
        a correction moves the goal, with the settling profile."""
        settler = self._settler
        assert settler is not None
        self._settle_ticks -= 1
        if self._settle_ticks <= 0 or (settler.done and self._velocity == 0.0):
            self._end_settling()
            return
        motor = self._enc0 + (hw_steps - self._hw_steps0) / mpc
        target = settler.feed(enc, motor, self._velocity)
        if target is not None:
            # never a goal whose deflection at the link's present position would come near
            # deflection_limit: a correction must not latch STALLED
            reach = SETTLE_DEFLECTION_SHARE * self._deflection_limit
            centre = enc + self._deflection_offset
            self._hold_at(min(centre + reach, max(centre - reach, target)))
            self._settling_move = True

    def _end_settling(self) -> None:
        """Settling over (time up, a new goal, a latch, torque off): normal profile again."""
        self._settler = None
        self._settling_move = False
        self._settle_ticks = 0

    def _hold_at(self, counts: float) -> None:
        """The goal (``command_goal``, ``goal_position`` and the step generator's) becomes
        ``counts`` (joint counts in the motor's frame) moved to the nearest whole microstep,
        to 1/16 count: a goal half a microstep from two could not be reached within the
        step generator's resolution, which would then dither about it for ever."""
        mpc = self._mpc
        on_step = self._enc0 + round((counts - self._enc0) * mpc) / mpc
        low, high = STEPPER_TABLE["command_goal"].encodable
        fine = max(low, min(high, _round_half_away(on_step * GOAL_FINE_PER_COUNT)))
        self.set("command_goal", fine)
        self.set("goal_position", _round_half_away(fine / GOAL_FINE_PER_COUNT))
        self._goal = fine / GOAL_FINE_PER_COUNT

    def _next_velocity_at(self, hw_steps: int, mpc: float) -> float:
        """The commanded joint velocity (counts/s) for the next tick, with the step counter
        at ``hw_steps`` and ``mpc`` microsteps per count."""
        error = self._goal - (self._enc0 + (hw_steps - self._hw_steps0) / mpc)
        resolution = 0.5 / mpc  # half a microstep, in counts: goals round to microsteps
        dt = _DT
        v_max = float(self._velocity_limit)
        accel = float(self._acceleration_limit)
        if self._settling_move:
            v_max = STEPPER_MAX_STEP_RATE / mpc
            accel = float(STEPPER_SETTLE_ACCEL_COUNTS_S2)
        if v_max * mpc > STEPPER_MAX_STEP_RATE:
            v_max = STEPPER_MAX_STEP_RATE / mpc
        velocity = self._velocity
        size = abs(error)
        if size < resolution and abs(velocity) <= accel * dt:
            return 0.0
        # Fastest speed from which the goal can still be reached braking at ``accel``, and
        # no faster than covering the remaining error within this tick.
        reachable = math.sqrt(2.0 * accel * size)
        desired = math.copysign(min(v_max, reachable, size / dt), error)
        step = accel * dt
        change = desired - velocity
        v = velocity + max(-step, min(step, change))
        return max(-v_max, min(v_max, v))

    def _refresh(self) -> None:
        """Bring the read-only registers up to date (fresh readings)."""
        enc = self.encoder.count()
        hw_steps = self.stepper.step_count()
        temperature = self.sensor("temperature")
        supply_mv = self.sensor("supply_mv")
        self._publish(enc, hw_steps, self._deflection(hw_steps, enc),
                      self._errors(temperature, supply_mv), self._velocity, temperature,
                      supply_mv)

    def _publish(self, enc: int, hw_steps: int, deflection: int, errors: int, velocity: float,
                 temperature: int, supply_mv: int) -> None:
        """Write the read-only registers from these readings."""
        history = self._enc_history
        span = len(history) - 1
        speed = (history[-1] - history[0]) * 1_000_000 // (span * TICK_US) if span else 0
        steps = hw_steps - self._step_offset
        image = self.image
        before = image[_POS_VEL_STEPS_AT:_POS_VEL_STEPS_END]
        try:
            _POS_VEL_STEPS.pack_into(image, _POS_VEL_STEPS_AT, enc, speed, steps)
        except struct.error:  # a value does not fit: fail exactly as register by register
            image[_POS_VEL_STEPS_AT:_POS_VEL_STEPS_END] = before  # (pack_into zero-fills)
            self.set("present_position", enc)
            self.set("present_velocity", speed)
            self.set("step_count", steps)
            raise
        _DEFLECTION.pack_into(image, _DEFLECTION_AT, deflection)
        flags = self._flags
        if velocity != 0.0:
            flags |= _MOVING
        if errors:
            flags |= _HARDWARE_ERROR
        volts = supply_mv // 100
        degrees = temperature // 10
        _FLAGS.pack_into(image, _FLAGS_AT, flags)
        _CYCLE_BLOCK.pack_into(image, _CYCLE_BLOCK_AT, enc, steps,
                               _INT16_MIN if speed < _INT16_MIN else
                               _INT16 if speed > _INT16 else speed, deflection, flags)
        _HW_VOLT_TEMP.pack_into(image, _HW_VOLT_TEMP_AT, errors,
                                0 if volts < 0 else 255 if volts > 255 else volts,
                                0 if degrees < 0 else 255 if degrees > 255 else degrees)


def _round_half_away(value: float) -> int:
    """``value`` rounded to the nearest integer, halves away from zero (as firmware does)."""
    return int(math.floor(value + 0.5)) if value >= 0 else -int(math.floor(-value + 0.5))
