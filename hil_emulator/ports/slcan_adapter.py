"""An emulated SLCAN (Lawicel) USB-CAN adapter on a :class:`~hil_emulator.ports.pty_port.PtyPort`.

A host opens the pty exactly like a CANable/USBtin; python-can's ``slcan`` interface works
unmodified.  Commands (each ends with ``\\r``): ``Sn`` (n = 0..8) bitrate, ``sxxyy`` BTR,
``O`` open, ``L`` listen-only open, ``C`` close, ``V``/``v``/``N`` version/serial, ``F``
status flags, ``tIIIL<data>`` / ``TIIIIIIIIL<data>`` transmit.  Accepted commands answer
``\\r`` (``z\\r`` / ``Z\\r`` after a transmit), rejected ones ``\\a`` (BEL).

Note: python-can 4.6 does not wait for these acknowledgements (it just writes ``C``, ``Sn``,
an empty line, ``O``); its reader treats each ``\\r``/``\\a``-terminated chunk as a line and
ignores the ones that are not frames.
"""

from __future__ import annotations

import threading

from hil_emulator.ports.pty_port import PtyPort

OK = b"\r"
BEL = b"\a"

BITRATES: dict[str, int] = {
    "0": 10_000,
    "1": 20_000,
    "2": 50_000,
    "3": 100_000,
    "4": 125_000,
    "5": 250_000,
    "6": 500_000,
    "7": 750_000,
    "8": 1_000_000,
}

STD_ID_MAX = 0x7FF
EXT_ID_MAX = 0x1FFF_FFFF
MAX_LINE = 64  # longest valid classic line is 'T' + 8 + 1 + 16 = 26 chars


def _parse_hex(text: str) -> int | None:
    if not text or any(c not in "0123456789abcdefABCDEF" for c in text):
        return None
    return int(text, 16)


class SlcanAdapter:
    """Lawicel SLCAN adapter emulation.  Not running a thread itself: call :meth:`poll`."""

    def __init__(
        self,
        port: PtyPort,
        version: str = "1013",
        sw_version: str = "STM32",
        serial_number: str = "A123",
    ) -> None:
        self.port = port
        self.version = version
        self.sw_version = sw_version
        self.serial_number = serial_number
        self.bitrate: int | None = None
        self.is_open = False
        self.listen_only = False
        self.errors = 0  # count of commands answered with BEL
        self._buffer = bytearray()
        self._write_lock = threading.Lock()

    # -- towards the emulator ---------------------------------------------------------------
    def poll(self, data: bytes | None = None) -> list[tuple[int, bytes]]:
        """Handle everything the host sent (``data``, or what waits on the pty when None);
        return the frames ``(id, data)`` it transmitted while the channel was open."""
        self._buffer += self.port.read_available() if data is None else data
        frames: list[tuple[int, bytes]] = []
        while True:
            idx = self._buffer.find(b"\r")
            if idx < 0:
                if len(self._buffer) > MAX_LINE:  # runaway garbage without terminator
                    self._buffer.clear()
                    self._error()
                break
            raw = bytes(self._buffer[:idx])
            del self._buffer[: idx + 1]
            line = raw.replace(b"\n", b"").decode("ascii", errors="replace")
            frames.extend(self._handle(line))
        return frames

    def send_frame(self, arbitration_id: int, data: bytes, extended: bool | None = None) -> bool:
        """Deliver a bus frame to the host as ``t``/``T`` line.  Returns False (nothing sent)
        while the channel is closed.  ``extended`` defaults to ``arbitration_id > 0x7FF``."""
        if extended is None:
            extended = arbitration_id > STD_ID_MAX
        if len(data) > 8:
            raise ValueError(f"classic CAN data is at most 8 bytes, got {len(data)}")
        limit = EXT_ID_MAX if extended else STD_ID_MAX
        if not 0 <= arbitration_id <= limit:
            raise ValueError(f"arbitration id {arbitration_id:#x} out of range")
        if not self.is_open:
            return False
        if extended:
            line = f"T{arbitration_id:08X}{len(data)}{bytes(data).hex().upper()}\r"
        else:
            line = f"t{arbitration_id:03X}{len(data)}{bytes(data).hex().upper()}\r"
        self._reply(line.encode("ascii"))
        return True

    # -- protocol ---------------------------------------------------------------------------
    def _reply(self, data: bytes) -> None:
        with self._write_lock:
            self.port.write(data)

    def _error(self) -> list[tuple[int, bytes]]:
        self.errors += 1
        self._reply(BEL)
        return []

    def _ok(self, text: str = "") -> list[tuple[int, bytes]]:
        self._reply(text.encode("ascii") + OK)
        return []

    def _handle(self, line: str) -> list[tuple[int, bytes]]:
        if not line:
            return self._ok()  # python-can sends an empty data-bitrate command
        cmd, arg = line[0], line[1:]
        if cmd in "tT":
            return self._transmit(cmd, arg)
        if cmd == "S":
            if self.is_open or arg not in BITRATES:
                return self._error()
            self.bitrate = BITRATES[arg]
            return self._ok()
        if cmd == "s":
            if self.is_open or len(arg) != 4 or _parse_hex(arg) is None:
                return self._error()
            self.bitrate = None  # custom BTR timing; not modelled
            return self._ok()
        if cmd in "OL" and not arg:
            if self.is_open:
                return self._error()
            self.is_open = True
            self.listen_only = cmd == "L"
            return self._ok()
        if cmd == "C" and not arg:
            self.is_open = False
            self.listen_only = False
            return self._ok()
        if cmd == "V" and not arg:
            return self._ok("V" + self.version)
        if cmd == "v" and not arg:
            return self._ok("v" + self.sw_version)
        if cmd == "N" and not arg:
            return self._ok("N" + self.serial_number)
        if cmd == "F" and not arg:
            return self._ok("F00")
        return self._error()

    def _transmit(self, cmd: str, arg: str) -> list[tuple[int, bytes]]:
        if not self.is_open or self.listen_only:
            return self._error()
        id_len = 8 if cmd == "T" else 3
        if len(arg) < id_len + 1:
            return self._error()
        ident = _parse_hex(arg[:id_len])
        length_digit = arg[id_len]
        payload = arg[id_len + 1 :]
        if ident is None or length_digit not in "012345678":
            return self._error()
        length = int(length_digit)
        if ident > (EXT_ID_MAX if cmd == "T" else STD_ID_MAX) or len(payload) != 2 * length:
            return self._error()
        if length and _parse_hex(payload) is None:
            return self._error()
        data = bytes.fromhex(payload)
        self._reply(b"Z\r" if cmd == "T" else b"z\r")
        return [(ident, data)]
