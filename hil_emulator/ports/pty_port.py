"""The emulator's end of a virtual serial port (a Linux pty).

A client (pyserial, dynamixel-sdk, python-can's ``slcan``) opens :attr:`PtyPort.path`, the
slave device; the emulator reads and writes the master end.  Notes:

* both ends are put in raw mode right after creation;
* the emulator keeps its own slave fd open, so reading the master never raises ``EIO`` when a
  client closes the port (dynamixel-sdk reopens it on every baud change);
* a pty does not enforce a baud rate, so pacing is done here: :meth:`PtyPort.write_paced`
  computes when the bytes would have finished on a real line and :class:`PacedWriter` holds
  bytes back and releases them as (injected) time passes;
* the master is in packet mode (``TIOCPKT``), so a client's ``tcflush(TCOFLUSH)``
  (pyserial's ``reset_output_buffer()``) is seen: Linux throws away what the client wrote
  and its kernel worker has not yet moved to the emulator's end, which a USB adapter would
  have sent.  No reader can take those bytes first; :attr:`PtyPort.host_flushes` counts the
  flushes and :attr:`PtyPort.on_host_flush` is told of each, so the loss is never silent;
* a pty cannot refuse a second client: ``TIOCEXCL`` would also lock out the first one
  (the emulator holds the slave open itself) and root ignores it.  Two programs that open
  one port both receive part of its replies; ``serial.Serial(path, exclusive=True)`` in
  every client (an advisory ``flock``) is how to make a second opener fail.
"""

from __future__ import annotations

import errno
import fcntl
import os
import struct
import termios
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from protocol.topology import BITS_PER_CHAR

#: Most bytes :meth:`PtyPort.read_available` takes in one call (a pty holds about 20 kB).
READ_LIMIT = 65_536
#: Packet mode: the first byte of every read from the master says what follows.
_TIOCPKT_DATA = 0x00
_TIOCPKT_FLUSHWRITE = 0x02


def byte_time_s(baud: int) -> float:
    """Seconds one byte occupies on a line at ``baud`` (8N1: :data:`BITS_PER_CHAR` bits)."""
    if baud <= 0:
        raise ValueError(f"baud must be positive, got {baud}")
    return BITS_PER_CHAR / baud


