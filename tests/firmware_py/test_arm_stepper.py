"""The arm stepper joint node on a VirtualHal: steps, index latch, deflection, slip."""

from __future__ import annotations

import pytest

from firmware_py.arm_stepper import StepperNodeApp
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import (
    STEPPER_TABLE,
    STEPPER_VELOCITY_LIMIT_MAX,
    StepperClear,
    StepperFlag,
)
from protocol.dynamixel import ErrorBit, StatusPacket, make_read, make_write
from protocol.image import BoardType
from protocol.robot import STEPPER_MAX_STEP_RATE
from tests.firmware_py.dxl_bench import transact as dxl_transact

#: Microsteps per joint count with the defaults: 6.00 x 200 x 10 / 10 000.
K = 600 * 200 * 10 / 1_000_000


def transact(sched: Scheduler, hal: VirtualHal, raw: bytes) -> list[StatusPacket]:
    return dxl_transact(sched, hal, raw, run_us=600)


def read(sched: Scheduler, hal: VirtualHal, name: str) -> int:
    reg = STEPPER_TABLE[name]
    (reply,) = transact(sched, hal, make_read(2, reg.address, reg.size).encode())
    return reg.decode(reply.params)


def status_error(sched: Scheduler, hal: VirtualHal) -> int:
    (reply,) = transact(sched, hal, make_read(2, 26, 1).encode())
    return reply.error


def write(sched: Scheduler, hal: VirtualHal, name: str, value: int) -> int:
    reg = STEPPER_TABLE[name]
    (ack,) = transact(sched, hal, make_write(2, reg.address, reg.encode(value)).encode())
    return ack.error


@pytest.fixture
def node() -> tuple[Scheduler, VirtualHal, StepperNodeApp]:
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.ARM_STEPPER, 2)
    assert isinstance(app, StepperNodeApp)
    write(sched, hal, "return_delay_time", 0)
    return sched, hal, app


def free_running(sched: Scheduler, hal: VirtualHal) -> None:
    """Thresholds out of reach: the encoder does not follow in these tests."""
    write(sched, hal, "slip_threshold", 65535)
    write(sched, hal, "deflection_limit", 65535)


def test_microsteps_per_count(node):
    _, _, app = node
    assert app.microsteps_per_count == pytest.approx(K)


def test_moves_to_goal_within_velocity_and_acceleration_limits(node):
    sched, hal, app = node
    free_running(sched, hal)
    write(sched, hal, "velocity_limit", 2000)
    write(sched, hal, "acceleration_limit", 20000)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 1000)
    stepper = hal.stepper()
    first = stepper.rate
    rates, moving_seen = [], False
    for _ in range(1000):
        sched.run_for(1_000)
        rates.append(stepper.rate)
        moving_seen |= bool(app.get("status_flags") & StepperFlag.MOVING)
    assert max(abs(r) for r in rates) <= 2000 * K + 1e-6
    assert max(rates) == pytest.approx(2000 * K)  # the limit was reached, not exceeded
    steps = [abs(b - a) for a, b in zip([first, *rates], rates, strict=False)]
    assert max(steps) <= 20000 * K / 1000 + 1e-6
    assert moving_seen
    assert abs(read(sched, hal, "step_count") - 1000 * K) <= 2
    assert stepper.rate == 0.0
    assert not read(sched, hal, "status_flags") & StepperFlag.MOVING
    assert stepper.current == 2000  # holding current at standstill (= run current)


def test_torque_off_means_no_current_and_no_steps(node):
    sched, hal, _ = node
    free_running(sched, hal)
    write(sched, hal, "goal_position", 500)
    sched.run_for(50_000)
    assert hal.stepper().current == 0 and hal.stepper().rate == 0.0
    write(sched, hal, "torque_enable", 1)
    sched.run_for(20_000)
    assert hal.stepper().current == 2000  # run current while moving
    assert hal.stepper().rate > 0
    write(sched, hal, "torque_enable", 0)
    sched.run_for(2_000)
    assert hal.stepper().current == 0 and hal.stepper().rate == 0.0


def test_step_count_is_since_power_up_and_can_be_zeroed(node):
    sched, hal, _ = node
    free_running(sched, hal)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 100)
    sched.run_for(300_000)  # the hardware counter runs before the reset
    hw = hal.stepper().step_count()
    assert hw == round(100 * K)
    hal.reset()
    write(sched, hal, "return_delay_time", 0)
    assert read(sched, hal, "step_count") == 0
    free_running(sched, hal)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 100)
    sched.run_for(300_000)
    assert read(sched, hal, "step_count") == hal.stepper().step_count() - hw
    write(sched, hal, "clear_flags", StepperClear.ZERO_STEP_COUNT)
    assert read(sched, hal, "step_count") == 0
    assert read(sched, hal, "clear_flags") == 0


