"""Serial links through pyserial: a device path, a pty, or any pyserial URL handler."""

from __future__ import annotations

from typing import Any

import serial

from host.errors import TransportError
from host.transport import HAND_SERIAL_BAUD, Transport, url_options


class SerialTransport(Transport):
    """A serial port (8N1) opened with ``serial.serial_for_url``.

    ``baud`` in bit/s (hand links 2 000 000, the arm bus 1 000 000).  ``exclusive`` asks
    the OS to refuse a second client of the same port (POSIX), so two programs never split
    one robot's replies.
    """

    def __init__(self, port: str, baud: int = HAND_SERIAL_BAUD, *, exclusive: bool = True,
                 url: str | None = None) -> None:
        super().__init__(url or port)
        self.port = port
        self.baud = int(baud)
        self.exclusive = exclusive
        self.serial = self._open()

    @classmethod
    def from_url(cls, url: str, **options: Any) -> SerialTransport:
        """``/dev/ttyUSB0?baud=1000000``, ``serial:///dev/ttyUSB0``, ``loop://``, …"""
        merged: dict[str, Any] = {**url_options(url), **options}
        port = url.split("?", 1)[0]
        if port.startswith("serial://"):
            port = port[len("serial://"):]
        baud = int(merged.pop("baud", HAND_SERIAL_BAUD))
        exclusive = str(merged.pop("exclusive", "1")).lower() not in ("0", "false", "no")
        if merged:
            raise TransportError(f"{url}: unknown serial options {sorted(merged)}")
        return cls(port, baud, exclusive=exclusive, url=url)

    def _open(self) -> serial.SerialBase:
        kwargs: dict[str, Any] = {"baudrate": self.baud, "timeout": 0}
        if self.exclusive and "://" not in self.port:
            kwargs["exclusive"] = True
        try:
            return serial.serial_for_url(self.port, **kwargs)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(f"cannot open {self.port}: {exc}") from exc

    def _send(self, data: bytes) -> None:
        try:
            self.serial.write(data)
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"{self.port}: write failed ({exc}); unplugged?") from exc

    def _recv(self, timeout: float | None) -> bytes:
        try:
            self.serial.timeout = timeout
            first = self.serial.read(1)
            if not first:
                return b""
            self.serial.timeout = 0
            waiting = self.serial.in_waiting
            return first + (self.serial.read(waiting) if waiting else b"")
        except (serial.SerialException, OSError, TypeError) as exc:
            raise TransportError(f"{self.port}: read failed ({exc}); unplugged?") from exc

    def _close(self) -> None:
        try:
            self.serial.close()
        except (serial.SerialException, OSError):
            pass

    def _reopen(self) -> None:
        self.serial = self._open()
