"""Control tables as data: the RX-64's and this project's arm stepper node's.

A control table is the byte image a Dynamixel-style node exposes to READ and WRITE: EEPROM
registers (kept across power cycles) from address 0, RAM registers from 24.  Multi-byte
registers are little-endian.  :class:`ControlTable` checks and applies host reads and writes
against an image (a ``bytearray`` the firmware model owns); a rejected write raises
:class:`RegisterRangeError` or :class:`RegisterAccessError` and leaves the image untouched,
and the firmware turns :attr:`~RegisterError.error_bit` into the status packet's error byte.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import ClassVar, Final, Literal

from protocol.dynamixel import ErrorBit
from protocol.errors import DynamixelError
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_STEPPER_JOINTS,
    RX64_POSITION_MAX,
    STEPPER_DEFAULT_ACCEL_COUNTS_S2,
    STEPPER_DEFAULT_CURRENT_MA,
    STEPPER_FULL_STEPS_PER_REV,
    STEPPER_MICROSTEPPING,
    STEPPER_REDUCTIONS,
    max_velocity_counts_per_s,
    reduction_x100,
)

Access = Literal["R", "RW"]
Area = Literal["EEPROM", "RAM"]

#: First RAM address in every table here (as on every protocol 1.0 Dynamixel).
RAM_START = 24


class RegisterError(DynamixelError):
    """A control-table read or write is not allowed; ``error_bit`` is the status error bit a
    servo reports for it."""

    # ClassVar: compiled (mypyc), an annotated class attribute would be an instance
    # attribute, which an exception raised without it does not have.
    error_bit: ClassVar[ErrorBit] = ErrorBit.RANGE


class RegisterRangeError(RegisterError):
    """Address range outside the table, a write into a gap, or a value outside its register's
    limits (status error bit RANGE)."""

    error_bit = ErrorBit.RANGE


class RegisterAccessError(RegisterError):
    """A write touches a read-only register (status error bit INSTRUCTION)."""

    error_bit = ErrorBit.INSTRUCTION


@dataclass(frozen=True)
class Register:
    """One register: ``size`` bytes (1, 2 or 4, little-endian) at ``address``.

    ``unit`` describes the value and its unit; ``minimum``/``maximum`` (inclusive) bound what a
    host may write (None: anything the encoding holds).  ``signed`` registers are two's
    complement.
    """

    address: int
    size: int
    access: Access
    default: int
    name: str
    area: Area
    unit: str
    signed: bool = False
    minimum: int | None = None
    maximum: int | None = None

    def __post_init__(self) -> None:
        if self.size not in (1, 2, 4):
            raise DynamixelError(f"register {self.name}: size {self.size} is not 1, 2 or 4")
        if not 0 <= self.address <= 0xFF - self.size + 1:
            raise DynamixelError(f"register {self.name}: address {self.address} out of 0..255")
        if self.access not in ("R", "RW") or self.area not in ("EEPROM", "RAM"):
            raise DynamixelError(f"register {self.name}: bad access {self.access!r}/{self.area!r}")
        self.check(self.default)

    @property
    def end(self) -> int:
        """One past the register's last address."""
        return self.address + self.size

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    @property
    def encodable(self) -> tuple[int, int]:
        """Smallest and largest value the register's bytes can hold."""
        bits = 8 * self.size
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)

    def check(self, value: int, limits: bool = True) -> None:
        """Raise :class:`RegisterRangeError` unless ``value`` fits (and, with ``limits``, is
        within ``minimum``..``maximum``)."""
        low, high = self.encodable
        if limits:
            low = low if self.minimum is None else max(low, self.minimum)
            high = high if self.maximum is None else min(high, self.maximum)
        if not low <= value <= high:
            raise RegisterRangeError(f"{self.name} = {value} is outside {low}..{high}")

    def encode(self, value: int) -> bytes:
        """The register's little-endian bytes for ``value`` (encoding range checked only)."""
        self.check(value, limits=False)
        return int(value).to_bytes(self.size, "little", signed=self.signed)

    def decode(self, data: bytes | bytearray) -> int:
        """The value of the register's ``size`` little-endian bytes."""
        return int.from_bytes(data, "little", signed=self.signed)


