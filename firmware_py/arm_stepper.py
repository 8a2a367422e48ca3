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
* ``step_count`` = hardware step counter since power-up, minus the offset recorded by
  ``clear_flags`` ZERO_STEP_COUNT.  ``present_position`` = encoder count.
* ``deflection`` = motor angle after the reduction minus joint angle, both relative to
  power-up, in joint counts: ``round(steps_since_power_up / microsteps_per_count) -
  (encoder - encoder_at_power_up)``, clamped to int16 (ZERO_STEP_COUNT does not change it).
* |deflection| > ``slip_threshold`` latches SLIP (the motor could not have followed its own
  steps); |deflection| > ``deflection_limit`` latches STALLED, reported as the OVERLOAD alarm
  bit.  Over-temperature (sensor ``temperature``, 0.1 °C) and supply (``supply_mv``) outside
  the voltage limits are live alarm bits.  An alarm in ``alarm_shutdown`` turns the torque
  off (``torque_enable`` := 0); the host clears the cause and enables it again.
* The first index pulse after power-up (or after REARM_INDEX) latches ``index_step_count``
  and ``index_encoder_count`` and sets ``index_seen`` and INDEX_SEEN, so the host can
  calibrate the encoder offset; later pulses leave the latch alone.
* Torque off: current 0 and no steps; on: ``run_current`` while moving, ``holding_current``
  at standstill, both capped by ``max_current``.
