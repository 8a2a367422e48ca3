"""A thread that takes a host port's bytes the moment they arrive, as a USB adapter does.

A USB-serial adapter's driver takes every byte a program writes at once; bytes that wait
in a pty until the emulator's loop next looks can be thrown away by the program's own
``tcflush(TCOFLUSH)`` (pyserial's ``reset_output_buffer()``, a habit of Dynamixel
libraries), or pile up behind a full pty while the simulation catches up.  In real time each
pty therefore has a :class:`PortReader`: a thread blocked on the master descriptor that
reads whatever arrives, stamps it with its arrival time (``time.monotonic()``, s) and queues
it for the simulation thread, which takes it with :meth:`PortReader.take` and hands it to
the wire model at the simulation time of its arrival.  The queue is bounded (``room``, like
an adapter's buffer); bytes beyond it are an overrun, counted in :attr:`PortReader.overrun`.

The simulation thread waits on :meth:`PortReader.fileno` (a pipe the reader writes one byte
to per chunk) instead of the pty.  Linux itself still throws away what a program flushes
before the kernel has moved it from its pty buffer to the emulator's end (a few µs after
``write()``, done by a kernel worker thread); no reader can take bytes before that.  The
pty is in packet mode, so such a flush is seen (``decode``: the port's
:meth:`~hil_emulator.ports.pty_port.PtyPort.unpacket`, which counts it).
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
from collections import deque
from collections.abc import Callable

from host.scheduling import Scheduling, adopt, current

#: Most bytes read from the pty in one go.
READ_CHUNK = 65_536


class PortReader:
    """Reads the pty master ``fd`` on its own thread until :meth:`stop`.

    ``room()`` says how many more bytes the link accepts now (the adapter buffer's free
    space); called on the reader's thread.  ``decode`` turns what one read returned into
    the client's bytes (a packet-mode pty's :meth:`~hil_emulator.ports.pty_port.PtyPort.unpacket`).
    The thread takes the real-time scheduling of the thread that creates it
    (:func:`~host.scheduling.adopt`): it holds the interpreter's lock while it
    queues, and the pacing thread must not wait behind it for a normal process's slice.
    """

    def __init__(self, fd: int, room: Callable[[], int], name: str = "port",
                 decode: Callable[[bytes], bytes] | None = None) -> None:
        self._fd = fd
        self._decode = decode
        self._room = room
        self._lock = threading.Lock()
        self._queue: deque[tuple[float, bytes]] = deque()
        self.queued = 0  #: bytes waiting for the simulation thread
        self.overrun = 0  #: bytes that did not fit
        self.bytes_read = 0  #: every byte read from the pty
        self._wake_r, self._wake_w = os.pipe()
        self._stop_r, self._stop_w = os.pipe()
        for fd_ in (self._wake_r, self._wake_w):
            os.set_blocking(fd_, False)
        self._scheduling: Scheduling = current()
        self.scheduling: Scheduling | None = None  #: what the reader thread got (once started)
        self._thread = threading.Thread(target=self._run, name=f"port-reader-{name}",
                                        daemon=True)
        self._thread.start()

    def fileno(self) -> int:
        """Readable while bytes wait in the queue (for the simulation loop's ``select``)."""
        return self._wake_r

    def take(self) -> list[tuple[float, bytes]]:
        """Everything queued, oldest first, as (arrival time s, bytes); empties the queue
        (after :meth:`stop` too)."""
        try:
            while self._wake_r >= 0 and os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass
        with self._lock:
            chunks = list(self._queue)
            self._queue.clear()
            self.queued = 0
        return chunks

    def _run(self) -> None:
        self.scheduling = adopt(self._scheduling)
        fd = self._fd
        while True:
            try:
                ready, _, _ = select.select([fd, self._stop_r], [], [])
            except (OSError, ValueError):
                return
            if self._stop_r in ready:
                return
            arrived = time.monotonic()
            try:
                data = os.read(fd, READ_CHUNK)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:  # no client at all (the emulator holds one)
                    time.sleep(0.001)
                    continue
                return
            if self._decode is not None:
                data = self._decode(data)
            if not data:
                continue
            self.bytes_read += len(data)
            with self._lock:
                fit = max(0, min(len(data), self._room() - self.queued))
                self.overrun += len(data) - fit
                if fit:
                    self._queue.append((arrived, data[:fit]))
                    self.queued += fit
            if fit:
                try:
                    os.write(self._wake_w, b"\0")
                except BlockingIOError:
                    pass  # the pipe is full of wake-ups already

    def stop(self) -> None:
        """End the thread and close its pipes (idempotent); the pty stays open."""
        if self._stop_w < 0:
            return
        os.write(self._stop_w, b"\0")
        self._thread.join()
        for fd in (self._wake_r, self._wake_w, self._stop_r, self._stop_w):
            os.close(fd)
        self._wake_r = self._wake_w = self._stop_r = self._stop_w = -1
