"""The boards of the hand and arm as virtual nodes: peripherals, identity, installed image.

:func:`make_node` gives a powered-off :class:`~firmware_py.mcu.Mcu` on a
:class:`~firmware_py.sim.virtual_hal.VirtualHal` with the board's UARTs, power switches, motors
and sensors, its identity programmed, and (optionally) an application image installed and
activated as a factory would; :func:`make_arm_node` gives a running arm node (Dynamixel
slave).  Tests use them directly; the emulator wires the same nodes to the plant and the
buses.
"""

from __future__ import annotations

import hashlib
import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import cast

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.errors import ConfigError
from firmware_py.flash_layout import (
    BOOT_CONTROL_PAGE,
    HEADER_PAGE,
    KEY_PAGE,
    ActivationRecord,
    KeyRecord,
    page_address,
)
from firmware_py.hal import Hal
from firmware_py.identity import IDENTITY_ADDRESS, Identity, default_identity
from firmware_py.mcu import Mcu, Program, ProgramFactory
from firmware_py.scheduler import Scheduler
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.image import BoardType, make_image, parse_image
from protocol.topology import (
    ARM_BOARDS,
    ARM_BUS_BAUD,
    FINGERS,
    HAND_BOARDS,
    HOST_LINK_BAUD,
    POGO_BAUD,
    TENDON_BAUD,
)
from protocol.topology import board as board_row

BOOTLOADER_PROGRAM = "firmware_py.boot_program:BootProgram"


@dataclass(frozen=True)
class BoardSpec:
    """How a factory makes a board: its program (``"module:Class"``, imported when a node
    first boots it) and its peripherals: UART names with baud rates, power switches, motors,
    sensors.  Its name, address and the rest are its row of :data:`protocol.topology.BOARDS`."""

    board: BoardType
    program: str
    uarts: Mapping[str, int]
    power_switches: tuple[str, ...] = ()
    motors: int = 0
    can: bool = False
    sensors: Mapping[str, int | tuple[int, ...]] = field(default_factory=dict)
    stepper: bool = False
    encoder: bool = False


def _channels(prefix: str, n: int, value: int = 0) -> dict[str, int | tuple[int, ...]]:
    return {f"{prefix}{i}": value for i in range(n)}


_IMU: dict[str, int | tuple[int, ...]] = {"accel": (0, 0, 1000), "mag": (0, 0, 0)}

BOARD_SPECS: dict[BoardType, BoardSpec] = {
    BoardType.PALM: BoardSpec(
        BoardType.PALM, "firmware_py.palm:PalmApp",
        {"host": HOST_LINK_BAUD, **{f"finger{k}": POGO_BAUD for k in range(FINGERS)}},
        power_switches=("finger0", "finger1", "finger2", "finger3"),
        can=True,
        sensors={**_IMU, "gyro": (0, 0, 0), **_channels("taxel", 32, 2000),
                 **_channels("temperature", 7, 250), "supply_mv": 24000},
    ),
    BoardType.FMCB: BoardSpec(
        BoardType.FMCB, "firmware_py.fmcb:FmcbApp", {"pogo": POGO_BAUD, "tendon": TENDON_BAUD},
        power_switches=("phalange",), motors=3,
        sensors={**_IMU, **_channels("temperature", 3, 250), "supply_mv": 24000},
    ),
    BoardType.F2: BoardSpec(
        BoardType.F2, "firmware_py.phalange:F2App", {"tendon": TENDON_BAUD},
        sensors={**_IMU, **_channels("taxel", 6, 2000), "strain": 0,
                 **_channels("thermistor", 4, 0)},
    ),
    BoardType.F3: BoardSpec(
        BoardType.F3, "firmware_py.phalange:F3App", {"tendon": TENDON_BAUD},
        sensors={**_IMU, **_channels("taxel", 12, 2000), **_channels("thermistor", 4, 2048)},
    ),
    # Arm nodes: Dynamixel protocol 1.0 slaves on one RS-485 bus; they run their application
    # directly (make_arm_node), with no hand bootloader.
    # "temperature" is in 0.1 degC, "supply_mv" in mV, "pot" 0..1023 over 300 deg, "load" in
    # 1/1023 of maximum torque (signed, + = CCW).
    BoardType.ARM_STEPPER: BoardSpec(
        BoardType.ARM_STEPPER, "firmware_py.arm_stepper:StepperNodeApp", {"bus": ARM_BUS_BAUD},
        sensors={"temperature": 250, "supply_mv": 24000}, stepper=True, encoder=True,
    ),
    BoardType.RX64: BoardSpec(
        BoardType.RX64, "firmware_py.rx64:Rx64ServoApp", {"bus": ARM_BUS_BAUD}, motors=1,
        sensors={"pot": 512, "temperature": 250, "supply_mv": 18000, "load": 0},
    ),
}

#: Application name (in the image header) → "module:Class" of its program, for every board
#: with the hand bootloader (a hand node boots the program its image names).
APP_PROGRAMS: dict[str, str] = {b.app: BOARD_SPECS[b.board_type].program for b in HAND_BOARDS}


def _program_class(path: str) -> type:
    module, _, attr = path.partition(":")
    cls = getattr(importlib.import_module(module), attr)
    assert isinstance(cls, type)
    return cls


def load_program(path: str) -> ProgramFactory:
    """Import ``"module:Class"`` and return it as a program factory."""
    return _factory(_program_class(path))


