"""Each host request paired with its reply, matched by request, and the reply's fields named.

A reply belongs to the request it answers, not to the place it has in the stream: a reply
that comes late, out of turn or not at all must not shift every later comparison by one.

* Arm (Dynamixel 1.0): a request is (instruction, id, address); a READ, PING or WRITE to one
  id expects one status packet from that id, a BULK_READ one from each id it names, a
  broadcast (SYNC_WRITE) none.  A status packet answers the newest request to its id sent
  before it that is still unanswered (the bus is half-duplex: the host waits for the reply
  or gives up before it asks that node again).  Its fields: the error byte (``error``) and
  each register the read covered whole, decoded by the node's control table
  (:data:`protocol.control_tables.TABLES_BY_MODEL`).
* Hand: a request is its message type and its ``txn`` sequence number (or, without the
  envelope, the ``palm.route`` finger and hop); the reply carries both.  Its fields are those
  of the innermost message (``fmcb.status`` inside ``txn`` inside ``palm.route`` inside
  ``txn``), with the envelopes' statuses.

Every field is a number (flags and enums as their values); ``reply_us`` is the time from the
request to its reply (µs).  Both functions take any bytes: what does not decode is skipped.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import construct as c

from protocol.control_tables import TABLES_BY_MODEL
from protocol.dynamixel import (
    BROADCAST_ID,
    DynamixelStreamDecoder,
    Instruction,
    InstructionPacket,
    StatusPacket,
    parse_bulk_read,
    parse_read,
    signed_by_direction_bit,
)
from protocol.errors import ProtocolError
from protocol.framing import Frame
from protocol.interpret import Interpretation, interpret, unwrap_envelopes
from protocol.stream import StreamDecoder
from protocol.topology import ARM_JOINTS, ARM_MODEL_BY_ID
from tools.hil_bench.replay.source import Timed

#: The field every exchange has: 1 when a reply came, 0 when none did.
REPLIED: Final = "replied"
#: The reply's time after its request (µs).
REPLY_US: Final = "reply_us"
#: The RX-64's registers whose bit 10 is a direction (clockwise), compared as signed numbers:
#: a speed through zero is a step of a unit or two, not of 1024.
SIGN_AND_MAGNITUDE: Final = frozenset({"present_speed", "present_load"})
_JOINT_BY_ID: Final = {j.dxl_id: j.name for j in ARM_JOINTS}


@dataclass
class Exchange:
    """One request: ``key`` (what it asks, as matching sees it), its time ``t`` (s), the
    ``prefix`` of its channels (``arm.J2``, ``hand.finger1.fmcb.status``) and the reply's
    ``fields`` (None: no reply) at ``reply_t`` (s)."""

    key: Hashable
    t: float
    prefix: str
    fields: dict[str, float] | None = None
    reply_t: float | None = None

    def values(self) -> dict[str, float]:
        """The channel values of this exchange, by field: ``replied``, and with a reply its
        fields and ``reply_us``."""
        out = {REPLIED: 0.0 if self.fields is None else 1.0}
        if self.fields is not None and self.reply_t is not None:
            out[REPLY_US] = round((self.reply_t - self.t) * 1e6, 3)
            out.update(self.fields)
        return out


# ------------------------------------------------------------------------------ the arm

def _expected(packet: InstructionPacket) -> list[tuple[int, int | None, int]]:
    """(id, address, length) of each reply ``packet`` asks for (length 0: no registers)."""
    code = packet.instruction
    try:
        if code == Instruction.BULK_READ:
            return [(i, a, n) for n, i, a in parse_bulk_read(packet.params)]
        if packet.id == BROADCAST_ID:
            return []
        if code == Instruction.READ:
            address, length = parse_read(packet.params)
            return [(packet.id, address, length)]
        if code in (Instruction.WRITE, Instruction.REG_WRITE) and packet.params:
            return [(packet.id, packet.params[0], 0)]
    except (ProtocolError, ValueError, IndexError, c.ConstructError):
        return []
    return [(packet.id, None, 0)]


def _registers(dxl_id: int, address: int | None, length: int, params: bytes
               ) -> dict[str, float]:
    table = TABLES_BY_MODEL.get(ARM_MODEL_BY_ID.get(dxl_id, -1))
    if table is None or address is None or len(params) != length:
        return {}
    out: dict[str, float] = {}
    for register in table:
        start = register.address - address
        if start >= 0 and start + register.size <= length:
            value = register.decode(params[start:start + register.size])
            if register.name in SIGN_AND_MAGNITUDE:
                value = signed_by_direction_bit(value)
            out[register.name] = float(value)
    return out


def arm_exchanges(tx: Iterable[Timed], rx: Iterable[Timed]) -> list[Exchange]:
    """The arm bus's requests in ``tx`` with their replies from ``rx`` (any bytes)."""
    requests = DynamixelStreamDecoder("instruction")
    exchanges: list[Exchange] = []
    by_id: dict[int, list[Exchange]] = defaultdict(list)
    shape: dict[int, tuple[int, int | None, int]] = {}
    for message in tx:
        for decoded in requests.feed(message.data, message.t):
            packet = decoded.packet
            if not isinstance(packet, InstructionPacket):
                continue
            for dxl_id, address, length in _expected(packet):
                name = _JOINT_BY_ID.get(dxl_id, f"id{dxl_id}")
                ex = Exchange((int(packet.instruction), dxl_id, address), message.t,
                              f"arm.{name}")
                exchanges.append(ex)
                by_id[dxl_id].append(ex)
                shape[id(ex)] = (dxl_id, address, length)
    replies = DynamixelStreamDecoder("status")
    for message in rx:
        for decoded in replies.feed(message.data, message.t):
            status = decoded.packet
            if not isinstance(status, StatusPacket):
                continue
            candidates = by_id.get(status.id, [])
            target = _newest(candidates, message.t)
            if target is None:
                continue
            dxl_id, address, length = shape[id(target)]
            fields = {"error": float(status.error)}
            fields.update(_registers(dxl_id, address, length, status.params))
            target.fields, target.reply_t = fields, message.t
    return exchanges


