"""The virtual HAL's plant side round-trips: what the plant drives, the firmware reads through
:mod:`firmware_py.hal`, and what the firmware commands, the plant reads back."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_py.errors import HalError
from firmware_py.hal import Hal
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_hal
from firmware_py.sim.virtual_sensors import VirtualSensors
from protocol.image import BoardType

counts16 = st.integers(-32768, 32767)
xyz = st.tuples(counts16, counts16, counts16)


def hal_of(board: BoardType) -> Hal:
    """The board's HAL as the firmware sees it (only the :class:`~firmware_py.hal.Hal` side)."""
    return make_hal(Scheduler(), board)


def plant_sensors(hal: Hal) -> VirtualSensors:
    assert isinstance(hal.sensors, VirtualSensors)
    return hal.sensors


Setter = Callable[[VirtualSensors, int, int, int], None]
_IMU_BOARDS = (BoardType.PALM, BoardType.FMCB, BoardType.F2, BoardType.F3)
VECTOR_CHANNELS: list[tuple[BoardType, str, Setter]] = [
    *((board, "accel", VirtualSensors.set_accel) for board in _IMU_BOARDS),
    *((board, "mag", VirtualSensors.set_mag) for board in _IMU_BOARDS),
    (BoardType.PALM, "gyro", VirtualSensors.set_gyro),
]


@pytest.mark.parametrize(("board", "channel", "setter"), VECTOR_CHANNELS)
@given(value=xyz)
def test_three_axis_inputs_reach_the_firmware(board: BoardType, channel: str, setter: Setter,
                                              value: tuple[int, int, int]) -> None:
    hal = hal_of(board)
    setter(plant_sensors(hal), *value)
    assert hal.sensors.read(channel) == value


@pytest.mark.parametrize(("board", "n"), [(BoardType.PALM, 32), (BoardType.F2, 6),
                                          (BoardType.F3, 12)])
@given(data=st.data())
def test_taxels_reach_the_firmware_in_order(board: BoardType, n: int, data: st.DataObject) -> None:
    counts = data.draw(st.lists(st.integers(0, 4095), min_size=n, max_size=n))
    hal = hal_of(board)
    plant_sensors(hal).set_taxels(counts)
    assert [hal.sensors.read(f"taxel{k}") for k in range(n)] == counts
    assert hal.sensors.read_burst(f"taxel{n - 1}", 4) == 4 * counts[-1]


@given(counts=st.integers(-(2 ** 23), 2 ** 23 - 1))
def test_strain_reaches_the_f2(counts: int) -> None:
    hal = hal_of(BoardType.F2)
    plant_sensors(hal).set_strain(counts)
    assert hal.sensors.read("strain") == counts


@pytest.mark.parametrize(("board", "n"), [(BoardType.PALM, 7), (BoardType.FMCB, 3)])
@given(data=st.data())
def test_numbered_temperatures_reach_the_firmware(board: BoardType, n: int,
                                                  data: st.DataObject) -> None:
    decic = data.draw(st.lists(st.integers(-400, 1500), min_size=n, max_size=n))
    hal = hal_of(board)
    plant_sensors(hal).set_temperatures(decic)
    assert [hal.sensors.read(f"temperature{k}") for k in range(n)] == decic


@pytest.mark.parametrize("board", [BoardType.F2, BoardType.F3])
@given(counts=st.lists(st.integers(0, 0xFFFF), min_size=4, max_size=4))
def test_thermistors_reach_the_phalanges(board: BoardType, counts: list[int]) -> None:
    hal = hal_of(board)
    plant_sensors(hal).set_thermistors(counts)
    assert [hal.sensors.read(f"thermistor{k}") for k in range(4)] == counts


@pytest.mark.parametrize("board", [BoardType.ARM_STEPPER, BoardType.RX64])
@given(decic=st.integers(-400, 1500), supply=st.integers(0, 30_000))
def test_arm_node_temperature_and_supply(board: BoardType, decic: int, supply: int) -> None:
    hal = hal_of(board)
    plant_sensors(hal).set_temperature(decic)
    plant_sensors(hal).set_supply_mv(supply)
    assert hal.sensors.read("temperature") == decic
    assert hal.sensors.read("supply_mv") == supply
    assert hal.sensors.read_burst("supply_mv", 3) == 3 * supply


@pytest.mark.parametrize("board", [BoardType.PALM, BoardType.FMCB])
@given(supply=st.integers(0, 30_000))
def test_hand_board_supply(board: BoardType, supply: int) -> None:
    hal = hal_of(board)
    plant_sensors(hal).set_supply_mv(supply)
    assert hal.sensors.read("supply_mv") == supply


@given(pot=st.integers(0, 1023), load=st.integers(-1023, 1023))
def test_servo_pot_and_load(pot: int, load: int) -> None:
    hal = hal_of(BoardType.RX64)
    plant_sensors(hal).set_pot(pot)
    plant_sensors(hal).set_load(load)
    assert (hal.sensors.read("pot"), hal.sensors.read("load")) == (pot, load)


def test_a_channel_the_board_lacks_is_refused_and_nothing_changes() -> None:
    hal = hal_of(BoardType.FMCB)
    sensors = plant_sensors(hal)
    before = dict(sensors.values)
    with pytest.raises(HalError):
        sensors.set_gyro(1, 2, 3)  # the fmcb has no gyro
    with pytest.raises(HalError):
        sensors.set_taxels([1, 2])  # nor taxels
    with pytest.raises(HalError):
        sensors.set_temperatures([250, 250])  # it has three windings, not two
    with pytest.raises(HalError):
        sensors.set_temperatures([250] * 4)
    with pytest.raises(HalError):
        sensors.set_temperature(250)  # numbered channels only
    with pytest.raises(HalError):
        sensors.set_input("pot", 1)
    assert sensors.values == before
    with pytest.raises(HalError):
        hal.sensors.read("gyro")


