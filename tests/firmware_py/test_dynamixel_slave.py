"""The Dynamixel 1.0 slave runtime, through arm nodes on a VirtualHal (no physics)."""

from __future__ import annotations

import pytest

from firmware_py.dynamixel_slave import EEPROM_PAGE, PACKET_GAP_US
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE, STEPPER_VELOCITY_LIMIT_MAX
from protocol.dynamixel import (
    ErrorBit,
    StatusPacket,
    make_action,
    make_bulk_read,
    make_ping,
    make_read,
    make_reg_write,
    make_reset,
    make_sync_write,
    make_write,
)
from protocol.image import BoardType
from tests.firmware_py.dxl_bench import transact


def read_value(sched: Scheduler, hal: VirtualHal, dxl_id: int, name: str, table=STEPPER_TABLE
               ) -> int:
    reg = table[name]
    (reply,) = transact(sched, hal, make_read(dxl_id, reg.address, reg.size).encode())
    return reg.decode(reply.params)


def write_value(sched: Scheduler, hal: VirtualHal, dxl_id: int, name: str, value: int,
                table=STEPPER_TABLE) -> list[StatusPacket]:
    reg = table[name]
    return transact(sched, hal, make_write(dxl_id, reg.address, reg.encode(value)).encode())


@pytest.fixture
def node() -> tuple[Scheduler, VirtualHal]:
    sched = Scheduler()
    hal, _ = make_arm_node(sched, BoardType.ARM_STEPPER, 1)
    return sched, hal


def test_ping_golden_bytes(node):
    sched, hal = node
    bus = hal.uart("bus")
    bus.deliver(bytes.fromhex("FF FF 01 02 01 FB"))
    sched.run_for(3_000)
    assert b"".join(bus.take_sent()) == bytes.fromhex("FF FF 01 02 00 FC")


@pytest.mark.parametrize(("board", "dxl_id", "model_bytes"), [
    (BoardType.ARM_STEPPER, 3, b"\x50\x5e"),
    (BoardType.RX64, 5, b"\x40\x00"),
])
def test_sdk_ping_reads_model_number(board, dxl_id, model_bytes):
    sched = Scheduler()
    hal, _ = make_arm_node(sched, board, dxl_id)
    (pong,) = transact(sched, hal, make_ping(dxl_id).encode())
    assert (pong.id, pong.error, pong.params) == (dxl_id, 0, b"")
    # READ addr 0, 2 bytes; checksum by hand: ~(id + 4 + 2 + 0 + 2)
    raw = bytes([0xFF, 0xFF, dxl_id, 4, 2, 0, 2, ~(dxl_id + 8) & 0xFF])
    bus = hal.uart("bus")
    bus.deliver(raw)
    sched.run_for(3_000)
    body = bytes([dxl_id, 4, 0]) + model_bytes
    assert b"".join(bus.take_sent()) == b"\xff\xff" + body + bytes([~sum(body) & 0xFF])


def test_other_ids_and_broadcast_get_no_reply(node):
    sched, hal = node
    assert transact(sched, hal, make_ping(2).encode()) == []
    assert transact(sched, hal, make_ping(0xFE).encode()) == []


@pytest.mark.parametrize("delay", [250, 10, 0])
def test_return_delay_is_honoured(node, delay):
    sched, hal = node
    if delay != 250:
        write_value(sched, hal, 1, "return_delay_time", delay)
    bus = hal.uart("bus")
    bus.sent.clear()
    t0 = sched.now_us()
    bus.deliver(make_ping(1).encode())
    sched.run_for(3_000)
    (chunk,) = bus.sent
    assert chunk.start_us - t0 == 2 * delay


def test_status_return_levels(node):
    sched, hal = node
    reg = STEPPER_TABLE["status_return_level"]
    for level in (0, 1, 2):
        write = make_write(1, reg.address, bytes([level])).encode()
        hal.uart("bus").deliver(write)  # the reply to this write follows the old level
        sched.run_for(3_000)
        assert len(transact(sched, hal, make_ping(1).encode())) == 1
        reads = transact(sched, hal, make_read(1, 25, 1).encode())
        assert len(reads) == (0 if level == 0 else 1)
        writes = transact(sched, hal, make_write(1, 25, b"\x01").encode())
        assert len(writes) == (1 if level == 2 else 0)