def test_index_latch(node):
    sched, hal, _ = node
    free_running(sched, hal)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 200)
    sched.run_for(100_000)
    hal.encoder().value = 1234
    hal.encoder().pulse_index()
    steps_at_index = hal.stepper().step_count()
    assert read(sched, hal, "index_seen") == 1
    assert read(sched, hal, "index_encoder_count") == 1234
    assert read(sched, hal, "index_step_count") == steps_at_index
    assert read(sched, hal, "status_flags") & StepperFlag.INDEX_SEEN
    hal.encoder().value = 5000
    hal.encoder().pulse_index()  # latched: a later pulse changes nothing
    assert read(sched, hal, "index_encoder_count") == 1234
    write(sched, hal, "clear_flags", StepperClear.REARM_INDEX)
    assert read(sched, hal, "index_seen") == 0
    assert not read(sched, hal, "status_flags") & StepperFlag.INDEX_SEEN
    hal.encoder().pulse_index()
    assert read(sched, hal, "index_encoder_count") == 5000


def test_deflection_sign(node):
    sched, hal, _ = node
    free_running(sched, hal)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 100)
    sched.run_for(500_000)
    steps = read(sched, hal, "step_count")
    assert steps > 0
    # the motor went forward, the joint (encoder) did not: motor ahead -> positive
    assert read(sched, hal, "deflection") == round(steps / K)
    hal.encoder().value = 150  # joint ahead of the motor -> negative
    assert read(sched, hal, "deflection") == round(steps / K) - 150 < 0
    assert read(sched, hal, "present_position") == 150


def test_slip_and_stall_latch_until_cleared(node):
    sched, hal, _ = node
    write(sched, hal, "torque_enable", 1)
    hal.encoder().value = -400  # the joint moved, the motor did not: |deflection| 400 > 300
    sched.run_for(2_000)
    flags = read(sched, hal, "status_flags")
    assert flags & StepperFlag.SLIP and flags & StepperFlag.STALLED
    assert status_error(sched, hal) & ErrorBit.OVERLOAD
    # STALLED holds (not in the factory alarm_shutdown): torque on, holding current, no steps
    assert read(sched, hal, "torque_enable") == 1
    assert hal.stepper().current == 2000 and hal.stepper().rate == 0.0
    hal.encoder().value = 0
    sched.run_for(5_000)
    assert read(sched, hal, "status_flags") & StepperFlag.SLIP  # latched
    write(sched, hal, "clear_flags", StepperClear.SLIP | StepperClear.STALL)
    flags = read(sched, hal, "status_flags")
    assert not flags & (StepperFlag.SLIP | StepperFlag.STALLED)
    assert status_error(sched, hal) == 0


def test_small_deflection_only_stalls(node):
    sched, hal, _ = node
    write(sched, hal, "torque_enable", 1)
    hal.encoder().value = 200  # deflection_limit 150 < 200 <= slip_threshold 300
    sched.run_for(2_000)
    flags = read(sched, hal, "status_flags")
    assert flags & StepperFlag.STALLED and not flags & StepperFlag.SLIP


def test_an_unpowered_joint_moved_by_hand_latches_nothing(node):
    """With the coils off the rotor turns with the joint, which the step count cannot
    follow: a deflection then is no load and no lost step, so neither latch is set; once the
    coils hold, the same deflection is a stall."""
    sched, hal, _ = node
    hal.encoder().value = 400  # beyond slip_threshold 300 and deflection_limit 150
    sched.run_for(2_000)
    assert read(sched, hal, "deflection") == -400
    assert not read(sched, hal, "status_flags") & (StepperFlag.SLIP | StepperFlag.STALLED)
    write(sched, hal, "torque_enable", 1)
    sched.run_for(2_000)
    assert read(sched, hal, "status_flags") & StepperFlag.STALLED


def test_voltage_and_temperature_from_sensors(node):
    sched, hal, _ = node
    hal.sensors.set_supply_mv(23700)  # the plant side: the node's interrupts hear it
    hal.sensors.set_temperature(415)
    assert read(sched, hal, "present_voltage") == 237
    assert read(sched, hal, "present_temperature") == 41
    hal.sensors.set_temperature(900)
    sched.run_for(2_000)
    assert status_error(sched, hal) & ErrorBit.OVERHEATING
    assert read(sched, hal, "hardware_error_status") == ErrorBit.OVERHEATING
    assert read(sched, hal, "status_flags") & StepperFlag.HARDWARE_ERROR


CYCLE_BLOCK = [  # (mirror, original): the host's one-range read of a cycle's state
    ("cycle_present_position", "present_position"),
    ("cycle_step_count", "step_count"),
    ("cycle_velocity", "present_velocity"),
    ("cycle_deflection", "deflection"),
    ("cycle_status_flags", "status_flags"),
]


