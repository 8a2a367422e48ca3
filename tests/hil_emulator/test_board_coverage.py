"""Every board of the table (:data:`protocol.topology.BOARDS`) has its firmware, a factory
and a rig: a row added without one of them fails here, naming the board."""

from __future__ import annotations

import pytest

from firmware_py.dynamixel_slave import DynamixelSlave
from firmware_py.hand_node import HandNode
from firmware_py.identity import read_identity
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import APP_PROGRAMS, BOARD_SPECS, load_program, make_hal, make_node
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.arm.rig import ArmRig
from hil_emulator.hand.rig import HandRig, LooseFinger
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.topology import BOARDS, HAND_BOARDS, Board, BoardType

#: Long enough for a node's bootloader to wait out its autoboot window, verify its image
#: and start the application (µs).
BOOT_US = AUTOBOOT_WINDOW_US + 500_000


def _name(b: Board) -> str:
    return b.app


@pytest.mark.parametrize("b", BOARDS, ids=_name)
def test_every_board_has_a_factory(b: Board) -> None:
    spec = BOARD_SPECS.get(b.board_type)
    assert spec is not None, f"{b.app}: no factory (firmware_py/sim/boards.py BOARD_SPECS)"
    assert spec.board == b.board_type
    hal = make_hal(Scheduler(), b.board_type)
    assert b.upstream in hal.uarts, f"{b.app}: its factory gives no {b.upstream!r} UART"
    assert read_identity(hal.flash).board_type == b.board_type


@pytest.mark.parametrize("b", BOARDS, ids=_name)
def test_every_board_has_firmware(b: Board) -> None:
    spec = BOARD_SPECS.get(b.board_type)
    assert spec is not None, f"{b.app}: no factory, so no program"
    program = spec.program
    module, _, attr = program.partition(":")
    cls = getattr(__import__(module, fromlist=[attr]), attr)
    if b in HAND_BOARDS:
        assert APP_PROGRAMS[b.app] == program
        assert issubclass(cls, HandNode) and cls.node_kind == b.app, program
        load_program(program)
    else:
        assert issubclass(cls, DynamixelSlave), program


@pytest.mark.parametrize("b", HAND_BOARDS, ids=_name)
def test_every_hand_board_boots_its_application(b: Board) -> None:
    """A factory-fresh node runs the program its image names once its bootloader let it."""
    scheduler = Scheduler()
    mcu = make_node(scheduler, b.board_type)
    mcu.power_on()
    scheduler.run_for(BOOT_US)
    assert mcu.program_name == b.app


def _board_types(hals: list[VirtualHal]) -> set[BoardType | None]:
    return {read_identity(hal.flash).board_type for hal in hals}


def _rig_boards() -> set[BoardType | None]:
    hand, loose, arm = HandRig(), LooseFinger(), ArmRig()
    hals = [mcu.hal for mcu in (*hand.mcus, loose.finger.fmcb, loose.finger.f2,
                                loose.finger.f3)]
    found = _board_types([h for h in hals if isinstance(h, VirtualHal)])
    return found | _board_types([hal for hal, _ in arm.nodes.values()])


def test_every_board_is_in_a_rig() -> None:
    found = _rig_boards()
    missing = [b.app for b in BOARDS if b.board_type not in found]
    assert not missing, f"no rig in hil_emulator/ builds {', '.join(missing)}"
