"""Dynamixel Protocol 1.0: packets, instruction builders, framing and a stream decoder.

Wire format (ROBOTIS e-Manual): instruction ``FF FF ID LEN INST P1..PN CHK``, status
``FF FF ID LEN ERR P1..PN CHK``, with ``LEN = N + 2`` (bounded to 2..250, dynamixel-sdk's
receive limit) and ``CHK = ~(ID + LEN + INST/ERR + sum(P)) & 0xFF``.  ID 0xFE broadcasts to
every servo and is never answered.

Layers: :data:`PACKET` (the one construct declaration) under :class:`InstructionPacket` /
:class:`StatusPacket`; ``make_*`` builders (commands as data) and ``parse_*`` readers of
instruction parameters (for emulated servos); :func:`check_packet` (pure framing: need more,
discard n, packet of n) under :class:`DynamixelStreamDecoder`; RX-64 unit conversions.
Pure: no I/O and no clocks (times are passed in by the caller).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum, IntEnum, IntFlag
from functools import partial
from typing import Final, Literal

import construct as cs
from construct import this

from protocol.errors import DynamixelChecksumError, DynamixelError, wrap_construct
from protocol.robot import RX64_POSITION_CENTRE, RX64_POSITION_MAX, RX64_RAD_PER_UNIT

BytesLike = bytes | bytearray | memoryview
HEADER: Final = b"\xff\xff"
BROADCAST_ID: Final = 0xFE  #: every servo executes the instruction, none replies
MAX_ID: Final = 0xFD  #: highest ID of one servo (a status packet never carries 0xFE or 0xFF)
MAX_LENGTH: Final = 250  #: largest LEN byte accepted (dynamixel-sdk's RXPACKET_MAX_LEN); smallest 2
MAX_PARAMS: Final = MAX_LENGTH - 2  #: most parameter bytes one packet can carry
MIN_PACKET_SIZE: Final = 6  #: header, ID, LEN, INST/ERR and checksum: a packet without parameters


class Instruction(IntEnum):
    """Protocol 1.0 instruction codes (byte 4 of an instruction packet)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06
    SYNC_WRITE = 0x83
    BULK_READ = 0x92


class ErrorBit(IntFlag):
    """Bits of a status packet's error byte (bit 7 is always 0)."""

    INPUT_VOLTAGE = 0x01
    ANGLE_LIMIT = 0x02
    OVERHEATING = 0x04
    RANGE = 0x08
    CHECKSUM = 0x10
    OVERLOAD = 0x20
    INSTRUCTION = 0x40


#: The known instruction codes' members (an unknown code stays a plain int).
_INSTRUCTIONS: dict[int, Instruction] = {i.value: i for i in Instruction}


def checksum(body: BytesLike) -> int:
    """Protocol 1.0 checksum of ``ID LEN INST/ERR P..`` (everything between header and CHK)."""
    return ~sum(body) & 0xFF


_U8 = cs.Int8ub
_BODY = cs.Struct(
    "id" / _U8,
    "length" / cs.Rebuild(_U8, cs.len_(this.params) + 2),
    cs.Check((this.length >= 2) & (this.length <= MAX_LENGTH)),
    "code" / _U8,  # instruction (instruction packet) or error byte (status packet)
    "params" / cs.Bytes(this.length - 2),
)

#: The one declaration of a protocol 1.0 packet (instruction or status: same layout).
PACKET = cs.Struct(
    "header" / cs.Const(HEADER),
    "body" / cs.RawCopy(_BODY),
    "checksum" / cs.Checksum(_U8, checksum, this.body.data),
)


def _params(params: bytes | bytearray) -> bytes:
    if len(params) > MAX_PARAMS:
        raise DynamixelError(f"{len(params)} parameter bytes exceed the maximum {MAX_PARAMS}")
    return bytes(params)


def encode_packet(id: int, code: int, params: bytes = b"") -> bytes:
    """Encode ``FF FF id LEN code params CHK`` (``code`` is the instruction or error byte)."""
    if not 0 <= id < 0xFF:
        raise DynamixelError(f"packet id {id} outside 0..254 (0xFF would read as a header)")
    params = _params(params)
    if not 0 <= code <= 0xFF:
        raise DynamixelError(f"packet code {code} outside 0..255")
    # Hand-written (every node answers every poll); tests check it against PACKET.build.
    body = bytes((id, len(params) + 2, code)) + params
    return HEADER + body + bytes((~sum(body) & 0xFF,))


