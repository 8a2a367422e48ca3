"""The arm nodes' fast paths: registers kept in attributes follow every way the image changes,
and the read-only registers always hold their documented formulas (after every tick, every
READ and BULK_READ)."""

from __future__ import annotations

import random

import pytest

from firmware_py.arm_stepper import VELOCITY_WINDOW, StepperNodeApp
from firmware_py.rx64 import SPEED_WINDOW, UNITS_PER_S_PER_SPEED, Rx64ServoApp
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE, ControlTable
from protocol.dynamixel import (
    ErrorBit,
    StatusPacket,
    make_bulk_read,
    make_read,
    make_sync_write,
    make_write,
)
from protocol.image import BoardType
from tests.firmware_py.dxl_bench import transact


def write(sched: Scheduler, hal: VirtualHal, dxl_id: int, table: ControlTable, name: str,
          value: int) -> int:
    reg = table[name]
    (ack,) = transact(sched, hal, make_write(dxl_id, reg.address, reg.encode(value)).encode(),
                      run_us=600)
    return ack.error


def read(sched: Scheduler, hal: VirtualHal, dxl_id: int, table: ControlTable, name: str) -> int:
    reg = table[name]
    (reply,) = transact(sched, hal, make_read(dxl_id, reg.address, reg.size).encode(),
                        run_us=600)
    return reg.decode(reply.params)


@pytest.fixture
def stepper() -> tuple[Scheduler, VirtualHal, StepperNodeApp]:
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.ARM_STEPPER, 2)
    assert isinstance(app, StepperNodeApp)
    write(sched, hal, 2, STEPPER_TABLE, "return_delay_time", 0)
    return sched, hal, app


@pytest.fixture
def servo() -> tuple[Scheduler, VirtualHal, Rx64ServoApp]:
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.RX64, 6)
    assert isinstance(app, Rx64ServoApp)
    write(sched, hal, 6, RX64_TABLE, "return_delay_time", 0)
    return sched, hal, app


# ---------------------------------------------------------------------- stepper


def test_gear_set_by_the_node_changes_the_step_rate_at_once(stepper):
    """The arm rig programs each joint's reduction with ``app.set`` after power-up."""
    sched, hal, app = stepper
    app.set("gear_reduction_x100", 1300)
    assert app.microsteps_per_count == pytest.approx(1300 * 200 * 10 / 1_000_000)
    write(sched, hal, 2, STEPPER_TABLE, "slip_threshold", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "deflection_limit", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "velocity_limit", 1000)
    write(sched, hal, 2, STEPPER_TABLE, "torque_enable", 1)
    write(sched, hal, 2, STEPPER_TABLE, "goal_position", 5000)
    sched.run_for(200_000)  # at the velocity limit by now
    assert hal.stepper().rate == pytest.approx(1000 * app.microsteps_per_count)


def test_eeprom_writes_change_the_microsteps_per_count(stepper):
    sched, hal, app = stepper
    assert write(sched, hal, 2, STEPPER_TABLE, "microstepping", 8) == 0
    assert app.microsteps_per_count == pytest.approx(600 * 200 * 8 / 1_000_000)
    raw = make_sync_write(STEPPER_TABLE["steps_per_rev"].address, 2, {2: b"\x90\x01"}).encode()
    transact(sched, hal, raw, run_us=600)  # 400 steps per rev, by SYNC_WRITE
    assert app.microsteps_per_count == pytest.approx(600 * 400 * 8 / 1_000_000)
    sched.run_for(50_000)  # the flash write completes
    hal.reset()  # kept in flash, read back at boot
    assert app.microsteps_per_count == pytest.approx(600 * 400 * 8 / 1_000_000)


def test_written_limits_apply_from_the_next_tick(stepper):
    sched, hal, app = stepper
    write(sched, hal, 2, STEPPER_TABLE, "slip_threshold", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "deflection_limit", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "torque_enable", 1)
    write(sched, hal, 2, STEPPER_TABLE, "goal_position", 3000)
    sched.run_for(5_000)
    assert hal.stepper().current == 2000
    write(sched, hal, 2, STEPPER_TABLE, "max_current", 500)
    sched.run_for(1_000)
    assert hal.stepper().current == 500  # capped
    write(sched, hal, 2, STEPPER_TABLE, "velocity_limit", 10)
    sched.run_for(50_000)
    assert abs(hal.stepper().rate) <= 10 * app.microsteps_per_count + 1e-9