class ControlTable:
    """A model's registers, with lookups and checked access to an image of the table.

    Registers may leave gaps (reserved addresses: read as 0, not writable) but never overlap.
    """

    def __init__(self, name: str, model_number: int, registers: Iterable[Register]) -> None:
        self.name = name
        self.model_number = model_number
        self.registers: tuple[Register, ...] = tuple(sorted(registers, key=lambda r: r.address))
        if not self.registers:
            raise DynamixelError(f"control table {name}: no registers")
        #: Table size in bytes (one past the last register).
        self.size: int = max(r.end for r in self.registers)
        self._by_name: dict[str, Register] = {}
        #: name -> (struct codec, address): the firmware's hot path reads registers by name.
        self._codec: dict[str, tuple[struct.Struct, int]] = {}
        self._owner: list[Register | None] = [None] * self.size
        for reg in self.registers:
            if reg.name in self._by_name:
                raise DynamixelError(f"control table {name}: register name {reg.name} twice")
            self._by_name[reg.name] = reg
            code = {1: "b", 2: "h", 4: "i"}[reg.size]
            self._codec[reg.name] = (struct.Struct("<" + (code if reg.signed else code.upper())),
                                     reg.address)
            for address in range(reg.address, reg.end):
                other = self._owner[address]
                if other is not None:
                    raise DynamixelError(
                        f"control table {name}: {reg.name} overlaps {other.name} at {address}"
                    )
                self._owner[address] = reg
        model = self._by_name.get("model_number")
        if model is None or model.address != 0 or model.default != model_number:
            raise DynamixelError(f"control table {name}: needs model_number {model_number} at 0")

    def __repr__(self) -> str:
        return f"ControlTable({self.name!r}, model {self.model_number}, {self.size} bytes)"

    def __iter__(self) -> Iterator[Register]:
        return iter(self.registers)

    def __len__(self) -> int:
        return len(self.registers)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __getitem__(self, name: str) -> Register:
        """The register called ``name`` (KeyError if none)."""
        return self._by_name[name]

    def at(self, address: int) -> Register | None:
        """The register starting at ``address``, or None."""
        reg = self.covering(address)
        return reg if reg is not None and reg.address == address else None

    def covering(self, address: int) -> Register | None:
        """The register holding the byte at ``address``, or None (gap or outside the table)."""
        return self._owner[address] if 0 <= address < self.size else None

    def defaults(self) -> bytearray:
        """A fresh image of the whole table holding every register's default (gaps are 0)."""
        image = bytearray(self.size)
        for reg in self.registers:
            image[reg.address : reg.end] = reg.encode(reg.default)
        return image

    def _check_span(self, image: bytearray | bytes, address: int, length: int) -> None:
        if len(image) != self.size:
            raise DynamixelError(f"{self.name}: image is {len(image)} bytes, table {self.size}")
        if length < 1 or address < 0 or address + length > self.size:
            raise RegisterRangeError(
                f"{self.name}: {length} bytes at {address} outside the table (0..{self.size - 1})"
            )

    def read(self, image: bytearray | bytes, address: int, length: int) -> bytes:
        """``length`` bytes of ``image`` from ``address`` (gaps included); a range not inside
        the table raises :class:`RegisterRangeError`."""
        self._check_span(image, address, length)
        return bytes(image[address : address + length])

    def write(self, image: bytearray, address: int, data: bytes) -> list[Register]:
        """Write ``data`` at ``address`` as a host WRITE would; return the registers touched.

        All or nothing: raises :class:`RegisterRangeError` (range outside the table, a byte in a
        gap, or a resulting register value outside its limits) or
        :class:`RegisterAccessError` (a read-only register touched) before changing ``image``.
        Writing part of a multi-byte register is allowed; its resulting value is checked.
        """
        self._check_span(image, address, len(data))
        touched: list[Register] = []
        for offset in range(address, address + len(data)):
            reg = self._owner[offset]
            if reg is None:
                raise RegisterRangeError(f"{self.name}: address {offset} is not a register")
            if not touched or touched[-1] is not reg:
                touched.append(reg)
        for reg in touched:
            if not reg.writable:
                raise RegisterAccessError(f"{self.name}: {reg.name} ({reg.address}) is read-only")
        after = bytearray(image)
        after[address : address + len(data)] = data
        for reg in touched:
            reg.check(reg.decode(after[reg.address : reg.end]))
        image[address : address + len(data)] = data
        return touched

    def value(self, image: bytearray | bytes, name: str) -> int:
        """The value of register ``name`` in ``image``."""
        codec, address = self._codec[name]
        return int(codec.unpack_from(image, address)[0])

    def set_value(self, image: bytearray, name: str, value: int) -> None:
        """Store ``value`` in register ``name`` of ``image`` - the node's own access: read-only
        registers and limits are not enforced, only that the value fits the register."""
        codec, address = self._codec[name]
        try:
            codec.pack_into(image, address, value)
        except struct.error:
            self._by_name[name].check(value, limits=False)  # raises RegisterRangeError
            raise

    def values(self, image: bytearray | bytes) -> dict[str, int]:
        """Every register's value, by name (for logs and tests)."""
        return {reg.name: reg.decode(image[reg.address : reg.end]) for reg in self.registers}


