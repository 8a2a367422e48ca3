"""Transports as a bench user meets them: loop://, a real pty, CAN (virtual and SLCAN),
the URL registry, closing, and a USB adapter unplugged and plugged back in."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from host.errors import HostError, TransportError, UsageError
from host.transports.base import Transport, open_transport, schemes, url_options, url_scheme
from host.transports.can_bus import CanTransport
from host.transports.serial_port import SerialTransport
from protocol.canlink import can_id
from protocol.framing import encode_frame, parse_frame
from protocol.stream import decode_all
from protocol.topology import ADDR_HOST, ADDR_PALM

#: A 27-byte hand frame (5 header, 20 payload, 2 CRC): CAN frames of 8 + 8 + 8 + 3 bytes.
FRAME = encode_frame(ADDR_PALM, 0x42, bytes(range(20)))
REPLY = encode_frame(ADDR_HOST, 0x42, bytes(range(100, 117)))


class Pty:
    """A pty pair: the transport opens the slave by name; the test plays the device on
    the master.  :meth:`unplug` closes both of the test's ends, as a USB adapter
    disappearing does."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave: int | None = slave

    def release_slave(self) -> None:
        """Close the test's own slave fd (once the transport holds the port)."""
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None

    def read(self, n: int, timeout: float = 1.0) -> bytes:
        """Up to ``n`` bytes the transport sent, waiting at most ``timeout`` s."""
        out = b""
        deadline = time.monotonic() + timeout
        os.set_blocking(self.master, False)
        while len(out) < n and time.monotonic() < deadline:
            try:
                out += os.read(self.master, n - len(out))
            except BlockingIOError:
                time.sleep(0.001)
        return out

    def unplug(self) -> None:
        self.release_slave()
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


@pytest.fixture
def pty() -> Iterator[Pty]:
    p = Pty()
    yield p
    p.unplug()