def decode_packet(data: BytesLike) -> tuple[int, int, bytes]:
    """Decode exactly one complete packet into ``(id, code, params)``.

    Raises :class:`DynamixelChecksumError` for a bad checksum and :class:`DynamixelError` for
    anything else (short, bad header, LEN out of 2..250, trailing or missing bytes).
    """
    raw = bytes(data)
    if len(raw) < MIN_PACKET_SIZE:
        raise DynamixelError(f"dynamixel packet: {len(raw)} bytes, a packet has at least 6")
    if raw[:2] != HEADER or raw[2] == 0xFF:
        raise DynamixelError(f"dynamixel packet: starts {raw[:3].hex(' ')}, not ff ff <id>")
    length = raw[3]
    if not 2 <= length <= MAX_LENGTH:
        raise DynamixelError(f"dynamixel packet: LEN {length} outside 2..{MAX_LENGTH}")
    if len(raw) != length + 4:
        raise DynamixelError(
            f"dynamixel packet: LEN {length} means {length + 4} bytes, got {len(raw)}"
        )
    expected = checksum(raw[2:-1])
    if raw[-1] != expected:
        raise DynamixelChecksumError(
            f"dynamixel packet from id {raw[2]}: checksum 0x{raw[-1]:02X} != 0x{expected:02X}"
        )
    parsed = wrap_construct(lambda: PACKET.parse(raw), "dynamixel packet", DynamixelError)
    body = parsed.body.value
    return int(body.id), int(body.code), bytes(body.params)


@dataclass(frozen=True)
class InstructionPacket:
    """A host-to-servo packet.  ``instruction`` is an :class:`Instruction` when known; other
    codes are kept as plain ints (a servo answers them with :attr:`ErrorBit.INSTRUCTION`)."""

    id: int
    # Not plain ``int``: compiled (mypyc), an ``int`` attribute would store a member as a
    # bare int and lose its :class:`Instruction` type.
    instruction: Instruction | int
    params: bytes = b""

    def __post_init__(self) -> None:
        if not 0 <= self.id <= BROADCAST_ID:
            raise DynamixelError(f"instruction packet id {self.id} outside 0..254")
        if not 0 <= self.instruction <= 0xFF:
            raise DynamixelError(f"instruction {self.instruction} is not a byte")
        object.__setattr__(self, "params", _params(self.params))
        # The member is stored as the object it is: compiled (mypyc), a value typed ``int``
        # on its way would be unboxed and lose its Instruction type.
        member = _INSTRUCTIONS.get(self.instruction)
        if member is not None:
            object.__setattr__(self, "instruction", member)

    @property
    def is_broadcast(self) -> bool:
        """True for ID 0xFE: every servo executes it and none replies."""
        return self.id == BROADCAST_ID

    def encode(self) -> bytes:
        """The packet's wire bytes, header to checksum."""
        return encode_packet(self.id, self.instruction, self.params)

    @classmethod
    def decode(cls, data: BytesLike) -> InstructionPacket:
        """Decode one complete instruction packet (see :func:`decode_packet` for errors)."""
        return cls(*decode_packet(data))


@dataclass(frozen=True)
class StatusPacket:
    """A servo-to-host reply: ``error`` is the error byte (:class:`ErrorBit` flags, 0..0x7F)
    and ``params`` the data read (empty for everything but READ)."""

    id: int
    error: int = 0
    params: bytes = b""

    def __post_init__(self) -> None:
        if not 0 <= self.id <= MAX_ID:
            raise DynamixelError(f"status packet id {self.id} outside 0..{MAX_ID}")
        if not 0 <= self.error <= 0x7F:
            raise DynamixelError(f"status error byte 0x{self.error:X} outside 0..0x7F (bit 7 set)")
        object.__setattr__(self, "params", _params(self.params))

    @property
    def errors(self) -> ErrorBit:
        """The error byte as flags."""
        return ErrorBit(self.error)

    def encode(self) -> bytes:
        """The packet's wire bytes, header to checksum."""
        return encode_packet(self.id, self.error, self.params)

    @classmethod
    def decode(cls, data: BytesLike) -> StatusPacket:
        """Decode one complete status packet (see :func:`decode_packet` for errors)."""
        return cls(*decode_packet(data))


def _byte(what: str, value: int, low: int = 0, high: int = 0xFF) -> int:
    if not low <= value <= high:
        raise DynamixelError(f"{what} {value} outside {low}..{high}")
    return value


