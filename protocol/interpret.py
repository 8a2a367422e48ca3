"""Name and decode a hand frame's payload from the catalogue, without knowing the bus.

A frame says only its destination address and type.  Replies go to address 0 and requests
to 1 (f2), 2 (f3) or 10 (fmcb, palm or a bootloader), so :func:`interpret` tries the node
kinds the address allows, in a fixed order, and takes the first whose declaration consumes
the payload exactly.  A caller that knows the node (a driver, or a capture tool that saw
the request) passes it as a hint and it is tried first.

The candidates of each (address, type, payload length, hint) are worked out once and kept
(a capture of a million frames names a few hundred kinds of frame).  A candidate whose
payload is a flat fixed-size record (it has a :class:`~protocol.flat_codec.FlatCodec`)
accepts exactly the payloads of its size and rejects every other length with the same
words, so its rejection is kept too; every other candidate is tried on each payload.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

from protocol.catalogue import REPLY, REQUEST, Message
from protocol.errors import PayloadError
from protocol.framing import Frame, FrameError, parse_frame
from protocol.messages import CATALOGUE
from protocol.topology import ADDR_BROADCAST, ADDR_HOST, NODE_ADDRESS, NodeKind

#: Node kinds in the order they are tried: the fmcb first (at address 10 it decides between
#: an fmcb's and the palm's message of one type), then the others in the board table's order,
#: then the bootloader (it answers at every node's address).
NODE_KINDS_TRIED: Final = (NodeKind.FMCB.value,
                           *(k.value for k in NodeKind if k != NodeKind.FMCB), "bootloader")
#: Node kinds a request to each node address may be for, in :data:`NODE_KINDS_TRIED` order.
_BY_ADDRESS: dict[int, tuple[str, ...]] = {
    address: tuple(n for n in NODE_KINDS_TRIED
                   if n == "bootloader" or NODE_ADDRESS[NodeKind(n)] == address)
    for address in NODE_ADDRESS.values()
}


@dataclass(frozen=True)
class Interpretation:
    """What a frame means: the message (or None), its direction and its decoded fields.

    ``error`` says why the payload did not decode when the type is known but no
    declaration fits it.
    """

    message: Message | None
    direction: str
    fields: dict[str, Any] | None
    error: str | None = None

    @property
    def name(self) -> str | None:
        """The message name, or None when unknown."""
        return self.message.name if self.message else None


def candidate_nodes(address: int, hint: str | None = None) -> tuple[str, ...]:
    """Node kinds a frame to ``address`` may be for, hint first."""
    nodes = NODE_KINDS_TRIED if address in (ADDR_HOST, ADDR_BROADCAST) else _BY_ADDRESS.get(address, NODE_KINDS_TRIED)
    if hint:
        nodes = (hint, *[n for n in nodes if n != hint])
    return nodes


def _candidates(address: int, msg_type: int, hint: str | None) -> list[Message]:
    """The messages a frame may be, in the order they are tried (each once)."""
    direction = REPLY if address == ADDR_HOST else REQUEST
    out: list[Message] = []
    seen: set[str] = set()
    for node in candidate_nodes(address, hint):
        msg = CATALOGUE.lookup(node, msg_type)
        if msg is None or msg.name in seen:
            continue
        seen.add(msg.name)
        if (msg.request if direction == REQUEST else msg.reply) is not None:
            out.append(msg)
    return out


#: One candidate of a plan: the message, and the error it always gives for this payload
#: length (None: try it on each payload).
_Step = tuple[Message, str | None]
_PLANS: dict[tuple[int, int, int, str | None], tuple[_Step, ...]] = {}
#: Bound on the plans kept (all are dropped when it is reached: garbage cannot grow it).
_PLAN_LIMIT = 8192


def _plan(address: int, msg_type: int, payload: bytes, hint: str | None) -> tuple[_Step, ...]:
    """The steps of :func:`interpret` for frames like this one (made once per length)."""
    key = (address, msg_type, len(payload), hint)
    plan = _PLANS.get(key)
    if plan is not None:
        return plan
    direction = REPLY if address == ADDR_HOST else REQUEST
    steps: list[_Step] = []
    for msg in _candidates(address, msg_type, hint):
        flat = msg.flat_codec(direction)
        error: str | None = None
        if flat is not None and flat.size != len(payload):
            try:
                msg.parse(direction, payload)
            except PayloadError as exc:
                error = str(exc)  # a flat record rejects a length, whatever the bytes
        steps.append((msg, error))
    if len(_PLANS) >= _PLAN_LIMIT:
        _PLANS.clear()
    plan = _PLANS[key] = tuple(steps)
    return plan


def interpret(frame: Frame, hint: str | None = None) -> Interpretation:
    """Decode ``frame`` against the catalogue (never raises for any payload)."""
    payload = frame.payload
    direction = REPLY if frame.address == ADDR_HOST else REQUEST
    first_error: str | None = None
    first_message: Message | None = None
    for msg, error in _plan(frame.address, frame.type, payload, hint):
        if error is None:
            try:
                return Interpretation(msg, direction, msg.parse(direction, payload))
            except PayloadError as exc:
                error = str(exc)
        if first_error is None:
            first_error, first_message = error, msg
    return Interpretation(first_message, direction, None, first_error)


#: Envelopes inside envelopes a capture may show (txn, palm.route, txn, message): enough.
MAX_WRAPPED: Final = 4


def _name(value: Any) -> str:
    return str(getattr(value, "name", value))


def interpret_inner(outer: Interpretation, frame: Frame) -> tuple[Interpretation, Frame] | None:
    """The message one envelope wraps, decoded as :func:`interpret` would a frame of its
    own, with that frame; None when ``outer`` wraps nothing (not an envelope, or a reply
    that carries no answer).  Never raises.

    * ``txn``: ``inner_type`` and ``inner``, to the same address; a reply's ``board`` names
      the node tried first.
    * ``palm.route``: ``frame``, a complete hand frame for (or from) the node ``hop`` of a
      finger; one that does not parse as a frame is an interpretation with its ``error``.
    """
    fields = outer.fields
    if fields is None:
        return None
    if outer.name == "txn":
        if outer.direction == REPLY and int(fields["status"]) != 0:  # TxnStatus.OK
            return None
        # a reply's board type (PALM, FMCB, F2, F3) bears the name of its node kind
        kind = (NodeKind.__members__.get(_name(fields["board"]))
                if outer.direction == REPLY else None)
        hint = None if kind is None else kind.value
        inner = Frame(frame.address, int(fields["inner_type"]), bytes(fields["inner"]))
        return interpret(inner, hint), inner
    if outer.name == "palm.route":
        raw = bytes(fields["frame"])
        if not raw:
            return None
        try:
            inner = parse_frame(raw)
        except FrameError as exc:
            return Interpretation(None, outer.direction, None, f"routed frame: {exc}"), frame
        return interpret(inner, _name(fields["hop"]).lower()), inner
    return None


def unwrap_envelopes(outer: Interpretation, frame: Frame) -> list[Interpretation]:
    """Every message inside ``outer``'s envelopes, outermost first (at most
    :data:`MAX_WRAPPED`): a palm poll's ``txn`` reply gives ``palm.route``, the finger's
    ``txn`` and its ``fmcb.status``.  Empty for a frame that is no envelope."""
    layers: list[Interpretation] = []
    while len(layers) < MAX_WRAPPED:
        found = interpret_inner(outer, frame)
        if found is None:
            break
        outer, frame = found
        layers.append(outer)
        if outer.message is None:
            break
    return layers