class PtyPort:
    """A pty whose slave path clients open as a serial port."""

    def __init__(self, baud: int = 1_000_000) -> None:
        self._master: int | None = None
        self._slave: int | None = None
        byte_time_s(baud)  # validate
        self.baud = baud
        self._path: str | None = None
        self._line_free_at = 0.0
        self.dropped = 0  # bytes discarded because the pty buffer was full
        #: Times the client was seen to flush its output (``tcflush(TCOFLUSH)``; Linux
        #: reports the flushes between two reads of the master as one): bytes it had
        #: written may have been discarded before the emulator could read them.
        self.host_flushes = 0
        #: Told (on whichever thread reads the port) of each such flush, or None.
        self.on_host_flush: Callable[[], None] | None = None

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> PtyPort:
        if self._master is not None:
            return self
        master, slave = os.openpty()
        try:
            tty.setraw(master)
            tty.setraw(slave)
            fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
            os.set_blocking(master, False)
            path = os.ttyname(slave)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        self._master, self._slave, self._path = master, slave, path
        return self

    def close(self) -> None:
        master, slave = self._master, self._slave
        self._master = self._slave = None
        for fd in (master, slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass

    @property
    def is_open(self) -> bool:
        return self._master is not None

    def __enter__(self) -> PtyPort:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

    # -- accessors -------------------------------------------------------------------------
    @property
    def path(self) -> str:
        """Slave device name (e.g. ``/dev/pts/7``); kept after :meth:`close`."""
        if self._path is None:
            raise RuntimeError("PtyPort is not open")
        return self._path

    def fileno(self) -> int:
        """Master fd, for ``select``/``selectors``."""
        return self._require_master()

    def _require_master(self) -> int:
        if self._master is None:
            raise RuntimeError("PtyPort is not open")
        return self._master

    # -- I/O ---------------------------------------------------------------------------------
    def unpacket(self, packet: bytes) -> bytes:
        """The client's bytes in one read of the master (packet mode): a data packet's
        payload, or ``b""`` for a status packet (a flush of the client's output is counted
        in :attr:`host_flushes` and told to :attr:`on_host_flush`)."""
        if not packet:
            return b""
        if packet[0] == _TIOCPKT_DATA:
            return packet[1:]
        if packet[0] & _TIOCPKT_FLUSHWRITE:
            self.host_flushes += 1
            if self.on_host_flush is not None:
                self.on_host_flush()
        return b""

    def read_available(self, max_bytes: int = READ_LIMIT) -> bytes:
        """What the client has written so far, at most ``max_bytes``; ``b""`` when nothing
        (never blocks).  The limit keeps one call short however fast a client writes."""
        fd = self._require_master()
        chunks: list[bytes] = []
        left = max_bytes
        while left > 0:
            try:
                packet = os.read(fd, min(4096, left) + 1)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EIO:  # no slave open at all; cannot happen while we hold one
                    break
                raise
            if not packet:
                break
            chunk = self.unpacket(packet)
            chunks.append(chunk)
            left -= len(chunk)
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        """Write immediately.  Returns bytes written; bytes that do not fit in the pty buffer
        (nobody reading) are dropped and counted in :attr:`dropped`, as on a real line."""
        fd = self._require_master()
        view = memoryview(bytes(data))
        written = 0
        while written < len(view):
            try:
                n = os.write(fd, view[written:])
            except BlockingIOError:
                break
            if n <= 0:
                break
            written += n
        self.dropped += len(view) - written
        return written

    def transmit_end_s(self, nbytes: int, now_s: float) -> float:
        """When ``nbytes`` queued at ``now_s`` would finish on the line (updates line state)."""
        start = max(now_s, self._line_free_at)
        end = start + nbytes * byte_time_s(self.baud)
        self._line_free_at = end
        return end

    def write_paced(self, data: bytes, now_s: float) -> float:
        """Write ``data`` now and return the time its last byte would have finished on a real
        line at :attr:`baud` (after anything still "on the line" from earlier calls).  The
        caller's real-time loop should not send anything that depends on it before then."""
        self.write(data)
        return self.transmit_end_s(len(data), now_s)


class PacedWriter:
    """Holds bytes and releases them to a :class:`PtyPort` no faster than its baud rate.

    Byte ``i`` of a burst queued when the line is free at ``t0`` is released at
    ``t0 + (i + 1) * 10 / baud``, i.e. only once it would have been fully transmitted.
    """

    def __init__(self, port: PtyPort) -> None:
        self.port = port
        self._pending: deque[int] = deque()
        self._line_time = 0.0  # when the last released byte finished on the line
        self.released = 0

    @property
    def pending(self) -> int:
        return len(self._pending)

    def queue(self, data: bytes, now_s: float) -> None:
        if not self._pending:
            self._line_time = max(self._line_time, now_s)
        self._pending.extend(data)

    def releasable(self, now_s: float) -> int:
        """How many pending bytes have finished transmission by ``now_s``."""
        if not self._pending:
            return 0
        n = int((now_s - self._line_time) / byte_time_s(self.port.baud) + 1e-9)
        return max(0, min(n, len(self._pending)))

    def pump(self, now_s: float) -> bytes:
        """Release the bytes due by ``now_s``; returns what was written."""
        n = self.releasable(now_s)
        if n == 0:
            return b""
        out = bytes(self._pending.popleft() for _ in range(n))
        self._line_time += n * byte_time_s(self.port.baud)
        self.port.write(out)
        self.released += n
        return out

    def next_release_s(self) -> float | None:
        """When the next pending byte becomes due, or None when nothing is pending."""
        if not self._pending:
            return None
        return self._line_time + byte_time_s(self.port.baud)


def make_link(link_dir: str | os.PathLike[str], name: str, port: PtyPort) -> Path:
    """Create (or replace a stale) symlink ``link_dir/name`` -> ``port.path``."""
    directory = Path(link_dir)
    directory.mkdir(parents=True, exist_ok=True)
    link = directory / name
    if link.exists() and not link.is_symlink():
        raise FileExistsError(f"{link} exists and is not a symlink")
    tmp = directory / f".{name}.tmp{os.getpid()}"
    if tmp.is_symlink():
        tmp.unlink()
    tmp.symlink_to(port.path)
    os.replace(tmp, link)  # atomic replacement of any stale link
    return link


def remove_link(link_dir: str | os.PathLike[str], name: str, port: PtyPort) -> bool:
    """Remove the symlink ``link_dir/name`` if it still points to ``port``'s pty; True if
    it did.  A link re-pointed elsewhere (another emulator's) is left alone."""
    link = Path(link_dir) / name
    try:
        if not link.is_symlink() or os.readlink(link) != port.path:
            return False
        link.unlink()
    except FileNotFoundError:
        return False
    return True


def remove_links(link_dir: str | os.PathLike[str], port: PtyPort) -> list[Path]:
    """Remove the symlinks in ``link_dir`` that still point to ``port``'s pty.

    Links re-pointed elsewhere (e.g. by another emulator instance) are left alone."""
    directory = Path(link_dir)
    removed: list[Path] = []
    if not directory.is_dir():
        return removed
    target = port.path
    for entry in directory.iterdir():
        if entry.is_symlink() and os.readlink(entry) == target:
            try:
                entry.unlink()
            except FileNotFoundError:
                continue
            removed.append(entry)
    return removed
