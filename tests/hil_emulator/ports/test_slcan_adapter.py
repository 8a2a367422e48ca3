"""Tests for hil_emulator.ports.slcan_adapter against python-can's unmodified slcan interface."""

from __future__ import annotations

import fcntl
import struct
import termios
import threading
import time
from collections.abc import Callable, Iterator

import can
import pytest
import serial

from hil_emulator.ports.pty_port import PtyPort
from hil_emulator.ports.slcan_adapter import SlcanAdapter

#: Longest a test waits for bytes or frames that must come (s of wall time): a hang guard,
#: not a timing bound (a read returns as soon as its bytes are there; a loaded machine's
#: pty hand-offs take tens of ms).
HANG_GUARD_S = 30.0


class AdapterLoop:
    """Runs adapter.poll() in a bounded background thread, collecting frames."""

    def __init__(self, adapter: SlcanAdapter) -> None:
        self.adapter = adapter
        self.frames: list[tuple[int, bytes]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            got = self.adapter.poll()
            if got:
                with self._lock:
                    self.frames.extend(got)
            time.sleep(0.0005)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=HANG_GUARD_S)
        assert not self._thread.is_alive()

    def wait_frames(self, n: int, timeout: float = HANG_GUARD_S) -> list[tuple[int, bytes]]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                if len(self.frames) >= n:
                    return list(self.frames)
            time.sleep(0.001)
        with self._lock:
            return list(self.frames)

    def wait_until(self, cond: Callable[[], bool], timeout: float = HANG_GUARD_S) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if cond():
                return True
            time.sleep(0.001)
        return bool(cond())


@pytest.fixture
def rig() -> Iterator[tuple[PtyPort, SlcanAdapter, AdapterLoop]]:
    with PtyPort() as port:
        adapter = SlcanAdapter(port)
        loop = AdapterLoop(adapter)
        loop.start()
        try:
            yield port, adapter, loop
        finally:
            loop.stop()


def _readable(fd: int) -> int:
    """Bytes waiting to be read on ``fd`` (``FIONREAD``)."""
    return int(struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0])


def _open_bus(port: PtyPort) -> can.BusABC:
    return can.Bus(interface="slcan", channel=port.path, bitrate=1_000_000, sleep_after_open=0)


def test_python_can_bus_round_trip(rig: tuple[PtyPort, SlcanAdapter, AdapterLoop]) -> None:
    port, adapter, loop = rig
    bus = _open_bus(port)
    try:
        assert loop.wait_until(lambda: adapter.is_open)
        assert adapter.bitrate == 1_000_000
        payload = b"\x42\x0a\x00\x00\x01\x61\x2d"
        bus.send(can.Message(arbitration_id=0x10A, data=payload, is_extended_id=False))
        assert loop.wait_frames(1) == [(0x10A, payload)]

        assert adapter.send_frame(0x18A, b"\x01\x02\xfe")
        msg = bus.recv(timeout=HANG_GUARD_S)
        assert msg is not None
        assert msg.arbitration_id == 0x18A and not msg.is_extended_id
        assert bytes(msg.data) == b"\x01\x02\xfe"

        bus.send(can.Message(arbitration_id=0x1ABCDEF0, data=b"", is_extended_id=True))
        assert loop.wait_frames(2)[1] == (0x1ABCDEF0, b"")
        assert adapter.send_frame(0x12345678, b"\xaa")
        msg = bus.recv(timeout=HANG_GUARD_S)
        assert msg is not None and msg.is_extended_id
        assert msg.arbitration_id == 0x12345678 and bytes(msg.data) == b"\xaa"

        assert bus.get_version(1) == (10, 13)  # type: ignore[attr-defined]
        assert bus.get_serial_number(1) == "A123"  # type: ignore[attr-defined]
    finally:
        bus.shutdown()
    assert loop.wait_until(lambda: not adapter.is_open)
    assert not adapter.send_frame(0x18A, b"\x00")


