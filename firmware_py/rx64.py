"""A ROBOTIS RX-64 servo (bus IDs 5-7) as firmware on the Dynamixel 1.0 slave runtime.

The servo exposes the full :data:`RX64_TABLE`.  A 1 kHz tick runs its position loop:

* Present position is sensor ``pot`` (0..1023 over 300°; position grows counter-clockwise).
* A setpoint moves toward ``goal_position`` at ``moving_speed`` (0.111 rpm/unit ≈ 2.27
  position units/s per unit; 0 = no limit: the setpoint is the goal).  It starts at the
  present position at power-up and whenever torque is enabled; ``goal_position`` is set to
  the present position and ``torque_limit`` to ``max_torque`` at power-up, as on the servo.
* Compliance (error ``e = setpoint - present``, e > 0 means the horn is clockwise of the
  goal and uses the CW margin/slope): ``|e| <= margin`` gives no torque; beyond it torque
  is ``punch + (torque_limit - punch) * (|e| - margin) / slope``, at least ``punch``, at
  most ``torque_limit`` (slope 0: the torque limit at once).  Duty = ±torque / 1023, positive
  driving counter-clockwise.  Torque disabled: bridge disabled, duty 0.
* ``present_load`` is the applied duty (0..1023, bit 10 set when driving clockwise);
  ``present_speed`` the pot's rate over 10 ms (bit 10 = clockwise); voltage and temperature
  come from ``supply_mv`` (mV) and ``temperature`` (0.1 °C).
* Alarms, latched until RESET or power cycle and OR-ed into every status error byte:
  OVERHEATING (temperature above ``temperature_limit``), INPUT_VOLTAGE (supply outside the
  voltage limits), OVERLOAD (sensor ``load``, 1/1023 of max torque, at or beyond the torque
  limit for more than :data:`OVERLOAD_MS` with torque on).  A latched alarm in
  ``alarm_shutdown`` sets ``torque_limit`` to 0 and keeps the output off until reset; one in
  ``alarm_led`` blinks the ``led`` register at 2 Hz.
* A goal outside [``cw_angle_limit``, ``ccw_angle_limit``] is refused with ANGLE_LIMIT
  (wheel mode, both limits 0, is not modelled: every goal is then accepted).

Implementation notes (the emulator runs three of these at 1 kHz): the tick reads each sensor
once; the registers it needs are kept in attributes (:meth:`reload_registers`); the
read-only registers are packed into the image with precompiled structs, before every
READ/BULK_READ and, for a tick's readings, when the image is next read or written
(:meth:`sync_image`: most ticks are followed by the next before anything looks), so the
image - and :meth:`get` - read as if every tick had written them; alarms are plain ints
inside (:attr:`alarms` still reads as an :class:`~protocol.dynamixel.ErrorBit`).
"""

from __future__ import annotations

import struct
from collections import deque
from typing import Final

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.hal import Hal
from protocol.control_tables import RX64_TABLE, Register
from protocol.dynamixel import RX64_RPM_PER_UNIT, ErrorBit
from protocol.robot import RX64_POSITION_UNITS, RX64_RANGE_DEG

#: Control tick period (µs): 1 kHz.
TICK_US: Final = 1_000
#: Time the load must stay at or beyond the torque limit before OVERLOAD latches (ms).
OVERLOAD_MS: Final = 200
#: Half period of the alarm LED blink (ticks).
LED_BLINK_TICKS: Final = 250
#: Position units per second per moving-speed unit (0.111 rpm = 0.666 deg/s; 300/1024 deg).
UNITS_PER_S_PER_SPEED: Final = RX64_RPM_PER_UNIT * 6.0 * RX64_POSITION_UNITS / RX64_RANGE_DEG
#: Window over which present_speed is measured (ticks).
SPEED_WINDOW: Final = 10
_CW_BIT: Final = 0x400