def block_and_originals(sched: Scheduler, hal: VirtualHal) -> tuple[list[int], list[int]]:
    """The cycle block and the registers it mirrors, from one READ of 26..88."""
    (reply,) = transact(sched, hal, make_read(2, 26, 89 - 26).encode())
    image = bytes(26) + reply.params

    def value(name: str) -> int:
        reg = STEPPER_TABLE[name]
        return reg.decode(image[reg.address : reg.end])

    return [value(m) for m, _ in CYCLE_BLOCK], [value(o) for _, o in CYCLE_BLOCK]


def test_the_cycle_block_mirrors_its_registers_every_tick_and_at_reads(node):
    sched, hal, app = node
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 300)
    seen_moving = seen_deflection = False
    for tick in range(400):
        sched.run_for(1_000)
        if tick == 100:
            hal.encoder().value = 40  # the joint moves on its own: deflection, velocity
        block = [app.get(m) for m, _ in CYCLE_BLOCK]
        assert block == [app.get(o) for _, o in CYCLE_BLOCK]  # after every tick
        seen_moving |= bool(block[4] & StepperFlag.MOVING)
        seen_deflection |= block[3] != 0
    assert seen_moving and seen_deflection
    hal.encoder().value = 70  # between ticks: the READ refreshes both
    mirrors, originals = block_and_originals(sched, hal)
    assert mirrors == originals and mirrors[0] == 70


def test_the_cycle_blocks_velocity_saturates_to_int16(node):
    sched, hal, app = node
    free_running(sched, hal)
    for step in range(12):  # 10 000 counts per ms: 10 M counts/s
        hal.encoder().value = 10_000 * step
        sched.run_for(1_000)
    assert app.get("present_velocity") > 32767
    assert app.get("cycle_velocity") == 32767
    hal.encoder().value = -10_000 * 30
    sched.run_for(1_000)
    assert app.get("cycle_velocity") == -32768


def test_deflection_offset_moves_what_the_protection_watches(node):
    """The host tells the node how far its deflection is off the elastic element's (the
    routes' coupling): the same encoder reading trips with offset 0 and not with the
    offset that explains it; beyond the offset it trips again."""
    sched, hal, _ = node
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "deflection_offset", 400)  # motor − joint expected +400
    hal.encoder().value = -400  # what the coupling did: deflection +400
    sched.run_for(2_000)
    assert not read(sched, hal, "status_flags") & (StepperFlag.SLIP | StepperFlag.STALLED)
    assert read(sched, hal, "deflection") == 400  # the register stays raw
    hal.encoder().value = -560  # 160 more than explained: a real stall
    sched.run_for(2_000)
    flags = read(sched, hal, "status_flags")
    assert flags & StepperFlag.STALLED and not flags & StepperFlag.SLIP
    write(sched, hal, "clear_flags", StepperClear.STALL)
    write(sched, hal, "deflection_offset", 0)
    write(sched, hal, "torque_enable", 1)  # the stall's alarm turned the coils off
    hal.encoder().value = -400
    sched.run_for(2_000)
    assert read(sched, hal, "status_flags") & StepperFlag.SLIP


def test_resync_rotor_takes_the_element_as_relaxed_with_torque_off_only(node):
    """An unpowered rotor turns with the joint: RESYNC_ROTOR moves the step origin so the
    deflection is the offset the host gave (step_count with it); with torque on it is
    ignored, so a stall stays one."""
    sched, hal, _ = node
    write(sched, hal, "slip_threshold", 65535)
    write(sched, hal, "deflection_limit", 65535)
    hal.encoder().value = -400  # the joint (and, unseen, the rotor) moved by hand
    sched.run_for(2_000)
    steps, deflection = read(sched, hal, "step_count"), read(sched, hal, "deflection")
    assert deflection == 400
    reference = steps / K - deflection  # the power-up reference a host derives
    write(sched, hal, "deflection_offset", 25)
    write(sched, hal, "clear_flags", StepperClear.RESYNC_ROTOR)
    assert read(sched, hal, "deflection") == 25
    assert read(sched, hal, "step_count") / K - 25 == pytest.approx(reference, abs=1.0)
    assert read(sched, hal, "goal_position") == 0  # the goal stays in the joint's frame
    write(sched, hal, "torque_enable", 1)
    hal.encoder().value = -600
    sched.run_for(2_000)
    before = read(sched, hal, "deflection")
    write(sched, hal, "clear_flags", StepperClear.RESYNC_ROTOR)  # torque on: ignored
    assert read(sched, hal, "deflection") == before


