"""DynamixelBus over a scripted transport: reply matching, wire-timed deadlines, retries,
error bits; golden bytes of the arm's cycle packets (written by hand)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from host.arm.bus import REPLY_GAP_S, DynamixelBus, DynamixelNodeError, Expect
from host.arm.facade import Arm
from host.arm.hold import DRAIN_LATENCIES, drain
from host.arm.state import JointInfo
from host.errors import NodeError, ReplyTimeout
from host.transports.base import Transport
from protocol.dynamixel import ErrorBit, make_read


class ScriptedTransport(Transport):
    """A test double of the transport only: each send() pops the next list of scripted
    ``(delay_s, bytes)`` replies, which then arrive that long after the send on this
    transport's own clock (recv advances it, as the emulator's does)."""

    def __init__(self, script: list[list[tuple[float, bytes]]]) -> None:
        super().__init__("scripted://bus")
        self.t = 0.0
        self.sent: list[tuple[float, bytes]] = []
        self.pending: list[tuple[float, bytes]] = []
        self.script = list(script)

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)

    def _send(self, data: bytes) -> None:
        self.sent.append((self.t, data))
        replies = self.script.pop(0) if self.script else []
        self.pending += [(self.t + delay, raw) for delay, raw in replies]
        self.pending.sort(key=lambda p: p[0])

    def _recv(self, timeout: float | None) -> bytes:
        if self.pending and (timeout is None or self.pending[0][0] <= self.t + timeout):
            at, data = self.pending.pop(0)
            self.t = max(self.t, at)
            return data
        self.t += timeout or 0.0
        return b""

    def _close(self) -> None:
        pass


# Status of id 1 carrying 2 data bytes 0x40 0x00 (model 64): ~(01+04+00+40+00) = ~0x45 = BA
STATUS_1_MODEL = bytes.fromhex("FFFF01040040 00BA".replace(" ", ""))
# Status of id 2 carrying 0x40 0x00: ~(02+04+00+40) = ~0x46 = B9
STATUS_2_MODEL = bytes.fromhex("FFFF0204004000B9")
# Status of id 1, error RANGE (0x08), no data: ~(01+02+08) = ~0x0B = F4
STATUS_1_RANGE = bytes.fromhex("FFFF010208F4")
# Status of id 1, error OVERHEATING (0x04), 0x40 0x00: ~(01+04+04+40) = ~0x49 = B6
STATUS_1_HOT = bytes.fromhex("FFFF0104044000B6")
# READ id 1, address 0, 2 bytes: ~(01+04+02+00+02) = ~0x09 = F6
READ_1_MODEL = bytes.fromhex("FFFF01040200 02F6".replace(" ", ""))


def bus_on(script: list[list[tuple[float, bytes]]], **kwargs: float) -> DynamixelBus:
    return DynamixelBus(ScriptedTransport(script), 1_000_000, latency_s=0.0,
                        **kwargs)  # type: ignore[arg-type]


def test_read_sends_the_packet_and_returns_the_data() -> None:
    bus = bus_on([[(100e-6, STATUS_1_MODEL)]])
    assert bus.read(1, 0, 2) == b"\x40\x00"
    assert bus.transport.sent == [(0.0, READ_1_MODEL)]  # type: ignore[attr-defined]


def test_a_reply_from_another_id_is_skipped() -> None:
    bus = bus_on([[(50e-6, STATUS_2_MODEL), (120e-6, STATUS_1_MODEL)]])
    assert bus.read(1, 0, 2) == b"\x40\x00"


@given(st.lists(st.integers(1, len(STATUS_1_MODEL)), min_size=1, max_size=12))
def test_reply_chunks_of_any_size_make_the_same_reply(cuts: list[int]) -> None:
    chunks: list[tuple[float, bytes]] = []
    at = 0
    for n in cuts:
        if at < len(STATUS_1_MODEL):
            chunks.append((10e-6 * (len(chunks) + 1), STATUS_1_MODEL[at : at + n]))
            at += n
    if at < len(STATUS_1_MODEL):
        chunks.append((10e-6 * (len(chunks) + 1), STATUS_1_MODEL[at:]))
    assert bus_on([chunks]).read(1, 0, 2) == b"\x40\x00"


def test_deadline_is_the_wire_time_plus_return_delay() -> None:
    # READ (8 bytes) + status with 2 data bytes (8 bytes) at 1 Mbaud: 160 µs, plus the
    # return delay (0 here) and a 2 µs turnaround: the deadline is 162 µs after the send.
    on_time = bus_on([[(161e-6, STATUS_1_MODEL)]], retries=0)
    on_time.return_delay_us[1] = 0
    assert on_time.read(1, 0, 2) == b"\x40\x00"
    late = bus_on([[(163e-6, STATUS_1_MODEL)]], retries=0)
    late.return_delay_us[1] = 0
    with pytest.raises(ReplyTimeout):
        late.read(1, 0, 2)
    assert late.transport.now() == pytest.approx(162e-6)


def test_a_request_after_writes_still_on_the_wire_waits_for_them_too() -> None:
    # Two SYNC_WRITEs of 26 bytes each expect no reply and return at once (t = 0); the READ
    # behind them goes out only when they have left the wire, 2 × 26 bytes × 10 µs = 520 µs
    # later, so its deadline is 520 + 162 µs: counted from the send it would be 162 µs.
    data = {1: b"\x00" * 8, 2: b"\x00" * 8}
    for delay, answers in ((561e-6, True), (683e-6, False)):
        bus = bus_on([[], [], [(delay, STATUS_1_MODEL)]], retries=0)
        bus.return_delay_us[1] = 0
        bus.sync_write(30, 8, data)
        bus.sync_write(30, 8, data)
        assert [len(raw) for _, raw in bus.transport.sent] == [26, 26]  # type: ignore[attr-defined]
        if answers:
            assert bus.read(1, 0, 2) == b"\x40\x00"
        else:
            with pytest.raises(ReplyTimeout):
                bus.read(1, 0, 2)
            assert bus.transport.now() == pytest.approx(682e-6)


def test_no_reply_times_out_after_the_retries_with_factory_delays() -> None:
    bus = bus_on([], retries=2)
    with pytest.raises(ReplyTimeout, match="node\\(s\\) 1") as caught:
        bus.read(1, 0, 2)
    # a second program on the port (a pty has no lock) also steals replies: say so
    assert "no other program has the port open" in str(caught.value)
    sent = bus.transport.sent  # type: ignore[attr-defined]
    assert len(sent) == 3
    # each attempt waits 160 µs of wire time + 500 µs factory return delay + 2 µs
    assert sent[1][0] == pytest.approx(662e-6)
    assert bus.transport.now() == pytest.approx(3 * 662e-6)
    assert bus.stats.retries == 2 and bus.stats.timeouts == 1


def test_a_corrupted_reply_is_retried() -> None:
    bad = bytearray(STATUS_1_MODEL)
    bad[5] ^= 0x10
    bus = bus_on([[(100e-6, bytes(bad))], [(100e-6, STATUS_1_MODEL)]])
    assert bus.read(1, 0, 2) == b"\x40\x00"
    assert bus.stats.retries == 1


def test_a_late_reply_to_an_earlier_request_is_dropped() -> None:
    bus = bus_on([[(5e-3, STATUS_1_MODEL)], [(100e-6, STATUS_1_HOT)]], retries=0)
    with pytest.raises(ReplyTimeout):
        bus.read(1, 0, 2)
    bus.transport.sleep(10e-3)  # the first reply arrives now, long after its deadline
    (status,) = bus.exchange([make_read(1, 0, 2)], [Expect(1, 2)])
    assert status.errors == ErrorBit.OVERHEATING  # the fresh reply, not the stale one


class CtrlCInTheWait(ScriptedTransport):
    """Ctrl-C while the host waits for replies: the first wait raises KeyboardInterrupt
    (nothing received by then, or, with ``taking``, the first chunk, lost with it)."""

    def __init__(self, script: list[list[tuple[float, bytes]]], taking: bool = False) -> None:
        super().__init__(script)
        self.interrupted = False
        self.taking = taking

    def _recv(self, timeout: float | None) -> bytes:
        if timeout and not self.interrupted:
            self.interrupted = True
            if self.taking:
                super()._recv(timeout)
            raise KeyboardInterrupt
        return super()._recv(timeout)


BULK_1_2 = [(2, 1, 0), (2, 2, 0)]  # model number of ids 1 and 2


def test_a_write_after_an_exchange_cut_short_waits_for_its_replies() -> None:
    """A write into the replies still on the half-duplex line would collide with them:
    after a Ctrl-C cut the exchange short, :meth:`wait_out_replies` lets them arrive."""
    transport = CtrlCInTheWait([[(1e-3, STATUS_1_MODEL), (2e-3, STATUS_2_MODEL)], []])
    bus = DynamixelBus(transport, 1_000_000, latency_s=0.1)
    with pytest.raises(KeyboardInterrupt):
        bus.bulk_read(BULK_1_2)
    assert bus.wait_out_replies()
    assert transport.now() == pytest.approx(2e-3)  # both replies came: not the deadline
    bus.sync_write(30, 2, {1: b"\x00\x00"})
    assert transport.sent[-1][0] == pytest.approx(2e-3)
    assert bus.wait_out_replies() and transport.now() == pytest.approx(2e-3)  # none due


def test_replies_lost_with_the_interruption_end_the_wait_at_a_silence() -> None:
    """The first reply went with the interrupted read: the second one and a silence of
    REPLY_GAP_S end the wait, not the deadline (the link's 100 ms latency)."""
    transport = CtrlCInTheWait([[(1e-3, STATUS_1_MODEL), (2e-3, STATUS_2_MODEL)]],
                               taking=True)
    bus = DynamixelBus(transport, 1_000_000, latency_s=0.1)
    with pytest.raises(KeyboardInterrupt):
        bus.bulk_read(BULK_1_2)
    assert not bus.wait_out_replies()
    assert transport.now() == pytest.approx(2e-3 + REPLY_GAP_S)


def test_an_exchange_that_ended_leaves_no_replies_due() -> None:
    for script in ([[(100e-6, STATUS_1_MODEL)]], []):  # answered, and timed out
        bus = bus_on(script, retries=0)
        try:
            bus.read(1, 0, 2)
        except ReplyTimeout:
            pass
        before = bus.transport.now()
        assert bus.wait_out_replies() and bus.transport.now() == before


def test_refusal_bits_raise_by_name_and_alarm_bits_are_returned() -> None:
    bus = bus_on([[(100e-6, STATUS_1_RANGE)]])
    with pytest.raises(DynamixelNodeError) as info:
        bus.write(1, 30, b"\x00\x04")
    assert info.value.dxl_id == 1 and info.value.names == ("RANGE",)
    assert info.value.error == ErrorBit.RANGE
    assert isinstance(info.value, NodeError)
    hot = bus_on([[(100e-6, STATUS_1_HOT)]])
    (status,) = hot.exchange([make_read(1, 0, 2)], [Expect(1, 2)])
    assert status.errors == ErrorBit.OVERHEATING


def test_a_reply_of_the_wrong_length_is_a_node_error() -> None:
    bus = bus_on([[(100e-6, STATUS_1_MODEL)]])
    with pytest.raises(NodeError, match="2 data bytes, 4 expected"):
        bus.read(1, 0, 4)


# ----------------------------------------------------------------- the arm's packets

def _arm_on(transport: ScriptedTransport) -> Arm:
    steppers = [JointInfo(i, i + 1, "stepper", 0x5E50, 2, r, 200, 10, 10_000, 100.0)
                for i, r in enumerate((6.0, 10.0, 13.0, 13.0))]
    servos = [JointInfo(i, i + 1, "servo", 64, 0) for i in range(4, 7)]
    return Arm(DynamixelBus(transport, latency_s=0.0), steppers + servos)


# BULK_READ of the cycle: stepper nodes 1-4 read their 13-byte (0x0D) cycle block at 76
# (0x4C), RX-64s 5-7 read 8 bytes at present_position (36 = 0x24).  22 parameter bytes,
# LEN 0x18; checksum ~(FE + 18 + 92 + 00 + 4*0D + (1+2+3+4) + 4*4C + 3*08 + (5+6+7) +
# 3*24) = ~(424 + 516 = 940 = 0x3AC) = 0x53.
GOLDEN_BULK_READ = bytes.fromhex(
    "FFFFFE1892" "00" "0D014C" "0D024C" "0D034C" "0D044C" "080524" "080624" "080724" "53")
# SYNC_WRITE of stepper goals to the command block (command_goal at 92 = 0x5C, 1/16 counts,
# then deflection_offset), 6 bytes: J1 1000 counts = 16 000 (80 3E 00 00), J2 -1 count = -16
# (F0 FF FF FF), offsets 0 (no state read yet).  LEN 0x12; checksum ~(FE + 12 + 83 + 5C +
# 06 + 01 + 80 + 3E + 02 + F0 + 3*FF) = ~(1699 = 0x6A3) = 0x5C.
GOLDEN_STEPPER_GOALS = bytes.fromhex("FFFFFE12835C0601803E0000000002F0FFFFFF00005C")
# SYNC_WRITE of servo goals at goal_position (30 = 0x1E), 2 bytes: J6 (id 6) to 0 rad = 512
# (00 02).  LEN 07; checksum ~(FE + 07 + 83 + 1E + 02 + 06 + 00 + 02) = ~0x1B0 -> 0x4F.
GOLDEN_SERVO_GOAL = bytes.fromhex("FFFFFE07831E020600024F")


def test_the_cycle_sends_goals_and_the_bulk_read_in_one_write() -> None:
    transport = ScriptedTransport([])
    arm = _arm_on(transport)
    commands = [arm.make_position("J1", 2 * math.pi * 1000 / 10_000),
                arm.make_position(1, -2 * math.pi / 10_000), arm.make_position("J6", 0.0)]
    with pytest.raises(ReplyTimeout):
        arm.bus.retries = 0
        arm.cycle(commands)
    assert transport.sent[0][1] == GOLDEN_STEPPER_GOALS + GOLDEN_SERVO_GOAL + GOLDEN_BULK_READ


# ----------------------------------------------------------------- another program on the bus

# Status of id 1 carrying 4 data bytes 01 02 03 04: ~(01+06+00+01+02+03+04) = ~0x11 = EE
STATUS_1_FOUR = bytes.fromhex("FFFF01060001020304EE")


def test_a_misfit_then_no_reply_is_retried_and_the_retry_answers() -> None:
    """Another program's reply (2 bytes from id 1) while this one's collided: retried."""
    bus = bus_on([[(100e-6, STATUS_1_MODEL)], [(100e-6, STATUS_1_FOUR)]])
    assert bus.read(1, 0, 4) == bytes([1, 2, 3, 4])
    assert bus.stats.retries == 1


def test_another_programs_read_heard_as_a_refusal_gives_way_to_the_nodes_answer() -> None:
    """Another program's READ of id 1 (instruction 2 = the ANGLE_LIMIT bit, 2 parameters)
    heard before node 1's own 2-byte answer: the answer is taken, nothing raised."""
    bus = bus_on([[(40e-6, READ_1_MODEL), (120e-6, STATUS_1_MODEL)]], retries=0)
    assert bus.read(1, 0, 2) == b"\x40\x00"


# BULK_READ of 2 bytes at address 0 of ids 1 and 2:
# ~(FE+09+92+00+02+01+00+02+02+00) = ~0x1A0 -> ~0xA0 = 5F
BULK_READ_1_2 = bytes.fromhex("FFFFFE0992000201000202005F")
# The same of id 2 alone: ~(FE+06+92+00+02+02+00) = ~0x19A -> ~0x9A = 65
BULK_READ_2 = bytes.fromhex("FFFFFE069200020200" + "65")


def test_a_bulk_read_missing_a_reply_asks_again_only_the_node_that_did_not_answer() -> None:
    """Another program's READ collided with node 2's reply (garbage where it was): the
    repeat is a BULK_READ of node 2 alone, and node 1's reply is kept."""
    garbage = bytes.fromhex("9a7bbefdda7fcc13")
    bus = bus_on([[(100e-6, STATUS_1_MODEL), (200e-6, garbage)], [(100e-6, STATUS_2_MODEL)]])
    replies = bus.bulk_read([(2, 1, 0), (2, 2, 0)])
    assert [s.id for s in replies.values()] == [1, 2]
    assert [raw for _, raw in bus.transport.sent] == [BULK_READ_1_2, BULK_READ_2]  # type: ignore[attr-defined]
    assert bus.stats.retries == 1


def test_a_repeat_that_brings_replies_does_not_use_up_the_retries() -> None:
    """With no retries left, a repeat still goes out while each brings a reply: three
    nodes, one reply an attempt, each of the others lost to a collision."""
    status_3 = bytes.fromhex("FFFF0304004000B8")  # ~(03+04+00+40) = ~0x47 = B8
    bus = bus_on([[(100e-6, STATUS_1_MODEL)], [(100e-6, STATUS_2_MODEL)],
                  [(100e-6, status_3)]], retries=0)
    replies = bus.bulk_read([(2, 1, 0), (2, 2, 0), (2, 3, 0)])
    assert sorted(replies) == [1, 2, 3]
    with pytest.raises(ReplyTimeout, match=r"node\(s\) 2"):  # no reply at all: no repeat
        bus_on([[(100e-6, STATUS_1_MODEL)]], retries=0).bulk_read([(2, 1, 0), (2, 2, 0)])


def test_replies_are_taken_by_their_id_whatever_their_order() -> None:
    bus = bus_on([[(100e-6, STATUS_2_MODEL), (200e-6, STATUS_1_MODEL)]], retries=0)
    assert sorted(bus.bulk_read([(2, 1, 0), (2, 2, 0)])) == [1, 2]


class ChattyLine(ScriptedTransport):
    """A line another program keeps busy: a frame every 20 ms, forever."""

    frames = 0

    def _recv(self, timeout: float | None) -> bytes:
        due = (self.frames + 1) * 0.02
        if timeout is not None and self.t + timeout < due:
            self.t += timeout
            return b""
        self.frames += 1
        self.t = max(self.t, due)
        return READ_1_MODEL


def test_the_hold_drops_what_the_line_carries_for_a_bounded_time_however_busy_it_is() -> None:
    """A monitor polling every 20 ms never leaves the line quiet for the serial latency
    (100 ms): the drain before a hold ends after DRAIN_LATENCIES of it, not never."""
    transport = ChattyLine([])
    arm = SimpleNamespace(transport=transport, bus=SimpleNamespace(latency_s=0.1))
    drain(arm)  # type: ignore[arg-type]
    assert transport.now() == pytest.approx(DRAIN_LATENCIES * 0.1, abs=0.021)


# SYNC_WRITE of 1 byte at 102 (watchdog_feed): id 1 -> 1: ~(FE+06+83+66+01+01+01) = ~0x1F0
# -> 0F; its read-back, BULK_READ of 1 byte at 102 of id 1: ~(FE+06+92+00+01+01+66) = ~0x1FE
# -> 01; node 1's answers: the old value 0 (~(01+03+00+00) = FB) and the new 1 (FA)
SYNC_FEED_1 = bytes.fromhex("FFFFFE0683660101010F")
READ_FEED_1 = bytes.fromhex("FFFFFE06920001016601")
FEED_0, FEED_1 = bytes.fromhex("FFFF01030000FB"), bytes.fromhex("FFFF01030001FA")


def test_a_setting_lost_to_a_collision_is_read_back_and_written_again() -> None:
    bus = bus_on([[], [(100e-6, FEED_0)], [], [(100e-6, FEED_1)]])
    bus.sync_write_confirmed(102, 1, {1: b"\x01"})
    assert [raw for _, raw in bus.transport.sent] == [  # type: ignore[attr-defined]
        SYNC_FEED_1, READ_FEED_1, SYNC_FEED_1, READ_FEED_1]


def test_a_setting_never_taken_is_an_error_naming_the_node() -> None:
    bus = bus_on([[], [(100e-6, FEED_0)]] * 3)
    with pytest.raises(NodeError, match=r"node\(s\) 1 did not take the write at address 102"):
        bus.sync_write_confirmed(102, 1, {1: b"\x01"}, attempts=3)