def test_alarm_shutdown_written_by_the_host_is_used(stepper):
    sched, hal, _ = stepper
    write(sched, hal, 2, STEPPER_TABLE, "alarm_shutdown", 0)
    write(sched, hal, 2, STEPPER_TABLE, "torque_enable", 1)
    hal.sensors.values["temperature"] = 900
    sched.run_for(3_000)
    assert read(sched, hal, 2, STEPPER_TABLE, "torque_enable") == 1  # alarm only
    assert read(sched, hal, 2, STEPPER_TABLE, "hardware_error_status") == ErrorBit.OVERHEATING
    write(sched, hal, 2, STEPPER_TABLE, "alarm_shutdown", int(ErrorBit.OVERHEATING))
    sched.run_for(1_000)
    assert read(sched, hal, 2, STEPPER_TABLE, "torque_enable") == 0


def _stepper_expected(app: StepperNodeApp, hal: VirtualHal, history: list[int]) -> dict[str, int]:
    """The read-only registers from the module docstring's formulas and the HAL's state."""
    k = (app.get("gear_reduction_x100") * app.get("steps_per_rev") * app.get("microstepping")
         / 1_000_000)
    enc, steps = hal.encoder().count(), hal.stepper().step_count()
    deflection = round((steps - app._hw_steps0) / k) - (enc - app._enc0)
    span = len(history) - 1
    supply_mv, decidegrees = hal.sensors.values["supply_mv"], hal.sensors.values["temperature"]
    assert isinstance(supply_mv, int) and isinstance(decidegrees, int)  # scalar channels
    return {
        "present_position": enc,
        "present_velocity": (history[-1] - history[0]) * 1000 // span if span else 0,
        "step_count": steps - app._step_offset,
        "deflection": max(-32768, min(32767, deflection)),
        "present_voltage": max(0, min(255, supply_mv // 100)),
        "present_temperature": max(0, min(255, decidegrees // 10)),
    }


def test_stepper_read_only_registers_hold_their_formulas(stepper):
    sched, hal, app = stepper
    rng = random.Random(7)
    write(sched, hal, 2, STEPPER_TABLE, "slip_threshold", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "deflection_limit", 65535)
    write(sched, hal, 2, STEPPER_TABLE, "torque_enable", 1)
    write(sched, hal, 2, STEPPER_TABLE, "goal_position", 400)
    history = list(app._enc_history)
    for t in range(300):
        k = app.microsteps_per_count
        hal.encoder().value = round(hal.stepper().step_count() / k) + rng.randint(-3, 3)
        if t % 50 == 7:
            hal.sensors.values["supply_mv"] = rng.choice([12_000, 24_000, 26_000])
            hal.sensors.values["temperature"] = rng.choice([250, 450, 850])
        sched.run_for(1_000)  # one tick
        history = [*history, hal.encoder().count()][-VELOCITY_WINDOW - 1:]
        expected = _stepper_expected(app, hal, history)
        assert {name: app.get(name) for name in expected} == expected
        flags = app.get("status_flags")
        assert bool(flags & 0x01) == (hal.stepper().rate != 0.0)  # MOVING
        assert bool(flags & 0x10) == (app.get("hardware_error_status") != 0)
    # a READ refreshes with what the sensors say now, between ticks
    sched.run_for(500)
    hal.sensors.values["temperature"] = 333
    assert read(sched, hal, 2, STEPPER_TABLE, "present_temperature") == 33


# ---------------------------------------------------------------------- RX-64


def test_alarms_read_as_error_bits(servo):
    sched, hal, app = servo
    assert app.alarms == 0 and app.alarm_bits() == 0
    hal.sensors.values["supply_mv"] = 24_000
    sched.run_for(2_000)
    assert app.alarms == ErrorBit.INPUT_VOLTAGE
    assert isinstance(app.alarms, ErrorBit) and app.alarm_bits() == ErrorBit.INPUT_VOLTAGE


def test_written_compliance_applies_from_the_next_tick(servo):
    sched, hal, app = servo
    write(sched, hal, 6, RX64_TABLE, "torque_enable", 1)
    write(sched, hal, 6, RX64_TABLE, "goal_position", 600)
    sched.run_for(2_000)
    assert hal.motor(0).duty == pytest.approx(app.compliance_torque(600 - 512) / 1023)
    for name, value in (("cw_compliance_margin", 100), ("punch", 0),
                        ("cw_compliance_slope", 0), ("torque_limit", 300)):
        write(sched, hal, 6, RX64_TABLE, name, value)
        sched.run_for(2_000)
        assert hal.motor(0).duty == pytest.approx(app.compliance_torque(600 - 512) / 1023)
    assert hal.motor(0).duty == 0.0  # inside the 100-unit margin
    write(sched, hal, 6, RX64_TABLE, "goal_position", 700)
    sched.run_for(2_000)
    assert hal.motor(0).duty == pytest.approx(300 / 1023)  # slope 0: the torque limit


def test_servo_read_only_registers_hold_their_formulas(servo):
    sched, hal, app = servo
    rng = random.Random(11)
    write(sched, hal, 6, RX64_TABLE, "torque_enable", 1)
    write(sched, hal, 6, RX64_TABLE, "moving_speed", 200)
    write(sched, hal, 6, RX64_TABLE, "goal_position", 800)
    pots = list(app._pots)
    for _ in range(300):
        pot = max(0, min(1023, round(app.setpoint) + rng.randint(-4, 4)))
        hal.sensors.values["pot"] = pot
        sched.run_for(1_000)
        pots = [*pots, pot][-SPEED_WINDOW - 1:]
        rate = (pots[-1] - pots[0]) * 1000 / (len(pots) - 1)
        speed = min(round(abs(rate) / UNITS_PER_S_PER_SPEED), 0x3FF)
        load = round(abs(hal.motor(0).duty) * 1023)
        assert app.get("present_position") == pot
        assert app.get("present_speed") == speed | (0x400 if rate < 0 and speed else 0)
        assert app.get("present_load") == load | (0x400 if hal.motor(0).duty < 0 and load
                                                   else 0)
        moving = app.setpoint != app.get("goal_position") or abs(800 - pot) > 1
        assert app.get("moving") == int(moving)


def test_servo_tick_registers_reach_the_image_when_it_is_next_read_or_written(servo):
    """A tick's read-only registers are owed to the image until something reads or writes
    it (get, set, a host write, sync_image), and then read as that tick left them."""
    sched, hal, app = servo
    write(sched, hal, 6, RX64_TABLE, "torque_enable", 1)
    present = RX64_TABLE["present_position"]
    for pot, reader in ((300, lambda: app.get("present_position")),
                        (310, lambda: app.set("led", 1)),
                        (320, lambda: write(sched, hal, 6, RX64_TABLE, "goal_position", 400)),
                        (330, app.sync_image)):
        hal.sensors.values["pot"] = pot
        sched.run_for(1_000)
        assert present.decode(app.image[present.address:present.end]) != pot  # owed
        reader()
        assert present.decode(app.image[present.address:present.end]) == pot
        assert app.get("present_position") == pot


def test_bulk_read_sees_fresh_values():
    sched = Scheduler()
    hal1, _ = make_arm_node(sched, BoardType.ARM_STEPPER, 1)
    hal5, _ = make_arm_node(sched, BoardType.RX64, 5)
    write(sched, hal1, 1, STEPPER_TABLE, "return_delay_time", 0)
    write(sched, hal5, 5, RX64_TABLE, "return_delay_time", 0)
    sched.run_for(10_500)  # between two ticks
    hal1.encoder().value = -1234
    hal5.sensors.values["pot"] = 77
    raw = make_bulk_read([(4, 1, 32), (2, 5, 36)]).encode()
    hal1.uart("bus").deliver(raw)
    hal5.uart("bus").deliver(raw)
    sched.run_for(100)
    (first,) = hal1.uart("bus").take_sent()
    hal5.uart("bus").deliver(first)
    sched.run_for(100)
    (second,) = hal5.uart("bus").take_sent()
    assert status_value(first) == -1234 and status_value(second) == 77


def status_value(raw: bytes) -> int:
    """The value a status packet carries (4 bytes: signed)."""
    params = StatusPacket.decode(raw).params
    return int.from_bytes(params, "little", signed=len(params) == 4)