def test_command_goal_commands_single_microsteps(node):
    """command_goal is in 1/16 counts: a goal of 13/16 count is 1.04 microsteps on J1
    (1.2 microsteps per count), which the node steps; goal_position reads the nearest
    count, and writing goal_position sets command_goal to 16×."""
    sched, hal, _ = node
    free_running(sched, hal)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "command_goal", 13)
    sched.run_for(50_000)
    assert read(sched, hal, "goal_position") == 1
    assert hal.stepper().step_count() == 1  # one microstep: 0.83 counts
    write(sched, hal, "goal_position", -2)
    assert read(sched, hal, "command_goal") == -32
    sched.run_for(100_000)
    assert hal.stepper().step_count() == round(-2 * K)


def test_step_rate_never_exceeds_the_controllers_maximum(node):
    sched, hal, _ = node
    free_running(sched, hal)
    assert read(sched, hal, "velocity_limit") == STEPPER_VELOCITY_LIMIT_MAX
    write(sched, hal, "gear_reduction_x100", 1300)  # J4: 2.6 microsteps per count
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 100_000)
    rates = []
    for _ in range(2000):
        sched.run_for(1_000)
        rates.append(hal.stepper().rate)
    assert max(rates) == pytest.approx(STEPPER_MAX_STEP_RATE)
    assert write(sched, hal, "velocity_limit", STEPPER_VELOCITY_LIMIT_MAX + 1) != 0


def test_a_stall_mid_move_stops_and_holds_the_motor_until_cleared(node):
    """A STALLED latch stops the step generator at once and holds the motor where it stands
    (torque on); goals do not move it until the host clears STALL, and the clear itself
    starts no move."""
    sched, hal, app = node
    write(sched, hal, "slip_threshold", 65535)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 3000)
    sched.run_for(150_000)  # about 56 counts on, the encoder left behind (deflection < 150)
    stepper = hal.stepper()
    assert stepper.rate > 0
    hal.encoder().value = round(stepper.step_count() / K) - 200  # 200 > deflection_limit 150
    sched.run_for(2_000)
    assert read(sched, hal, "status_flags") & StepperFlag.STALLED
    held = stepper.step_count()
    assert stepper.rate == 0.0 and stepper.current == 2000
    assert read(sched, hal, "torque_enable") == 1
    assert read(sched, hal, "goal_position") == round(held / K)
    write(sched, hal, "goal_position", 3000)  # ignored while latched
    sched.run_for(200_000)
    assert stepper.step_count() == held
    hal.encoder().value = round(held / K)
    write(sched, hal, "clear_flags", StepperClear.STALL)
    sched.run_for(200_000)
    assert stepper.step_count() == held  # cleared: still held
    assert not read(sched, hal, "status_flags") & StepperFlag.STALLED
    write(sched, hal, "goal_position", 3000)
    sched.run_for(50_000)
    assert stepper.rate > 0  # the next goal moves it


def test_overload_in_alarm_shutdown_cuts_the_coils_as_before(node):
    sched, hal, _ = node
    write(sched, hal, "alarm_shutdown", int(ErrorBit.OVERLOAD | ErrorBit.OVERHEATING))
    write(sched, hal, "torque_enable", 1)
    hal.encoder().value = 200
    sched.run_for(2_000)
    assert read(sched, hal, "torque_enable") == 0
    assert hal.stepper().current == 0


def test_cleared_against_a_stop_it_backs_off_and_relatches_only_if_pushed_further(node):
    """A joint against its stop: STALLED holds the spring wound; a clear does not latch
    again at once, a goal back unwinds it, and winding further than a quarter of the limit
    past where it was latches again."""
    sched, hal, app = node
    write(sched, hal, "slip_threshold", 65535)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 400)  # the encoder stays at 0: the joint is blocked
    sched.run_for(600_000)
    stepper = hal.stepper()
    assert read(sched, hal, "status_flags") & StepperFlag.STALLED
    wound = round(stepper.step_count() / K)
    assert 150 < wound < 160 and stepper.rate == 0.0
    write(sched, hal, "clear_flags", StepperClear.STALL)
    sched.run_for(100_000)
    assert not read(sched, hal, "status_flags") & StepperFlag.STALLED
    write(sched, hal, "goal_position", 0)  # back off: unwinds the spring
    sched.run_for(600_000)
    assert round(stepper.step_count() / K) == 0
    assert not read(sched, hal, "status_flags") & StepperFlag.STALLED
    write(sched, hal, "goal_position", 400)  # into the stop again: latches at the limit
    sched.run_for(600_000)
    assert read(sched, hal, "status_flags") & StepperFlag.STALLED
    write(sched, hal, "clear_flags", StepperClear.STALL)
    write(sched, hal, "goal_position", 400)  # further in: latches past wound + 150 // 4
    sched.run_for(600_000)
    assert read(sched, hal, "status_flags") & StepperFlag.STALLED
    assert wound < round(stepper.step_count() / K) <= wound + 150 // 4 + 2
