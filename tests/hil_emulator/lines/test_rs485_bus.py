"""The multidrop RS-485 line: timing, no echo, collisions, faults and the Manchester line code."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from firmware_py.scheduler import Scheduler
from firmware_py.sim.virtual_ports import VirtualUart
from hil_emulator.lines.rs485_bus import Rs485Bus

Received = dict[str, list[tuple[bytes, int]]]


def _recorder(sched: Scheduler, out: list[tuple[bytes, int]]) -> Callable[[bytes, int], None]:
    def receive(data: bytes, t_us: int) -> None:
        out.append((data, sched.now_us()))

    return receive


def make_bus(
    n: int = 3, **kwargs: Any
) -> tuple[Scheduler, Rs485Bus, list[VirtualUart], Received]:
    """A bus with ``n`` nodes n0, n1, ...; ``got[name]`` collects (bytes, scheduler time)."""
    sched = Scheduler()
    bus = Rs485Bus(sched, **kwargs)
    uarts: list[VirtualUart] = []
    got: Received = {}
    for i in range(n):
        name = f"n{i}"
        uart = VirtualUart(sched, 2_000_000, name)
        got[name] = []
        uart.set_receiver(_recorder(sched, got[name]))
        bus.attach(uart, name)
        uarts.append(uart)
    return sched, bus, uarts, got


def test_frames_reach_all_others_not_the_sender_at_end_plus_turnaround() -> None:
    sched, bus, (a, b, c), got = make_bus(turnaround_us=3)
    a.send(b"hello")
    sched.run_until(1_000)
    b.send(b"reply!")
    sched.run_until(2_000)
    end_a = a.sent[-1].end_us
    assert end_a == 25  # 5 bytes x 10 bits at 2 Mbaud
    assert got["n0"] == [(b"reply!", 1_000 + 30 + 3)]
    assert got["n1"] == [(b"hello", end_a + 3)]
    assert got["n2"] == [(b"hello", end_a + 3), (b"reply!", 1_033)]
    assert bus.collisions == 0
    assert [(t.name, t.collided) for t in bus.log] == [("n0", False), ("n1", False)]
    # Every field of the log's transmissions (made without __init__ from source).
    assert [(t.start_us, t.end_us, t.data, t.received) for t in bus.log] == [
        (0, 25, b"hello", b"hello"), (1_000, 1_030, b"reply!", b"reply!")]
    assert a.peer is None and a.sink is not None


def test_wire_time_148_plus_7_bytes_at_2_mbaud() -> None:
    sched, bus, (a, b, _), got = make_bus(turnaround_us=0)
    frame = bytes(range(148)) + bytes(7)
    assert bus.wire_time_us(len(frame)) == 775
    a.send(frame)
    sched.run_until(10_000)
    (data, t), = got["n1"]
    assert data == frame
    assert abs(t - 775) <= 1
    assert bus.log[0].end_us - bus.log[0].start_us == 775


def test_overlapping_frames_collide_and_arrive_corrupted() -> None:
    sched, bus, (a, b, c), got = make_bus(seed=7)
    fa, fb = b"\x42\x01\x02\x03" * 8, b"\x42\x09\x08\x07" * 8
    a.send(fa)
    sched.run_until(50)  # a's frame takes 160 µs
    b.send(fb)
    sched.run_until(5_000)
    assert bus.collisions == 1
    assert all(t.collided for t in bus.log)
    received = [d for d, _ in got["n2"]]
    assert len(received) == 2
    for data in received:
        assert len(data) == len(fa)
        assert data != fa and data != fb
    # a hears only b's (garbled) frame, b only a's; both see the same line
    assert got["n0"][0][0] == received[1]
    assert got["n1"][0][0] == received[0]


def test_back_to_back_frames_do_not_collide() -> None:
    sched, bus, (a, b, _), got = make_bus()
    a.send(b"abcd")
    sched.run_until(a.sent[-1].end_us)  # b starts the instant a's last bit is out
    b.send(b"wxyz")
    sched.run_until(5_000)
    assert bus.collisions == 0
    assert [d for d, _ in got["n2"]] == [b"abcd", b"wxyz"]


def test_three_way_collision_counts_each_late_starter() -> None:
    sched, bus, (a, b, c), got = make_bus()
    a.send(b"abcd" * 4)
    sched.run_until(10)
    b.send(b"wxyz" * 4)
    c.send(b"1234" * 4)
    sched.run_until(5_000)
    assert bus.collisions == 2
    assert all(t.collided for t in bus.log)


def test_own_queued_frames_do_not_collide() -> None:
    sched, bus, (a, _, c), got = make_bus()
    a.send(b"one")
    a.send(b"two")
    sched.run_until(1_000)
    assert bus.collisions == 0
    assert [d for d, _ in got["n2"]] == [b"one", b"two"]


def _corrupted(seed: int, rate: float) -> list[bytes]:
    sched, bus, (a, b, _), got = make_bus(seed=seed, bit_error_rate=rate)
    for i in range(5):
        a.send(bytes(range(i, 200 + i)))
        sched.run_for(2_000)
    return [d for d, _ in got["n1"]]


def test_bit_errors_seeded() -> None:
    assert _corrupted(1, 0.0) == [bytes(range(i, 200 + i)) for i in range(5)]
    noisy = _corrupted(1, 0.05)
    assert len(noisy) == 5
    assert all(d != bytes(range(i, 200 + i)) and len(d) == 200 for i, d in enumerate(noisy))
    assert noisy == _corrupted(1, 0.05)
    assert noisy != _corrupted(2, 0.05)


def test_line_cut_and_drop() -> None:
    sched, bus, (a, b, c), got = make_bus()
    bus.set_line_cut(True)
    a.send(b"lost")
    sched.run_for(1_000)
    assert got["n1"] == [] and got["n2"] == []
    assert bus.log[0].received == b""
    bus.set_line_cut(False)
    a.send(b"back")
    sched.run_for(1_000)
    assert [d for d, _ in got["n1"]] == [b"back"]
    bus.drop(1.0)
    b.send(b"gone")
    sched.run_for(1_000)
    assert [d for d, _ in got["n0"]] == []
    bus.drop(0.5)
    for _ in range(40):
        a.send(b"x")
        sched.run_for(100)
    assert 5 < len(got["n1"]) - 1 < 35
    with pytest.raises(ValueError):
        bus.drop(1.5)


def test_manchester_clean_is_exact_and_twice_as_long() -> None:
    sched, bus, (a, b, _), got = make_bus(line_code="manchester", turnaround_us=0)
    frame = bytes(range(148)) + bytes(7)
    assert bus.wire_time_us(len(frame)) == 1_550
    a.send(frame)
    sched.run_until(10_000)
    assert got["n1"] == [(frame, 1_550)]
    assert bus.manchester_bad_characters == 0


def _manchester_noisy(seed: int) -> tuple[list[bytes], int]:
    sched, bus, (a, b, _), got = make_bus(line_code="manchester", chip_error_rate=0.01,
                                          seed=seed)
    for _ in range(4):
        a.send(bytes(range(256)))
        sched.run_for(5_000)
    return [d for d, _ in got["n1"]], bus.manchester_bad_characters


def test_manchester_chip_errors_drop_characters_deterministically() -> None:
    data, bad = _manchester_noisy(3)
    assert bad > 0
    assert sum(len(d) for d in data) == 4 * 256 - bad
    assert (data, bad) == _manchester_noisy(3)
    assert (data, bad) != _manchester_noisy(4)


def test_attach_twice_rejected() -> None:
    sched = Scheduler()
    bus = Rs485Bus(sched)
    uart = VirtualUart(sched)
    bus.attach(uart, "x")
    with pytest.raises(ValueError):
        bus.attach(uart, "y")