def _recv_until(t: Transport, n: int, timeout: float = 1.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        out += t.recv(0.05)
    return out


# --- loop:// ------------------------------------------------------------------------------

def test_loop_url_echoes_frames_and_reports_its_url() -> None:
    with open_transport("loop://") as t:
        assert isinstance(t, SerialTransport)
        assert t.url == "loop://"
        t.send(FRAME)
        assert _recv_until(t, len(FRAME)) == FRAME
        assert t.recv(0.0) == b""


def test_loop_url_takes_baud_and_keeps_pyserial_options() -> None:
    with open_transport("loop://?baud=115200&logging=debug") as t:
        assert isinstance(t, SerialTransport)
        assert t.baud == 115_200
        assert t.serial.baudrate == 115_200
        t.send(b"\x01")
        assert _recv_until(t, 1) == b"\x01"


@pytest.mark.parametrize("baud", ["-1", "0", "99999999999", "abc", "1e400"])
def test_a_baud_rate_no_serial_port_runs_at_is_a_usage_error(baud: str) -> None:
    """``?baud=-1`` reached pyserial and came back as "check the path" (exit 1)."""
    with pytest.raises(UsageError, match="baud"):
        open_transport(f"/dev/no-such-port?baud={baud}")


# --- a real pty ---------------------------------------------------------------------------

def test_pty_bytes_both_ways(pty: Pty) -> None:
    with SerialTransport(pty.path) as t:
        pty.release_slave()
        t.send(FRAME)
        assert pty.read(len(FRAME)) == FRAME
        os.write(pty.master, REPLY[:5])
        os.write(pty.master, REPLY[5:])
        got = _recv_until(t, len(REPLY))
        assert parse_frame(got) == parse_frame(REPLY)


def test_pty_recv_timeout_on_the_wall_clock(pty: Pty) -> None:
    with SerialTransport(pty.path) as t:
        pty.release_slave()
        start = time.monotonic()
        assert t.recv(0.08) == b""
        waited = time.monotonic() - start
        assert 0.07 <= waited < 0.5
        start = time.monotonic()
        assert t.recv(0.0) == b""
        assert t.recv(-1.0) == b""
        assert time.monotonic() - start < 0.05
        # recv(None) waits for the first bytes however long that takes.
        timer = threading.Timer(0.05, os.write, (pty.master, b"\x5a"))
        start = time.monotonic()  # before the timer starts: its 50 ms cannot begin earlier
        timer.start()
        assert t.recv(None) == b"\x5a"
        assert time.monotonic() - start >= 0.04
        timer.join()


def test_pty_recv_returns_what_arrived_without_waiting_out_the_timeout(pty: Pty) -> None:
    with SerialTransport(pty.path) as t:
        os.write(pty.master, REPLY)
        time.sleep(0.02)
        start = time.monotonic()
        assert t.recv(5.0) == REPLY
        assert time.monotonic() - start < 0.5


def test_path_url_options_set_the_baud(pty: Pty) -> None:
    with open_transport(f"{pty.path}?baud=1000000") as t:
        assert isinstance(t, SerialTransport)
        assert t.baud == 1_000_000 and t.port == pty.path
    with open_transport(f"serial://{pty.path}?baud=57600&exclusive=0") as t:
        assert isinstance(t, SerialTransport)
        assert (t.baud, t.exclusive, t.port) == (57_600, False, pty.path)


def test_unknown_serial_option_is_a_usage_error(pty: Pty) -> None:
    with pytest.raises(UsageError, match="bauds"):
        open_transport(f"{pty.path}?bauds=9600")


def test_exclusive_port_refused_to_this_process_says_it_holds_it(pty: Pty) -> None:
    with SerialTransport(pty.path), pytest.raises(TransportError, match=pty.path) as info:
        SerialTransport(pty.path)
    assert "this program holds it already" in str(info.value)
    assert "another program" not in str(info.value)


def test_exclusive_port_refuses_a_second_program_and_names_it(pty: Pty) -> None:
    with subprocess.Popen(  # closes its pipes when done
            [sys.executable, "-c", "import serial, sys; s = serial.Serial(sys.argv[1], "
             "exclusive=True); print('held', flush=True); sys.stdin.read()", pty.path],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) as holder:
        try:
            assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
            with pytest.raises(TransportError, match=pty.path) as info:
                SerialTransport(pty.path)
            assert "another program (python" in str(info.value)
            assert f"pid {holder.pid})" in str(info.value)
            assert "?exclusive=0" in str(info.value)
        finally:
            holder.kill()


def test_missing_port_names_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "ttyUSB9"
    with pytest.raises(TransportError, match="ttyUSB9") as info:
        open_transport(str(missing))
    assert isinstance(info.value, ConnectionError)


# --- unplugging and plugging back in -----------------------------------------------------

def test_unplugged_port_raises_transport_error_on_recv_and_send(pty: Pty) -> None:
    t = SerialTransport(pty.path)
    try:
        pty.unplug()
        for call in (lambda: t.recv(0.2), lambda: t.recv(None), lambda: t.recv(0.0),
                     lambda: t.send(FRAME)):
            start = time.monotonic()
            with pytest.raises(TransportError) as info:
                call()
            assert time.monotonic() - start < 0.5
            message = str(info.value)
            assert pty.path in message and "unplugged" in message and "reopen" in message
            assert isinstance(info.value, ConnectionError)
    finally:
        t.close()


def test_reopen_after_the_device_comes_back_through_a_symlink(tmp_path: Path) -> None:
    link = tmp_path / "palm"
    first = Pty()
    link.symlink_to(first.path)
    t = SerialTransport(str(link))
    try:
        first.release_slave()
        t.send(b"\x01")
        assert first.read(1) == b"\x01"
        first.unplug()
        with pytest.raises(TransportError):
            t.recv(0.1)
        # Still gone: reopen says so and leaves the transport closed.
        with pytest.raises(TransportError, match="palm"):
            t.reopen()
        assert t.closed
        with pytest.raises(TransportError, match="closed"):
            t.send(b"\x02")
        # The emulator (or the adapter) comes back on a new pty; the link is re-pointed.
        second = Pty()
        try:
            link.unlink()
            link.symlink_to(second.path)
            t.reopen()
            assert not t.closed
            second.release_slave()
            t.send(b"\x03")
            assert second.read(1) == b"\x03"
            os.write(second.master, b"\x04")
            assert _recv_until(t, 1) == b"\x04"
        finally:
            t.close()
            second.unplug()
    finally:
        t.close()


# --- lifetime -----------------------------------------------------------------------------

def test_close_is_idempotent_and_send_after_close_fails(pty: Pty) -> None:
    t = open_transport(pty.path)
    with t as same:
        assert same is t
        assert not t.closed
    assert t.closed
    t.close()
    t.close()
    assert "closed" in repr(t)
    with pytest.raises(TransportError, match="closed") as info:
        t.send(b"\x00")
    assert isinstance(info.value, ConnectionError)
    with pytest.raises(TransportError, match="closed"):
        t.recv(0.0)


def test_reopen_after_close(pty: Pty) -> None:
    t = SerialTransport(pty.path)
    t.close()
    t.reopen()
    try:
        pty.release_slave()
        t.send(b"\x07")
        assert pty.read(1) == b"\x07"
    finally:
        t.close()


# --- CAN: python-can virtual --------------------------------------------------------------

@pytest.fixture
def virtual_channel(request: pytest.FixtureRequest) -> str:
    return f"hostpolish-{request.node.name}-{os.getpid()}"


def test_can_virtual_segments_into_palm_ids(virtual_channel: str) -> None:
    palm = can.Bus(interface="virtual", channel=virtual_channel)
    try:
        with open_transport(f"can://virtual/{virtual_channel}") as t:
            assert isinstance(t, CanTransport) and t.node == 0x0A
            t.send(FRAME)
            got = []
            while (m := palm.recv(0.5)) is not None:
                got.append(m)
            assert [m.arbitration_id for m in got] == [0x10A] * 4
            assert [len(m.data) for m in got] == [8, 8, 8, 3]
            assert all(not m.is_extended_id for m in got)
            assert b"".join(bytes(m.data) for m in got) == FRAME
            # Replies: 0x18A, cut anywhere; other ids are not this palm's and are ignored.
            palm.send(can.Message(arbitration_id=0x18B, data=b"\xaa" * 8,
                                  is_extended_id=False))
            for i in range(0, len(REPLY), 3):
                palm.send(can.Message(arbitration_id=can_id(0x0A, to_host=True),
                                      data=REPLY[i:i + 3], is_extended_id=False))
            palm.send(can.Message(arbitration_id=0x10A, data=b"\xbb", is_extended_id=False))
            data = _recv_until(t, len(REPLY))
            assert [f.to_bytes() for f in decode_all(data)] == [REPLY]
            start = time.monotonic()
            assert t.recv(0.05) == b""
            assert 0.04 <= time.monotonic() - start < 0.5
    finally:
        palm.shutdown()


def test_can_virtual_node_option(virtual_channel: str) -> None:
    palm = can.Bus(interface="virtual", channel=virtual_channel)
    try:
        with open_transport(f"can://virtual/{virtual_channel}?node=3") as t:
            t.send(b"\x01\x02")
            m = palm.recv(0.5)
            assert m is not None and m.arbitration_id == 0x103
            palm.send(can.Message(arbitration_id=0x183, data=b"\x09", is_extended_id=False))
            assert _recv_until(t, 1) == b"\x09"
    finally:
        palm.shutdown()


def test_can_url_without_channel_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="can://INTERFACE/CHANNEL"):
        open_transport("can://virtual")


