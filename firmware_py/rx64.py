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
"""

from __future__ import annotations

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.hal import Hal
from protocol.control_tables import RX64_TABLE, Register
from protocol.dynamixel import RX64_RPM_PER_UNIT, ErrorBit

#: Control tick period (µs): 1 kHz.
TICK_US = 1_000
#: Time the load must stay at or beyond the torque limit before OVERLOAD latches (ms).
OVERLOAD_MS = 200
#: Half period of the alarm LED blink (ticks).
LED_BLINK_TICKS = 250
#: Position units per second per moving-speed unit (0.111 rpm = 0.666 deg/s; 300/1024 deg).
UNITS_PER_S_PER_SPEED = RX64_RPM_PER_UNIT * 6.0 * 1024 / 300
#: Window over which present_speed is measured (ticks).
SPEED_WINDOW = 10
_CW_BIT = 0x400


def _with_direction(magnitude: int, clockwise: bool) -> int:
    return min(magnitude, 0x3FF) | (_CW_BIT if clockwise and magnitude else 0)


class Rx64ServoApp(DynamixelSlave):
    """The RX-64's firmware on ``hal`` (factory bus ID ``dxl_id``, 1 Mbaud)."""

    def __init__(self, hal: Hal, dxl_id: int = 1) -> None:
        super().__init__(hal, RX64_TABLE, {"id": dxl_id, "baud_rate": 1})
        self.motor = hal.motor(0)
        self.setpoint = 0.0  #: position the loop drives toward (units)
        self.alarms = 0  #: latched ErrorBit alarms
        self.shutdown = False  #: an alarm in alarm_shutdown turned the output off
        self._overload_ms = 0
        self._ticks = 0
        self._pots: list[int] = []
        self._duty = 0.0

    # ------------------------------------------------------------------ hooks

    def power_up(self) -> None:
        present = self._pot()
        self.alarms = 0
        self.shutdown = False
        self._overload_ms = self._ticks = 0
        self._pots = [present]
        self.setpoint = float(present)
        self.set("goal_position", present)
        self.set("torque_limit", self.get("max_torque"))
        self.motor.set_duty(0.0)
        self.motor.set_enabled(False)
        self._duty = 0.0
        self._refresh(0.0)
        self.hal.clock.call_every(TICK_US, self._tick)

    def before_read(self) -> None:
        self._refresh(self.motor_duty)

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
        if "torque_enable" in names and self.get("torque_enable"):
            self.setpoint = float(self._pot())
        if "torque_limit" in names and self.shutdown:
            self.set("torque_limit", 0)

    def alarm_bits(self) -> int:
        return self.alarms

    # ------------------------------------------------------------------ loop

    @property
    def motor_duty(self) -> float:
        """The duty last commanded (−1..1, + = counter-clockwise)."""
        return self._duty

    def _pot(self) -> int:
        return max(0, min(1023, self.sensor("pot")))

    def compliance_torque(self, error: float) -> int:
        """Torque magnitude (1/1023 of maximum) for a position error of ``error`` units
        (setpoint − present), from the compliance margin, slope, punch and torque limit."""
        side = "cw" if error > 0 else "ccw"
        beyond = abs(error) - self.get(f"{side}_compliance_margin")
        limit = 0 if self.shutdown else self.get("torque_limit")
        if beyond <= 0 or limit == 0:
            return 0
        punch = min(self.get("punch"), limit)
        slope = self.get(f"{side}_compliance_slope")
        if slope == 0:
            return limit
        torque = punch + (limit - punch) * beyond / slope
        return int(min(limit, max(punch, round(torque))))

    def _tick(self) -> None:
        """The 1 kHz tick: alarms, setpoint, compliance, duty, registers."""
        self._ticks += 1
        present = self._pot()
        self._pots.append(present)
        del self._pots[: -SPEED_WINDOW - 1]
        self._check_alarms()
        goal = float(self.get("goal_position"))
        speed = self.get("moving_speed")
        if speed == 0:
            self.setpoint = goal
        else:
            step = speed * UNITS_PER_S_PER_SPEED * TICK_US / 1e6
            self.setpoint += max(-step, min(step, goal - self.setpoint))
        if self.get("torque_enable") and not self.shutdown:
            error = self.setpoint - present
            torque = self.compliance_torque(error)
            duty = torque / 1023 if error > 0 else -torque / 1023
            self.motor.set_enabled(True)
        else:
            duty = 0.0
            self.motor.set_enabled(False)
        self.motor.set_duty(duty)
        self._duty = duty
        if self.alarms & self.get("alarm_led"):
            if self._ticks % LED_BLINK_TICKS == 0:
                self.set("led", 1 - self.get("led"))
        self._refresh(duty)

    def _check_alarms(self) -> None:
        if self.sensor("temperature") // 10 > self.get("temperature_limit"):
            self.alarms |= ErrorBit.OVERHEATING
        decivolts = self.sensor("supply_mv") // 100
        if not self.get("min_voltage_limit") <= decivolts <= self.get("max_voltage_limit"):
            self.alarms |= ErrorBit.INPUT_VOLTAGE
        limit = self.get("torque_limit")
        if self.get("torque_enable") and not self.shutdown and limit:
            over = abs(self.sensor("load")) >= limit
            self._overload_ms = self._overload_ms + 1 if over else 0
            if self._overload_ms > OVERLOAD_MS:
                self.alarms |= ErrorBit.OVERLOAD
        if self.alarms & self.get("alarm_shutdown") and not self.shutdown:
            self.shutdown = True
            self.set("torque_limit", 0)

    def _refresh(self, duty: float) -> None:
        """Bring the read-only registers up to date (``duty`` is the applied duty)."""
        pots = self._pots or [self._pot()]
        present = self._pot()
        self.set("present_position", present)
        span = len(pots) - 1
        rate = (pots[-1] - pots[0]) * 1_000_000 / (span * TICK_US) if span else 0.0
        self.set("present_speed",
                 _with_direction(round(abs(rate) / UNITS_PER_S_PER_SPEED), rate < 0))
        self.set("present_load", _with_direction(round(abs(duty) * 1023), duty < 0))
        self.set("present_voltage", max(0, min(255, self.sensor("supply_mv") // 100)))
        self.set("present_temperature", max(0, min(255, self.sensor("temperature") // 10)))
        error = abs(self.get("goal_position") - present)
        margin = max(self.get("cw_compliance_margin"), self.get("ccw_compliance_margin"))
        moving = self.setpoint != self.get("goal_position") or (
            self.get("torque_enable") and error > margin)
        self.set("moving", int(bool(moving)))