def make_ping(id: int) -> InstructionPacket:
    """PING ``id``: the servo answers with an empty status (even at status return level 0)."""
    return InstructionPacket(id, Instruction.PING)


def make_read(id: int, address: int, length: int) -> InstructionPacket:
    """READ ``length`` bytes from control-table ``address`` of servo ``id``."""
    params = bytes([_byte("address", address), _byte("read length", length, 1, MAX_PARAMS)])
    return InstructionPacket(id, Instruction.READ, params)


def _write_params(address: int, data: bytes) -> bytes:
    if not 1 <= len(data) <= MAX_PARAMS - 1:
        raise DynamixelError(f"write data of {len(data)} bytes outside 1..{MAX_PARAMS - 1}")
    return bytes([_byte("address", address)]) + bytes(data)


def make_write(id: int, address: int, data: bytes) -> InstructionPacket:
    """WRITE ``data`` (little-endian register bytes) at ``address`` of servo ``id``."""
    return InstructionPacket(id, Instruction.WRITE, _write_params(address, data))


def make_reg_write(id: int, address: int, data: bytes) -> InstructionPacket:
    """REG_WRITE: like WRITE, but held until an ACTION."""
    return InstructionPacket(id, Instruction.REG_WRITE, _write_params(address, data))


def make_action(id: int = BROADCAST_ID) -> InstructionPacket:
    """ACTION: apply the pending REG_WRITE (usually broadcast)."""
    return InstructionPacket(id, Instruction.ACTION)


def make_reset(id: int) -> InstructionPacket:
    """RESET: restore the factory control table (ID becomes 1)."""
    return InstructionPacket(id, Instruction.RESET)


_SYNC_WRITE = cs.Struct(
    "address" / _U8,
    "length" / _U8,
    "entries" / cs.GreedyRange(cs.Struct("id" / _U8, "data" / cs.Bytes(this._.length))),
    cs.Terminated,
)

_BULK_READ = cs.Struct(
    cs.Const(b"\x00"),
    "entries" / cs.GreedyRange(cs.Struct("length" / _U8, "id" / _U8, "address" / _U8)),
    cs.Terminated,
)


def make_sync_write(address: int, length: int, data: Mapping[int, bytes]) -> InstructionPacket:
    """SYNC_WRITE (broadcast): ``length`` bytes at ``address`` on each servo of ``data``
    (``{id: bytes}``, in the mapping's order; every value exactly ``length`` bytes)."""
    _byte("address", address)
    _byte("sync write length", length, 1, MAX_PARAMS - 3)
    if not data:
        raise DynamixelError("sync write needs at least one servo")
    for id_, value in data.items():
        _byte("sync write id", id_, 0, MAX_ID)
        if len(value) != length:
            raise DynamixelError(f"sync write data for id {id_}: {len(value)} bytes, not {length}")
    # Hand-written (the host sends one with every cycle); tests check it against _SYNC_WRITE.
    params = bytes((address, length)) + b"".join(
        bytes((id_,)) + bytes(value) for id_, value in data.items())
    return InstructionPacket(BROADCAST_ID, Instruction.SYNC_WRITE, params)


def make_bulk_read(entries: Iterable[tuple[int, int, int]]) -> InstructionPacket:
    """BULK_READ (broadcast) of ``(length, id, address)`` triples; each servo answers in turn
    (an MX-series feature: a real RX-64 probably does not implement it)."""
    items = [
        {"length": _byte("bulk read length", n, 1, MAX_PARAMS),
         "id": _byte("bulk read id", id_, 0, MAX_ID), "address": _byte("address", address)}
        for n, id_, address in entries
    ]
    if not items:
        raise DynamixelError("bulk read needs at least one entry")
    build = partial(_BULK_READ.build, {"entries": items})
    params = wrap_construct(build, "bulk read", DynamixelError)
    return InstructionPacket(BROADCAST_ID, Instruction.BULK_READ, params)


def parse_read(params: bytes) -> tuple[int, int]:
    """READ parameters -> ``(address, length)``."""
    if len(params) != 2 or params[1] == 0:
        raise DynamixelError(f"read: parameters {bytes(params).hex(' ')!r}, expected addr, n>0")
    return params[0], params[1]