def test_write_read_round_trip(node):
    sched, hal = node
    (ack,) = write_value(sched, hal, 1, "velocity_limit", 1234)
    assert (ack.error, ack.params) == (0, b"")
    assert read_value(sched, hal, 1, "velocity_limit") == 1234
    (reply,) = transact(sched, hal, make_read(1, 52, 4).encode())
    assert reply.params == (1234).to_bytes(4, "little")


def test_eeprom_persists_across_reset_but_ram_does_not(node):
    sched, hal = node
    write_value(sched, hal, 1, "return_delay_time", 20)
    write_value(sched, hal, 1, "led", 1)
    sched.run_for(5_000)  # the flash page is written
    assert EEPROM_PAGE in hal.flash.writes
    hal.reset()
    assert read_value(sched, hal, 1, "return_delay_time") == 20
    assert read_value(sched, hal, 1, "led") == 0


def test_power_cycle_keeps_eeprom():
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.RX64, 5)
    write_value(sched, hal, 5, "max_torque", 500, RX64_TABLE)
    write_value(sched, hal, 5, "torque_limit", 100, RX64_TABLE)
    sched.run_for(5_000)
    hal.halt(restart_clock=True)
    hal.flash.power_loss()
    app.start()
    assert read_value(sched, hal, 5, "max_torque", RX64_TABLE) == 500
    assert read_value(sched, hal, 5, "torque_limit", RX64_TABLE) == 500  # from max torque


def test_reg_write_waits_for_action(node):
    sched, hal = node
    (ack,) = transact(sched, hal, make_reg_write(1, 25, b"\x01").encode())
    assert ack.error == 0
    assert read_value(sched, hal, 1, "led") == 0
    assert read_value(sched, hal, 1, "registered") == 1
    assert transact(sched, hal, make_action().encode()) == []  # broadcast: no reply
    assert read_value(sched, hal, 1, "led") == 1
    assert read_value(sched, hal, 1, "registered") == 0
    (nak,) = transact(sched, hal, make_action(1).encode())  # nothing registered
    assert nak.errors == ErrorBit.INSTRUCTION


def test_sync_write_reaches_several_nodes():
    sched = Scheduler()
    nodes = {i: make_arm_node(sched, BoardType.ARM_STEPPER, i)[0] for i in (1, 2, 3)}
    raw = make_sync_write(52, 4, {1: (100).to_bytes(4, "little"),
                                  3: (300).to_bytes(4, "little")}).encode()
    for hal in nodes.values():
        assert transact(sched, hal, raw) == []
    assert read_value(sched, nodes[1], 1, "velocity_limit") == 100
    assert read_value(sched, nodes[2], 2, "velocity_limit") == STEPPER_VELOCITY_LIMIT_MAX
    assert read_value(sched, nodes[3], 3, "velocity_limit") == 300


def test_out_of_range_write_sets_range_bit(node):
    sched, hal = node
    (nak,) = write_value(sched, hal, 1, "status_return_level", 3)
    assert nak.errors == ErrorBit.RANGE
    assert read_value(sched, hal, 1, "status_return_level") == 2
    (nak,) = transact(sched, hal, make_write(1, 19, b"\x00").encode())  # a gap (18 alarm_shutdown, 20 encoder)
    assert nak.errors == ErrorBit.RANGE
    (nak,) = transact(sched, hal, make_read(1, 95, 10).encode())  # past the end (98)
    assert nak.errors == ErrorBit.RANGE and nak.params == b""


def test_read_only_write_sets_instruction_bit(node):
    sched, hal = node
    (nak,) = transact(sched, hal, make_write(1, 0, b"\x01\x00").encode())
    assert nak.errors == ErrorBit.INSTRUCTION
    assert read_value(sched, hal, 1, "model_number") == 0x5E50


def test_unknown_instruction_and_bad_checksum():
    sched = Scheduler()
    hal, _ = make_arm_node(sched, BoardType.ARM_STEPPER, 1)
    body = bytes([1, 2, 0x07])
    (nak,) = transact(sched, hal, b"\xff\xff" + body + bytes([~sum(body) & 0xFF]))
    assert nak.errors == ErrorBit.INSTRUCTION
    assert transact(sched, hal, bytes.fromhex("FF FF 01 02 01 FA")) == []  # bad checksum