@given(hall=st.integers(0, 7), current=st.integers(-5000, 5000))
def test_motor_hall_state_and_current_reach_the_firmware(hall: int, current: int) -> None:
    hal = make_hal(Scheduler(), BoardType.FMCB)
    for index, motor in enumerate(hal.motors):
        motor.set_hall_state(hall)
        motor.set_current_ma(current + index)
    assert [hal.motor(i).hall_state() for i in range(3)] == [hall] * 3
    assert [hal.motor(i).current_ma() for i in range(3)] == [current, current + 1, current + 2]
    for index, motor in enumerate(hal.motors):  # both at once, as the finger plant writes
        motor.set_hall_and_current(7 - hall, -current - index)
    assert [hal.motor(i).hall_state() for i in range(3)] == [7 - hall] * 3
    assert [hal.motor(i).current_ma() for i in range(3)] == [-current, -current - 1,
                                                             -current - 2]


@given(duty=st.floats(-2.0, 2.0), enabled=st.booleans(), brake=st.booleans())
def test_motor_commands_reach_the_plant(duty: float, enabled: bool, brake: bool) -> None:
    hal = make_hal(Scheduler(), BoardType.RX64)
    firmware_side = hal.motor(0)
    firmware_side.set_duty(duty)
    firmware_side.set_enabled(enabled)
    firmware_side.set_brake(brake)
    plant_side = hal.motors[0]
    assert plant_side.commanded_duty() == max(-1.0, min(1.0, duty))
    assert plant_side.bridge_enabled() is enabled
    assert plant_side.braking() is brake
    assert plant_side.drive_command() == (brake, enabled, plant_side.commanded_duty())


@given(rate=st.floats(-50_000.0, 50_000.0), dt_us=st.integers(1, 2_000_000),
       current=st.integers(0, 2000))
def test_stepper_position_is_the_exact_count_the_firmware_truncates(
        rate: float, dt_us: int, current: int) -> None:
    scheduler = Scheduler()
    hal = make_hal(scheduler, BoardType.ARM_STEPPER)
    hal.stepper().set_step_rate(1000.0)
    hal.stepper().set_current(current)
    scheduler.run_for(500_000)  # 500 steps
    hal.stepper().set_step_rate(rate)
    scheduler.run_for(dt_us)
    plant_side = hal.stepper()
    expected = 500.0 + rate * dt_us / 1e6
    assert plant_side.position_steps() == pytest.approx(expected, abs=1e-6)
    assert hal.stepper().step_count() == int(plant_side.position_steps())
    assert plant_side.commanded_rate() == rate
    assert plant_side.commanded_current_ma() == current


@given(count=st.integers(-10 ** 6, 10 ** 6), index_count=st.integers(-10 ** 6, 10 ** 6))
def test_encoder_count_and_index_pulse_reach_the_firmware(count: int, index_count: int) -> None:
    hal = make_hal(Scheduler(), BoardType.ARM_STEPPER)
    latched: list[int] = []
    hal.encoder().set_index_callback(latched.append)
    plant_side = hal.encoder()
    plant_side.set_count(count)
    assert hal.encoder().count() == count
    plant_side.pulse_index()  # at the present count
    plant_side.pulse_index(index_count)  # at the mark's own count
    assert latched == [count, index_count]
    assert hal.encoder().count() == index_count


@given(load=st.integers(0, 3000), state=st.sampled_from([1, 2]))
def test_power_switch_load_and_state(load: int, state: int) -> None:
    hal = make_hal(Scheduler(), BoardType.FMCB)
    switch = hal.power("phalange")
    switch.set_load_ma(load)
    assert switch.current_ma() == 0  # off: no load current
    switch.set(state)  # the firmware switches it on
    assert switch.state == state  # what the plant (the rig) reads
    assert switch.current_ma() == load


def test_read_bursts_reads_each_channel_as_read_burst_does() -> None:
    """One call for a scan of channels: each total what read_burst gives, in order; a
    faulty channel still goes through its fault (and tells its watcher) at every read."""
    sensors = VirtualSensors({"taxel0": 7, "taxel1": -3, "taxel2": 40000, "accel": (1, 2, 3)})
    channels = ("taxel0", "taxel1", "taxel2")
    assert sensors.read_bursts(channels, 4) == [sensors.read_burst(c, 4) for c in channels]
    assert sensors.read_bursts(channels, 4) == [28, -12, 160000]
    with pytest.raises(HalError, match="no sensor channel 'taxel9'"):
        sensors.read_bursts(("taxel0", "taxel9"), 4)
    with pytest.raises(HalError, match="not a scalar"):
        sensors.read_bursts(("accel",), 4)
    heard: list[str] = []
    sensors.watch_channel("taxel1", lambda: heard.append("taxel1"))
    sensors.faults["taxel1"] = lambda value: 100
    assert sensors.read_bursts(channels, 4) == [28, 400, 160000]
    assert heard == ["taxel1"] * 4


def test_the_virtual_hal_module_still_offers_every_part() -> None:
    """``from firmware_py.sim.virtual_hal import VirtualUart`` (the import before the virtual
    HAL was split by peripheral) gives the class its own module declares."""
    from firmware_py.sim import virtual_drives, virtual_hal, virtual_ports, virtual_sensors

    for part in (virtual_ports, virtual_drives, virtual_sensors):
        public = [name for name, value in vars(part).items()
                  if not name.startswith("_") and getattr(value, "__module__", None) == part.__name__]
        assert public, part.__name__
        for name in public:
            assert name in virtual_hal.__all__, name
            assert getattr(virtual_hal, name) is getattr(part, name), name