def parse_write(params: bytes) -> tuple[int, bytes]:
    """WRITE / REG_WRITE parameters -> ``(address, data)``."""
    if len(params) < 2:
        raise DynamixelError(f"write: {len(params)} parameter bytes, expected at least 2")
    return params[0], bytes(params[1:])


def parse_sync_write(params: bytes) -> tuple[int, int, dict[int, bytes]]:
    """SYNC_WRITE parameters -> ``(address, length, {id: data})`` (duplicate ids rejected)."""
    if len(params) < 2 or params[1] == 0:
        raise DynamixelError("sync write: missing address/length or length 0")
    address, length = params[0], params[1]
    step = length + 1
    result: dict[int, bytes] = {}
    if (len(params) - 2) % step:
        # Not whole entries: let the declaration say what is wrong.
        wrap_construct(lambda: _SYNC_WRITE.parse(params), "sync write", DynamixelError)
        raise DynamixelError(f"sync write: {len(params) - 2} bytes of entries of {step}")
    # Fast path (every node parses every SYNC_WRITE on the bus), checked against _SYNC_WRITE.
    for at in range(2, len(params), step):
        id_ = params[at]
        if id_ in result:
            raise DynamixelError(f"sync write: id {id_} appears twice")
        result[id_] = bytes(params[at + 1 : at + step])
    return address, length, result


#: The last BULK_READ parameters parsed and their entries (every node on the bus parses
#: each BULK_READ: the first does the work).
_last_bulk_read: tuple[bytes, list[tuple[int, int, int]]] | None = None


def parse_bulk_read(params: bytes) -> list[tuple[int, int, int]]:
    """BULK_READ parameters -> ``[(length, id, address), ...]`` (the same list for the same
    parameters as the call before: do not change it)."""
    global _last_bulk_read
    last = _last_bulk_read
    if last is not None and last[0] == params:
        return last[1]
    if not params or params[0] != 0 or (len(params) - 1) % 3:
        parsed = wrap_construct(lambda: _BULK_READ.parse(params), "bulk read", DynamixelError)
        return [(int(e.length), int(e.id), int(e.address)) for e in parsed.entries]
    # Fast path, checked against _BULK_READ.
    entries = [(params[i], params[i + 1], params[i + 2]) for i in range(1, len(params), 3)]
    _last_bulk_read = (bytes(params), entries)
    return entries


class FrameKind(Enum):
    """Outcome of :func:`check_packet`.  ``BAD_CHECKSUM`` is a discard (drop ``n`` bytes as
    for ``DISCARD``) told apart only so a decoder can count checksum failures."""

    NEED_MORE = "need_more"
    DISCARD = "discard"
    BAD_CHECKSUM = "bad_checksum"
    PACKET = "packet"


def _resync_distance(buf: bytes | bytearray, start: int) -> int:
    """Bytes to drop from ``start`` so the next ``FF FF`` candidate (after ``start``) leads;
    with none, everything is dropped except a trailing ``FF`` (half a header)."""
    found = buf.find(HEADER, start + 1)
    end = len(buf)
    if found >= 0:
        while found + 2 < end and buf[found + 2] == 0xFF:  # FF FF FF..: take the last pair
            found += 1
        return found - start
    if end - 1 > start and buf[end - 1] == 0xFF:
        return end - 1 - start
    return end - start


def check_packet(buf: BytesLike, start: int = 0) -> tuple[FrameKind, int]:
    """Frame the bytes of ``buf`` from ``start``; pure, never raises for any byte content.

    Returns one of:

    * ``(NEED_MORE, n)`` - a packet may start here; at least ``n`` more bytes are needed.
    * ``(DISCARD, n)`` / ``(BAD_CHECKSUM, n)`` - drop ``n`` bytes (>= 1): the scan resumes
      at the next ``FF FF`` candidate.  A candidate is rejected for ID 0xFF, LEN outside
      2..250 or (``BAD_CHECKSUM``) a checksum mismatch - then the scan restarts just after
      the candidate's first ``FF``, so a real packet hidden inside is still found.
    * ``(PACKET, n)`` - a complete, checksum-verified packet of ``n`` bytes starts here.
    """
    if isinstance(buf, memoryview):
        buf = buf.tobytes()
    end = len(buf)
    if not 0 <= start <= end:
        raise ValueError(f"start {start} outside the buffer (0..{end})")
    avail = end - start
    if avail == 0:
        return FrameKind.NEED_MORE, MIN_PACKET_SIZE
    if buf[start] != 0xFF or (avail >= 2 and buf[start + 1] != 0xFF):
        return FrameKind.DISCARD, _resync_distance(buf, start)
    if avail < 3:
        return FrameKind.NEED_MORE, MIN_PACKET_SIZE - avail
    if buf[start + 2] == 0xFF:  # FF FF FF: the header may start one byte later
        return FrameKind.DISCARD, _resync_distance(buf, start)
    if avail < 4:
        return FrameKind.NEED_MORE, MIN_PACKET_SIZE - avail
    length = buf[start + 3]
    if not 2 <= length <= MAX_LENGTH:
        return FrameKind.DISCARD, _resync_distance(buf, start)
    total = length + 4
    if avail < total:
        return FrameKind.NEED_MORE, total - avail
    if checksum(buf[start + 2 : start + total - 1]) != buf[start + total - 1]:
        return FrameKind.BAD_CHECKSUM, _resync_distance(buf, start)
    return FrameKind.PACKET, total


