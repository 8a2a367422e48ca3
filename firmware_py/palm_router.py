"""The palm's finger links: one transaction in flight per finger, a short queue behind it.

The original motherboard kept one transmit slot per finger and overwrote it when the host
sent again before the finger had answered.  Here each finger's pogo UART is a
:class:`FingerLink`: a :class:`Transaction` (a frame to write, the reply type it waits for,
a timeout) is either in flight, waiting in a queue of at most :data:`QUEUE_DEPTH`, or
refused (``RouteStatus.BUSY``).  Nothing already accepted is ever overwritten or reordered.

Replies are matched as the fmcb sends them: a frame to the host address (0) whose type is
the request's.  A late reply to a transaction that timed out, arriving while a new one of the
same type waits, cannot be told apart (the wire has no sequence numbers); a host that needs
certainty routes a ``txn`` envelope, whose reply echoes its sequence number.

The link also keeps the finger's summary (power, presence, the last polled status) and the
breakaway state: a finger that answered once since power-up and then misses
:data:`LOST_AFTER_MISSES` consecutive polls is *lost* (at a poll rate of r Hz that is
detected within 3/r s: 30 ms at 100 Hz) until it answers again.  A routed transaction the
fmcb lets time out counts as a miss and one it answers as an answer (polls are skipped while
routes keep the link busy), so under host traffic a loss is detected after three
consecutive routed timeouts (three times the host's ``timeout_ms``).

:func:`route_transaction` turns a ``palm.route`` request into a transaction: hop 0 writes
the frame as is; hops 1 and 2 wrap it in an ``fmcb.tunnel`` and unwrap the bytes heard.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

from firmware_py.hal import Clock, Timer, Uart
from protocol.errors import ProtocolError
from protocol.framing import OVERHEAD, Frame
from protocol.messages import CATALOGUE
from protocol.messages.fmcb import TUNNEL_MAX
from protocol.messages.palm import FingerPower, RouteStatus
from protocol.stream import StreamDecoder, decode_all
from protocol.topology import (
    ADDR_BROADCAST,
    ADDR_FMCB,
    ADDR_HOST,
    HOP_NODE,
    Hop,
    wire_time_us,
)

#: Transactions that may wait behind the one in flight, per finger.
QUEUE_DEPTH: Final = 4
#: Consecutive missed polls after which a finger that had answered is declared lost.
LOST_AFTER_MISSES: Final = 3
#: Time an fmcb takes from the end of a request to the start of its reply (µs), assumed.
FMCB_TURNAROUND_US: Final = 500
#: Inter-frame gap of the finger links' decoders (µs), as on every hand link.
LINK_GAP_US: Final = 10_000

_TUNNEL = CATALOGUE.by_name("fmcb.tunnel")

DoneCallback = Callable[[Frame | None, int], None]
"""Called once per transaction with the reply frame (or None) and a route status code."""


@dataclass
class Transaction:
    """One exchange on a finger link.

    ``frame`` is written on the pogo UART; ``expect_type`` is the reply's message type
    (None: nothing comes back, the transaction ends once written); ``timeout_us`` counts
    from the moment the frame is handed to the UART; ``kind`` is ``"route"`` or ``"poll"``
    (a lost finger refuses routes but keeps being polled).
    """

    frame: bytes
    expect_type: int | None
    timeout_us: int
    on_done: DoneCallback
    kind: str = "route"
    timer: Timer | None = field(default=None, repr=False)


class FingerLink:
    """The palm's side of one finger's pogo link, and what the palm knows of that finger."""

    def __init__(self, index: int, uart: Uart, clock: Clock, queue_depth: int = QUEUE_DEPTH
                 ) -> None:
        self.index = index
        self.uart = uart
        self.clock = clock
        self.queue_depth = queue_depth
        self.in_flight: Transaction | None = None
        self.queue: deque[Transaction] = deque()
        self._posted: dict[int, bytes] = {}
        self._decoder = StreamDecoder(gap_s=LINK_GAP_US / 1e6)
        # What the palm knows of the finger.
        self.power: int = FingerPower.OFF
        self.present = False
        self.ever_seen = False
        self.lost = False
        self.misses = 0
        self.last_seen_us: int | None = None
        self.hall_pos = [0, 0, 0]
        self.effort = [0, 0, 0]
        self.cap_sent = 255
        # Counters.
        self.stray_frames = 0
        self.timeouts = 0
        #: Told whether the finger's fmcb answered a routed transaction (True) or let it
        #: time out (False): the palm counts those as answers and misses like its polls,
        #: which it skips while routes keep the link busy.
        self.on_route_heard: Callable[[bool], None] | None = None

    # --- wiring ---------------------------------------------------------------------------
    def start(self) -> None:
        """Listen to the finger's UART."""
        self.uart.set_receiver(self._on_bytes)

    @property
    def idle(self) -> bool:
        """Nothing in flight and nothing queued."""
        return self.in_flight is None and not self.queue

    # --- transactions ---------------------------------------------------------------------
    def submit(self, txn: Transaction) -> bool:
        """Start ``txn`` now or queue it; False (and nothing done) when the queue is full."""
        if self.in_flight is not None and len(self.queue) >= self.queue_depth:
            return False
        self.queue.append(txn)
        if self.in_flight is None:
            self._start_next()
        return True

    def post(self, frame: bytes, key: int) -> None:
        """Send a one-way frame when the link is quiet; a later post with ``key`` replaces it.

        Writing while a finger may be answering would collide on the half-duplex pogo pair,
        so one-way frames (the governor's effort cap) wait for the end of the transaction.
        """
        if self.in_flight is None:
            self.uart.send(frame)
        else:
            self._posted[key] = frame

    def abort_all(self, status: int) -> None:
        """End the transaction in flight and every queued one with ``status``."""
        pending = ([self.in_flight] if self.in_flight is not None else []) + list(self.queue)
        self.queue.clear()
        self._posted.clear()
        self.in_flight = None
        for txn in pending:
            if txn.timer is not None:
                txn.timer.cancel()
            txn.on_done(None, status)

    def _start_next(self) -> None:
        while self.in_flight is None:
            for frame in self._posted.values():
                self.uart.send(frame)
            self._posted.clear()
            if not self.queue:
                return
            txn = self.queue.popleft()
            if self.power == FingerPower.OFF:
                txn.on_done(None, RouteStatus.UNPOWERED)
                continue
            if self.lost and txn.kind == "route":
                txn.on_done(None, RouteStatus.LINK_DOWN)
                continue
            self.uart.send(txn.frame)
            if txn.expect_type is None:
                txn.on_done(None, RouteStatus.OK)
                continue
            self.in_flight = txn
            txn.timer = self.clock.call_later(txn.timeout_us, self._timeout_of(txn))

    def _timeout_of(self, txn: Transaction) -> Callable[[], None]:
        def expire() -> None:
            if self.in_flight is txn:
                self.timeouts += 1
                self._finish(None, RouteStatus.NO_REPLY)

        return expire

    def _finish(self, frame: Frame | None, status: int) -> None:
        txn = self.in_flight
        if txn is None:
            return
        self.in_flight = None
        if txn.timer is not None:
            txn.timer.cancel()
        if txn.kind == "route" and self.on_route_heard is not None \
                and status in (RouteStatus.OK, RouteStatus.NO_REPLY):
            self.on_route_heard(frame is not None)
        txn.on_done(frame, status)
        self._start_next()

    def _on_bytes(self, data: bytes, t_us: int) -> None:
        for frame in self._decoder.feed(data, t_us / 1e6):
            txn = self.in_flight
            if txn is not None and frame.address == ADDR_HOST and frame.type == txn.expect_type:
                self._finish(frame, RouteStatus.OK)
            else:
                self.stray_frames += 1

    # --- finger state ---------------------------------------------------------------------
    def powered_up(self) -> None:
        """The finger was switched on from off: it boots, knows nothing, has not answered."""
        self.present = False
        self.ever_seen = False
        self.lost = False
        self.misses = 0
        self.last_seen_us = None
        self.cap_sent = 255
        self._decoder.reset()

    def powered_down(self) -> None:
        """The finger was switched off: everything waiting for it ends as unpowered."""
        self.abort_all(RouteStatus.UNPOWERED)
        self.powered_up()

    def answered(self) -> bool:
        """A poll was answered now; True if the finger had been lost (it returned)."""
        self.present = True
        self.ever_seen = True
        self.misses = 0
        self.last_seen_us = self.clock.now_us()
        returned = self.lost
        self.lost = False
        return returned

    def missed(self) -> bool:
        """A poll went unanswered; True when this miss makes the finger lost."""
        self.present = False
        self.misses += 1
        if self.ever_seen and not self.lost and self.misses >= LOST_AFTER_MISSES:
            self.lost = True
            return True
        return False

    def last_seen_ms(self) -> int:
        """Milliseconds since the finger last answered, saturating at 65535."""
        if self.last_seen_us is None:
            return 0xFFFF
        return min(0xFFFF, (self.clock.now_us() - self.last_seen_us) // 1000)


def _expects_reply(hop: int, inner: Frame) -> bool:
    """True if the node behind ``hop`` answers ``inner`` (per the catalogue)."""
    if inner.address == ADDR_BROADCAST:
        return False
    msg = CATALOGUE.lookup(HOP_NODE[Hop(hop)], inner.type)
    return msg is None or msg.reply is not None


def tunnel_max_ms(timeout_ms: int, request_bytes: int, baud: int) -> int:
    """How long the fmcb may listen on the tendons so its tunnel reply beats ``timeout_ms``.

    The palm's wait covers: the tunnel request on the pogo line, the fmcb's listening time,
    its turnaround and the longest tunnel reply (:data:`TUNNEL_MAX` bytes heard).
    """
    reply_bytes = OVERHEAD + 2 + TUNNEL_MAX
    spare_us = (timeout_ms * 1000 - wire_time_us(request_bytes, baud)
                - wire_time_us(reply_bytes, baud) - FMCB_TURNAROUND_US)
    return max(0, math.floor(spare_us / 1000))


def route_transaction(hop: int, inner: Frame, raw: bytes, timeout_ms: int, baud: int,
                      respond: Callable[[int, bytes], None]) -> Transaction | None:
    """The transaction that delivers ``raw`` (the complete frame ``inner``) to ``hop``.

    ``respond(status, reply_frame_bytes)`` is called once when it ends.  ``timeout_ms`` 0
    means the host wants no reply.  Returns None when the frame cannot go there (a tunnel
    carries at most :data:`TUNNEL_MAX` bytes).
    """
    wants = timeout_ms > 0 and _expects_reply(hop, inner)
    if hop == Hop.FMCB:
        def hop0_done(frame: Frame | None, status: int) -> None:
            respond(status, frame.to_bytes() if frame is not None else b"")

        return Transaction(raw, inner.type if wants else None, timeout_ms * 1000, hop0_done)
    if len(raw) > TUNNEL_MAX:
        return None
    request_bytes = OVERHEAD + 4 + len(raw)  # u16 length, u16 max_ms, data
    max_ms = tunnel_max_ms(timeout_ms, request_bytes, baud) if wants else 0
    frame = _TUNNEL.request_frame(ADDR_FMCB, data=raw, max_ms=max_ms)
    # With no reply wanted the palm still waits for the fmcb's (empty) tunnel answer, so that
    # answer cannot be mistaken for the next tunnel's.
    wait_us = timeout_ms * 1000 if wants else (
        wire_time_us(len(frame) + OVERHEAD + 2 + TUNNEL_MAX, baud) + FMCB_TURNAROUND_US + 1000)

    def tunnel_done(reply: Frame | None, status: int) -> None:
        if reply is None:
            respond(status, b"")
            return
        try:
            heard = _TUNNEL.parse_reply(reply.payload)["data"]
        except ProtocolError:
            respond(RouteStatus.NO_REPLY, b"")
            return
        answers = [f for f in decode_all(heard) if f.address == ADDR_HOST]
        if answers:
            respond(RouteStatus.OK, answers[0].to_bytes())
        else:
            respond(RouteStatus.NO_REPLY if wants else RouteStatus.OK, b"")

    return Transaction(frame, _TUNNEL.type_id, wait_us, tunnel_done)
