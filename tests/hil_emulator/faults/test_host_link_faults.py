"""Faults of the host's links (``hil_emulator/faults/host_link.py``): each effect observable,
and gone once cleared."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hil_emulator.ports.host_links import SerialLink
from host.errors import TransportError
from protocol.dynamixel import make_ping
from tests.ground_truth import arm_rig_of, hand_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, answers, arm_ping_answered, host_of


def test_link_corruption_loss_latency_noise_and_vanish_on_the_palm_link(hand: FaultyEmulator) -> None:
    host = host_of(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    entry = hand.faults.inject("link_corruption", {"link": "palm", "byte_error_rate": 1.0,
                                                   "direction": "down"})
    assert not answers(host.palm)
    assert tap.received and all(a != b for a, b in zip(tap.sent, tap.received, strict=True))
    hand.faults.clear(entry)
    assert answers(host.palm)
    entry = hand.faults.inject("link_loss", {"link": "palm", "probability": 1.0})
    assert not answers(host.palm)
    hand.faults.clear(entry)
    t0 = host.session.now()
    host.palm.ping()
    quick = host.session.now() - t0
    entry = hand.faults.inject("link_latency", {"link": "palm", "latency_us": 5_000,
                                                "jitter_us": 1_000})
    t0 = host.session.now()
    host.palm.ping()  # 5–6 ms more, within the 30 ms link timeout
    assert host.session.now() - t0 >= quick + 0.005
    hand.faults.clear(entry)
    hand.faults.inject("link_noise_burst", {"link": "palm", "length": 40})
    hand.step(5 * MS)
    assert answers(host.palm)  # both ends resynchronise
    entry = hand.faults.inject("port_vanish", {"link": "palm"})
    with pytest.raises(TransportError, match="vanished"):
        host.palm.ping()
    hand.faults.clear(entry)
    assert answers(host.palm)


def test_a_stuck_host_transmitter_blocks_the_link_until_cleared(hand: FaultyEmulator) -> None:
    host = host_of(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    palm_received: list[bytes] = []
    palm_uart = hand_rig_of(hand).host_uart
    receiver = palm_uart._receiver
    assert receiver is not None

    def spy(data: bytes, t_us: int) -> None:
        palm_received.append(data)
        receiver(data, t_us)

    palm_uart.set_receiver(spy)
    entry = hand.faults.inject("serial_driver_stuck", {"link": "palm"})
    hand.step(10 * MS)
    assert not answers(host.palm)
    assert tap.sent and not tap.received  # nothing the host wrote reached the line
    line = b"".join(palm_received)
    assert len(line) >= 0.9 * 200 * 40 and set(line) == {0}  # a break at line rate (2 Mbaud)
    hand.faults.clear(entry)
    palm_received.clear()
    hand.step(5 * MS)
    assert not palm_received  # the line idles
    assert answers(host.palm)


def test_a_stuck_host_transmitter_on_the_arm_link_jams_until_cleared() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    tap = emu.link_tap("arm")
    entry = emu.faults.inject("serial_driver_stuck", {"link": "arm", "mode": "noise"})
    emu.step(5 * MS)
    assert tap.down(make_ping(5).encode()) == b""  # the host's frames never reach the line
    sent = [t for t in arm_rig_of(emu).bus.log if t.name == "host"]
    assert sum(len(t.data) for t in sent) >= 500  # 1 Mbaud: 100 characters a ms
    emu.faults.clear(entry)
    emu.step(2 * MS)
    assert tap.down(make_ping(5).encode()) == make_ping(5).encode()
    assert arm_ping_answered(emu, 5)


def test_misread_resamples_uart_characters_bit_by_bit() -> None:
    from hil_emulator.lines.uart_sampling import misread

    data = bytes(range(0, 256, 7))
    assert misread(data, 115_200, 115_200) == data
    assert misread(data, 2_000_000, 2_010_000) == data  # 0.5 %: within a UART's tolerance
    # 0x55 is start 0, data 1,0,1,0,1,0,1,0 (LSB first), stop 1.  Read twice as fast, the
    # first character samples sent bits 0,1,1,2,2,3,3,4 → 0x66 and its stop bit at 4.75
    # finds 0 (framing error: left out); the next falling edge is the 1 → 0 at bit 6, whose
    # samples run into the stop bit and the idle line: 0,1,1,0,0,1,1,1 → 0xE6.
    assert misread(b"\x55", 1, 2) == b"\xe6"
    # 0x0F read twice as slow: the start bit's sample (at bit 1) finds 1, a glitch; the next
    # edge is bit 5, whose samples at 7, 9, 11 … read 0 then the idle line → 0xFE.
    assert misread(b"\x0f", 2, 1) == b"\xfe"
    fast = misread(data, 1_000_000, 2_000_000)
    slow = misread(data, 2_000_000, 1_000_000)
    assert fast != data and len(data) > len(slow) > 0  # a slow receiver spans characters
    assert misread(data, 2_000_000, 2_200_000) != data  # 10 % off: every frame broken
    assert misread(b"", 1, 2) == b""


def test_a_baud_mismatch_breaks_every_frame_both_ways_until_cleared(hand: FaultyEmulator) -> None:
    from protocol.stream import decode_all

    host = host_of(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    entry = hand.faults.inject("baud_mismatch", {"link": "palm", "baud": 1_000_000})
    assert not answers(host.palm)
    assert tap.sent and tap.received != tap.sent
    assert not [f for f in decode_all(bytes(tap.received)) if f.crc_ok]  # nothing whole
    hand.faults.clear(entry)
    assert answers(host.palm)
    arm = FaultyEmulator("arm", seed=1, physics=False)
    entry = arm.faults.inject("baud_mismatch", {"link": "arm", "baud": 1_100_000,
                                                "side": "host"})
    arm_tap = arm.link_tap("arm")
    assert arm_tap.down(make_ping(5).encode()) != make_ping(5).encode()
    replies: list[bytes] = []
    arm_tap.up(make_ping(5).encode(), 0, lambda data, t: replies.append(data))
    assert replies and replies[0] != make_ping(5).encode()  # the host misreads the replies
    arm.faults.clear(entry)
    assert arm_tap.down(make_ping(5).encode()) == make_ping(5).encode()


def test_port_vanish_recreates_the_pty_at_the_same_link_path(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", physics=False)
    try:
        emu.open_ports(str(tmp_path))
        link = tmp_path / "arm"
        before = os.path.realpath(link)
        entry = emu.faults.inject("port_vanish", {"link": "arm"})
        assert not link.exists()
        emu.step(1 * MS)
        emu.faults.clear(entry)
        assert link.exists()
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, make_ping(5).encode())
            emu.step(3 * MS)
            assert os.read(fd, 64)[:3] == b"\xff\xff\x05"
        finally:
            os.close(fd)
        arm_link = emu.links["arm"]
        assert isinstance(arm_link, SerialLink)
        assert os.path.realpath(link) != before or arm_link.port.is_open
    finally:
        emu.close()