Direction = Literal["instruction", "status", "auto"]

# Parameter counts a genuine instruction can have; used only by the "auto" heuristic.
_INSTRUCTION_SHAPES: dict[int, Callable[[int], bool]] = {
    Instruction.PING: lambda n: n == 0,
    Instruction.READ: lambda n: n == 2,
    Instruction.WRITE: lambda n: n >= 2,
    Instruction.REG_WRITE: lambda n: n >= 2,
    Instruction.ACTION: lambda n: n == 0,
    Instruction.RESET: lambda n: n == 0,
}


def guess_direction(raw: bytes | bytearray) -> Literal["instruction", "status"]:
    """Guess whether a framed packet is an instruction or a status (bytes alone can't tell).

    Heuristic: *instruction* if byte 4 is > 0x7F (SYNC_WRITE, BULK_READ: never an error
    byte), if the ID is 0xFE (no servo replies from the broadcast ID), or if byte 4 is a known
    instruction code (1..6) with a parameter count that instruction can have (PING/ACTION/
    RESET: 0, READ: 2, WRITE/REG_WRITE: >= 2).  Otherwise *status*.  So an ordinary status
    (error 0) is always right, and a status whose error byte is 1..6 is misread only when
    its parameter count also fits (e.g. error 0x01 with no data looks like a PING).
    """
    id_, code, n_params = raw[2], raw[4], len(raw) - MIN_PACKET_SIZE
    if code > 0x7F or id_ > MAX_ID:
        return "instruction"
    shape = _INSTRUCTION_SHAPES.get(code)
    if shape is not None and shape(n_params):
        return "instruction"
    return "status"


@dataclass(frozen=True)
class DecodedPacket:
    """A packet found by :class:`DynamixelStreamDecoder`: ``offset`` is the stream position
    of its first header byte, ``t`` the time (s) passed to the ``feed()`` that completed it."""

    offset: int
    packet: InstructionPacket | StatusPacket
    raw: bytes
    t: float | None = None

    @property
    def is_status(self) -> bool:
        """True for a status packet, False for an instruction packet."""
        return isinstance(self.packet, StatusPacket)


@dataclass(frozen=True)
class BadChecksumPacket:
    """A candidate packet whose checksum failed (kept with ``report_bad_checksums``):
    ``offset`` of its first header byte, its ``raw`` bytes as framed by its LEN byte, and
    the time (s) passed to the ``feed()`` that completed it."""

    offset: int
    raw: bytes
    t: float | None = None


#: The instruction packet :meth:`DynamixelStreamDecoder.take_whole` decoded last, with its
#: bytes (every node on a bus is handed the same packet).
_last_instruction: tuple[bytes, InstructionPacket] | None = None