def _eeprom(address: int, size: int, access: Access, default: int, name: str, unit: str,
            minimum: int | None = None, maximum: int | None = None,
            signed: bool = False) -> Register:
    return Register(address, size, access, default, name, "EEPROM", unit, signed, minimum, maximum)


def _ram(address: int, size: int, access: Access, default: int, name: str, unit: str,
         minimum: int | None = None, maximum: int | None = None, signed: bool = False) -> Register:
    return Register(address, size, access, default, name, "RAM", unit, signed, minimum, maximum)


_ALARM = "error bits (ErrorBit: 0x01 voltage .. 0x40 instruction)"

#: ROBOTIS RX-64 (model 64), protocol 1.0, from the e-Manual.  Limits are given only where
#: the reference states them (IDs, baud, flags, 10-bit values).  ``goal_position`` and
#: ``torque_limit`` defaults are placeholders: a real servo copies present position and max
#: torque into them at power-up.  The firmware version is not documented; 0 here.
RX64_TABLE = ControlTable("RX-64", 64, [
    _eeprom(0, 2, "R", 64, "model_number", "model number"),
    _eeprom(2, 1, "R", 0, "firmware_version", "firmware version"),
    _eeprom(3, 1, "RW", 1, "id", "bus ID (0..253)", 0, 253),
    _eeprom(4, 1, "RW", 34, "baud_rate", "bps = 2 000 000 / (value + 1)", 0, 254),
    _eeprom(5, 1, "RW", 250, "return_delay_time", "2 us units", 0, 254),
    _eeprom(6, 2, "RW", 0, "cw_angle_limit", "position units (0.29 deg)", 0, RX64_POSITION_MAX),
    _eeprom(8, 2, "RW", RX64_POSITION_MAX, "ccw_angle_limit", "position units (0.29 deg)", 0,
            RX64_POSITION_MAX),
    _eeprom(11, 1, "RW", 80, "temperature_limit", "deg C"),
    _eeprom(12, 1, "RW", 60, "min_voltage_limit", "0.1 V"),
    _eeprom(13, 1, "RW", 190, "max_voltage_limit", "0.1 V"),
    _eeprom(14, 2, "RW", 1023, "max_torque", "1/1023 of maximum torque", 0, 1023),
    _eeprom(16, 1, "RW", 2, "status_return_level", "0 ping only, 1 reads, 2 all", 0, 2),
    _eeprom(17, 1, "RW", 36, "alarm_led", _ALARM, 0, 127),
    _eeprom(18, 1, "RW", 36, "alarm_shutdown", _ALARM + "; torque off on these", 0, 127),
    _ram(24, 1, "RW", 0, "torque_enable", "0 off, 1 on", 0, 1),
    _ram(25, 1, "RW", 0, "led", "0 off, 1 on", 0, 1),
    _ram(26, 1, "RW", 1, "cw_compliance_margin", "position units"),
    _ram(27, 1, "RW", 1, "ccw_compliance_margin", "position units"),
    _ram(28, 1, "RW", 32, "cw_compliance_slope", "position units"),
    _ram(29, 1, "RW", 32, "ccw_compliance_slope", "position units"),
    _ram(30, 2, "RW", 0, "goal_position", "0..1023 over 300 deg (0.29 deg/unit)", 0,
         RX64_POSITION_MAX),
    _ram(32, 2, "RW", 0, "moving_speed", "0.111 rpm/unit, 0 = maximum", 0, 1023),
    _ram(34, 2, "RW", 1023, "torque_limit", "1/1023 of maximum torque", 0, 1023),
    _ram(36, 2, "R", 0, "present_position", "0..1023 over 300 deg"),
    _ram(38, 2, "R", 0, "present_speed", "0.111 rpm/unit, bit 10 = CW"),
    _ram(40, 2, "R", 0, "present_load", "1/1023 of max torque, bit 10 = CW"),
    _ram(42, 1, "R", 0, "present_voltage", "0.1 V"),
    _ram(43, 1, "R", 0, "present_temperature", "deg C"),
    _ram(44, 1, "R", 0, "registered", "1 = a REG_WRITE awaits ACTION"),
    _ram(46, 1, "R", 0, "moving", "1 = moving"),
    _ram(47, 1, "RW", 0, "lock", "1 = EEPROM locked until power cycle", 0, 1),
    _ram(48, 2, "RW", 32, "punch", "minimum current, 1/1023 of maximum", 0, 1023),
])