def _exchange(client: serial.Serial, cmd: bytes, n: int) -> bytes:
    client.write(cmd)
    return client.read(n)


def test_raw_commands_and_garbage(rig: tuple[PtyPort, SlcanAdapter, AdapterLoop]) -> None:
    port, adapter, loop = rig
    with serial.Serial(port.path, 115200, timeout=HANG_GUARD_S) as c:
        assert _exchange(c, b"t10A1FF\r", 1) == b"\a"  # channel closed
        assert _exchange(c, b"S9\r", 1) == b"\a"
        assert _exchange(c, b"S6\r", 1) == b"\r"
        assert adapter.bitrate == 500_000
        assert _exchange(c, b"V\r", 6) == b"V1013\r"
        assert _exchange(c, b"v\r", 7) == b"vSTM32\r"
        assert _exchange(c, b"N\r", 6) == b"NA123\r"
        assert _exchange(c, b"O\r", 1) == b"\r"
        assert _exchange(c, b"O\r", 1) == b"\a"  # already open
        assert _exchange(c, b"S8\r", 1) == b"\a"  # bitrate change while open
        assert _exchange(c, b"F\r", 4) == b"F00\r"
        for garbage in (
            b"hello\r",
            b"t10A\r",
            b"t10A2FF\r",
            b"t8001AA\r",  # 0x800 is not an 11-bit id
            b"tXYZ1AA\r",
            b"t10A9" + b"00" * 9 + b"\r",
            b"T1234567\r",
            b"\xff\xfe\r",
        ):
            assert _exchange(c, garbage, 1) == b"\a", garbage
        assert _exchange(c, b"t7FF0\r", 2) == b"z\r"
        assert _exchange(c, b"T1FFFFFFF201AB\r", 2) == b"Z\r"
        assert loop.wait_frames(2) == [(0x7FF, b""), (0x1FFFFFFF, b"\x01\xab")]
        assert _exchange(c, b"C\r", 1) == b"\r"
        assert not adapter.is_open
        assert adapter.errors >= 10


def test_listen_only_rejects_transmit(rig: tuple[PtyPort, SlcanAdapter, AdapterLoop]) -> None:
    port, adapter, loop = rig
    with serial.Serial(port.path, 115200, timeout=HANG_GUARD_S) as c:
        assert _exchange(c, b"L\r", 1) == b"\r"
        assert adapter.is_open and adapter.listen_only
        assert _exchange(c, b"t1001AA\r", 1) == b"\a"
        assert adapter.send_frame(0x100, b"\x05")
        assert c.read(8) == b"t100105\r"


def test_send_frame_validation() -> None:
    with PtyPort() as port:
        adapter = SlcanAdapter(port)
        assert not adapter.send_frame(0x10, b"")  # closed: nothing sent
        assert port.read_available() == b""
        with pytest.raises(ValueError):
            adapter.send_frame(0x10, bytes(9))
        with pytest.raises(ValueError):
            adapter.send_frame(0x800, b"", extended=False)
        with pytest.raises(ValueError):
            adapter.send_frame(0x2000_0000, b"")


def test_unterminated_garbage_is_bounded() -> None:
    with PtyPort() as port, serial.Serial(port.path, 115200, timeout=HANG_GUARD_S) as c:
        adapter = SlcanAdapter(port)
        c.write(b"x" * 200)
        c.flush()
        deadline = time.monotonic() + HANG_GUARD_S
        while _readable(port.fileno()) < 200 and time.monotonic() < deadline:
            time.sleep(0.001)  # the pty hands the bytes over (a kernel worker) when it runs
        assert adapter.poll() == []
        assert adapter.errors == 1  # one BEL, buffer dropped instead of growing
        assert c.read(1) == b"\a"
        c.write(b"V\r")
        deadline = time.monotonic() + HANG_GUARD_S
        reply = b""
        while time.monotonic() < deadline and not reply.endswith(b"\r"):
            adapter.poll()
            reply += c.read(c.in_waiting or 1)
        assert reply == b"V1013\r"
