"""One hand link as a conversation: requests matched to replies, routing, events.

A :class:`HandSession` owns one :class:`~host.transports.base.Transport` to a hand link: the
palm's port (``link="palm"``), or a loose finger's cable (``link="finger"``, its fmcb on the
other end).  Every request travels in the ``txn`` envelope with a sequence number, and the
reply is matched by that number, never by type, so replies may arrive in any order and a
late reply to a request that already timed out is recognised and dropped.  A request sent
with ``txn=False`` goes as the original hand's host sent it, plain, and its reply is matched
by type (:meth:`HandSession.start`).

Where a request goes is a :class:`Target`: the link's own node, or a node behind it
(``finger``, ``hop``: 0 fmcb, 1 f2, 2 f3).  Behind the palm the request is routed with
``palm.route``; the routed frame is itself a ``txn`` with its own sequence number, so a stale
answer the palm picked up on a finger link is told apart too.  The palm reaches f2/f3 through
the fmcb's tendon tunnel; on a loose finger's cable the session wraps the frame in
``fmcb.tunnel`` itself.  Timeouts add up along the hops (:class:`Timeouts`).

All waiting goes through ``transport.recv(timeout)`` and ``transport.now()``: on an
in-process emulator the same code runs on the simulation clock.

Unsolicited ``palm.finger_event`` frames are kept in :attr:`HandSession.events` (a bounded
queue) and handed to subscribers (:meth:`HandSession.subscribe`) as they arrive, whatever
the session is waiting for.
"""

from __future__ import annotations

import logging
import secrets
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

from host.code_names import code_name
from host.errors import NodeError, ReplyTimeout, RouteError, UsageError
from host.recording.prologue import Prologue
from host.transports.base import Transport, declared_links, link_of
from protocol.catalogue import Message
from protocol.errors import ProtocolError
from protocol.framing import Frame, encode_frame, parse_frame
from protocol.messages import CATALOGUE
from protocol.messages.common import TxnStatus
from protocol.messages.fmcb import ControlMode
from protocol.messages.palm import FingerEvent as EventCode
from protocol.messages.palm import RouteStatus
from protocol.stream import StreamDecoder, decode_all
from protocol.topology import ADDR_HOST, ADDR_PALM, FINGERS, HOP_ADDRESS, HOP_NODE, Hop

log = logging.getLogger(__name__)

_TXN: Final = CATALOGUE.by_name("txn")
_ROUTE: Final = CATALOGUE.by_name("palm.route")
_TUNNEL: Final = CATALOGUE.by_name("fmcb.tunnel")
_EVENT: Final = CATALOGUE.by_name("palm.finger_event")

#: Requests never repeated automatically: repeating them changes the outcome.
NOT_IDEMPOTENT: Final = frozenset({"reset", "txn", "fmcb.tunnel", "fmcb.param_commit"})
#: Waits shorter than this (s) count as over: clocks tick in µs at best.
_EPSILON_S: Final = 1e-6
#: Route statuses worth trying again (the finger may answer next time).
ROUTE_RETRYABLE: Final = frozenset({RouteStatus.NO_REPLY, RouteStatus.BUSY})
#: Finger events kept in :attr:`HandSession.events` (oldest dropped first).
EVENT_QUEUE: Final = 256

Tap = Callable[[str, float, bytes], None]
"""Called with ``("tx" | "rx", time_s, frame_bytes)`` for every frame sent or decoded."""


def is_idempotent(name: str, fields: Mapping[str, Any] | None = None) -> bool:
    """True if sending request ``name`` twice leaves the robot as sending it once."""
    if name in NOT_IDEMPOTENT or name.startswith("bl."):
        return False
    mode = (fields or {}).get("mode")
    relative = mode == ControlMode.RELATIVE or (
        isinstance(mode, str) and mode.lower() == ControlMode.RELATIVE.name.lower())
    return not (name == "fmcb.control" and relative)


@dataclass(frozen=True)
class Target:
    """Where a request goes: the link's own node (``finger`` None), or the node at ``hop``
    (0 fmcb, 1 f2, 2 f3) of finger ``finger`` behind it."""

    finger: int | None = None
    hop: int = 0

    def describe(self) -> str:
        """``"palm"``-free wording for messages: ``"finger 2 f3"`` or ``"the link's node"``."""
        if self.finger is None and self.hop == 0:
            return "the link's node"
        where = "" if self.finger is None else f"finger {self.finger} "
        node = HOP_NODE[Hop(self.hop)] if self.hop in HOP_NODE else f"hop {self.hop}"
        return f"{where}{node}"