# Plain-int alarm bits for the hot path (IntFlag arithmetic is slow).
_OVERHEATING: Final = int(ErrorBit.OVERHEATING)
_INPUT_VOLTAGE: Final = int(ErrorBit.INPUT_VOLTAGE)
_OVERLOAD: Final = int(ErrorBit.OVERLOAD)

#: present_position, present_speed, present_load, present_voltage, present_temperature.
_PRESENT: Final = struct.Struct("<HHHBB")
_PRESENT_AT: Final = RX64_TABLE["present_position"].address
_MOVING: Final = struct.Struct("<B")
_MOVING_AT: Final = RX64_TABLE["moving"].address
assert RX64_TABLE["present_temperature"].end == _PRESENT_AT + _PRESENT.size


def _round_nonnegative(x: float) -> int:
    """``round(x)`` (half to even) of a finite ``x >= 0``, without the builtin's generic
    dispatch (compiled, ``round`` of a float looks up ``__round__`` on every call).
    ``x - int(x)`` is exact for a double, so the halfway test is too."""
    n = int(x)
    frac = x - n
    if frac > 0.5 or (frac == 0.5 and n & 1):
        n += 1
    return n


if __file__.endswith(".py"):  # run from source (pure Python): the builtin is the faster
    _round_nonnegative = round  # type: ignore[assignment]  # noqa: F811


