"""The kinds of target the fuzzer knows, and one open link to a target.

A target is reached through any host transport URL: ``emu://…`` opens a *fresh* emulator
in process for every example (so examples are independent and shrinkable; ``physics=1``
adds the MuJoCo plant, off by default for speed), a serial port or pyserial URL reaches a
real board (opened once and kept; only the wire-level oracles apply).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

from host.errors import TransportError
from host.transports.base import Transport, open_transport, url_options
from protocol import dynamixel as dx
from protocol.catalogue import Message
from protocol.errors import ProtocolError
from protocol.framing import Frame, encode_frame
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.messages.fmcb import ControlMode
from protocol.stream import StreamDecoder
from protocol.topology import (
    ADDR_FMCB,
    ADDR_HOST,
    FINGER_BOARDS,
    HAND_BOARDS,
    SERVO_IDS,
    STEPPER_IDS,
    Board,
)
from tools.errors import TargetSilent, WrongTarget
from tools.fuzz.oracles import Introspection

#: Inter-frame gap of the hand nodes' decoders (µs): a partial frame older than this is
#: dropped, so the liveness ping waits a little longer first.
FRAME_GAP_US: Final = 10_000
#: How long the fmcb listens on the tendon bus for a tunnelled frame's answer (ms).
TUNNEL_LISTEN_MS: Final = 10


@dataclass(frozen=True)
class TargetKind:
    """How to fuzz one kind of node: its catalogue namespace and address, whether its
    frames travel inside ``fmcb.tunnel`` (f2, f3 behind a finger's fmcb), whether it
    speaks Dynamixel 1.0, and the emulator URL that has it."""

    name: str
    url: str
    node: str
    address: int = ADDR_FMCB
    via_tunnel: bool = False
    dynamixel: bool = False
    ping_deadline_s: float = 0.05
    #: Addresses of the other nodes on the target's line (never a "foreign" address).
    neighbours: tuple[int, ...] = ()
    #: The board ``identify`` must report (None: not a hand node, not checked).
    board: BoardType | None = None

    def messages(self) -> list[Message]:
        """The catalogue requests this node understands (common ones included)."""
        return [m for m in CATALOGUE if m.node in ("common", self.node) and m.request]

    def wrap(self, frame: bytes) -> bytes:
        """The bytes that carry ``frame`` to the node (inside a tunnel for f2/f3)."""
        if not self.via_tunnel:
            return frame
        return CATALOGUE["fmcb.tunnel"].request_frame(ADDR_FMCB, max_ms=TUNNEL_LISTEN_MS,
                                                      data=frame)

    @property
    def reply_wait_us(self) -> int:
        """How long a step listens for its answer (µs): a tunnel waits on the tendon bus."""
        return (TUNNEL_LISTEN_MS + 5) * 1000 if self.via_tunnel else 5_000


#: The palm answers its first ping later than a finger's board (s).
PALM_PING_DEADLINE_S: Final = 0.2


def _hand_target(board: Board) -> TargetKind:
    """How to fuzz a hand board: the palm on the hand's link, a finger's boards on a loose
    finger's cable (the fmcb directly, a phalange inside its tunnel among its neighbours)."""
    assert board.address is not None
    if board.hop is None:
        return TargetKind(board.app, "emu://hand/palm", board.app, board.address,
                          ping_deadline_s=PALM_PING_DEADLINE_S, board=board.board_type)
    tunnelled = [b.address for b in FINGER_BOARDS if b.hop and b.address is not None]
    return TargetKind(board.app, "emu://loose-finger/finger0", board.app, board.address,
                      via_tunnel=bool(board.hop), board=board.board_type,
                      neighbours=tuple(a for a in tunnelled if a != board.address)
                      if board.hop else ())


TARGETS: Final = {
    **{b.app: _hand_target(b) for b in HAND_BOARDS},
    "bootloader": TargetKind("bootloader", "emu://loose-finger/finger0?ready=0", "bootloader",
                             board=BoardType.FMCB),
    "arm": TargetKind("arm", "emu://arm/arm", "arm", dynamixel=True),
}

def is_motion_frame(frame: bytes, node: str) -> bool:
    """True if ``frame`` is a valid hand frame that commands motion on a finger: an
    ``fmcb.control`` in a mode other than idle, an ``fmcb.motor_raw`` enabling a motor, or
    either inside a ``txn`` envelope or a ``palm.route``."""
    try:
        frames = StreamDecoder().feed(frame)
    except Exception:  # noqa: BLE001 - never raises in practice; be safe
        return False
    return any(_is_motion(f, node) for f in frames)


def _is_motion(frame: Frame, node: str) -> bool:
    return _payload_moves(frame.type, frame.payload, node)


def _payload_moves(type_id: int, payload: bytes, node: str) -> bool:
    msg = CATALOGUE.lookup(node, type_id)
    if msg is None or msg.request is None:
        return False
    try:
        fields = msg.parse_request(payload)
    except Exception:  # noqa: BLE001 - a payload the node would drop
        return False
    if msg.name == "fmcb.control":
        return int(fields["mode"]) != ControlMode.IDLE
    if msg.name == "fmcb.motor_raw":
        return bool(fields["enable"] & 7)
    if msg.name == "txn":
        return _payload_moves(fields["inner_type"], fields["inner"], node)
    if msg.name == "palm.route":
        inner = StreamDecoder().feed(fields["frame"])
        return any(_is_motion(f, "fmcb") for f in inner)
    return False


def is_motion_packet(packet: bytes) -> bool:
    """True if a Dynamixel instruction packet (valid checksum) may move a joint: any
    write (WRITE, REG_WRITE, ACTION, SYNC_WRITE) or RESET."""
    kind, size = dx.check_packet(packet)
    if kind != dx.FrameKind.PACKET:
        return False
    try:
        _id, code, _params = dx.decode_packet(packet[:size])
    except Exception:  # noqa: BLE001
        return False
    return code in (dx.Instruction.WRITE, dx.Instruction.REG_WRITE, dx.Instruction.ACTION,
                    dx.Instruction.SYNC_WRITE, dx.Instruction.RESET)


def _same_kind(answer: Any, request: bytes, link: TargetLink) -> bool:
    if link.kind.dynamixel:
        return len(request) > 2 and getattr(answer, "id", None) == request[2]
    inner = request
    if link.kind.via_tunnel:
        frames = StreamDecoder().feed(request)
        if frames:
            try:
                inner = CATALOGUE["fmcb.tunnel"].parse_request(frames[0].payload)["data"]
            except Exception:  # noqa: BLE001
                return True
    return len(inner) > 4 and answer.type == inner[4]


class TargetLink:
    """One open link to a target, with what the oracles need: write steps, listen, ping,
    the protected state over the wire, and the introspection when emulated."""

    def __init__(self, kind: TargetKind, transport: Transport,
                 introspection: Introspection | None = None, emulator: Any = None) -> None:
        self.kind = kind
        self.transport = transport
        self.introspection = introspection
        self.emulator = emulator
        self._ping_id = 0

    # --- opening ------------------------------------------------------------------------
    @classmethod
    def open(cls, kind: TargetKind, port: str, seed: int = 0,
             shared: dict[str, Transport] | None = None) -> TargetLink:
        """A link to ``kind`` on ``port``: a fresh emulator for ``emu://`` URLs, else the
        transport in ``shared`` (opened once).  The target must answer a ping before
        anything is sent to it: :class:`TargetSilent` if it does not (a wrong port or
        ``--target``, a board unpowered), so a dead link is never taken for a finding; and
        a hand node must identify as the target's board (:class:`WrongTarget`: the palm's
        port fuzzed as an fmcb, both at address 10)."""
        if port.startswith("emu://"):
            link = cls._open_emulated(kind, port, seed)
        else:
            cache = shared if shared is not None else {}
            transport = cache.get(port)
            if transport is None or transport.closed:
                transport = cache[port] = open_transport(port)
            link = cls(kind, transport)
            link.prepare()
        if not link.alive():
            link.close()
            raise TargetSilent(
                f"no {kind.name} answers a ping on {port} within "
                f"{kind.ping_deadline_s * 1e3:.0f} ms (one retry) before anything was sent: "
                f"check the port and the target (in the emulator in process the {kind.name} "
                f"is on {kind.url}), and that the board is powered and running")
        board = link.identify_board()
        if board is not None and kind.board is not None and board != kind.board:
            link.close()
            raise WrongTarget(
                f"the node answering on {port} at address {kind.address} identifies as "
                f"{board.name}, not {kind.board.name} (the {kind.name} target): check the "
                f"port and the target (in the emulator in process the {kind.name} is on "
                f"{kind.url})")
        return link

    @classmethod
    def _open_emulated(cls, kind: TargetKind, port: str, seed: int) -> TargetLink:
        from hil_emulator.emulator import Emulator
        from hil_emulator.inprocess import EmulatorTransport, bring_up
        from hil_emulator.introspection import EmulatorIntrospection

        rest = port.split("://", 1)[1].split("?", 1)[0]
        config, _, link_name = rest.partition("/")
        options = url_options(port)
        physics = options.get("physics", "0") not in ("0", "false", "no")
        ready = options.get("ready", "1") not in ("0", "false", "no")
        emulator = Emulator(config, seed=int(options.get("seed", seed)), physics=physics,
                            can="none")
        if ready and config != "arm":
            bring_up(emulator)
        transport = EmulatorTransport(emulator, link_name or {"arm": "arm",
                                                              "loose-finger": "finger0"}
                                      .get(config, "palm"))
        link = cls(kind, transport, EmulatorIntrospection(emulator), emulator)
        link.prepare()
        return link

    def prepare(self) -> None:
        """Put the target where the campaign starts: a bootloader target halts its
        autoboot countdown."""
        if self.kind.name == "bootloader":
            self.transport.send(CATALOGUE["bl.halt"].request_frame(self.kind.address))
            self.listen(0.02)

    def close(self) -> None:
        """Close an emulated target's link (a real port stays open for the next example)."""
        if self.emulator is not None:
            self.transport.close()
            self.emulator.close()

    # --- traffic ------------------------------------------------------------------------
    def wrap(self, frame: bytes) -> bytes:
        """The bytes that carry ``frame`` to the target (inside a tunnel for f2/f3)."""
        return self.kind.wrap(frame)

    def write(self, chunks: tuple[tuple[bytes, int], ...]) -> None:
        """Send each chunk after its gap (µs) on the link's clock."""
        for chunk, gap_us in chunks:
            if gap_us:
                self.transport.sleep(gap_us / 1e6)
            self.transport.send(chunk)

    def listen(self, seconds: float) -> bytes:
        """Everything the target sends during ``seconds`` (link clock)."""
        end = self.transport.now() + seconds
        out = bytearray()
        while (left := end - self.transport.now()) > 0:
            out += self.transport.recv(timeout=left)
        return bytes(out)

    @property
    def reply_wait_us(self) -> int:
        """How long a step listens for its answer (µs): a tunnel waits on the tendon bus."""
        return self.kind.reply_wait_us

    def answers(self, data: bytes, like: bytes | None = None) -> list[Any]:
        """Replies in ``data``: hand frames to the host (for a tunnelled target, the frames
        inside non-empty tunnel replies) or Dynamixel status packets.  With ``like`` (the
        bytes of a request) only answers to that request's type (hand) or ID (Dynamixel):
        a slow answer to an earlier request may still be on its way."""
        if like is not None:
            return [a for a in self.answers(data) if _same_kind(a, like, self)]
        if self.kind.dynamixel:
            return [p.packet for p in dx.DynamixelStreamDecoder("status").feed(data)]
        decoder = StreamDecoder()
        frames = [f for f in decoder.feed(data) + decoder.flush() if f.address == ADDR_HOST]
        if not self.kind.via_tunnel:
            return frames
        tunnel = CATALOGUE["fmcb.tunnel"]
        inner: list[Any] = []
        for f in frames:
            if f.type != tunnel.type_id:
                inner.append(f)  # an fmcb answer of another type is an answer too
                continue
            try:
                heard = tunnel.parse_reply(f.payload)["data"]
            except Exception:  # noqa: BLE001
                inner.append(f)
                continue
            inner += [g for g in StreamDecoder().feed(heard) if g.address == ADDR_HOST]
        return inner

    def ping_once(self) -> bool:
        """One ping: True if the answer came within the deadline."""
        if self.kind.dynamixel:
            ids = (*STEPPER_IDS, *SERVO_IDS)
            dxl_id = ids[self._ping_id % len(ids)]
            self._ping_id += 1
            self.transport.send(dx.make_ping(dxl_id).encode())
            got = self.listen(self.kind.ping_deadline_s)
            return any(getattr(p, "id", None) == dxl_id for p in self.answers(got))
        ping = CATALOGUE["ping"]
        self.transport.send(self.wrap(encode_frame(self.kind.address, ping.type_id)))
        got = self.listen(self.kind.ping_deadline_s)
        return any(f.type == ping.type_id for f in self.answers(got))

    def identify_board(self) -> BoardType | None:
        """The board the target's node reports to ``identify`` (None: not a hand target,
        or no answer: then it is not checked).  The palm and an fmcb share address 10, so
        a ping alone does not tell an fmcb's port from the palm's."""
        if self.kind.board is None:
            return None
        identify = CATALOGUE["identify"]
        self.transport.sleep(FRAME_GAP_US * 1.2 / 1e6)
        self.transport.send(self.wrap(identify.request_frame(self.kind.address)))
        for f in self.answers(self.listen(self.kind.ping_deadline_s)):
            if f.type == identify.type_id:
                try:
                    return BoardType(identify.parse_reply(f.payload)["board"])
                except (ValueError, KeyError, ProtocolError):
                    return None
        return None

    def alive(self) -> bool:
        """The liveness oracle: after the inter-frame gap, a ping answered (one retry).  On
        a real port a :class:`TransportError` (the port gone: unplugged, the emulator
        behind a pty stopped) is raised, not taken for a target that stopped answering."""
        try:
            self.transport.sleep(FRAME_GAP_US * 1.2 / 1e6)
            return self.ping_once() or self.ping_once()
        except TransportError:
            if self.emulator is None:
                raise
            return False

    def protected_over_wire(self) -> tuple[bytes, ...]:
        """Bootloader target: the SHA-256 of the bootloader pages and identify's board, uid
        and address, as the wire tells them (empty for other targets)."""
        if self.kind.name != "bootloader":
            return ()
        # Back into the bootloader (a bl.boot may have started the application), halted.
        self.transport.send(CATALOGUE["reset"].request_frame(self.kind.address))
        self.listen(0.02)
        self.prepare()
        out: list[bytes] = []
        for name, fields in (("bl.hash", {"start_page": 0, "pages": 32}), ("identify", {})):
            msg = CATALOGUE[name]
            self.transport.send(msg.request_frame(self.kind.address, fields))
            replies = [f for f in self.answers(self.listen(0.1)) if f.type == msg.type_id]
            if not replies:
                out.append(b"no answer to " + name.encode())
                continue
            parsed = msg.parse_reply(replies[-1].payload)
            if name == "identify":
                parsed = {k: parsed[k] for k in ("board", "uid", "address")}
            out.append(repr(sorted(parsed.items())).encode())
        return tuple(out)
