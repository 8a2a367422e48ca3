"""Tests of protocol.control_tables: the RX-64 table against the reference, checked reads and
writes, and the layout rules of the arm stepper node's table.

The expected RX-64 addresses, sizes and defaults are copied by hand from
the ROBOTIS RX-64 e-Manual (protocol 1.0 control table), not read from the code under test.
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.control_tables import (
    RAM_START,
    REST_DEFLECTION_UNKNOWN,
    RX64_TABLE,
    STEPPER_CYCLE_BLOCK,
    STEPPER_CYCLE_BLOCK_FIRMWARE,
    STEPPER_MODEL_NUMBER,
    STEPPER_REST_DEFLECTION_FIRMWARE,
    STEPPER_ROTOR_RESYNC_FIRMWARE,
    STEPPER_TABLE,
    STEPPER_WATCHDOG_FEED_FIRMWARE,
    STEPPER_WATCHDOG_FIRMWARE,
    TABLES_BY_MODEL,
    ControlTable,
    Register,
    RegisterAccessError,
    RegisterError,
    RegisterRangeError,
    StepperClear,
    StepperFlag,
    WatchdogFeed,
)
from protocol.dynamixel import ErrorBit
from protocol.errors import DynamixelError, ProtocolError

# (address, size, access, default) from the reference; None = default not stated there.
RX64_REFERENCE = {
    "model_number": (0, 2, "R", 64),
    "firmware_version": (2, 1, "R", None),
    "id": (3, 1, "RW", 1),
    "baud_rate": (4, 1, "RW", 34),
    "return_delay_time": (5, 1, "RW", 250),
    "cw_angle_limit": (6, 2, "RW", 0),
    "ccw_angle_limit": (8, 2, "RW", 1023),
    "temperature_limit": (11, 1, "RW", 80),
    "min_voltage_limit": (12, 1, "RW", 60),
    "max_voltage_limit": (13, 1, "RW", 190),
    "max_torque": (14, 2, "RW", 1023),
    "status_return_level": (16, 1, "RW", 2),
    "alarm_led": (17, 1, "RW", 36),
    "alarm_shutdown": (18, 1, "RW", 36),
    "torque_enable": (24, 1, "RW", 0),
    "led": (25, 1, "RW", 0),
    "cw_compliance_margin": (26, 1, "RW", 1),
    "ccw_compliance_margin": (27, 1, "RW", 1),
    "cw_compliance_slope": (28, 1, "RW", 32),
    "ccw_compliance_slope": (29, 1, "RW", 32),
    "goal_position": (30, 2, "RW", None),
    "moving_speed": (32, 2, "RW", None),
    "torque_limit": (34, 2, "RW", None),
    "present_position": (36, 2, "R", 0),
    "present_speed": (38, 2, "R", 0),
    "present_load": (40, 2, "R", 0),
    "present_voltage": (42, 1, "R", 0),
    "present_temperature": (43, 1, "R", 0),
    "registered": (44, 1, "R", 0),
    "moving": (46, 1, "R", 0),
    "lock": (47, 1, "RW", 0),
    "punch": (48, 2, "RW", 32),
}

# The EEPROM image 0..18 written out by hand (little-endian): model 64 = 40 00, firmware,
# ID 1, baud 34 = 22, delay 250 = FA, CW limit 0 = 00 00, CCW 1023 = FF 03, (10 reserved),
# temperature 80 = 50, voltages 60 = 3C / 190 = BE, max torque FF 03, level 2, alarms 36 = 24.
RX64_EEPROM_IMAGE = bytes.fromhex("40 00 00 01 22 FA 00 00 FF 03 00 50 3C BE FF 03 02 24 24")


def test_rx64_registers_match_the_reference() -> None:
    assert RX64_TABLE.model_number == 64 and RX64_TABLE.size == 50
    assert {r.name for r in RX64_TABLE} == set(RX64_REFERENCE)
    for name, (address, size, access, default) in RX64_REFERENCE.items():
        reg = RX64_TABLE[name]
        assert (reg.address, reg.size, reg.access) == (address, size, access), name
        if default is not None:
            assert reg.default == default, name
        assert reg.area == ("EEPROM" if address < RAM_START else "RAM"), name
        assert reg.unit, name


def test_rx64_default_image() -> None:
    image = RX64_TABLE.defaults()
    assert isinstance(image, bytearray) and len(image) == 50
    assert image[:19] == RX64_EEPROM_IMAGE
    assert image[24:30] == bytes([0, 0, 1, 1, 32, 32])
    assert image[48:50] == b"\x20\x00"
    assert RX64_TABLE.value(image, "punch") == 32
    assert RX64_TABLE.read(image, 0, 2) == b"\x40\x00"  # what dynamixel-sdk's ping reads
    assert RX64_TABLE.defaults() is not image


def test_lookups() -> None:
    assert RX64_TABLE.at(30) is RX64_TABLE["goal_position"]
    assert RX64_TABLE.at(31) is None and RX64_TABLE.covering(31) is RX64_TABLE["goal_position"]
    assert RX64_TABLE.covering(10) is None and RX64_TABLE.covering(50) is None
    assert "punch" in RX64_TABLE and "nonsense" not in RX64_TABLE
    with pytest.raises(KeyError):
        RX64_TABLE["nonsense"]
    assert TABLES_BY_MODEL == {64: RX64_TABLE, STEPPER_MODEL_NUMBER: STEPPER_TABLE}


def test_write_and_read_back() -> None:
    image = RX64_TABLE.defaults()
    touched = RX64_TABLE.write(image, 30, b"\x00\x02")  # goal position 512
    assert touched == [RX64_TABLE["goal_position"]]
    assert RX64_TABLE.value(image, "goal_position") == 512
    # one WRITE spanning goal position, moving speed and torque limit (6 bytes)
    touched = RX64_TABLE.write(image, 30, bytes.fromhex("FF 03 64 00 00 02"))
    assert [r.name for r in touched] == ["goal_position", "moving_speed", "torque_limit"]
    assert RX64_TABLE.read(image, 30, 6) == bytes.fromhex("FF 03 64 00 00 02")
    # part of a multi-byte register: the low byte only
    assert RX64_TABLE.write(image, 32, b"\x10") == [RX64_TABLE["moving_speed"]]
    assert RX64_TABLE.value(image, "moving_speed") == 0x10
    # reads may span gaps (reserved bytes read 0) and read-only registers
    assert RX64_TABLE.read(image, 8, 4) == b"\xff\x03\x00\x50"
    assert len(RX64_TABLE.read(image, 0, 50)) == 50


@pytest.mark.parametrize(
    ("address", "data", "error", "bit"),
    [
        (36, b"\x00\x00", RegisterAccessError, ErrorBit.INSTRUCTION),  # present position
        (0, b"\x40", RegisterAccessError, ErrorBit.INSTRUCTION),  # model number
        (34, b"\x00\x00\x00\x00", RegisterAccessError, ErrorBit.INSTRUCTION),  # into 36
        (30, b"\x00\x04", RegisterRangeError, ErrorBit.RANGE),  # goal position 1024
        (31, b"\x04", RegisterRangeError, ErrorBit.RANGE),  # high byte making 1024+
        (3, b"\xfe", RegisterRangeError, ErrorBit.RANGE),  # ID 254 (broadcast)
        (16, b"\x03", RegisterRangeError, ErrorBit.RANGE),  # status return level 3
        (24, b"\x02", RegisterRangeError, ErrorBit.RANGE),  # torque enable 2
        (10, b"\x00", RegisterRangeError, ErrorBit.RANGE),  # reserved address
        (9, b"\x03\x00", RegisterRangeError, ErrorBit.RANGE),  # runs into reserved 10
        (49, b"\x00\x00", RegisterRangeError, ErrorBit.RANGE),  # past the end
        (50, b"\x00", RegisterRangeError, ErrorBit.RANGE),
        (30, b"", RegisterRangeError, ErrorBit.RANGE),
    ],
)
def test_rejected_writes_leave_the_image_alone(
    address: int, data: bytes, error: type[RegisterError], bit: ErrorBit
) -> None:
    image = RX64_TABLE.defaults()
    with pytest.raises(error) as info:
        RX64_TABLE.write(image, address, data)
    assert info.value.error_bit == bit
    assert isinstance(info.value, DynamixelError) and isinstance(info.value, ProtocolError)
    assert image == RX64_TABLE.defaults()


@pytest.mark.parametrize(("address", "length"), [(49, 2), (50, 1), (-1, 1), (0, 0), (0, 51)])
def test_reads_outside_the_table(address: int, length: int) -> None:
    with pytest.raises(RegisterRangeError):
        RX64_TABLE.read(RX64_TABLE.defaults(), address, length)


def test_image_of_the_wrong_size_is_refused() -> None:
    with pytest.raises(DynamixelError, match="image"):
        RX64_TABLE.read(bytearray(10), 0, 2)


def test_set_value_is_the_nodes_own_access() -> None:
    image = RX64_TABLE.defaults()
    RX64_TABLE.set_value(image, "present_position", 700)  # read-only for the host
    assert image[36:38] == (700).to_bytes(2, "little")
    RX64_TABLE.set_value(image, "present_load", 1024 + 100)  # beyond no limit, fits 2 bytes
    with pytest.raises(RegisterRangeError):
        RX64_TABLE.set_value(image, "present_voltage", 256)
    with pytest.raises(RegisterRangeError):
        RX64_TABLE.set_value(image, "present_position", -1)


def test_signed_registers() -> None:
    image = STEPPER_TABLE.defaults()
    STEPPER_TABLE.write(image, 28, b"\xff\xff\xff\xff")
    assert STEPPER_TABLE.value(image, "goal_position") == -1
    STEPPER_TABLE.set_value(image, "deflection", -300)
    assert image[60:62] == (-300).to_bytes(2, "little", signed=True)
    assert STEPPER_TABLE.values(image)["deflection"] == -300
    with pytest.raises(RegisterRangeError):
        STEPPER_TABLE.set_value(image, "deflection", 40_000)


def test_table_construction_rules() -> None:
    model = Register(0, 2, "R", 7, "model_number", "EEPROM", "model number")
    with pytest.raises(DynamixelError, match="overlaps"):
        ControlTable("t", 7, [model, Register(1, 1, "RW", 0, "x", "EEPROM", "")])
    with pytest.raises(DynamixelError, match="twice"):
        ControlTable("t", 7, [model, Register(4, 1, "RW", 0, "model_number", "EEPROM", "")])
    with pytest.raises(DynamixelError, match="model_number"):
        ControlTable("t", 8, [model])
    with pytest.raises(DynamixelError, match="size"):
        Register(4, 3, "RW", 0, "x", "EEPROM", "")
    with pytest.raises(RegisterRangeError):
        Register(4, 1, "RW", 5, "x", "EEPROM", "", minimum=0, maximum=4)
    with pytest.raises(DynamixelError, match="access"):
        Register(4, 1, "W", 0, "x", "EEPROM", "")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- stepper table

STEPPER_REQUIRED = {
    # name: (size, access, signed)
    "model_number": (2, "R", False),
    "firmware_version": (1, "R", False),
    "id": (1, "RW", False),
    "baud_rate": (1, "RW", False),
    "return_delay_time": (1, "RW", False),
    "status_return_level": (1, "RW", False),
    "alarm_shutdown": (1, "RW", False),
    "torque_enable": (1, "RW", False),
    "led": (1, "RW", False),
    "goal_position": (4, "RW", True),
    "present_position": (4, "R", True),
    "step_count": (4, "R", True),
    "index_step_count": (4, "R", True),
    "index_encoder_count": (4, "R", True),
    "index_seen": (1, "R", False),
    "deflection": (2, "R", True),
    "velocity_limit": (4, "RW", False),
    "acceleration_limit": (4, "RW", False),
    "run_current": (2, "RW", False),
    "holding_current": (2, "RW", False),
    "microstepping": (1, "RW", False),
    "gear_reduction_x100": (2, "RW", False),
    "steps_per_rev": (2, "RW", False),
    "status_flags": (1, "R", False),
    "slip_threshold": (2, "RW", False),
    "clear_flags": (1, "RW", False),
    "present_velocity": (4, "R", True),
    "present_temperature": (1, "R", False),
    "present_voltage": (1, "R", False),
    "hardware_error_status": (1, "R", False),
}


def test_stepper_has_the_required_registers() -> None:
    for name, (size, access, signed) in STEPPER_REQUIRED.items():
        reg = STEPPER_TABLE[name]
        assert (reg.size, reg.access, reg.signed) == (size, access, signed), name
    assert STEPPER_TABLE["gear_reduction_x100"].area == "EEPROM"
    assert STEPPER_TABLE["steps_per_rev"].area == "EEPROM"
    assert STEPPER_TABLE["gear_reduction_x100"].default == 600


def test_stepper_registers_do_not_overlap_and_are_aligned() -> None:
    used: set[int] = set()
    for reg in STEPPER_TABLE:
        span = set(range(reg.address, reg.address + reg.size))
        assert not span & used, reg.name
        used |= span
        assert reg.address % reg.size == 0, reg.name
        assert reg.area == ("EEPROM" if reg.address < RAM_START else "RAM"), reg.name
        assert reg.unit, reg.name


def test_stepper_mirrors_the_dynamixel_layout() -> None:
    # addresses 0..18 and the first RAM bytes mean what they mean on the RX-64
    for name in ["model_number", "firmware_version", "id", "baud_rate", "return_delay_time",
                 "temperature_limit", "min_voltage_limit", "max_voltage_limit",
                 "status_return_level", "alarm_led", "alarm_shutdown", "torque_enable", "led"]:
        ours, theirs = STEPPER_TABLE[name], RX64_TABLE[name]
        assert (ours.address, ours.size, ours.access) == (theirs.address, theirs.size,
                                                          theirs.access), name
    image = STEPPER_TABLE.defaults()
    assert STEPPER_MODEL_NUMBER == 0x5E50
    assert STEPPER_TABLE.read(image, 0, 2) == b"\x50\x5e"  # ping's READ(0, 2), little-endian
    assert image[3] == 1


def test_stepper_flag_bits() -> None:
    assert [int(f) for f in StepperFlag] == [0x01, 0x02, 0x04, 0x08, 0x10, 0x20]
    assert StepperFlag.WATCHDOG == 0x20
    assert StepperFlag.MOVING == 1 and StepperFlag.SLIP == 2
    assert StepperFlag.INDEX_SEEN == 4 and StepperFlag.STALLED == 8
    image = STEPPER_TABLE.defaults()
    assert STEPPER_TABLE.write(image, 27, bytes([StepperClear.ZERO_STEP_COUNT]))
    with pytest.raises(RegisterAccessError):
        STEPPER_TABLE.write(image, 40, b"\x00\x00\x00\x00")  # step count is read-only
    assert STEPPER_TABLE.write(image, 27, bytes([StepperClear.RESYNC_ROTOR]))
    with pytest.raises(RegisterRangeError):
        STEPPER_TABLE.write(image, 27, b"\x20")


# --------------------------------------------------------------------------- properties


@given(st.sampled_from([RX64_TABLE, STEPPER_TABLE]), st.integers(-2, 80), st.binary(max_size=8))
def test_writes_are_all_or_nothing(table: ControlTable, address: int, data: bytes) -> None:
    image = table.defaults()
    before = bytes(image)
    try:
        touched = table.write(image, address, data)
    except RegisterError:
        assert bytes(image) == before
        return
    assert table.read(image, address, len(data)) == data
    assert all(r.writable for r in touched)
    assert image[:address] == before[:address]
    assert image[address + len(data) :] == before[address + len(data) :]


@given(st.data())
def test_every_writable_register_round_trips_its_limits(data: st.DataObject) -> None:
    table = data.draw(st.sampled_from([RX64_TABLE, STEPPER_TABLE]))
    reg = data.draw(st.sampled_from([r for r in table if r.writable]))
    low, high = reg.encodable
    low = low if reg.minimum is None else reg.minimum
    high = high if reg.maximum is None else reg.maximum
    value = data.draw(st.integers(low, high))
    image = table.defaults()
    encoded = value.to_bytes(reg.size, "little", signed=reg.signed)
    assert table.write(image, reg.address, encoded) == [reg]
    assert table.value(image, reg.name) == value


def test_stepper_cycle_block_addresses() -> None:
    # written by hand: the host reads 76..88 in one BULK_READ range
    block = [(r.name, r.address, r.size, r.access, r.signed) for r in STEPPER_TABLE
             if r.address >= 75]
    assert block == [
        ("cycle_present_position", 76, 4, "R", True),
        ("cycle_step_count", 80, 4, "R", True),
        ("cycle_velocity", 84, 2, "R", True),
        ("cycle_deflection", 86, 2, "R", True),
        ("cycle_status_flags", 88, 1, "R", False),
        ("command_goal", 92, 4, "RW", True),
        ("deflection_offset", 96, 2, "RW", True),
        ("watchdog_timeout", 98, 2, "RW", False),
        ("rest_deflection", 100, 2, "RW", True),
        ("watchdog_feed", 102, 1, "RW", False),
        ("keep_alive", 103, 1, "RW", False),
    ]
    assert STEPPER_TABLE.size == 104
    assert STEPPER_CYCLE_BLOCK == ("cycle_present_position", "cycle_status_flags")
    assert STEPPER_CYCLE_BLOCK_FIRMWARE == 2
    assert STEPPER_ROTOR_RESYNC_FIRMWARE == 3
    assert STEPPER_WATCHDOG_FIRMWARE == 4
    assert STEPPER_REST_DEFLECTION_FIRMWARE == 5
    assert STEPPER_TABLE["firmware_version"].default == STEPPER_WATCHDOG_FEED_FIRMWARE == 6
    assert STEPPER_TABLE["watchdog_feed"].default == WatchdogFeed.ANY_INSTRUCTION == 0
    assert STEPPER_TABLE["rest_deflection"].default == REST_DEFLECTION_UNKNOWN == -32768