class Rx64ServoApp(DynamixelSlave):
    """The RX-64's firmware on ``hal`` (factory bus ID ``dxl_id``, 1 Mbaud)."""

    CACHED_REGISTERS = frozenset({
        "temperature_limit", "min_voltage_limit", "max_voltage_limit", "alarm_led",
        "alarm_shutdown", "torque_enable", "cw_compliance_margin", "ccw_compliance_margin",
        "cw_compliance_slope", "ccw_compliance_slope", "goal_position", "moving_speed",
        "torque_limit", "punch",
    })

    def __init__(self, hal: Hal, dxl_id: int = 1) -> None:
        super().__init__(hal, RX64_TABLE, {"id": dxl_id, "baud_rate": 1})
        self.motor = hal.motor(0)
        self.setpoint = 0.0  #: position the loop drives toward (units)
        self._alarms = 0  # latched ErrorBit alarms, plain int
        self.shutdown = False  #: an alarm in alarm_shutdown turned the output off
        self._overload_ms = 0
        self._ticks = 0
        self._pots: deque[int] = deque(maxlen=SPEED_WINDOW + 1)
        self._duty = 0.0
        self._bridge_on = False  # what the tick last wrote to the motor's enable
        #: The last tick's readings (pot, duty, temperature, supply) whose registers are not
        #: written into the image yet (:meth:`sync_image`), or None.
        self._unpublished: tuple[int, float, int, int] | None = None
        # Registers kept in attributes (reload_registers: from the image at every boot).
        self._temperature_limit = self._min_voltage = self._max_voltage = 0
        self._alarm_led = self._alarm_shutdown = self._torque_enable = 0
        self._cw_margin = self._ccw_margin = self._cw_slope = self._ccw_slope = 0
        self._goal = self._moving_speed = self._torque_limit = self._punch = 0
        self._goal_f = 0.0  # the goal as the setpoint's float (converted once per write)

    @property
    def alarms(self) -> ErrorBit | int:
        """Latched ErrorBit alarms (0 when none)."""
        return ErrorBit(self._alarms) if self._alarms else 0

    @alarms.setter
    def alarms(self, value: int) -> None:
        self._alarms = int(value)

    # ------------------------------------------------------------------ hooks

    def reload_registers(self) -> None:
        get = self.get
        self._temperature_limit = get("temperature_limit")
        self._min_voltage = get("min_voltage_limit")
        self._max_voltage = get("max_voltage_limit")
        self._alarm_led = get("alarm_led")
        self._alarm_shutdown = get("alarm_shutdown")
        self._torque_enable = get("torque_enable")
        self._cw_margin = get("cw_compliance_margin")
        self._ccw_margin = get("ccw_compliance_margin")
        self._cw_slope = get("cw_compliance_slope")
        self._ccw_slope = get("ccw_compliance_slope")
        self._goal = get("goal_position")
        self._goal_f = float(self._goal)
        self._moving_speed = get("moving_speed")
        self._torque_limit = get("torque_limit")
        self._punch = get("punch")

    def power_up(self) -> None:
        self._unpublished = None  # a fresh image: nothing from before is owed to it
        present = self._pot()
        self._alarms = 0
        self.shutdown = False
        self._overload_ms = self._ticks = 0
        self._pots = deque([present], maxlen=SPEED_WINDOW + 1)
        self.setpoint = float(present)
        self.set("goal_position", present)
        self.set("torque_limit", self.get("max_torque"))
        self.motor.set_duty(0.0)
        self.motor.set_enabled(False)
        self._duty = 0.0
        self._bridge_on = False
        self._refresh(0.0)
        self.hal.clock.call_every(TICK_US, self._tick)

    def before_read(self) -> None:
        self._refresh(self._duty)

    def validate_write(self, after: bytearray, touched: list[Register]) -> int:
        if not any(r.name == "goal_position" for r in touched):
            return 0
        table = self.table
        cw, ccw = table.value(after, "cw_angle_limit"), table.value(after, "ccw_angle_limit")
        goal = table.value(after, "goal_position")
        if (cw or ccw) and not cw <= goal <= ccw:
            return int(ErrorBit.ANGLE_LIMIT)
        return 0

    def after_write(self, touched: list[Register]) -> None:
        names = {r.name for r in touched}
        if "torque_enable" in names and self._torque_enable:
            self.setpoint = float(self._pot())
        if "torque_limit" in names and self.shutdown:
            self.set("torque_limit", 0)

    def alarm_bits(self) -> int:
        return self._alarms

    # ------------------------------------------------------------------ loop

    @property
    def motor_duty(self) -> float:
        """The duty last commanded (−1..1, + = counter-clockwise)."""
        return self._duty

    def _pot(self) -> int:
        pot = self.sensor("pot")
        return 0 if pot < 0 else 1023 if pot > 1023 else pot

    def compliance_torque(self, error: float) -> int:
        """Torque magnitude (1/1023 of maximum) for a position error of ``error`` units
        (setpoint − present), from the compliance margin, slope, punch and torque limit."""
        return self._compliance(error, 0 if self.shutdown else self._torque_limit)

    def _compliance(self, error: float, limit: int) -> int:
        if error > 0:
            beyond = error - self._cw_margin
            slope = self._cw_slope
        else:
            beyond = -error - self._ccw_margin
            slope = self._ccw_slope
        if beyond <= 0 or limit == 0:
            return 0
        punch = self._punch
        if limit < punch:
            punch = limit
        if slope == 0:
            return limit
        torque = round(punch + (limit - punch) * beyond / slope)
        return int(limit if limit < torque else punch if torque < punch else torque)

    def _tick(self) -> None:
        """The 1 kHz tick: alarms, setpoint, compliance, duty, registers.

        The read-only registers are published, not written: the image gets them when it is
        next read or written (:meth:`sync_image`), from this tick's readings and the state
        as it is now (whatever would change that state syncs first).  Most ticks are
        followed by another before anything reads them (a READ refreshes them anyway)."""
        self._unpublished = None  # this tick writes them all anew
        self._ticks += 1
        read = self.hal.sensors.read
        present = read("pot")
        if type(present) is not int:
            present = self.sensor("pot")
        present = 0 if present < 0 else 1023 if present > 1023 else present
        self._pots.append(present)
        # alarms (latched)
        temperature = read("temperature")
        if type(temperature) is not int:
            temperature = self.sensor("temperature")
        alarms = self._alarms
        if temperature // 10 > self._temperature_limit:
            alarms |= _OVERHEATING
        supply_mv = read("supply_mv")
        if type(supply_mv) is not int:
            supply_mv = self.sensor("supply_mv")
        decivolts = supply_mv // 100
        if not self._min_voltage <= decivolts <= self._max_voltage:
            alarms |= _INPUT_VOLTAGE
        limit = self._torque_limit
        if self._torque_enable and not self.shutdown and limit:
            load = read("load")
            if type(load) is not int:
                load = self.sensor("load")
            if (-load if load < 0 else load) >= limit:
                self._overload_ms += 1
                if self._overload_ms > OVERLOAD_MS:
                    alarms |= _OVERLOAD
            else:
                self._overload_ms = 0
        self._alarms = alarms
        if alarms & self._alarm_shutdown and not self.shutdown:
            self.shutdown = True
            self.set("torque_limit", 0)
        # setpoint
        goal = self._goal_f
        speed = self._moving_speed
        if speed == 0:
            self.setpoint = goal
        else:
            step = speed * UNITS_PER_S_PER_SPEED * TICK_US / 1e6
            self.setpoint += max(-step, min(step, goal - self.setpoint))
        # output
        if self._torque_enable and not self.shutdown:
            error = self.setpoint - present
            torque = self._compliance(error, self._torque_limit)
            duty = torque / 1023 if error > 0 else -torque / 1023
            bridge_on = True
        else:
            duty = 0.0
            bridge_on = False
        # The driver holds what was last written and this program is its only writer
        # (power_up writes both; a halt stops this tick): write only what changed.  A
        # zero duty's sign drives alike (0·stall), so ±0.0 count as the same.
        if bridge_on is not self._bridge_on:
            self.motor.set_enabled(bridge_on)
            self._bridge_on = bridge_on
        if duty != self._duty:
            self.motor.set_duty(duty)
        self._duty = duty
        if alarms & self._alarm_led:
            if self._ticks % LED_BLINK_TICKS == 0:
                self.set("led", 1 - self.get("led"))
        self._unpublished = (present, duty, temperature, supply_mv)

    def sync_image(self) -> None:
        """Write the last tick's read-only registers into the image if not yet done."""
        pending = self._unpublished
        if pending is not None:
            present, duty, temperature, supply_mv = pending
            self._publish(present, duty, temperature, supply_mv, self._pots)

    def _refresh(self, duty: float) -> None:
        """Bring the read-only registers up to date (``duty`` is the applied duty)."""
        present = self._pot()
        self._publish(present, duty, self.sensor("temperature"), self.sensor("supply_mv"),
                      self._pots or (present,))

    def _publish(self, present: int, duty: float, temperature: int, supply_mv: int,
                 pots: deque[int] | tuple[int]) -> None:
        """Write the read-only registers from these readings (``pots``: the pot's recent
        readings, oldest first)."""
        self._unpublished = None
        span = len(pots) - 1
        rate = (pots[-1] - pots[0]) * 1_000_000 / (span * TICK_US) if span else 0.0
        speed = _round_nonnegative((-rate if rate < 0 else rate) / UNITS_PER_S_PER_SPEED)
        if speed > 0x3FF:
            speed = 0x3FF
        if rate < 0 and speed:
            speed |= _CW_BIT
        load = _round_nonnegative((-duty if duty < 0 else duty) * 1023)
        if load > 0x3FF:
            load = 0x3FF
        if duty < 0 and load:
            load |= _CW_BIT
        volts = supply_mv // 100
        degrees = temperature // 10
        _PRESENT.pack_into(self.image, _PRESENT_AT, present, speed, load,
                           0 if volts < 0 else 255 if volts > 255 else volts,
                           0 if degrees < 0 else 255 if degrees > 255 else degrees)
        goal = self._goal
        cw, ccw = self._cw_margin, self._ccw_margin
        moving = self.setpoint != goal or (
            self._torque_enable and abs(goal - present) > (ccw if ccw > cw else cw))
        _MOVING.pack_into(self.image, _MOVING_AT, 1 if moving else 0)
