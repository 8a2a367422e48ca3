"""Host ports in real time take every byte as it arrives, as a USB adapter's driver does:
a reader thread per pty, arrival stamps, a 4 KiB adapter buffer beyond which bytes are an
overrun.  Over real ptys, with dynamixel-sdk's pyserial."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import serial

from hil_emulator.emulator import Emulator
from hil_emulator.ports.host_links import ADAPTER_BUFFER_BYTES, PtyBacked, SerialLink
from protocol import dynamixel as dxl
from tests.hil_emulator.emulator_thread import serving

HANG_GUARD_S = 20.0  # a guard against a hang, not a timing bound


def _emulator(link: str) -> Emulator:
    if link == "arm":
        return Emulator("arm", physics=False)
    return Emulator("hand", physics=False, can="none")


def _wait(condition: object, what: str) -> None:
    deadline = time.monotonic() + HANG_GUARD_S
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"hang: {what}"
        time.sleep(0.001)


@contextmanager
def stalled(emulator: Emulator) -> Iterator[None]:
    """The simulation thread busy in one event for the duration of the block."""
    started, release = threading.Event(), threading.Event()

    def busy() -> None:
        started.set()
        release.wait(HANG_GUARD_S)

    emulator.scheduler.call_at(emulator.scheduler.now_us() + 1_000, busy)
    _wait(started.is_set, "the stall begins")
    try:
        yield
    finally:
        release.set()


def _read_at_once(emulator: Emulator, name: str) -> SerialLink:
    """The pty link ``name`` of a serving emulator, once its reader thread runs."""
    link = emulator.links[name]
    assert isinstance(link, SerialLink)
    _wait(lambda: link.reader is not None, "the reader starts")
    return link


def _reader_bytes(link: PtyBacked) -> int:
    return link.reader.bytes_read if link.reader is not None else 0


@pytest.mark.parametrize("name", ["arm", "palm"])
def test_bytes_are_taken_at_once_while_the_simulation_thread_is_busy(name: str) -> None:
    """The simulation thread is stuck in one long event; what a client writes meanwhile is
    read off the pty at once (not at the next event), so the client's own flush of its
    output cannot lose it, and it all enters the simulation afterwards."""
    emulator = _emulator(name)
    with serving(emulator):
        link = _read_at_once(emulator, name)
        packet = dxl.make_ping(0xFE).encode()  # broadcast: nobody answers
        with stalled(emulator), serial.Serial(link.path, 1_000_000, timeout=0) as port:
            for k in range(100):
                port.write(packet)
                _wait(lambda k=k: _reader_bytes(link) >= (k + 1) * len(packet),
                      "the reader takes the bytes")
                port.reset_output_buffer()
            assert link.stats()["bytes_in"] == 0  # the simulation thread has not looked
        _wait(lambda: link.stats()["bytes_in"] == 100 * len(packet), "the bytes enter")
    assert link.stats()["overrun"] == 0


@pytest.mark.parametrize("name", ["arm", "palm"])
def test_a_thousand_writes_each_flushed_once_handed_over_lose_nothing(name: str) -> None:
    """1,000 writes, each followed by ``reset_output_buffer()`` once Linux has handed the
    bytes to the emulator's end of the pty: nothing is lost, none is an overrun."""
    emulator = _emulator(name)
    packet = dxl.make_ping(0xFE).encode()
    with serving(emulator):
        link = _read_at_once(emulator, name)
        with serial.Serial(link.path, 1_000_000, timeout=0) as port:
            for k in range(1000):
                port.write(packet)
                _wait(lambda k=k: _reader_bytes(link) >= (k + 1) * len(packet),
                      "the reader takes the bytes")
                port.reset_output_buffer()
        _wait(lambda: link.stats()["bytes_in"] == 1000 * len(packet), "every byte enters")
    assert link.stats()["overrun"] == 0


def test_a_client_that_writes_and_closes_loses_nothing() -> None:
    emulator = _emulator("arm")
    packet = dxl.make_ping(0xFE).encode()
    with serving(emulator):
        link = emulator.links["arm"]
        assert isinstance(link, SerialLink)
        for _ in range(300):
            with serial.Serial(link.path, 1_000_000, timeout=0) as port:
                port.write(packet)
        _wait(lambda: link.stats()["bytes_in"] == 300 * len(packet), "every byte enters")


def test_beyond_the_adapter_buffer_bytes_are_an_overrun_counted() -> None:
    """The simulation thread busy, a client writes 10 KiB: the adapter buffer takes 4 KiB
    (they all reach the wire afterwards), the rest is an overrun, counted."""
    emulator = _emulator("arm")
    flood = bytes(10 * 1024)
    with serving(emulator):
        link = emulator.links["arm"]
        assert isinstance(link, PtyBacked)
        _wait(lambda: link.reader is not None, "the reader starts")
        with stalled(emulator):
            with serial.Serial(link.path, 1_000_000, timeout=0) as port:
                port.write(flood)
            _wait(lambda: _reader_bytes(link) == len(flood), "the reader reads the flood")
        _wait(lambda: link.stats()["bytes_in"] == ADAPTER_BUFFER_BYTES, "4 KiB enter")
    stats = link.stats()
    assert stats["overrun"] == len(flood) - ADAPTER_BUFFER_BYTES
    assert stats["bytes_in"] == ADAPTER_BUFFER_BYTES


@pytest.mark.parametrize("name", ["arm", "palm"])
def test_a_host_that_flushes_its_output_is_told_once_and_counted(name: str) -> None:
    """Linux may throw away what a client flushes right after writing (its pty buffer, before
    the kernel hands the bytes over): the loss is never silent.  Flushes are counted (Linux
    reports the ones between two reads of the port as one), the first is said in one line,
    and the bytes that did arrive are the client's own (no packet-mode header among them)."""
    emulator = _emulator(name)
    told: list[str] = []
    emulator.pacer.on_notice = told.append
    packet = dxl.make_ping(0xFE).encode()
    with serving(emulator):
        link = _read_at_once(emulator, name)
        with serial.Serial(link.path, 1_000_000, timeout=0) as port:
            for _ in range(20):
                port.write(packet)
                port.reset_output_buffer()
            _wait(lambda: link.host_flushes >= 1, "the flushes are seen")
            port.write(packet)  # a last one, not flushed: it arrives
            _wait(lambda: link.stats()["bytes_in"] % len(packet) == 0
                  and link.stats()["bytes_in"] > 0 and _reader_bytes(link) > 0,
                  "the last write arrives")
        _wait(lambda: link.stats()["bytes_in"] == _reader_bytes(link), "every byte enters")
    assert 1 <= link.stats()["host_flushes"] <= 20
    flushed = [line for line in told if "flushed its output" in line]
    assert len(flushed) == 1 and f"on the {name} port" in flushed[0] and "\n" not in flushed[0]
    assert _reader_bytes(link) % len(packet) == 0  # whole pings only: no header byte kept