class StepperFlag(IntFlag):
    """Bits of the stepper node's ``status_flags`` register (address 26)."""

    MOVING = 0x01  # a move towards goal_position is in progress
    SLIP = 0x02  # |deflection| exceeded slip_threshold: steps were lost (latched; not while the host has the coils off)
    INDEX_SEEN = 0x04  # the joint encoder's index pulse has been latched
    STALLED = 0x08  # |deflection| exceeded deflection_limit: over-deflection/stall (latched; not while the host has the coils off)
    HARDWARE_ERROR = 0x10  # hardware_error_status is not 0
    WATCHDOG = 0x20  # the command watchdog stopped a move: no instruction within watchdog_timeout (until the next goal; not an alarm)


class WatchdogFeed(IntEnum):
    """Values of the stepper node's ``watchdog_feed`` register (address 102): what keeps its
    command watchdog from stopping a move."""

    ANY_INSTRUCTION = 0  # any instruction addressed to the node (power-up: a plain-SDK host)
    GOALS_ONLY = 1  # goal writes and keep_alive writes only (a host streaming goals)


class StepperClear(IntFlag):
    """Command bits for the stepper node's ``clear_flags`` register (address 27); the node acts
    on a write and the register reads back 0."""

    SLIP = 0x01  # clear StepperFlag.SLIP
    STALL = 0x02  # clear StepperFlag.STALLED
    ZERO_STEP_COUNT = 0x04  # set step_count to 0
    REARM_INDEX = 0x08  # forget the index latch: index_seen, index_* registers to 0
    RESYNC_ROTOR = 0x10  # torque off only: the unpowered rotor turned with the joint; take
    #                      the elastic element as relaxed and move the step origin so that
    #                      deflection = deflection_offset (step_count moves with it)


