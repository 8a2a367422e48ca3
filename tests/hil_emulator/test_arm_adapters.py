"""Several USB–RS-485 adapters on the arm's one bus (``hil-emulator --arm-adapters N``), each
a pty: every adapter hears every frame on the line but its own, and two that transmit at
once collide, as on RS-485.  In process, stepped (no wall clock)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from hil_emulator.emulator import MAX_ARM_ADAPTERS, Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.ports.host_links import SerialLink
from protocol.dynamixel import DynamixelStreamDecoder, StatusPacket, make_ping
from tools.cli.serve_emulator import main as hil_emulator


@pytest.fixture
def emulator() -> Iterator[Emulator]:
    with Emulator("arm", physics=False, arm_adapters=2) as emu:
        emu.open_ports()
        yield emu


def _client(path: str) -> int:
    """A host program's end of ``path`` (non-blocking)."""
    return os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)


def _drain(fd: int) -> bytes:
    out = b""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:
            return out
        if not chunk:
            return out
        out += chunk


def _statuses(data: bytes) -> list[tuple[int, int]]:
    """(id, error byte) of the packets in ``data`` read as status packets."""
    packets = [d.packet for d in DynamixelStreamDecoder("status").feed(data)]
    return [(p.id, p.error) for p in packets if isinstance(p, StatusPacket)]


def test_the_ports_list_every_adapter_and_arm_stays_the_first(emulator: Emulator) -> None:
    ports = emulator.describe()
    second = emulator.links["arm2"]
    assert isinstance(second, SerialLink)
    assert ports["arm_adapters"] == [ports["arm"], second.path]
    assert len(set(ports["arm_adapters"])) == 2


def test_a_second_adapter_hears_the_host_and_the_nodes_and_not_its_own_echo(
        emulator: Emulator) -> None:
    host, other = (_client(p) for p in emulator.describe()["arm_adapters"] if p)
    try:
        ping = make_ping(3).encode()
        os.write(other, ping)
        emulator.step(5_000)
        heard_by_host = _drain(host)
        heard_by_other = _drain(other)
        # The host hears the other program's PING (bytes as sent) and node 3's answer.
        assert heard_by_host.startswith(ping)
        assert (3, 0) in _statuses(heard_by_host[len(ping):])
        # The other adapter hears node 3's answer, and not its own PING back.
        assert not heard_by_other.startswith(ping) and _statuses(heard_by_other) == [(3, 0)]
        # And the other way round: the host's PING reaches the other adapter.
        os.write(host, make_ping(5).encode())
        emulator.step(5_000)
        assert _drain(other).startswith(make_ping(5).encode())
        assert _statuses(_drain(host)) == [(5, 0)]
    finally:
        os.close(host)
        os.close(other)


def test_two_adapters_sending_at_once_collide_and_no_node_answers(emulator: Emulator) -> None:
    host, other = (_client(p) for p in emulator.describe()["arm_adapters"] if p)
    try:
        assert emulator.arm is not None
        before = emulator.arm.bus.collisions
        os.write(host, make_ping(1).encode())
        os.write(other, make_ping(2).encode())
        emulator.step(5_000)  # both enter the line at the same simulated time
        assert emulator.arm.bus.collisions == before + 1
        assert _statuses(_drain(host)) == [] and _statuses(_drain(other)) == []
        os.write(other, make_ping(2).encode())  # alone on the line: answered
        emulator.step(5_000)
        assert _statuses(_drain(other)) == [(2, 0)]
    finally:
        os.close(host)
        os.close(other)


@pytest.mark.parametrize("count", [0, MAX_ARM_ADAPTERS + 1])
def test_an_adapter_count_out_of_range_is_refused(count: int) -> None:
    with pytest.raises(EmulatorConfigError, match="adapters"):
        Emulator("arm", physics=False, arm_adapters=count)


def test_adapters_without_an_arm_are_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert hil_emulator(["--config", "hand", "--arm-adapters", "2", "--no-physics"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no arm" in err[0]
