"""What every hand-protocol program shares: frame decoding, dispatch, replies.

A :class:`HandNode` listens on one or more UARTs with the protocol's stream decoder (10 ms
inter-frame gap, as the original f2/f3/palm parsers), accepts frames addressed to it or
broadcast, checks the payload against the catalogue (a wrong length is dropped and counted,
never acted on), and calls the handler registered for that message.  It answers the common
messages (ping, reset, hardware version, identify, transaction envelope) itself.

A handler gets a :class:`~firmware_py.node_request.Request` and returns the reply fields (a
dict), ``None`` when the message has no reply, or
:data:`~firmware_py.node_request.DEFERRED` when it will answer later.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Final

from mypy_extensions import mypyc_attr

from firmware_py.hal import Hal, Uart
from firmware_py.identity import read_identity
from firmware_py.node_request import DEFERRED, Handler, Request
from firmware_py.slot_service import SlotService
from protocol.catalogue import REQUEST, Message
from protocol.errors import ProtocolError
from protocol.framing import Frame, encode_frame
from protocol.messages import CATALOGUE, CATALOGUE_HASH
from protocol.messages.common import Running, TxnStatus
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_BROADCAST, ADDR_HOST

#: Inter-frame gap after which a partial frame is dropped (µs).
FRAME_GAP_US: Final = 10_000


@dataclass
class NodeCounters:
    """Protocol statistics of a node (counts)."""

    frames: int = 0
    not_for_me: int = 0
    unknown_type: int = 0
    bad_payload: int = 0
    replies: int = 0


#: What :meth:`HandNode.dispatch` finds for a type id without a handler.
_NO_ROUTE: Final[tuple[Message | None, Handler | None]] = (None, None)


# The compiled core (mypyc) lets a program written in Python subclass it, as the source does.
@mypyc_attr(allow_interpreted_subclasses=True)
class HandNode:
    """Base of every hand-protocol program (applications and the bootloader).

    ``node_kind`` chooses the catalogue section (``"fmcb"``, ``"bootloader"``, …);
    ``fw_version`` is reported by identify: the class's ``FW_VERSION`` unless the booted
    image's version replaces it (:meth:`firmware_py.mcu.Mcu.boot`).
    """

    node_kind: ClassVar[str] = "common"
    #: The version the program declares (major, minor, patch).
    FW_VERSION: ClassVar[tuple[int, int, int]] = (0, 1, 0)
    running: ClassVar[Running] = Running.APPLICATION
    #: The program knows the two-slot layout and answers ``slot.*`` (False: a program
    #: built for the one-slot layout, which answers none of them).
    two_slots: ClassVar[bool] = True

    def __init__(self, hal: Hal) -> None:
        self.hal = hal
        #: The version identify reports (major, minor, patch).
        self.fw_version: tuple[int, int, int] = self.FW_VERSION
        self.identity = read_identity(hal.flash)
        self.address = self.identity.address
        self.counters = NodeCounters()
        self._handlers: dict[int, Handler] = {}
        #: By type id: the message it means on this node (catalogue lookup) and its handler.
        self._routes: dict[int, tuple[Message | None, Handler]] = {}
        self._decoders: dict[int, StreamDecoder] = {}
        self.handle("ping", lambda req: {})
        self.handle("hw_version", lambda req: {"version": self.identity.hw_version})
        self.handle("identify", self._identify)
        self.handle("reset", self._reset)
        self.handle("txn", self._txn)
        board = self.identity.board_type
        #: The ``slot.*`` service (None on a one-slot program or a board without an identity).
        self.slots: SlotService | None = None
        if self.two_slots and board is not None:
            application = self.running == Running.APPLICATION
            self.slots = SlotService(self, hal, board, application, health=self.health_check)
            if application:
                self.slots.start_self_check()

    def health_check(self) -> bool:
        """The application's own check before it confirms a trial image it was asked to
        confirm itself (see :mod:`firmware_py.slot_service`): True by default, once it has
        run :data:`~firmware_py.slot_service.SELF_CHECK_US` without a reset."""
        return True

    # --- wiring ---------------------------------------------------------------------------
    def listen(self, uart: Uart) -> None:
        """Decode hand frames arriving on ``uart`` and dispatch them."""
        decoder = StreamDecoder(gap_s=FRAME_GAP_US / 1e6)
        self._decoders[id(uart)] = decoder

        counters, broadcast = self.counters, ADDR_BROADCAST

        def on_bytes(data: bytes, t_us: int) -> None:
            # A whole frame for another node (a bus delivers frame by frame): count it as
            # on_frame would, without building it.
            address = data[1] if len(data) > 1 else broadcast
            t = t_us / 1e6
            if address != self.address and address != broadcast and decoder.pass_frame(data, t):
                counters.not_for_me += 1
                return
            for frame in decoder.feed(data, t):
                self.on_frame(frame, uart)

        uart.set_receiver(on_bytes)

    def handle(self, name: str, handler: Handler) -> None:
        """Register ``handler`` for the message called ``name``."""
        msg = CATALOGUE.by_name(name)
        self._handlers[msg.type_id] = handler
        self._routes[msg.type_id] = (CATALOGUE.lookup(self.node_kind, msg.type_id), handler)

    # --- dispatch -------------------------------------------------------------------------
    def accepts(self, frame: Frame) -> bool:
        """True if the frame is for this node (its address or broadcast)."""
        return frame.address in (self.address, ADDR_BROADCAST)

    def on_frame(self, frame: Frame, uart: Uart) -> None:
        """A complete, CRC-valid frame arrived on ``uart``."""
        if not self.accepts(frame):
            self.counters.not_for_me += 1
            return
        self.counters.frames += 1
        reply_to_broadcast = frame.address != ADDR_BROADCAST

        def send(payload: bytes | None, status: int) -> None:
            if payload is not None and reply_to_broadcast:
                self.send_reply(uart, frame.type, payload)

        self.dispatch(frame.type, frame.payload, frame, uart, send)

    def dispatch(self, msg_type: int, payload: bytes, frame: Frame, uart: Uart,
                 send: Callable[[bytes | None, int], None]) -> None:
        """Decode ``payload`` as message ``msg_type`` and run its handler."""
        msg, handler = self._routes.get(msg_type, _NO_ROUTE)
        if msg is None or handler is None or msg.request is None:
            self.counters.unknown_type += 1
            send(None, TxnStatus.UNKNOWN_TYPE)
            return
        try:
            fields = msg.parse(REQUEST, payload)
        except ProtocolError:
            self.counters.bad_payload += 1
            send(None, TxnStatus.BAD_PAYLOAD)
            return
        request = Request(msg, fields, frame, uart, send)
        result = handler(request)
        if result is DEFERRED:
            return
        if result is None or msg.reply is None:
            return
        request.respond(result)

    def send_reply(self, uart: Uart, msg_type: int, payload: bytes) -> None:
        """Send a reply frame to the host address with the request's type."""
        self.counters.replies += 1
        uart.send(encode_frame(ADDR_HOST, msg_type, payload))

    # --- common messages ------------------------------------------------------------------
    def _identify(self, req: Request) -> dict[str, Any]:
        major, minor, patch = self.fw_version
        return {
            "board": self.identity.board,
            "address": self.address,
            "running": self.running,
            "hw_version": self.identity.hw_version,
            "fw_version": {"major": major, "minor": minor, "patch": patch},
            "catalogue": CATALOGUE_HASH,
            "uid": self.identity.uid,
            "uptime_us": self.hal.clock.now_us() & 0xFFFFFFFF,
        }

    def _reset(self, req: Request) -> None:
        req.respond({})
        # Reset after the acknowledgement has left the UART.
        self.hal.clock.call_later(200, self.hal.reset)
        return None

    def _txn(self, req: Request) -> Any:
        seq = req.fields["seq"]
        inner_type = req.fields["inner_type"]
        txn = CATALOGUE.by_name("txn")

        answered: list[bool] = []

        def send(payload: bytes | None, status: int) -> None:
            answered.append(True)
            req.respond(
                txn.build_reply(
                    seq=seq,
                    board=self.identity.board,
                    address=self.address,
                    inner_type=inner_type,
                    status=status,
                    inner=payload or b"",
                )
            )

        if inner_type == txn.type_id:
            send(None, TxnStatus.REFUSED)
            return DEFERRED
        inner_frame = Frame(req.frame.address, inner_type, req.fields["inner"], req.frame.offset)
        msg = CATALOGUE.lookup(self.node_kind, inner_type)
        self.dispatch(inner_type, req.fields["inner"], inner_frame, req.uart, send)
        if not answered and msg is not None and msg.reply is None:
            send(b"", TxnStatus.OK)  # messages without replies are acknowledged by the envelope
        return DEFERRED