#: Model number of the arm stepper node: 0x5E50, "SE" (series-elastic) + 0x50 - chosen to
#: stay clear of ROBOTIS model numbers (12, 18, 24, 28, 29, 64, 310, 320, 1020, ...).
STEPPER_MODEL_NUMBER = 0x5E50
#: The first stepper node firmware version with the cycle block (addresses 76-88).
STEPPER_CYCLE_BLOCK_FIRMWARE = 2
#: The first stepper node firmware version that honours ``clear_flags`` RESYNC_ROTOR.
STEPPER_ROTOR_RESYNC_FIRMWARE = 3
#: The first stepper node firmware version with the command watchdog (``watchdog_timeout``,
#: StepperFlag.WATCHDOG).
STEPPER_WATCHDOG_FIRMWARE = 4
#: The first stepper node firmware version that takes the host's ``rest_deflection``.
STEPPER_REST_DEFLECTION_FIRMWARE = 5
#: The first stepper node firmware version with ``watchdog_feed`` and ``keep_alive`` (a host
#: chooses what keeps the command watchdog fed), and whose stepping holds, instead of
#: latching STALLED, where goals older than ``watchdog_timeout`` would wind its element past
#: ``deflection_limit``.
STEPPER_WATCHDOG_FEED_FIRMWARE = 6
#: The stepper node's firmware version.
STEPPER_FIRMWARE_VERSION = STEPPER_WATCHDOG_FEED_FIRMWARE
#: ``rest_deflection`` meaning "not given" (its power-up value): the node identifies the
#: deflection that holds its link at rest from the swing itself.
REST_DEFLECTION_UNKNOWN: Final = -32768
#: The stepper node's factory ``alarm_shutdown``: OVERHEATING only.  A STALLED latch (the
#: OVERLOAD bit) stops the node's stepping and holds its motor, torque on, instead of cutting
#: the coils: a gravity-loaded joint that lost its torque falls, and its swing overloads the
#: joints it hangs from, which then latch and fall too (one latch dropped the whole arm).
#: A host that wants the coils cut on OVERLOAD writes 0x24 (as the RX-64's default).
STEPPER_ALARM_SHUTDOWN_DEFAULT: Final = int(ErrorBit.OVERHEATING)
#: ``watchdog_timeout`` at power-up (ms): on, so a node stops a move by itself whatever host
#: started it; long enough for a stock dynamixel-sdk program that polls while it waits
#: (docs/decisions/watchdog-default.md).
STEPPER_WATCHDOG_DEFAULT_MS: Final = 500
_COUNTS = "joint encoder counts (0.036 deg)"
#: ``command_goal`` units per joint encoder count: a goal finer than a count, so a host can
#: command single microsteps (J1: 1.2 microsteps per count at 1/10 stepping).
GOAL_FINE_PER_COUNT: Final = 16
#: Largest ``velocity_limit`` (joint encoder counts/s): the controllers' maximum step rate
#: (:data:`protocol.robot.STEPPER_MAX_STEP_RATE`) on the joint with the smallest reduction
#: (J1); every node also caps its own step rate there, so J2 runs at most 2300 counts/s.
STEPPER_VELOCITY_LIMIT_MAX: Final = int(max(max_velocity_counts_per_s(j)
                                            for j in range(ARM_STEPPER_JOINTS)))