class DynamixelStreamDecoder:
    """Turns a byte stream (in chunks of any size) into packets, counting what it drops.

    ``direction`` says what the stream carries: ``"instruction"`` (host -> servos),
    ``"status"`` (servos -> host; frames that cannot be a status - ID > 253 or bit 7 of the
    error byte set - are rejected and scanned past, as dynamixel-sdk does) or ``"auto"``
    (a half-duplex tap seeing both; see :func:`guess_direction`).

    ``gap_timeout`` (seconds): when a ``feed()`` call's ``t`` is more than this after the
    previous call's, a pending partial packet is dropped first (counted in ``gap_drops`` and
    ``bytes_discarded``).  Without ``t`` no gap is detected.

    Counters: ``packets`` (yielded), ``checksum_failures``, ``resyncs`` (discard events,
    checksum failures and rejections included), ``bytes_discarded``, ``rejected``,
    ``gap_drops``.  ``feed()`` never raises for any byte content.

    With ``report_bad_checksums`` each checksum failure is also kept in
    :attr:`bad_checksums` (for capture tools; the scan still resumes inside it).
    """

    def __init__(self, direction: Direction = "auto", gap_timeout: float | None = None,
                 report_bad_checksums: bool = False) -> None:
        if direction not in ("instruction", "status", "auto"):
            raise ValueError(f"direction must be instruction, status or auto, not {direction!r}")
        if gap_timeout is not None and not gap_timeout >= 0:
            raise ValueError(f"gap_timeout must be >= 0 seconds, not {gap_timeout}")
        self.direction: Direction = direction
        self.gap_timeout = gap_timeout
        #: The bytes held back as the start of a possible packet (read-only; a node asks
        #: whether anything is, without :attr:`pending`'s call, for every packet it sees).
        self.held = bytearray()
        self._base = 0  # stream offset of self.held[0]
        self._last_t: float | None = None
        self.packets = self.checksum_failures = self.resyncs = 0  # counters: see the class doc
        self.bytes_discarded = self.rejected = self.gap_drops = 0
        self.report_bad_checksums = report_bad_checksums
        #: Checksum failures seen, in stream order (only with ``report_bad_checksums``).
        self.bad_checksums: list[BadChecksumPacket] = []

    @property
    def pending(self) -> int:
        """Bytes held back as the start of a possible packet."""
        return len(self.held)

    @property
    def offset(self) -> int:
        """Total bytes fed so far (the stream offset of the next byte)."""
        return self._base + len(self.held)

    def reset(self) -> None:
        """Drop any pending partial packet (counted as discarded)."""
        self.bytes_discarded += len(self.held)
        self._base += len(self.held)
        self.held.clear()

    def feed(self, data: BytesLike, t: float | None = None) -> list[DecodedPacket]:
        """Add ``data`` (arriving at time ``t``, seconds) and return the packets it completes."""
        if t is not None:
            last, self._last_t = self._last_t, t
            gap = self.gap_timeout
            if gap is not None and last is not None and self.held and t - last > gap:
                self.gap_drops += 1
                self.reset()
        buf = self.held
        buf += data
        out: list[DecodedPacket] = []
        pos = 0
        while True:
            kind, n = check_packet(buf, pos)
            if kind is FrameKind.NEED_MORE:
                break
            if kind is FrameKind.PACKET:
                raw = bytes(buf[pos : pos + n])
                packet = self._make_packet(raw)
                if packet is not None:
                    out.append(DecodedPacket(self._base + pos, packet, raw, t))
                    self.packets += 1
                    pos += n
                    continue
                self.rejected += 1
                n = _resync_distance(buf, pos)
            elif kind is FrameKind.BAD_CHECKSUM:
                self.checksum_failures += 1
                if self.report_bad_checksums:
                    raw = bytes(buf[pos : pos + buf[pos + 3] + 4])
                    self.bad_checksums.append(BadChecksumPacket(self._base + pos, raw, t))
            self.resyncs += 1
            self.bytes_discarded += n
            pos += n
        del buf[:pos]
        self._base += pos
        return out

    def take_whole(self, data: bytes, t: float | None = None) -> InstructionPacket | None:
        """The instruction packet ``data`` is, if it is exactly one whole packet with a good
        checksum, this decoder reads instructions and nothing is held: the decoder ends as
        :meth:`feed` would leave it (counters, stream offset, arrival time).  Returns None,
        having done nothing, in every other case (then call :meth:`feed`).

        For the arm's nodes, which each get every instruction on their bus as one whole
        packet: the packet is decoded once for all of them (the last one decoded is kept,
        and packets are immutable), not once per node.
        """
        if type(data) is not bytes or self.held or self.direction != "instruction":
            return None
        global _last_instruction
        last = _last_instruction
        if last is not None and last[0] == data:
            packet = last[1]
        else:
            n = len(data)
            if (n < MIN_PACKET_SIZE or data[0] != 0xFF or data[1] != 0xFF or data[2] == 0xFF
                    or not 2 <= data[3] <= MAX_LENGTH or data[3] + 4 != n
                    or ~sum(data[2:-1]) & 0xFF != data[-1]):
                return None
            packet = InstructionPacket(data[2], data[4], data[5:-1])
            _last_instruction = (data, packet)
        if t is not None:
            self._last_t = t  # nothing is held: no gap can discard anything
        self.packets += 1
        self._base += len(data)
        return packet

    def _make_packet(self, raw: bytes) -> InstructionPacket | StatusPacket | None:
        direction = self.direction
        if direction == "auto":
            direction = guess_direction(raw)
        params = raw[5:-1]
        if direction == "instruction":
            return InstructionPacket(raw[2], raw[4], params)
        if raw[2] > MAX_ID or raw[4] > 0x7F:
            return None
        return StatusPacket(raw[2], raw[4], params)