"""

from __future__ import annotations

import math

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.hal import Hal
from protocol.control_tables import STEPPER_TABLE, Register, StepperClear, StepperFlag
from protocol.dynamixel import ErrorBit

#: Control tick period (µs): 1 kHz.
TICK_US = 1_000
#: Window over which present_velocity is measured (ticks).
VELOCITY_WINDOW = 10
_INT16 = 32767


class StepperNodeApp(DynamixelSlave):
    """The stepper joint node's application on ``hal`` (factory bus ID ``dxl_id``)."""

    def __init__(self, hal: Hal, dxl_id: int = 1) -> None:
        super().__init__(hal, STEPPER_TABLE, {"id": dxl_id, "baud_rate": 1})
        self.stepper = hal.stepper()
        self.encoder = hal.encoder()
        self._hw_steps0 = 0  # hardware counter at power-up
        self._step_offset = 0  # hardware counter at the last ZERO_STEP_COUNT
        self._enc0 = 0  # encoder at power-up
        self._velocity = 0.0  # commanded joint velocity (counts/s)
        self._flags = 0  # latched StepperFlag bits (SLIP, STALLED, INDEX_SEEN)
        self._enc_history: list[int] = []

    # ------------------------------------------------------------------ hooks

    def power_up(self) -> None:
        self._hw_steps0 = self._step_offset = self.stepper.step_count()
        self._enc0 = self.encoder.count()
        self._velocity = 0.0
        self._flags = 0
        self._enc_history = [self._enc0]
        self.set("goal_position", self._enc0)
        self.stepper.set_step_rate(0.0)
        self.stepper.set_current(0)
        self.encoder.set_index_callback(self._on_index)
        self._refresh()
        self.hal.clock.call_every(TICK_US, self._tick)

    def before_read(self) -> None:
        self._refresh()

    def after_write(self, touched: list[Register]) -> None:
        names = {r.name for r in touched}
        if "clear_flags" in names:
            self._clear(self.get("clear_flags"))
            self.set("clear_flags", 0)
        if "torque_enable" in names and not self.get("torque_enable"):
            self._velocity = 0.0
            self.stepper.set_step_rate(0.0)
        self._refresh()

    def alarm_bits(self) -> int:
        return self._hardware_errors()

    # ------------------------------------------------------------------ quantities

    @property
    def microsteps_per_count(self) -> float:
        """Motor microsteps per joint encoder count."""
        return (self.get("gear_reduction_x100") * self.get("steps_per_rev")
                * self.get("microstepping") / 1_000_000)

    def motor_position(self) -> float:
        """Commanded motor angle after the reduction, in joint counts, in the encoder's frame
        (equal to the encoder count when the elastic element is relaxed)."""
        steps = self.stepper.step_count() - self._hw_steps0
        return self._enc0 + steps / self.microsteps_per_count

    def deflection(self) -> int:
        """Motor angle after the reduction minus joint angle since power-up (counts, int16)."""
        steps = self.stepper.step_count() - self._hw_steps0
        value = round(steps / self.microsteps_per_count) - (self.encoder.count() - self._enc0)
        return max(-_INT16 - 1, min(_INT16, value))

    def _hardware_errors(self) -> int:
        bits = 0
        if self.sensor("temperature") // 10 > self.get("temperature_limit"):
            bits |= ErrorBit.OVERHEATING
        decivolts = self.sensor("supply_mv") // 100
        if not self.get("min_voltage_limit") <= decivolts <= self.get("max_voltage_limit"):
            bits |= ErrorBit.INPUT_VOLTAGE
        if self._flags & StepperFlag.STALLED:
            bits |= ErrorBit.OVERLOAD
        return int(bits)

    # ------------------------------------------------------------------ events

    def _on_index(self, encoder_count: int) -> None:
        if self._flags & StepperFlag.INDEX_SEEN:
            return
        self._flags |= StepperFlag.INDEX_SEEN
        self.set("index_step_count", self.stepper.step_count() - self._step_offset)
        self.set("index_encoder_count", encoder_count)
        self.set("index_seen", 1)
        self._refresh()

    def _clear(self, bits: int) -> None:
        if bits & StepperClear.SLIP:
            self._flags &= ~StepperFlag.SLIP
        if bits & StepperClear.STALL:
            self._flags &= ~StepperFlag.STALLED
        if bits & StepperClear.ZERO_STEP_COUNT:
            self._step_offset = self.stepper.step_count()
        if bits & StepperClear.REARM_INDEX:
            self._flags &= ~StepperFlag.INDEX_SEEN
            for name in ("index_step_count", "index_encoder_count", "index_seen"):
                self.set(name, 0)

    def _tick(self) -> None:
        """The 1 kHz control tick: alarms, trajectory, step rate, current, registers."""
        self._enc_history.append(self.encoder.count())
        del self._enc_history[: -VELOCITY_WINDOW - 1]
        self._check_deflection()
        errors = self._hardware_errors()
        if errors & self.get("alarm_shutdown") and self.get("torque_enable"):
            self.set("torque_enable", 0)
        if self.get("torque_enable"):
            self._velocity = self._next_velocity(TICK_US / 1e6)
            self.stepper.set_step_rate(self._velocity * self.microsteps_per_count)
            moving = self._velocity != 0.0
            current = self.get("run_current") if moving else self.get("holding_current")
            self.stepper.set_current(min(current, self.get("max_current")))
        else:
            self._velocity = 0.0
            self.stepper.set_step_rate(0.0)
            self.stepper.set_current(0)
        self._refresh()

    def _check_deflection(self) -> None:
        size = abs(self.deflection())
        if size > self.get("slip_threshold"):
            self._flags |= StepperFlag.SLIP
        if size > self.get("deflection_limit"):
            self._flags |= StepperFlag.STALLED

    def _next_velocity(self, dt: float) -> float:
        """The commanded joint velocity (counts/s) for the next tick of ``dt`` seconds."""
        v_max = float(self.get("velocity_limit"))
        accel = float(self.get("acceleration_limit"))
        error = self.get("goal_position") - self.motor_position()
        resolution = 1.0 / self.microsteps_per_count  # one microstep, in counts
        if abs(error) < resolution and abs(self._velocity) <= accel * dt:
            return 0.0
        # Fastest speed from which the goal can still be reached braking at ``accel``, and
        # no faster than covering the remaining error within this tick.
        reachable = math.sqrt(2.0 * accel * abs(error))
        desired = math.copysign(min(v_max, reachable, abs(error) / dt), error)
        step = accel * dt
        v = self._velocity + max(-step, min(step, desired - self._velocity))
        return max(-v_max, min(v_max, v))

    def _refresh(self) -> None:
        """Bring the read-only registers up to date."""
        enc = self.encoder.count()
        self.set("present_position", enc)
        history = self._enc_history
        span = len(history) - 1
        velocity = (history[-1] - history[0]) * 1_000_000 // (span * TICK_US) if span else 0
        self.set("present_velocity", velocity)
        self.set("step_count", self.stepper.step_count() - self._step_offset)
        self.set("deflection", self.deflection())
        errors = self._hardware_errors()
        self.set("hardware_error_status", errors)
        flags = self._flags
        if self._velocity != 0.0:
            flags |= StepperFlag.MOVING
        if errors:
            flags |= StepperFlag.HARDWARE_ERROR
        self.set("status_flags", int(flags))
        self.set("present_voltage", max(0, min(255, self.sensor("supply_mv") // 100)))
        self.set("present_temperature", max(0, min(255, self.sensor("temperature") // 10)))
