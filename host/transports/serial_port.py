"""Serial links through pyserial: a device path, a pty, or any pyserial URL handler."""

from __future__ import annotations

import os
import select
from collections.abc import Mapping
from typing import Any, ClassVar, Final
from urllib.parse import urlencode

import serial

from host.errors import TransportError, UsageError
from host.transports.base import HAND_SERIAL_BAUD, LinkKind, Transport, url_options

#: Highest ``?baud=`` taken (bit/s): the fastest USB-serial adapters (FT232H, 12 Mbaud).
MAX_BAUD: Final = 12_000_000

#: What a user reads when a port stops working under an open transport.
_GONE = ("the port is gone (USB adapter unplugged, robot switched off, or the emulator "
         "stopped); plug it back in and run the command again (a program calls reopen())")


def lock_holder(path: str) -> int | None:
    """The process id holding the advisory ``flock`` of the device ``path`` (what
    ``exclusive`` takes), from ``/proc/locks``; None where it cannot be told."""
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii") as locks:
            lines = locks.read().splitlines()
    except OSError:
        return None
    where = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in lines:
        fields = line.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5] == where:
            try:
                return int(fields[4])
            except ValueError:
                return None
    return None


def _who_holds(path: str) -> str:
    """Why an exclusive open of ``path`` failed, as the end of a sentence."""
    pid = lock_holder(path)
    if pid == os.getpid():
        return ("; this program holds it already (a link it opened earlier): close that "
                "link first")
    who = "another program"
    if pid is not None:
        try:
            with open(f"/proc/{pid}/comm", encoding="utf-8") as comm:
                who = f"another program ({comm.read().strip()}, pid {pid})"
        except OSError:
            who = f"another program (pid {pid})"
    return (f"; {who} has it open (handctl, armctl, a recorder, a terminal): close that "
            "one first, or share the port knowingly with ?exclusive=0")


_DEVICE: Final = LinkKind("serial", budget_s=0.100)
_NETWORK: Final = LinkKind("network", budget_s=0.250)


class SerialTransport(Transport):
    """A serial port (8N1) opened with ``serial.serial_for_url``.

    ``baud`` in bit/s (hand links 2 000 000, the arm bus 1 000 000).  ``exclusive`` asks
    the OS to refuse a second client of the same port (POSIX), so two programs never split
    one robot's replies.  Waiting in :meth:`recv` is on the wall clock; a device port is
    waited on with ``select`` (the port's settings are not touched per call), a pyserial
    URL handler (``loop://``, ``socket://``) with its read timeout.
    """

    #: A device or pty: a USB adapter's latency timer (16 ms by default, each way) and, on
    #: the emulator's ptys, a busy machine's scheduling; a network link adds its round trip;
    #: ``loop://`` hands back what was written at once.
    schemes: ClassVar[Mapping[str, LinkKind]] = {
        "serial": _DEVICE, "spy": _DEVICE, "loop": LinkKind("loop", 0.030, exact_timing=True),
        "socket": _NETWORK, "rfc2217": _NETWORK}

    def __init__(self, port: str, baud: int = HAND_SERIAL_BAUD, *, exclusive: bool = True,
                 url: str | None = None) -> None:
        super().__init__(url or port)
        self.port = port
        self.baud = int(baud)
        self.exclusive = exclusive
        self.serial = self._open()
        self._timeout: float | None = 0.0

    @classmethod
    def from_url(cls, url: str, **options: Any) -> SerialTransport:
        """``/dev/ttyUSB0?baud=1000000``, ``serial:///dev/ttyUSB0``, ``loop://``, …

        ``baud`` (bit/s) and ``exclusive`` (0/1) are this transport's options; other
        options of a pyserial URL handler (``loop://?logging=debug``) go to pyserial, and
        on a plain path they are a :class:`UsageError`.
        """
        merged: dict[str, Any] = {**url_options(url), **options}
        port = url.split("?", 1)[0]
        if port.startswith("serial://"):
            port = port[len("serial://"):]
        try:
            baud = int(merged.pop("baud", HAND_SERIAL_BAUD))
        except ValueError:
            raise UsageError(f"{url}: baud must be a number of bit/s") from None
        if not 0 < baud <= MAX_BAUD:
            raise UsageError(f"{url}: baud {baud} is not a rate a serial port runs at: give "
                             f"1..{MAX_BAUD} bit/s")
        exclusive = str(merged.pop("exclusive", "1")).lower() not in ("0", "false", "no")
        if merged:
            if "://" not in port:
                raise UsageError(f"{url}: unknown serial options {sorted(merged)}; "
                                 "a serial port takes ?baud=N&exclusive=0|1")
            port = f"{port}?{urlencode(merged)}"
        return cls(port, baud, exclusive=exclusive, url=url)

    def _open(self) -> serial.SerialBase:
        kwargs: dict[str, Any] = {"baudrate": self.baud, "timeout": 0}
        if self.exclusive and "://" not in self.port:
            kwargs["exclusive"] = True
        try:
            port = serial.serial_for_url(self.port, **kwargs)
        except (serial.SerialException, OSError, ValueError) as exc:
            held = ""
            if "exclusive" in kwargs and "exclusively lock" in str(exc):
                held = _who_holds(self.port)
            raise TransportError(f"cannot open {self.port}: {exc}{held}") from exc
        self._timeout = 0.0
        return port

    def _send(self, data: bytes) -> None:
        try:
            self.serial.write(data)
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"{self.port}: write failed ({exc}): {_GONE}") from exc

    def _recv(self, timeout: float | None) -> bytes:
        try:
            fd = getattr(self.serial, "fd", None)
            if isinstance(fd, int):
                # A device: wait on the descriptor; a vanished device reads as an error.
                if timeout != 0.0:
                    ready, _, _ = select.select([fd], [], [], timeout)
                    if not ready:
                        return b""
                first = self.serial.read(1)
            else:
                if timeout != self._timeout:
                    self.serial.timeout = self._timeout = timeout
                first = self.serial.read(1)
            if not first:
                return b""
            waiting = self.serial.in_waiting
            return first + (self.serial.read(waiting) if waiting else b"")
        except (serial.SerialException, OSError, TypeError, ValueError) as exc:
            raise TransportError(f"{self.port}: read failed ({exc}): {_GONE}") from exc

    def _close(self) -> None:
        try:
            self.serial.close()
        except (serial.SerialException, OSError):
            pass

    def _reopen(self) -> None:
        self.serial = self._open()