def test_can_send_after_close(virtual_channel: str) -> None:
    t = open_transport(f"can://virtual/{virtual_channel}")
    t.close()
    t.close()
    with pytest.raises(TransportError, match="closed"):
        t.send(FRAME)


# --- CAN: the emulator's SLCAN adapter ----------------------------------------------------

class AdapterThread:
    """Polls an emulated SLCAN adapter and echoes each hand frame back as the palm would."""

    def __init__(self) -> None:
        from hil_emulator.ports.pty_port import PtyPort
        from hil_emulator.ports.slcan_adapter import SlcanAdapter

        self.port = PtyPort().open()
        self.adapter = SlcanAdapter(self.port)
        self.received: list[tuple[int, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.received.extend(self.adapter.poll())
            time.sleep(0.0005)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.port.close()


@pytest.fixture
def slcan() -> Iterator[AdapterThread]:
    a = AdapterThread()
    yield a
    a.stop()


def test_can_slcan_against_the_emulated_adapter(slcan: AdapterThread) -> None:
    with open_transport(f"can://slcan/{slcan.port.path}") as t:
        deadline = time.monotonic() + 2.0
        while not slcan.adapter.is_open and time.monotonic() < deadline:
            time.sleep(0.005)
        assert slcan.adapter.is_open and slcan.adapter.bitrate == 1_000_000
        t.send(FRAME)
        deadline = time.monotonic() + 2.0
        while len(slcan.received) < 4 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert [i for i, _ in slcan.received] == [0x10A] * 4
        assert b"".join(d for _, d in slcan.received) == FRAME
        for i in range(0, len(REPLY), 8):
            assert slcan.adapter.send_frame(0x18A, REPLY[i:i + 8])
        assert [f.to_bytes() for f in decode_all(_recv_until(t, len(REPLY)))] == [REPLY]
    deadline = time.monotonic() + 2.0
    while slcan.adapter.is_open and time.monotonic() < deadline:
        time.sleep(0.005)
    assert not slcan.adapter.is_open  # close sent C


def test_can_slcan_missing_device_is_a_transport_error(tmp_path: Path) -> None:
    with pytest.raises(TransportError, match="slcan"):
        open_transport(f"can://slcan/{tmp_path / 'ttyACM7'}")


# --- the URL registry ---------------------------------------------------------------------

def test_unknown_scheme_lists_the_known_ones() -> None:
    with pytest.raises(UsageError) as info:
        open_transport("bogus://x")
    message = str(info.value)
    assert "'bogus'" in message
    for scheme in ("serial", "loop", "socket", "can", "emu"):
        assert scheme in message


def test_empty_url_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="/dev/ttyUSB0"):
        open_transport("")


def test_schemes_include_builtins_and_the_emulator_entry_point() -> None:
    known = schemes()
    assert known == sorted(known)
    assert {"serial", "loop", "socket", "rfc2217", "spy", "can", "emu"} <= set(known)


def test_url_helpers() -> None:
    assert url_scheme("/dev/ttyUSB0") == "serial"
    assert url_scheme("./robot/palm?baud=9600") == "serial"
    assert url_scheme("CAN://virtual/x") == "can"
    assert url_options("/dev/ttyUSB0?baud=9600") == {"baud": "9600"}
    assert url_options("can://virtual/x?node=3&bitrate=500000") == {"node": "3",
                                                                     "bitrate": "500000"}
    assert url_options("/dev/ttyUSB0") == {}


def test_emu_entry_point_opens_the_emulator_in_process() -> None:
    with open_transport("emu://arm/arm?ready=0&physics=0&name=test_transports") as t:
        assert type(t).__name__ == "EmulatorTransport"
        start = t.now()
        assert t.recv(0.01) == b""
        assert t.now() - start == pytest.approx(0.01, abs=1e-4)  # simulation seconds
    with pytest.raises(UsageError, match="has no 'palm' link"):
        open_transport("emu://arm/palm?ready=0&physics=0&name=test_transports")
    for url, says in (("emu://nosuch/palm", "unknown emulator configuration 'nosuch'"),
                      ("emu://arm/arm?bogus=1", "unknown emulator options"),
                      ("emu://arm/arm?seed=abc", "seed='abc' is not an integer")):
        with pytest.raises(UsageError, match=says):  # a bad URL: exit 2 in the CLIs
            open_transport(url)


def test_transport_errors_are_host_errors() -> None:
    assert issubclass(TransportError, HostError) and issubclass(TransportError,
                                                               ConnectionError)
    assert issubclass(UsageError, ValueError)
