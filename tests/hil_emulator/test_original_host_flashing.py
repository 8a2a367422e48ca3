"""The original host's flashing flows, unmodified, against the emulated nodes (in process, on
the simulation clock): the motor module's and the palm's reset-based ``burn`` (halt about
3.02 s after the reset), the phalanges' power-cycle ``pburn``/``dburn`` (tunnelled through
the motor module), and a raw binary that must be reported as not booted."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from firmware_py.hand_node import HandNode
from firmware_py.sim.boards import default_image
from hil_emulator.inprocess import EmulatorTransport, forget_shared_emulators
from host.transports.base import open_transport
from protocol.image import BoardType
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from tests.ground_truth import hand_rig_of
from tests.hil_emulator.original_host import OriginalHost

#: A new version, so a successful burn is visible in identify.
NEW = "9.8.7"


@pytest.fixture
def loose() -> Iterator[OriginalHost]:
    transport = open_transport("emu://loose-finger/finger0?physics=0&name=original-host")
    try:
        yield OriginalHost(transport)
    finally:
        transport.close()
        forget_shared_emulators()


@pytest.fixture
def palm() -> Iterator[OriginalHost]:
    transport = open_transport("emu://hand/palm?physics=0&name=original-host")
    try:
        yield OriginalHost(transport)
    finally:
        transport.close()
        forget_shared_emulators()


def _program(host: OriginalHost, hop: str) -> str | None:
    """Name of the program the node at ``hop`` runs ('bootloader' or its application)."""
    assert isinstance(host.transport, EmulatorTransport)
    emu = host.transport.emulator
    if hop == "palm":
        assert emu.hand is not None
        return emu.hand.palm.program_name
    assert emu.loose is not None
    return getattr(emu.loose.finger, hop).program_name


def _version(host: OriginalHost, hop: str) -> tuple[int, int, int]:
    assert isinstance(host.transport, EmulatorTransport)
    emu = host.transport.emulator
    if hop == "palm":
        mcu = hand_rig_of(emu).palm
    else:
        assert emu.loose is not None
        mcu = getattr(emu.loose.finger, hop)
    assert isinstance(mcu.program, HandNode)
    return tuple(mcu.program.fw_version)


def test_motor_module_burn_halts_3_02_s_after_the_reset_and_boots(loose: OriginalHost) -> None:
    image = default_image(BoardType.FMCB, NEW)
    t0 = loose.transport.now()
    assert loose.burn_node(image)
    halt_at = next(t for t, what in loose.node.log if what == "halt")
    assert 3.0 <= halt_at - t0 <= 3.1  # the original's timing …
    assert halt_at - t0 < AUTOBOOT_WINDOW_US / 1e6 - 1.0  # … with a second to spare
    loose.transport.sleep(0.05)
    assert _program(loose, "fmcb") == "fmcb" and _version(loose, "fmcb") == (9, 8, 7)


@pytest.mark.parametrize(("address", "hop", "board"), [(1, "f2", BoardType.F2),
                                                        (2, "f3", BoardType.F3)])
def test_phalange_burn_through_the_motor_modules_relay(loose: OriginalHost, address: int,
                                                       hop: str, board: BoardType) -> None:
    image = default_image(board, NEW)
    t0 = loose.transport.now()
    assert loose.burn_phalange(address, image)
    p = loose.phalanges[address]
    halt_at = next(t for t, what in p.log if what == "halt")
    assert 2.0 <= halt_at - t0 - 1.0 <= 2.1  # about 2 s after phalange power came back
    loose.transport.sleep(0.05)
    assert _program(loose, hop) == hop and _version(loose, hop) == (9, 8, 7)
    # Every page took one attempt: the original's 30 ms wait covers a relayed page write.
    pages = -(-len(image) // 256)
    assert loose.transport.now() - t0 < 3.1 + pages * 0.045 + 0.5


def test_palm_burn_halts_after_the_reset_and_boots(palm: OriginalHost) -> None:
    image = default_image(BoardType.PALM, NEW)
    assert palm.burn_node(image)
    palm.transport.sleep(0.05)
    assert _program(palm, "palm") == "palm" and _version(palm, "palm") == (9, 8, 7)


def test_a_raw_binary_is_reported_as_not_booted(loose: OriginalHost) -> None:
    """What the original host would burn: a bare binary, no header.  Every page is written,
    but the boot is not acknowledged, so the original host says "failed to boot" — and the
    node truly stays in its bootloader."""
    raw = bytes(range(256)) * 12
    assert not loose.burn_node(raw)
    assert "failed to boot" in [what for _, what in loose.node.log]
    loose.transport.sleep(AUTOBOOT_WINDOW_US / 1e6)
    assert _program(loose, "fmcb") == "bootloader"


def test_overlapping_relay_requests_are_both_answered(loose: OriginalHost) -> None:
    """The original host may relay a second phalange request before the first's answer:
    both pings are answered, in order."""
    f2, f3 = loose.phalanges[1], loose.phalanges[2]
    loose.node.send(0x20, b"\x00")  # autopoll off: the relay has the bus to itself
    loose.node.wait(0.05)
    f2.send(0x01)
    f3.send(0x01)
    got: list[int] = []
    start = loose.transport.now()
    while loose.transport.now() - start < 0.1 and len(got) < 4:
        loose._listen(0.01)
        got += [1 for t, _ in f2.parser.frames if t == 0x01]
        got += [2 for t, _ in f3.parser.frames if t == 0x01]
        f2.parser.frames.clear()
        f3.parser.frames.clear()
    # Both phalange parsers hear both replies (they share the relay): each ping answered once.
    assert sorted(got) == [1, 1, 2, 2]