#: The arm stepper node: a series-elastic joint driven by a stepper motor through a
#: reduction, with an absolute-after-index joint encoder.  Addresses 0..18 mean what they
#: mean on a Dynamixel where a stepper has the same notion (model, ID, baud, return delay,
#: limits, status return level, alarms), so dynamixel-sdk's ping (a READ of 2 bytes at 0) and
#: bus scans work unchanged; 20-23 say which joint encoder and which arm (``arm_serial``:
#: the arm's serial number, programmed into each of its stepper nodes at assembly, what its
#: host names its calibration file by); RAM starts at 24; 4-byte registers are 4-aligned.
#: Addresses 76-88 are the *cycle block*: read-only mirrors, refreshed whenever the registers
#: they mirror are, of what a host's read-and-command cycle needs - ``present_position``,
#: ``step_count``, ``present_velocity`` (saturated to int16: ±32767 counts/s = ±20.6 rad/s),
#: ``deflection`` and ``status_flags`` - in one contiguous 13-byte range, so a BULK_READ
#: (one range per node) gets them without the 34 bytes of other registers between the
#: originals.  Addresses 92-97 are the *command block* a host writes every cycle in one
#: SYNC_WRITE: ``command_goal`` (the goal in 1/16 counts; writing it sets ``goal_position``
#: to the nearest count, and writing ``goal_position`` sets it to 16×) and
#: ``deflection_offset``, what the host knows the node's deflection is off the elastic
#: element's by (the routes' coupling, −C·Δq in counts): SLIP and STALLED compare
#: |deflection − deflection_offset| with their thresholds; ``deflection`` itself stays raw.  The goal is not in it: the host knows what it wrote.  Nodes report
#: firmware_version >= :data:`STEPPER_CYCLE_BLOCK_FIRMWARE` when they have it.
#: A STALLED latch (|deflection − deflection_offset| > ``deflection_limit``) stops the step
#: generator at once and holds the motor where it stands (the goal registers say where),
#: torque on at ``holding_current``; the node does not step again until the host clears STALL
#: (``clear_flags``), which leaves it holding there until the next goal.  Its neighbours are
#: not affected.
#: Address 98 is the *command watchdog*: ``watchdog_timeout`` (ms, 0 = off).  When no
#: instruction addressed to the node (PING, READ, WRITE, REG_WRITE, ACTION, a SYNC_WRITE
#: with an entry for it, a BULK_READ naming it; broadcasts included) has arrived within it
#: while the node is stepping, the node stops: it brakes at ``acceleration_limit`` and holds
#: its motor where it stopped (the goal registers say where), torque on, nothing latched, and
#: sets StepperFlag.WATCHDOG until the next goal (``goal_position`` or ``command_goal``) moves
#: it again.  Then, for 3 s, it settles the joint: at up to three turns of the link's swing it
#: moves the motor (by at most ``protocol.robot.STEPPER_SETTLE_MAX_CHANGE_COUNTS`` from the
#: hold) so that the elastic element holds the link still where it turns.  Nodes report firmware_version >= :data:`STEPPER_WATCHDOG_FIRMWARE` when they
#: have it.
#: Address 100, ``rest_deflection`` (counts, the node's frame as ``deflection`` reads): the
#: deflection that holds the link at rest where a watchdog stop would leave it, as the host's
#: model of the arm (gravity, the routes' coupling) says; a host that knows it writes it
#: with every goal.  The settling then uses it instead of identifying it from the swing, once
#: the swing has shown it plausible (within the deflections seen since the stop); −32768
#: (power-up) = not given.  Nodes report firmware_version >=
#: :data:`STEPPER_REST_DEFLECTION_FIRMWARE` when they have it.
#: Address 102, ``watchdog_feed`` (:class:`WatchdogFeed`), says what feeds the command
#: watchdog: 0 (power-up) any instruction addressed to the node, as above - a program that
#: writes a goal once and polls keeps its move going; 1 only writes of a goal
#: (``goal_position``, ``command_goal``, in a WRITE, a SYNC_WRITE entry or an ACTION) or of
#: address 103, ``keep_alive`` (any value; reads 0) - a host that streams goals, each right
#: only until the next (the routes' coupling offsets), so another program's READs cannot
#: keep a dead host's goals driving the arm.  Whatever feeds it, a node stepping on goals
#: older than ``watchdog_timeout`` (no goal written since) stops as the watchdog does, torque
#: on, WATCHDOG set, instead of latching STALLED when its element (|deflection −
#: ``deflection_offset``|) is winding so that braking would end within an eighth of
#: ``deflection_limit`` of it.  Nodes report firmware_version >=
#: :data:`STEPPER_WATCHDOG_FEED_FIRMWARE` when they have both.
#: Motor angle after the reduction, in encoder counts, is ``step_count * 10000 /
#: (steps_per_rev * microstepping * gear_reduction_x100 / 100)``; ``deflection`` is that minus
#: ``present_position`` (zeroed at the index latch).  Velocity and acceleration limits are in
#: joint encoder counts (joint side) so they do not change with microstepping or gearing.
#: ``arm_serial`` of a node never programmed with its arm's serial number.
ARM_SERIAL_UNSET: Final = 0