# --------------------------------------------------------------------------- RX-64 units

# The position range (300 degrees over 1024 units, centre 512) is in protocol.robot.
RX64_RPM_PER_UNIT = 0.111  #: revolutions per minute per speed unit
_DIRECTION_BIT: Final = 0x400  # bit 10 of present speed / present load: set = clockwise


def rx64_position_to_radians(units: float) -> float:
    """Position register (0..1023 over 300 degrees) -> radians from the centre (512 = 0 rad);
    positive is counter-clockwise, the direction in which the register increases."""
    return (units - RX64_POSITION_CENTRE) * RX64_RAD_PER_UNIT


def radians_to_rx64_position(angle: float) -> int:
    """Radians from the centre -> position register, rounded and clipped to 0..1023."""
    units = round(angle / RX64_RAD_PER_UNIT) + RX64_POSITION_CENTRE
    return min(max(units, 0), RX64_POSITION_MAX)


def rx64_speed_to_rpm(units: int) -> float:
    """Moving-speed register (0..1023, 0.111 rpm/unit) -> rpm (magnitude).  Beware: 0 in the
    moving-speed register means "maximum, no speed control", not 0 rpm."""
    return (units & 0x3FF) * RX64_RPM_PER_UNIT


def rpm_to_rx64_speed(rpm: float) -> int:
    """Speed magnitude in rpm -> moving-speed register, rounded and clipped to 1..1023."""
    return min(max(round(abs(rpm) / RX64_RPM_PER_UNIT), 1), 0x3FF)


def signed_by_direction_bit(value: int) -> int:
    """A sign-and-magnitude register's value (0..2047, bit 10 = clockwise: the RX-64's present
    speed and load) as a signed number of its units, counter-clockwise > 0."""
    magnitude = value & 0x3FF
    return -magnitude if value & _DIRECTION_BIT else magnitude


def rx64_present_speed_to_rad_s(value: int) -> float:
    """Present-speed register (0..2047, bit 10 = clockwise) -> rad/s, counter-clockwise > 0."""
    return signed_by_direction_bit(value) * RX64_RPM_PER_UNIT * 2 * math.pi / 60


def rad_s_to_rx64_present_speed(speed: float) -> int:
    """Signed rad/s (counter-clockwise > 0) -> present-speed register (clipped to 1023 units)."""
    magnitude = min(round(abs(speed) * 60 / (2 * math.pi) / RX64_RPM_PER_UNIT), 0x3FF)
    return magnitude | (_DIRECTION_BIT if speed < 0 and magnitude else 0)


def rx64_load_to_fraction(value: int) -> float:
    """Present-load register (0..2047, bit 10 = clockwise) -> signed fraction of maximum
    torque in [-1, 1] (1023 = 100 %); counter-clockwise load is positive."""
    return signed_by_direction_bit(value) / 0x3FF


def fraction_to_rx64_load(fraction: float) -> int:
    """Signed fraction of maximum torque -> present-load register (clipped to +-1)."""
    magnitude = min(round(abs(fraction) * 0x3FF), 0x3FF)
    return magnitude | (_DIRECTION_BIT if fraction < 0 and magnitude else 0)


def baud_register_to_bps(value: int) -> float:
    """Baud-rate register (0..254) -> bit/s, ``2_000_000 / (value + 1)``
    (1 -> 1 M, 3 -> 500 k, 16 -> 117647 for "115200", 34 -> 57143 for "57600")."""
    _byte("baud register", value, 0, 254)
    return 2_000_000 / (value + 1)


def bps_to_baud_register(bps: float) -> int:
    """Bit/s -> the nearest baud-rate register value (0..254)."""
    if not bps > 0:
        raise DynamixelError(f"baud rate {bps} must be positive")
    return min(max(round(2_000_000 / bps) - 1, 0), 254)
