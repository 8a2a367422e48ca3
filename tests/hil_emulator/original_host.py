"""The original hand's host-side flashing, as it behaved on the wire, for end-to-end tests.

A test model of the original ROS driver's serial message processor and of its loose-finger
and loose-palm command-line ``burn`` flows, written from their documented behaviour (frames,
timeouts, retries), not from this project's host library:

* frames built as the original built them (sync 0x42, address, u16 length, type, payload,
  CRC-16/XMODEM), no transaction envelope;
* a byte-at-a-time parser with no timeout that keeps frames to address 0 or 0xFF with a good
  CRC; "listen for type T for S seconds" polls the link in 10 ms slices and succeeds on
  the first frame of type T (payload unchecked), after resetting the parser;
* a phalange is reached by wrapping its frames in the motor module's relay request (0x1f:
  u16 length, u16 listen time 10 ms, the bytes); the bytes heard come back in the relay's
  reply and are fed to the phalange's own parser;
* ``program_app``: power off (for the motor module and the palm: a reset request, its
  acknowledgement awaited 0.5 s at most), listen 1 s, power on, listen 2 s, halt autoboot
  (0.5 s), write every 256-byte page of the file from page 32 (the last zero-padded; each
  write: a 10 ms flush, then up to 50 attempts of send + 30 ms wait for a reply of status
  0), boot (0.5 s): success only if the boot is acknowledged.

Waits run on the link's clock: on the in-process emulator they are simulated.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from host.transports.base import Transport
from protocol.framing import encode_frame

PING, BOOT, READ_PAGE, WRITE_PAGE, HALT, RESET = 0x01, 0x08, 0x0A, 0x0B, 0x0C, 0x09
PHALANGE_POWER, RELAY = 0x1E, 0x1F
#: Time slice of one poll of the link (s).
SLICE_S = 0.01
#: Listening time of a relayed phalange request on the phalange bus (ms).
RELAY_LISTEN_MS = 10


@dataclass
class Parser:
    """The original's byte parser: no timeout, no length guard, frames to 0 / 0xFF only."""

    frames: list[tuple[int, bytes]] = field(default_factory=list)
    _buf: bytearray = field(default_factory=bytearray)

    def reset(self) -> None:
        self._buf.clear()

    def feed(self, data: bytes) -> None:
        from protocol.crc import crc16_xmodem

        for b in data:
            buf = self._buf
            if not buf:
                if b == 0x42:
                    buf.append(b)
                continue
            buf.append(b)
            if len(buf) < 5:
                continue
            length = buf[2] | buf[3] << 8
            if len(buf) < 5 + length + 2:
                continue
            body, crc = bytes(buf[:5 + length]), buf[5 + length] | buf[6 + length] << 8
            buf.clear()
            if crc == crc16_xmodem(body) and body[1] in (0x00, 0xFF):
                self.frames.append((body[4], body[5:]))