#: The node at the other end of the link (the palm, or a loose finger's fmcb).
LINK_NODE: Final = Target()


@dataclass(frozen=True)
class Timeouts:
    """How long each stage may take; a routed request's deadline is their sum.

    ``link_s`` (s): the host link both ways and the first node's turnaround, including a
    palm poll that may be occupying the finger link; ``fmcb_ms`` (ms): what the palm waits
    for an fmcb's reply (the route timeout at hop 0); ``tendon_ms`` (ms): what a phalange
    behind the fmcb's tunnel adds (hops 1 and 2).
    """

    link_s: float = 0.030
    fmcb_ms: int = 10
    tendon_ms: int = 10

    @classmethod
    def for_url(cls, url: str, link_s: float | None = None) -> Timeouts:
        """The defaults for the link ``url`` names, with ``link_s`` (s) if given:
        the budget the link's backend declares (:func:`~host.transports.base.link_of`)."""
        if link_s is None:
            declared = link_of(url).budget_s
            link_s = cls.link_s if declared is None else declared
        if not link_s > 0:
            raise UsageError(f"link budget {link_s} s: it must be > 0")
        return cls(link_s=float(link_s))

    def route_ms(self, hop: int, extra_ms: int = 0) -> int:
        """The ``palm.route`` timeout (ms) for a node at ``hop``."""
        return self.fmcb_ms + (self.tendon_ms if hop else 0) + extra_ms


class _LinkBudgets(Mapping[str, float]):
    """Default :attr:`Timeouts.link_s` (s) by kind of link, as the transports declare them
    (:class:`~host.transports.base.LinkKind`; read when first asked).  In process the simulation
    clock makes wire times exact, so the palm's own budget (30 ms) is all; a serial link
    adds a USB adapter's latency timer (16 ms by default, each way) and, on the emulator's
    ptys, a busy machine's scheduling; CAN adapters buffer similarly; a network link adds
    its round trip."""

    def _table(self) -> dict[str, float]:
        return {name: kind.budget_s for name, kind in declared_links().items()
                if kind.budget_s is not None}

    def __getitem__(self, name: str) -> float:
        return self._table()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table())

    def __len__(self) -> int:
        return len(self._table())


LINK_BUDGET_S: Final[Mapping[str, float]] = _LinkBudgets()


def frame_gap_s(url: str, timeouts: Timeouts) -> float:
    """The pause (s, link clock) after which the session's decoder drops a partial frame.

    In process the bytes arrive at their wire times, so the decoder's own rule holds
    (:class:`~protocol.stream.StreamDecoder`'s 10 ms).  Anywhere else the host sees the
    bytes when its reads return, and one frame may arrive in pieces far apart: a USB
    adapter hands over what it has every latency timer (16 ms), a USB-CAN adapter and the
    host's CAN driver batch the frame's 8-byte pieces, and a busy machine may not schedule
    the reader for tens of ms.  There a pause within a frame is allowed as long as the
    link budget (``timeouts.link_s``); only a longer silence drops a partial frame (a reply
    cut off by a reset, say), and by then its request has timed out anyway."""
    default = StreamDecoder().gap_s
    assert default is not None
    if link_of(url).exact_timing:
        return default
    return max(default, timeouts.link_s)


def first_seq(url: str) -> int:
    """Where a session's sequence numbers start (they count up from the one after it,
    modulo 256).  In process, 0, so a run is repeatable.  On a real link a random number:
    a program stopped mid-request (Ctrl-C) leaves replies on their way, and a session
    opened right after it, counting from 0 too, would take the one to its own first
    request's number as the answer."""
    if link_of(url).exact_timing:
        return 0
    return secrets.randbelow(256)


@dataclass(frozen=True)
class FingerEvent:
    """An unsolicited ``palm.finger_event``: ``event`` is its name (``"lost"``,
    ``"returned"``, ``"breaker_trip"``, ``"powered"``, ``"unpowered"``), ``palm_time_us``
    the palm's µs timestamp, ``t`` the host link's clock (s) when it arrived."""

    finger: int
    event: str
    code: int
    palm_time_us: int
    t: float


