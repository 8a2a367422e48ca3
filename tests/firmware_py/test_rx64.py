"""The RX-64 servo firmware on a VirtualHal: compliance, alarms, angle limits."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.rx64 import OVERLOAD_MS, UNITS_PER_S_PER_SPEED, Rx64ServoApp, _round_nonnegative
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import RX64_TABLE
from protocol.dynamixel import (
    ErrorBit,
    StatusPacket,
    make_read,
    make_reset,
    make_write,
)
from protocol.image import BoardType
from tests.firmware_py.dxl_bench import transact as dxl_transact

ID = 6


def transact(sched: Scheduler, hal: VirtualHal, raw: bytes) -> list[StatusPacket]:
    return dxl_transact(sched, hal, raw, run_us=600)


def read(sched: Scheduler, hal: VirtualHal, name: str) -> int:
    reg = RX64_TABLE[name]
    (reply,) = transact(sched, hal, make_read(ID, reg.address, reg.size).encode())
    return reg.decode(reply.params)


def write(sched: Scheduler, hal: VirtualHal, name: str, value: int) -> int:
    """Write a register; returns the status error byte."""
    reg = RX64_TABLE[name]
    (ack,) = transact(sched, hal, make_write(ID, reg.address, reg.encode(value)).encode())
    return ack.error


@pytest.fixture
def servo() -> tuple[Scheduler, VirtualHal, Rx64ServoApp]:
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.RX64, ID)
    assert isinstance(app, Rx64ServoApp)
    write(sched, hal, "return_delay_time", 0)
    return sched, hal, app


def duty_for_goal(sched: Scheduler, hal: VirtualHal, goal: int) -> float:
    assert write(sched, hal, "goal_position", goal) & ~ErrorBit.INPUT_VOLTAGE == 0
    sched.run_for(2_000)
    return hal.motor(0).duty


def test_power_up_values(servo):
    sched, hal, _ = servo
    assert read(sched, hal, "model_number") == 64
    assert read(sched, hal, "present_position") == 512  # the pot
    assert read(sched, hal, "goal_position") == 512  # copied from present at power-up
    assert read(sched, hal, "torque_limit") == 1023  # copied from max torque
    assert read(sched, hal, "present_voltage") == 180
    assert read(sched, hal, "present_temperature") == 25
    hal.sensors.values["pot"] = 700
    assert read(sched, hal, "present_position") == 700


def test_compliance_margin_punch_slope_and_saturation(servo):
    sched, hal, _ = servo
    write(sched, hal, "torque_enable", 1)
    assert duty_for_goal(sched, hal, 512) == 0.0
    assert duty_for_goal(sched, hal, 513) == 0.0  # inside the margin (1)
    assert duty_for_goal(sched, hal, 511) == 0.0
    # just outside: punch 32 + (1023 - 32) * 1 / 32 = 62.97
    assert duty_for_goal(sched, hal, 514) == pytest.approx(63 / 1023)
    write(sched, hal, "punch", 200)
    write(sched, hal, "cw_compliance_slope", 254)
    assert duty_for_goal(sched, hal, 514) == pytest.approx(203 / 1023)  # at least the punch
    assert duty_for_goal(sched, hal, 900) == pytest.approx(1.0)  # saturated
    write(sched, hal, "torque_limit", 400)
    assert duty_for_goal(sched, hal, 900) == pytest.approx(400 / 1023)
    # clockwise side: negative duty, load reported with bit 10
    assert duty_for_goal(sched, hal, 100) == pytest.approx(-400 / 1023)
    assert read(sched, hal, "present_load") == 0x400 | 400
    assert read(sched, hal, "moving") == 1


def test_torque_disabled_gives_no_duty(servo):
    sched, hal, _ = servo
    assert duty_for_goal(sched, hal, 900) == 0.0
    assert not hal.motor(0).enabled
    write(sched, hal, "torque_enable", 1)
    sched.run_for(2_000)
    assert hal.motor(0).enabled and hal.motor(0).duty > 0


def test_moving_speed_limits_the_setpoint(servo):
    sched, hal, app = servo
    write(sched, hal, "moving_speed", 100)
    write(sched, hal, "goal_position", 900)
    start = app.setpoint
    sched.run_for(100_000)
    moved = app.setpoint - start
    assert moved == pytest.approx(100 * UNITS_PER_S_PER_SPEED * 0.1, rel=0.02)


def test_angle_limit_error(servo):
    sched, hal, _ = servo
    write(sched, hal, "cw_angle_limit", 100)
    write(sched, hal, "ccw_angle_limit", 900)
    assert write(sched, hal, "goal_position", 950) == ErrorBit.ANGLE_LIMIT
    assert write(sched, hal, "goal_position", 50) == ErrorBit.ANGLE_LIMIT
    assert read(sched, hal, "goal_position") == 512
    assert write(sched, hal, "goal_position", 800) == 0
    assert read(sched, hal, "goal_position") == 800


def test_overheating_shutdown_latches_until_reset(servo):
    sched, hal, _ = servo
    write(sched, hal, "torque_enable", 1)
    assert duty_for_goal(sched, hal, 900) > 0
    hal.sensors.values["temperature"] = 900  # 90 degC > 80
    sched.run_for(2_000)
    assert hal.motor(0).duty == 0.0
    assert read(sched, hal, "torque_limit") == 0
    hal.sensors.values["temperature"] = 300  # cooled down: still latched
    sched.run_for(10_000)
    (reply,) = transact(sched, hal, make_read(ID, 36, 2).encode())
    assert reply.errors == ErrorBit.OVERHEATING
    write(sched, hal, "torque_limit", 1023)
    sched.run_for(2_000)
    assert hal.motor(0).duty == 0.0 and read(sched, hal, "torque_limit") == 0
    leds = set()
    for _ in range(4):  # alarm LED (36 includes overheating) blinks
        sched.run_for(250_000)
        leds.add(read(sched, hal, "led"))
    assert leds == {0, 1}
    (ack,) = transact(sched, hal, make_reset(ID).encode())
    assert ack.errors == ErrorBit.OVERHEATING  # reported by the reply, then cleared
    (reply,) = transact(sched, hal, make_read(ID, 34, 2).encode())
    assert reply.error == 0 and RX64_TABLE["torque_limit"].decode(reply.params) == 1023
    write(sched, hal, "return_delay_time", 0)
    write(sched, hal, "torque_enable", 1)
    assert duty_for_goal(sched, hal, 900) > 0


def test_voltage_alarm_without_shutdown(servo):
    sched, hal, _ = servo
    write(sched, hal, "torque_enable", 1)
    hal.sensors.values["supply_mv"] = 24000  # above 19.0 V
    sched.run_for(2_000)
    (reply,) = transact(sched, hal, make_read(ID, 36, 2).encode())
    assert reply.errors == ErrorBit.INPUT_VOLTAGE
    assert duty_for_goal(sched, hal, 900) > 0  # not in alarm_shutdown (36)


def test_overload_needs_sustained_load(servo):
    sched, hal, _ = servo
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "torque_limit", 500)
    hal.sensors.values["load"] = -600
    sched.run_for((OVERLOAD_MS - 50) * 1000)
    (reply,) = transact(sched, hal, make_read(ID, 36, 2).encode())
    assert reply.error == 0
    sched.run_for(100_000)
    (reply,) = transact(sched, hal, make_read(ID, 36, 2).encode())
    assert reply.errors == ErrorBit.OVERLOAD
    assert read(sched, hal, "torque_limit") == 0  # overload is in alarm_shutdown


def test_eeprom_persists_ram_resets(servo):
    sched, hal, _ = servo
    write(sched, hal, "max_torque", 600)
    write(sched, hal, "cw_compliance_margin", 5)
    sched.run_for(5_000)
    hal.reset()
    write(sched, hal, "return_delay_time", 0)  # still 0 from flash, so this is harmless
    assert read(sched, hal, "max_torque") == 600
    assert read(sched, hal, "torque_limit") == 600
    assert read(sched, hal, "cw_compliance_margin") == 1


@settings(deadline=None)
@given(st.floats(min_value=0.0, max_value=1e9, allow_nan=False)
       | st.integers(min_value=0, max_value=4000).map(lambda k: k / 2))
def test_publish_rounding_is_round(x: float) -> None:
    """The registers' rounding is the builtin's, halves to even included."""
    assert _round_nonnegative(x) == round(x)


RX64_ACTIONS = st.one_of(
    st.tuples(st.just("goal_position"), st.integers(0, 1023)),
    st.tuples(st.just("torque_enable"), st.integers(0, 1)),
    st.tuples(st.just("torque_limit"), st.sampled_from([0, 1, 300, 1023])),
    st.tuples(st.just("cw_compliance_margin"), st.integers(0, 40)),
    st.tuples(st.just("pot"), st.integers(-5, 1030)),
    st.tuples(st.just("temperature"), st.sampled_from([250, 900])),  # 90 °C: overheating
)


@settings(max_examples=40, deadline=None)
@given(st.lists(RX64_ACTIONS, min_size=1, max_size=12))
def test_after_every_tick_the_motor_holds_what_the_tick_commanded(
        actions: list[tuple[str, int]]) -> None:
    """The tick writes the motor's enable and duty only when they change: the driver must
    still hold, after every tick, what a tick writing both every time would leave."""
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.RX64, ID)
    assert isinstance(app, Rx64ServoApp)
    motor = hal.motor(0)
    for name, value in actions:
        if name == "pot":
            hal.sensors.set_pot(value)
        elif name == "temperature":
            hal.sensors.set_temperature(value)
        else:
            write(sched, hal, name, value)
        for _ in range(5):
            sched.run_for(1_000)
            assert motor.enabled == (bool(app.get("torque_enable")) and not app.shutdown)
            assert motor.duty == app.motor_duty  # ±0.0 alike