class Processor:
    """One node's message processor: ``raw_tx`` sends a frame; ``listen(s)`` polls the
    link for ``s`` seconds, feeding whatever parser is listening."""

    def __init__(self, address: int, raw_tx: Callable[[bytes], None],
                 listen: Callable[[float], None], clock: Callable[[], float]) -> None:
        self.address = address
        self.raw_tx = raw_tx
        self.listen = listen
        self.clock = clock
        self.parser = Parser()
        self.last: bytes = b""
        self.log: list[tuple[float, str]] = []

    def send(self, msg_type: int, payload: bytes = b"") -> None:
        self.raw_tx(encode_frame(self.address, msg_type, payload))

    def listen_for(self, msg_type: int, seconds: float) -> bool:
        """Wait up to ``seconds`` for a frame of ``msg_type``; its payload in :attr:`last`."""
        self.parser.reset()
        self.parser.frames.clear()
        start = self.clock()
        while self.clock() - start < seconds:
            self.listen(SLICE_S)
            for t, payload in self.parser.frames:
                if t == msg_type:
                    self.parser.frames.clear()
                    self.last = payload
                    return True
            self.parser.frames.clear()
        return False

    def wait(self, seconds: float) -> None:
        """Listen for ``seconds`` whatever arrives (the original's plain listen)."""
        start = self.clock()
        while self.clock() - start < seconds:
            self.listen(SLICE_S)
        self.parser.frames.clear()

    # --- requests ----------------------------------------------------------------------------
    def request(self, msg_type: int, payload: bytes = b"", seconds: float = 0.5) -> bool:
        self.log.append((self.clock(), f"send 0x{msg_type:02x}"))
        self.send(msg_type, payload)
        return self.listen_for(msg_type, seconds)

    def halt_autoboot(self) -> bool:
        return self.request(HALT)

    def boot(self) -> bool:
        return self.request(BOOT)

    def reset(self) -> bool:
        return self.request(RESET)

    def write_page(self, page: int, data: bytes) -> bool:
        self.listen(SLICE_S)  # flush what earlier hiccups left
        for _ in range(50):
            self.send(WRITE_PAGE, struct.pack("<I", page) + data)
            if not self.listen_for(WRITE_PAGE, 0.03):
                continue
            if len(self.last) != 5 or self.last[4] != 0:
                continue
            return True
        return False

    def program_app(self, image: bytes, power_off: Callable[[], bool],
                    power_on: Callable[[], bool], *, last_page: int = 1024) -> bool:
        """The original ``programAppFile`` (``last_page``: the phalange burns stop at 256)."""
        if not power_off():
            return False
        self.wait(1.0)
        if not power_on():
            return False
        self.wait(2.0)
        self.log.append((self.clock(), "halt"))
        if not self.halt_autoboot():
            self.log.append((self.clock(), "unable to halt autoboot"))
            return False
        for k, page in enumerate(range(32, last_page)):
            chunk = image[256 * k: 256 * (k + 1)]
            if not chunk:
                break
            if not self.write_page(page, chunk.ljust(256, b"\x00")):
                self.log.append((self.clock(), f"couldn't write page {page}"))
                return False
        if not self.boot():
            self.log.append((self.clock(), "failed to boot"))
            return False
        return True


class OriginalHost:
    """The original host on one serial link: the node at address 10 (a motor module on a
    loose-finger cable, or a palm) and, behind a motor module, its phalanges 1 and 2."""

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.node = Processor(10, transport.send, self._listen, transport.now)
        self.phalanges = {a: Processor(a, self._relay, self._listen, transport.now)
                          for a in (1, 2)}

    def _listen(self, seconds: float) -> None:
        deadline = self.transport.now() + seconds
        while True:
            left = deadline - self.transport.now()
            if left <= 0:
                break
            data = self.transport.recv(left)
            if data:
                self.node.parser.feed(data)
                self._deliver_relayed()

    def _deliver_relayed(self) -> None:
        """Relay replies (0x1f) carry the phalange bus's bytes: feed them to the phalanges'
        parsers (each keeps the frames for its own listen)."""
        kept = []
        for t, payload in self.node.parser.frames:
            if t == RELAY and len(payload) >= 2:
                n = payload[0] | payload[1] << 8
                for p in self.phalanges.values():
                    p.parser.feed(payload[2:2 + n])
            else:
                kept.append((t, payload))
        self.node.parser.frames[:] = kept

    def _relay(self, frame: bytes) -> None:
        self.node.send(RELAY, struct.pack("<HH", len(frame), RELAY_LISTEN_MS) + frame)

    # --- the command-line flows ----------------------------------------------------------------
    def burn_node(self, image: bytes) -> bool:
        """``burn`` of a motor module or a palm: reset as the power cycle, then programming;
        the CLI then sends one more boot (to the application) whatever happens."""
        ok = self.node.program_app(image, lambda: (self.node.reset(), True)[1], lambda: True)
        self.node.boot()
        return ok

    def set_phalange_power(self, on: bool) -> bool:
        return self.node.request(PHALANGE_POWER, bytes([1 if on else 0]))

    def burn_phalange(self, address: int, image: bytes) -> bool:
        """``pburn`` / ``dburn``: phalange power off, 1 s, on, 2 s, halt, pages 32..255,
        boot; True if the boot was acknowledged."""
        p = self.phalanges[address]
        return p.program_app(image, lambda: (self.set_phalange_power(False), True)[1],
                             lambda: (self.set_phalange_power(True), True)[1], last_page=256)
