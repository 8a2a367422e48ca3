"""Tests for hil_emulator.ports.pty_port (real ptys, pyserial, dynamixel-sdk)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
import serial

from hil_emulator.ports.pty_port import PacedWriter, PtyPort, byte_time_s, make_link, remove_links

#: Longest a test waits for bytes that must come (s of wall time): a hang guard, not a
#: timing bound (reads return as soon as the bytes are there; on a loaded machine a pty's
#: hand-off, done by a kernel worker, can take tens of ms).
HANG_GUARD_S = 30.0


def _read_for(port: PtyPort, n: int, timeout: float = HANG_GUARD_S) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        got += port.read_available()
        if len(got) < n:
            time.sleep(0.001)
    return got


@pytest.fixture
def port():
    with PtyPort() as p:
        yield p


def test_open_properties(port: PtyPort) -> None:
    assert port.is_open
    assert port.path.startswith("/dev/")
    assert isinstance(port.fileno(), int)
    assert port.read_available() == b""


def test_pyserial_both_directions(port: PtyPort) -> None:
    with serial.Serial(port.path, 1_000_000, timeout=HANG_GUARD_S) as client:
        client.write(b"\xff\xff\x01\x02\x01\xfb")
        assert _read_for(port, 6) == b"\xff\xff\x01\x02\x01\xfb"
        assert port.write(b"hello") == 5
        assert client.read(5) == b"hello"


def test_client_close_and_reopen(port: PtyPort) -> None:
    client = serial.Serial(port.path, 57_600, timeout=HANG_GUARD_S)
    client.write(b"abc")
    assert _read_for(port, 3) == b"abc"
    client.close()
    assert port.read_available() == b""  # no EIO with the client gone
    assert port.read_available() == b""
    with serial.Serial(port.path, 1_000_000, timeout=HANG_GUARD_S) as client2:
        client2.write(b"xyz")
        assert _read_for(port, 3) == b"xyz"
        port.write(b"ok")
        assert client2.read(2) == b"ok"


def test_dynamixel_sdk_port_handler(port: PtyPort) -> None:
    dxl = pytest.importorskip("dynamixel_sdk")
    handler = dxl.PortHandler(port.path)
    assert handler.openPort()
    try:
        assert handler.setBaudRate(1_000_000)  # closes and reopens the pty
        assert port.read_available() == b""
        packet = [0xFF, 0xFF, 0x01, 0x02, 0x01, 0xFB]
        assert handler.writePort(packet) == len(packet)
        assert _read_for(port, len(packet)) == bytes(packet)
    finally:
        handler.closePort()
    assert port.read_available() == b""


def test_close_idempotent() -> None:
    p = PtyPort().open()
    path = p.path
    p.close()
    p.close()
    assert not p.is_open
    assert p.path == path
    with pytest.raises(RuntimeError):
        p.read_available()


def test_write_paced_computation(port: PtyPort) -> None:
    port.baud = 57_600
    n = 12
    end = port.write_paced(bytes(n), now_s=100.0)
    assert end == pytest.approx(100.0 + n * 10 / 57_600)
    # a second burst queued before the first finished starts after it
    end2 = port.write_paced(bytes(3), now_s=100.0)
    assert end2 == pytest.approx(end + 3 * 10 / 57_600)
    # after the line went idle, timing restarts from now
    assert port.write_paced(b"\x01", now_s=200.0) == pytest.approx(200.0 + 10 / 57_600)


@pytest.mark.parametrize("baud", [9_600, 57_600, 1_000_000])
def test_paced_writer_never_faster_than_baud(baud: int) -> None:
    with PtyPort(baud=baud) as p, serial.Serial(p.path, baud, timeout=HANG_GUARD_S) as client:
        writer = PacedWriter(p)
        n = 40
        t0 = 10.0
        writer.queue(bytes(range(n)), now_s=t0)
        bt = byte_time_s(baud)
        released = 0
        # step an injected clock in irregular increments
        t = t0
        step = bt * 0.37
        while writer.pending:
            t += step
            released += len(writer.pump(t))
            # never more bytes than could have been transmitted by t
            assert released <= (t - t0) / bt + 1e-6
            # and nothing held back longer than necessary
            assert released >= min(n, int((t - t0) / bt - 1e-6))
        assert released == n
        assert t - t0 >= n * bt - 1e-12
        assert writer.next_release_s() is None
        assert client.read(n) == bytes(range(n))


def test_paced_writer_nothing_before_first_byte_time(port: PtyPort) -> None:
    writer = PacedWriter(port)
    writer.queue(b"abc", now_s=0.0)
    bt = byte_time_s(port.baud)
    assert writer.pump(bt * 0.99) == b""
    assert writer.next_release_s() == pytest.approx(bt)
    assert writer.pump(bt * 2.0) == b"ab"
    assert writer.pump(1.0) == b"c"


def test_symlinks(tmp_path: Path, port: PtyPort) -> None:
    link_dir = tmp_path / "dev"
    link = make_link(link_dir, "ttyHAND0", port)
    assert link.is_symlink() and os.readlink(link) == port.path
    # stale link gets replaced
    (link_dir / "ttyCAN0").symlink_to("/dev/pts/does-not-exist")
    make_link(link_dir, "ttyCAN0", port)
    assert os.readlink(link_dir / "ttyCAN0") == port.path
    # a link re-pointed elsewhere is not ours any more
    with PtyPort() as other:
        make_link(link_dir, "ttyOTHER", other)
        removed = remove_links(link_dir, port)
        assert sorted(p.name for p in removed) == ["ttyCAN0", "ttyHAND0"]
        assert (link_dir / "ttyOTHER").is_symlink()
    # a regular file is never clobbered
    (link_dir / "plain").write_text("x")
    with pytest.raises(FileExistsError):
        make_link(link_dir, "plain", port)
    assert remove_links(tmp_path / "missing", port) == []