def install_one_slot_firmware(mcu: Mcu) -> None:
    """Give ``mcu`` firmware built for the one-slot layout (an older bootloader and
    applications that answer no ``slot.*`` message), from its next reset or power-up: a
    node a host must still flash the one-slot way."""
    def older(path: str) -> ProgramFactory:
        cls = _program_class(path)
        return _factory(type(f"OneSlot{cls.__name__}", (cls,), {"two_slots": False}))

    mcu.install_programs(older(BOOTLOADER_PROGRAM),
                         {name: older(path) for name, path in APP_PROGRAMS.items()})


def _factory(cls: Callable[..., Program]) -> ProgramFactory:
    def make(hal: Hal, mcu: Mcu) -> Program:
        return cls(hal, mcu)

    return make


class _LazyApps(dict[str, ProgramFactory]):
    """Application table that imports a program only when a node first boots it."""

    def __init__(self, table: Mapping[str, str]) -> None:
        super().__init__()
        self._table = dict(table)

    def get(self, key: str, default: ProgramFactory | None = None) -> ProgramFactory | None:  # type: ignore[override]
        if not dict.__contains__(self, key) and key in self._table:
            self[key] = load_program(self._table[key])
        return super().get(key, default)

    def __contains__(self, key: object) -> bool:
        """A program this board can boot, loaded or not yet."""
        return dict.__contains__(self, key) or key in self._table


def make_hal(scheduler: Scheduler, board: BoardType, identity: Identity | None = None
             ) -> VirtualHal:
    """A virtual HAL with the board's peripherals, default sensor values and identity."""
    spec = BOARD_SPECS[board]
    hal = VirtualHal(scheduler, uarts=dict(spec.uarts), power_switches=spec.power_switches,
                     motors=spec.motors, can=spec.can, stepper=spec.stepper,
                     encoder=spec.encoder)
    hal.sensors.values.update(spec.sensors)
    ident = identity or default_identity(board)
    hal.flash.load(IDENTITY_ADDRESS, ident.to_bytes())
    return hal


def app_version(app_name: str) -> str:
    """The version an application program declares (its class ``FW_VERSION``), "x.y.z"."""
    module, _, attr = APP_PROGRAMS[app_name].partition(":")
    version = getattr(importlib.import_module(module), attr).FW_VERSION
    return ".".join(str(part) for part in version)


def default_image(board: BoardType, version: str | None = None, timestamp: int = 0) -> bytes:
    """A valid image for ``board``: its payload is a stand-in whose bytes name the program.

    An emulated MCU runs the firmware_py program named in the header's app name; the
    payload is what a real build would contain, here deterministic filler of a real size.
    ``version`` defaults to the one the program declares (:func:`app_version`).
    """
    app = board_row(board).app
    if version is None:
        version = app_version(app)
    seed = f"{app}-{version}".encode()
    payload = b"".join(hashlib.sha256(seed + bytes([i])).digest() for i in range(64))  # 2 KiB
    return make_image(payload, board, version, app, timestamp)


def install_image(hal: VirtualHal, image: bytes, activate: bool = True) -> None:
    """Program an image into flash directly (JTAG) and, with ``activate``, make it bootable."""
    parsed = parse_image(image)
    hal.flash.load(page_address(HEADER_PAGE), image)
    if activate:
        record = ActivationRecord(parsed.header.sha256).to_page()
        hal.flash.load(page_address(BOOT_CONTROL_PAGE), record)


def provision_key(hal: VirtualHal, public_key: bytes, required: bool = True) -> None:
    """Factory provisioning (JTAG): the node accepts only images signed with ``public_key``
    (32 bytes, ED25519) and, with ``required``, refuses unsigned ones."""
    hal.flash.load(page_address(KEY_PAGE), KeyRecord(bytes(public_key), required).to_page())


def make_node(scheduler: Scheduler, board: BoardType, *, image: bytes | None = None,
              installed: bool = True, uid: int = 0,
              apps: Mapping[str, ProgramFactory] | None = None,
              bootloader: ProgramFactory | None = None) -> Mcu:
    """A powered-off node of ``board`` type.

    With ``installed`` (default) a valid, activated image is in flash (``image`` or
    :func:`default_image`), so after power-on the bootloader's autoboot starts the app.
    """
    hal = make_hal(scheduler, board, default_identity(board, uid))
    if installed:
        install_image(hal, image if image is not None else default_image(board))
    programs = apps if apps is not None else _LazyApps(APP_PROGRAMS)
    return Mcu(hal, bootloader or load_program(BOOTLOADER_PROGRAM), programs)


def make_arm_node(scheduler: Scheduler, board: BoardType, dxl_id: int
                  ) -> tuple[VirtualHal, DynamixelSlave]:
    """A powered arm node of ``board`` (ARM_STEPPER or RX64) with factory ID ``dxl_id`` at
    1 Mbaud, its application started (arm nodes have no hand bootloader).  The HAL's reset
    (watchdog, ``hal.reset()``) reboots the application."""
    if board_row(board) not in ARM_BOARDS:
        raise ConfigError(f"{board!r} is not an arm node")
    cls = _program_class(BOARD_SPECS[board].program)
    assert issubclass(cls, DynamixelSlave)
    app_class = cast("Callable[[VirtualHal, int], DynamixelSlave]", cls)  # (hal, dxl_id)
    hal = make_hal(scheduler, board)
    app = app_class(hal, dxl_id)
    hal.on_reset = app.reboot
    app.start()
    return hal, app