@dataclass
class SessionCounters:
    """What the session saw (counts)."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    stale_replies: int = 0
    stray_frames: int = 0
    events: int = 0


@dataclass
class PendingReply:
    """A request sent and not yet answered; :meth:`HandSession.wait` gives its result."""

    message: Message
    fields: dict[str, Any]
    target: Target
    payload: bytes
    route_ms: int
    retries_left: int
    txn: bool = True
    seq: int = -1
    inner_seq: int | None = None
    routed: bool = False
    reply_type: int = -1
    deadline: float = 0.0
    budget_s: float = 0.0
    done: bool = False
    result: dict[str, Any] | None = None
    error: Exception | None = field(default=None, repr=False)

    @property
    def name(self) -> str:
        """Catalogue name of the request."""
        return self.message.name


class HandSession:
    """Requests and replies on one hand link; see the module docs."""

    def __init__(self, transport: Transport, *, link: str = "palm",
                 timeouts: Timeouts | None = None, retries: int = 2) -> None:
        """``timeouts`` default to :meth:`Timeouts.for_url` of the transport's URL."""
        if link not in ("palm", "finger"):
            raise UsageError(f"link {link!r}: a hand link is 'palm' or 'finger'")
        self.transport = transport
        self.link = link
        self.timeouts = timeouts or Timeouts.for_url(transport.url)
        self.retries = retries
        self.decoder = StreamDecoder(gap_s=frame_gap_s(transport.url, self.timeouts))
        self.counters = SessionCounters()
        self.events: deque[FingerEvent] = deque(maxlen=EVENT_QUEUE)
        self.taps: list[Tap] = []
        #: The first frames each way since the session opened, while no tap listened (for
        #: a recorder attaching later).
        self.prologue = Prologue()
        self._subscribers: list[Callable[[FingerEvent], None]] = []
        self._pending: dict[int, PendingReply] = {}
        self._untagged: list[PendingReply] = []
        self._seq = first_seq(transport.url)

    # --- lifetime --------------------------------------------------------------------------
    def close(self) -> None:
        """Close the transport (idempotent)."""
        self.transport.close()

    def __enter__(self) -> HandSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def now(self) -> float:
        """The link's clock (s)."""
        return self.transport.now()

    # --- requests --------------------------------------------------------------------------
    def request(self, name: str, fields: Mapping[str, Any] | None = None, *,
                to: Target | None = LINK_NODE, retries: int | None = None,
                extra_ms: int = 0, txn: bool = True) -> dict[str, Any]:
        """Send request ``name`` with ``fields`` to ``to`` (None: the link's own node) and
        return the reply's fields.

        ``retries`` (default: the session's, but 0 for requests that are not idempotent)
        repeats the request after a timeout, a busy node or a route that got no reply;
        ``extra_ms`` lengthens the node's time to answer (a flash write).  ``txn`` False
        sends it without the ``txn`` envelope (see :meth:`start`).  Raises
        :class:`ReplyTimeout`, :class:`RouteError`, :class:`NodeError`.
        """
        return self.wait(self.start(name, fields, to=to, retries=retries, extra_ms=extra_ms,
                                    txn=txn))

    def start(self, name: str, fields: Mapping[str, Any] | None = None, *,
              to: Target | None = LINK_NODE, retries: int | None = None,
              extra_ms: int = 0, txn: bool = True) -> PendingReply:
        """Send request ``name`` now and return it pending: several may be in flight, and
        :meth:`wait` takes them in any order.

        ``txn`` False sends the request (and, when routed, the frame inside the route or
        tunnel) without the ``txn`` envelope, as the original hand's host did: the bytes a
        recorded session sent, or a node that does not know the envelope.  Its reply is
        matched by type, oldest such request first, so a late reply may be taken for a
        newer request's: keep one in flight at a time.  Un-enveloped, a request that has
        no reply gets none (it ends in :class:`ReplyTimeout`; routed, in a ``no_reply``
        :class:`RouteError`).
        """
        try:
            message = CATALOGUE.by_name(name)
        except (KeyError, ProtocolError) as exc:
            raise UsageError(f"no message called {name!r} in the catalogue") from exc
        if message.request is None:
            raise UsageError(f"{name} is not a request (nothing sends it to a node)")
        if to is None:
            to = LINK_NODE
        if not isinstance(to, Target):
            raise UsageError(f"to={to!r}: give a Target(finger, hop), or None for the "
                             f"link's own node")
        self._check_target(to)
        plain = dict(fields or {})
        try:
            payload = message.build_request(plain)
        except ProtocolError as exc:
            raise UsageError(f"{name}: cannot build the request from {plain}: {exc}") from exc
        if retries is None:
            retries = self.retries if is_idempotent(name, plain) else 0
        pending = PendingReply(message, plain, to, payload,
                               self.timeouts.route_ms(to.hop, extra_ms), retries, txn=txn)
        self._send(pending)
        return pending

    def wait(self, pending: PendingReply) -> dict[str, Any]:
        """Wait for ``pending``'s reply (retrying as it allows) and return its fields."""
        while True:
            while not pending.done:
                remaining = pending.deadline - self.transport.now()
                if remaining <= _EPSILON_S:
                    # a host busy elsewhere past the deadline takes what came meanwhile
                    # first: a reply waiting unread did not time out
                    self._read(0.0)
                    if not pending.done:
                        self._expire(pending)
                    break
                self._read(remaining)
            if pending.error is None:
                assert pending.result is not None
                return pending.result
            if pending.retries_left > 0 and _retryable(pending.error):
                pending.retries_left -= 1
                self.counters.retries += 1
                self._send(pending)
                continue
            raise pending.error

    def pump(self, timeout: float = 0.0) -> None:
        """Take in what the link has (waiting up to ``timeout`` s for something): replies
        to pending requests and finger events."""
        self._read(timeout)

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass on the link's clock while taking in replies and events."""
        end = self.transport.now() + seconds
        while (left := end - self.transport.now()) > _EPSILON_S:
            self._read(left)

    # --- events ----------------------------------------------------------------------------
    def subscribe(self, callback: Callable[[FingerEvent], None]) -> Callable[[], None]:
        """Call ``callback(event)`` for every finger event; returns the unsubscribe call."""
        self._subscribers.append(callback)

        def unsubscribe() -> None:
            if callback in self._subscribers:
                self._subscribers.remove(callback)

        return unsubscribe

    def next_event(self, timeout: float = 0.0) -> FingerEvent | None:
        """The oldest queued finger event, waiting up to ``timeout`` s for one."""
        end = self.transport.now() + timeout
        while not self.events:
            left = end - self.transport.now()
            if left <= _EPSILON_S:
                return None
            self._read(left)
        return self.events.popleft()

    # --- internals: sending ----------------------------------------------------------------
    def _check_target(self, to: Target) -> None:
        if to.hop not in HOP_ADDRESS:
            raise UsageError(f"hop {to.hop}: a finger has hops 0 (fmcb), 1 (f2), 2 (f3)")
        if self.link == "palm":
            if to.finger is None and to.hop != 0:
                raise UsageError("a phalange behind the palm needs a finger index")
            if to.finger is not None and not 0 <= to.finger < FINGERS:
                raise UsageError(f"finger {to.finger}: the hand has fingers 0..{FINGERS - 1}")
        elif to.finger not in (None, 0):
            raise UsageError(f"finger {to.finger}: a loose finger's link has finger 0 only")

    def _next_seq(self) -> int:
        for _ in range(256):
            self._seq = (self._seq + 1) & 0xFF
            if self._seq not in self._pending:
                return self._seq
        raise UsageError("256 requests are in flight on this link; wait for some first")

    def _envelope(self, address: int, seq: int, inner_type: int, inner: bytes) -> bytes:
        return encode_frame(address, _TXN.type_id,
                            _TXN.build_request(seq=seq, inner_type=inner_type, inner=inner))

    def _send(self, pending: PendingReply) -> None:
        """(Re)send ``pending`` with fresh sequence numbers and deadline."""
        msg, to = pending.message, pending.target
        body_type, body = msg.type_id, pending.payload
        pending.inner_seq = None
        pending.routed = to.finger is not None or to.hop != 0
        wait_s = self.timeouts.link_s
        if pending.routed:
            address = HOP_ADDRESS[Hop(to.hop)]
            if pending.txn:
                pending.inner_seq = self._next_seq()
                inner = self._envelope(address, pending.inner_seq, msg.type_id, pending.payload)
            else:
                inner = encode_frame(address, msg.type_id, pending.payload)
            if self.link == "palm":
                body_type, body = _ROUTE.type_id, _ROUTE.build_request(
                    finger=to.finger, hop=to.hop, timeout_ms=pending.route_ms, frame=inner)
                # The palm serves one transaction per finger: ours queue behind each other.
                ahead = sum(p.route_ms for p in (*self._pending.values(), *self._untagged)
                            if p.target.finger == to.finger)
                wait_s += (pending.route_ms + ahead) / 1000
            else:
                tendon_ms = pending.route_ms - self.timeouts.fmcb_ms
                body_type, body = _TUNNEL.type_id, _TUNNEL.build_request(
                    data=inner, max_ms=tendon_ms)
                wait_s += tendon_ms / 1000
        pending.done, pending.result, pending.error = False, None, None
        if pending.txn:
            pending.seq = self._next_seq()
            frame = self._envelope(ADDR_PALM, pending.seq, body_type, body)
            self._pending[pending.seq] = pending
        else:
            pending.seq, pending.reply_type = -1, body_type
            frame = encode_frame(ADDR_PALM, body_type, body)
            self._untagged.append(pending)
        self.counters.requests += 1
        now = self.transport.now()
        pending.budget_s = wait_s
        pending.deadline = now + wait_s
        for tap in self.taps:
            tap("tx", now, frame)
        self._keep("tx", now, frame)
        self.transport.send(frame)

    def _keep(self, direction: str, t: float, frame: bytes | Frame) -> None:
        """Keep a frame in the :attr:`prologue` while no tap listens; a tap ends it."""
        prologue = self.prologue
        if prologue.complete:
            if self.taps:
                prologue.complete = False
            else:
                prologue.add(direction, t, frame if isinstance(frame, bytes)
                             else frame.to_bytes())

    def _expire(self, pending: PendingReply) -> None:
        if pending.txn:
            self._pending.pop(pending.seq, None)
        elif pending in self._untagged:
            self._untagged.remove(pending)
        self.counters.timeouts += 1
        pending.done = True
        pending.error = ReplyTimeout(
            f"no reply to {pending.name} from {self._where(pending.target)} within "
            f"{pending.budget_s:.3f} s on {self.transport.url}; is the hand powered "
            f"and is this the hand's port?")

    def _where(self, to: Target) -> str:
        if to == LINK_NODE:
            return "the palm" if self.link == "palm" else "the finger's fmcb"
        return to.describe()

    # --- internals: receiving --------------------------------------------------------------
    def _read(self, timeout: float) -> None:
        for t, data in self.transport.recv_timed(timeout):
            self._take(data, t)

    def _take(self, data: bytes, t: float) -> None:
        """Decode and dispatch ``data``, which arrived at ``t`` (s, the link's clock)."""
        for frame in self.decoder.feed(data, t):
            if self.taps:
                raw = frame.to_bytes()
                for tap in self.taps:
                    tap("rx", t, raw)
            self._keep("rx", t, frame)
            if frame.address != ADDR_HOST:
                self.counters.stray_frames += 1
            elif frame.type == _TXN.type_id:
                self._on_txn_reply(frame.payload)
            elif frame.type == _EVENT.type_id:
                self._on_event(frame.payload, t)
            else:
                self._on_untagged_reply(frame.type, frame.payload)

    def _on_event(self, payload: bytes, t: float) -> None:
        try:
            f = _EVENT.parse_reply(payload)
        except ProtocolError:
            self.counters.stray_frames += 1
            return
        event = FingerEvent(f["finger"], code_name(EventCode, f["event"], "event"), f["event"],
                            f["time"], t)
        self.counters.events += 1
        self.events.append(event)
        for callback in list(self._subscribers):
            try:
                callback(event)
            except Exception:  # a subscriber's bug must not break the link
                log.exception("finger-event subscriber %r failed", callback)

    def _on_txn_reply(self, payload: bytes) -> None:
        try:
            reply = _TXN.parse_reply(payload)
        except ProtocolError:
            self.counters.stray_frames += 1
            return
        pending = self._pending.pop(reply["seq"], None)
        if pending is None:
            self.counters.stale_replies += 1
            return
        pending.done = True
        try:
            first = "palm" if self.link == "palm" else "fmcb"
            pending.result = self._unwrap(pending, self._txn_body(reply, pending, first))
        except (NodeError, RouteError, ReplyTimeout) as exc:
            pending.error = exc

    def _on_untagged_reply(self, frame_type: int, payload: bytes) -> None:
        """A reply without the envelope: the oldest un-enveloped request of its type."""
        pending = next((p for p in self._untagged if p.reply_type == frame_type), None)
        if pending is None:
            self.counters.stray_frames += 1
            return
        self._untagged.remove(pending)
        pending.done = True
        try:
            pending.result = self._unwrap(pending, payload)
        except (NodeError, RouteError, ReplyTimeout) as exc:
            pending.error = exc

    def _unwrap(self, pending: PendingReply, body: bytes) -> dict[str, Any]:
        """The request's reply fields from the outer reply's body, through route or
        tunnel."""
        to = pending.target
        if not pending.routed:
            return self._parse(pending.message, body, to)
        if self.link == "palm":
            route = _ROUTE.parse_reply(body)
            if route["status"] != RouteStatus.OK:
                name = code_name(RouteStatus, route["status"], "status")
                raise RouteError(_route_advice(pending.name, to, name), status=route["status"],
                                 finger=route["finger"], hop=route["hop"])
            frames = [parse_frame(bytes(route["frame"]))]
        else:
            frames = decode_all(bytes(_TUNNEL.parse_reply(body)["data"]))
        for frame in frames:
            if frame.address != ADDR_HOST:
                continue
            if not pending.txn:
                if frame.type == pending.message.type_id:
                    return self._parse(pending.message, frame.payload, to)
                continue
            if frame.type != _TXN.type_id:
                continue
            inner = _TXN.parse_reply(frame.payload)
            if inner["seq"] != pending.inner_seq:
                self.counters.stale_replies += 1
                continue
            return self._parse(pending.message, self._txn_body(inner, pending, to.describe()),
                               to)
        raise ReplyTimeout(f"no reply to {pending.name} from {to.describe()}: the frame "
                           f"delivered was not its answer")

    @staticmethod
    def _txn_body(reply: dict[str, Any], pending: PendingReply, who: str) -> bytes:
        if reply["status"] != TxnStatus.OK:
            raise NodeError(f"{who} refused {pending.name}: "
                            f"{code_name(TxnStatus, reply['status'], 'status')}",
                            status=reply["status"])
        return bytes(reply["inner"])

    @staticmethod
    def _parse(message: Message, payload: bytes, to: Target) -> dict[str, Any]:
        if message.reply is None:
            return {}
        try:
            return message.parse_reply(payload)
        except ProtocolError as exc:
            raise NodeError(f"{to.describe()} answered {message.name} with a reply that "
                            f"does not parse: {exc}") from exc


def _retryable(error: Exception) -> bool:
    if isinstance(error, ReplyTimeout):
        return True
    if isinstance(error, RouteError):
        return error.status in ROUTE_RETRYABLE
    return isinstance(error, NodeError) and getattr(error, "status", None) == TxnStatus.BUSY


def _route_advice(name: str, to: Target, status: str) -> str:
    up = "`handctl up`" if to.finger is None else f"`handctl up --finger {to.finger}`"
    k = "N" if to.finger is None else to.finger
    advice = {
        "unpowered": f"power it first: {up} (Hand.bring_up) powers the finger, waits for "
                     f"its boards and powers its phalanges; palm.finger_power, or `handctl "
                     f"power {k} full`, switches only its supply",
        "link_down": "the finger has left the palm (broken away); push it back on",
        "no_reply": "the node did not answer in time (booting, or phalanges unpowered? "
                    f"{up} brings its boards up)",
        "busy": "the palm's queue for that finger is full; wait for earlier requests",
        "bad_destination": "no such finger or hop, or the frame is too long",
    }.get(status, "")
    return f"{name} to {to.describe()}: route {status}" + (f"; {advice}" if advice else "")