def _newest(pending: Sequence[Exchange], t: float) -> Exchange | None:
    """The newest unanswered request in ``pending`` sent before ``t`` (the first of several
    sent together), or None.  Strictly before: in process a host sends its next request at
    the very instant it took the reply to the last, and that reply is the last's."""
    best: Exchange | None = None
    for ex in pending:
        if ex.fields is None and ex.t < t and (best is None or ex.t > best.t):
            best = ex
    return best


# ------------------------------------------------------------------------------ the hand

def _frames(messages: Iterable[Timed]) -> list[tuple[float, Frame]]:
    decoder = StreamDecoder()
    out: list[tuple[float, Frame]] = []
    for message in messages:
        out.extend((message.t, frame) for frame in decoder.feed(message.data, message.t))
    return out


def _layers(frame: Frame) -> list[Interpretation]:
    outer = interpret(frame)
    return [outer, *unwrap_envelopes(outer, frame)]


def _key_and_place(layers: Sequence[Interpretation], msg_type: int) -> tuple[Hashable, str]:
    """The matching key of a hand request or reply (type and ``txn`` seq, else the route's
    finger and hop) and where it went (``palm``, ``finger1.fmcb``)."""
    outer = layers[0].fields or {}
    key: tuple[Any, ...] = (msg_type,)
    place = "palm"
    for layer in layers:
        if layer.name == "palm.route" and layer.fields is not None:
            finger, hop = int(layer.fields["finger"]), _number(layer.fields["hop"])
            place = f"finger{finger}.{_hop_name(layer.fields['hop'])}"
            if layers[0].name != "txn":
                key = (msg_type, finger, hop)
            break
    if layers[0].name == "txn" and "seq" in outer:
        key = (msg_type, int(outer["seq"]))
    return key, place


def _hop_name(value: Any) -> str:
    return str(getattr(value, "name", value)).lower()


def _number(value: Any) -> float:
    if isinstance(value, c.EnumIntegerString):
        return float(value.int)
    return float(value)


def flatten(value: Any, prefix: str = "") -> dict[str, float]:
    """A decoded message's numeric fields by dotted path (``tactile.distal[3]``); flags and
    enums as their numbers; text and bytes left out."""
    out: dict[str, float] = {}
    if isinstance(value, dict):
        for k, v in value.items():
            if not str(k).startswith("_"):
                out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            out.update(flatten(v, f"{prefix}[{i}]"))
    elif isinstance(value, c.EnumIntegerString):
        out[prefix] = float(value.int)
    elif isinstance(value, bool | int | float) and prefix:
        out[prefix] = float(value)
    return out


def _reply_fields(layers: Sequence[Interpretation]) -> dict[str, float]:
    fields: dict[str, float] = {}
    for layer in layers[:-1]:
        if layer.fields is not None and "status" in layer.fields:
            fields[f"{(layer.name or 'envelope').rpartition('.')[2]}_status"] = _number(
                layer.fields["status"])
    inner = layers[-1]
    if inner.fields is not None and inner.name not in ("txn", "palm.route"):
        fields.update(flatten(dict(inner.fields)))
    return fields


def hand_exchanges(tx: Iterable[Timed], rx: Iterable[Timed]) -> list[Exchange]:
    """The hand link's requests in ``tx`` with their replies from ``rx`` (any bytes);
    unsolicited frames (``palm.finger_event``) answer nothing and are left out."""
    exchanges: list[Exchange] = []
    by_key: dict[Hashable, list[Exchange]] = defaultdict(list)
    for t, frame in _frames(tx):
        layers = _layers(frame)
        key, place = _key_and_place(layers, frame.type)
        name = layers[-1].name or f"type{frame.type:#04x}"
        node = place.rpartition(".")[2]
        if node != "palm" and name.startswith(node + "."):
            name = name[len(node) + 1:]  # finger0.fmcb + fmcb.status: finger0.fmcb.status
        elif node == "palm" and name.startswith("palm."):
            name = name[len("palm."):]
        ex = Exchange(key, t, f"hand.{place}.{name}")
        exchanges.append(ex)
        by_key[key].append(ex)
    for t, frame in _frames(rx):
        layers = _layers(frame)
        key, _place = _key_and_place(layers, frame.type)
        target = _newest(by_key.get(key, ()), t)
        if target is not None:
            target.fields, target.reply_t = _reply_fields(layers), t
    return exchanges


#: Each link kind's pairing (:data:`tools.hil_bench.replay.source.LINK_TOPICS`).
PAIRING: Final = {"arm": arm_exchanges, "hand": hand_exchanges}