STEPPER_TABLE = ControlTable("arm stepper node", STEPPER_MODEL_NUMBER, [
    _eeprom(0, 2, "R", STEPPER_MODEL_NUMBER, "model_number", "model number (0x5E50)"),
    _eeprom(2, 1, "R", STEPPER_FIRMWARE_VERSION, "firmware_version", "firmware version"),
    _eeprom(3, 1, "RW", 1, "id", "bus ID (0..253)", 0, 253),
    _eeprom(4, 1, "RW", 1, "baud_rate", "bps = 2 000 000 / (value + 1); 1 = 1 Mbps", 0, 254),
    _eeprom(5, 1, "RW", 250, "return_delay_time", "2 us units", 0, 254),
    _eeprom(6, 2, "RW", reduction_x100(STEPPER_REDUCTIONS[0]), "gear_reduction_x100",
            "motor revs per joint rev x 100", 100),
    _eeprom(8, 2, "RW", STEPPER_FULL_STEPS_PER_REV, "steps_per_rev",
            "full steps per motor rev (200 = 1.8 deg)", 1),
    _eeprom(10, 1, "RW", STEPPER_MICROSTEPPING, "microstepping",
            "microsteps per full step (1..128)", 1, 128),
    _eeprom(11, 1, "RW", 80, "temperature_limit", "deg C (driver)", 0, 150),
    _eeprom(12, 1, "RW", 100, "min_voltage_limit", "0.1 V", 50, 250),
    _eeprom(13, 1, "RW", 250, "max_voltage_limit", "0.1 V", 50, 250),
    _eeprom(14, 2, "RW", 2000, "max_current", "mA, cap on run/holding current", 0, 3000),
    _eeprom(16, 1, "RW", 2, "status_return_level", "0 ping only, 1 reads, 2 all", 0, 2),
    _eeprom(17, 1, "RW", 36, "alarm_led", _ALARM, 0, 127),
    _eeprom(18, 1, "RW", STEPPER_ALARM_SHUTDOWN_DEFAULT, "alarm_shutdown",
            _ALARM + "; torque off on these (OVERLOAD: STALLED holds instead, see above)",
            0, 127),
    _eeprom(20, 2, "R", ARM_ENCODER_COUNTS_PER_REV, "encoder_resolution",
            "joint encoder counts per joint rev"),
    _eeprom(22, 2, "R", ARM_SERIAL_UNSET, "arm_serial",
            "the arm's serial number, the same in each of its stepper nodes (programmed "
            "at assembly; 0 = none)"),
    _ram(24, 1, "RW", 0, "torque_enable", "0 coils off, 1 on", 0, 1),
    _ram(25, 1, "RW", 0, "led", "0 off, 1 on", 0, 1),
    _ram(26, 1, "R", 0, "status_flags", "StepperFlag bits"),
    _ram(27, 1, "RW", 0, "clear_flags",
         "StepperClear command bits (" + ", ".join(f"{bit.name} {int(bit)}" for bit in StepperClear)
         + "), reads 0", 0,
         sum(int(bit) for bit in StepperClear)),
    _ram(28, 4, "RW", 0, "goal_position", _COUNTS, signed=True),
    _ram(32, 4, "R", 0, "present_position", _COUNTS, signed=True),
    _ram(36, 4, "R", 0, "present_velocity", "joint encoder counts/s", signed=True),
    _ram(40, 4, "R", 0, "step_count", "microsteps integrated since power-up", signed=True),
    _ram(44, 4, "R", 0, "index_step_count", "step_count latched at the index pulse",
         signed=True),
    _ram(48, 4, "R", 0, "index_encoder_count", "encoder count latched at the index pulse",
         signed=True),
    _ram(52, 4, "RW", STEPPER_VELOCITY_LIMIT_MAX, "velocity_limit",
         "joint encoder counts/s (the node never steps faster than its maximum step rate)", 1,
         STEPPER_VELOCITY_LIMIT_MAX),
    _ram(56, 4, "RW", STEPPER_DEFAULT_ACCEL_COUNTS_S2, "acceleration_limit",
         "joint encoder counts/s^2", 1, 10_000_000),
    _ram(60, 2, "R", 0, "deflection", "motor angle after reduction - joint angle, counts",
         signed=True),
    _ram(62, 2, "RW", 300, "slip_threshold", "counts of |deflection| flagging SLIP", 1),
    _ram(64, 2, "RW", 150, "deflection_limit", "counts of |deflection| flagging STALLED", 1),
    _ram(66, 2, "RW", STEPPER_DEFAULT_CURRENT_MA, "run_current", "mA while moving", 0, 3000),
    _ram(68, 2, "RW", STEPPER_DEFAULT_CURRENT_MA, "holding_current", "mA at standstill", 0,
         3000),
    _ram(70, 1, "R", 0, "index_seen", "1 = index pulse latched"),
    _ram(71, 1, "R", 0, "hardware_error_status", "ErrorBit bits of the active faults"),
    _ram(72, 1, "R", 0, "present_voltage", "0.1 V"),
    _ram(73, 1, "R", 0, "present_temperature", "deg C (driver)"),
    _ram(74, 1, "R", 0, "registered", "1 = a REG_WRITE awaits ACTION"),
    # the cycle block: read-only mirrors in one range (see above)
    _ram(76, 4, "R", 0, "cycle_present_position", "mirror of present_position", signed=True),
    _ram(80, 4, "R", 0, "cycle_step_count", "mirror of step_count", signed=True),
    _ram(84, 2, "R", 0, "cycle_velocity", "present_velocity saturated to int16, counts/s",
         signed=True),
    _ram(86, 2, "R", 0, "cycle_deflection", "mirror of deflection", signed=True),
    _ram(88, 1, "R", 0, "cycle_status_flags", "mirror of status_flags"),
    # the command block: what a host writes every cycle (see above)
    _ram(92, 4, "RW", 0, "command_goal", "goal in 1/16 joint encoder counts", signed=True),
    _ram(96, 2, "RW", 0, "deflection_offset",
         "counts the deflection is expected off the elastic element's (host: -C*dq)",
         signed=True),
    # the command watchdog (see above)
    _ram(98, 2, "RW", STEPPER_WATCHDOG_DEFAULT_MS, "watchdog_timeout",
         "ms without an instruction to the node after which a move stops, holds and settles "
         "the joint's swing; 0 = off",
         0, 60_000),
    # the host's model of the link at rest, for the settling (see above)
    _ram(100, 2, "RW", REST_DEFLECTION_UNKNOWN, "rest_deflection",
         "counts of deflection holding the link at rest where a watchdog stop leaves it "
         "(host's model; -32768 = not given: identified from the swing)", signed=True),
    # what feeds the command watchdog, and the explicit keep-alive (see above)
    _ram(102, 1, "RW", int(WatchdogFeed.ANY_INSTRUCTION), "watchdog_feed",
         "what feeds the watchdog: 0 any instruction to the node, 1 goal and keep_alive "
         "writes only", 0, 1),
    _ram(103, 1, "RW", 0, "keep_alive", "a write feeds the watchdog (any mode); reads 0"),
])

#: The stepper node's command block: its first and last register (see :data:`STEPPER_TABLE`).
STEPPER_COMMAND_BLOCK: Final = ("command_goal", "deflection_offset")

#: The stepper node's cycle block: its first and last register (see :data:`STEPPER_TABLE`).
STEPPER_CYCLE_BLOCK: Final = ("cycle_present_position", "cycle_status_flags")

#: Tables by model number (what a PING + READ(0, 2) reports).
TABLES_BY_MODEL: dict[int, ControlTable] = {t.model_number: t for t in (RX64_TABLE, STEPPER_TABLE)}