def test_id_change_takes_effect_after_reply(node):
    sched, hal = node
    (ack,) = write_value(sched, hal, 1, "id", 9)
    assert ack.id == 1
    assert transact(sched, hal, make_ping(1).encode()) == []
    (pong,) = transact(sched, hal, make_ping(9).encode())
    assert pong.id == 9


def test_baud_change_after_reply(node):
    sched, hal = node
    bus = hal.uart("bus")
    bus.sent.clear()
    bus.deliver(make_write(1, 4, b"\x03").encode())
    sched.run_for(3_000)
    assert bus.baud == 500_000
    (chunk,) = bus.sent  # the reply still went out at 1 Mbaud: 6 bytes in 60 µs
    assert chunk.end_us - chunk.start_us == 60


def test_reset_restores_factory_except_id(node):
    sched, hal = node
    write_value(sched, hal, 1, "return_delay_time", 20)
    write_value(sched, hal, 1, "id", 9)
    write_value(sched, hal, 9, "velocity_limit", 77)
    (ack,) = transact(sched, hal, make_reset(9).encode())
    assert ack.id == 9 and ack.error == 0
    assert read_value(sched, hal, 9, "return_delay_time") == 250
    assert read_value(sched, hal, 9, "velocity_limit") == STEPPER_VELOCITY_LIMIT_MAX
    sched.run_for(10_000)
    hal.reset()
    assert read_value(sched, hal, 9, "return_delay_time") == 250  # saved to flash too


def test_bulk_read_answers_in_turn():
    sched = Scheduler()
    hal1, _ = make_arm_node(sched, BoardType.ARM_STEPPER, 1)
    hal2, _ = make_arm_node(sched, BoardType.ARM_STEPPER, 2)
    for hal, i in ((hal1, 1), (hal2, 2)):
        write_value(sched, hal, i, "return_delay_time", 0)
    raw = make_bulk_read([(2, 1, 0), (1, 2, 3)]).encode()
    bus1, bus2 = hal1.uart("bus"), hal2.uart("bus")
    bus1.sent.clear()
    bus2.sent.clear()
    bus1.deliver(raw)
    bus2.deliver(raw)
    sched.run_for(20)
    assert len(bus1.sent) == 1 and bus2.sent == []
    (reply1,) = bus1.take_sent()
    assert StatusPacket.decode(reply1).params == b"\x50\x5e"
    sched.run_for(100)
    assert bus2.sent == []  # still waiting for node 1's packet (fallback later)
    bus2.deliver(reply1)  # node 1's status passes on the bus
    sched.run_for(100)
    (reply2,) = bus2.take_sent()
    assert StatusPacket.decode(reply2) == StatusPacket(2, 0, b"\x02")
    # without hearing node 1, node 2 answers after the fallback delay
    bus2.deliver(raw)
    sched.run_for(2_000)
    assert len(bus2.sent) == 1


def test_false_header_in_a_corrupted_packet_does_not_deafen_the_node(node):
    # Found by hil-fuzz: a broadcast SYNC_WRITE with a bad checksum whose parameters hold
    # FF FF 7F D8 — a false header announcing 216 bytes.  The node resynchronises onto it;
    # the partial packet must be dropped after the inter-packet gap, not swallow what follows.
    sched, hal = node
    corrupted = bytes.fromhex("FF FF FE 09 83 1C 04 01 FE FF FF 7F D8")
    assert transact(sched, hal, corrupted) == []
    sched.run_for(PACKET_GAP_US)  # the host's next instruction comes after a pause
    ping = bytes.fromhex("FF FF 01 02 01 FB")
    (status,) = transact(sched, hal, ping)
    assert (status.id, status.error) == (1, 0)


def test_a_packet_split_within_the_gap_still_arrives(node):
    sched, hal = node
    ping = bytes.fromhex("FF FF 01 02 01 FB")
    bus = hal.uart("bus")
    bus.take_sent()
    bus.deliver(ping[:3])
    sched.run_for(PACKET_GAP_US // 2)
    assert transact(sched, hal, ping[3:]) != []
