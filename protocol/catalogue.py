"""The message catalogue machinery: every hand message declared once, with construct.

A :class:`Message` has a name, the node kind that understands it, a type id, and the
construct declarations of its request payload (host → node) and reply payload (node →
host, ``None`` when the node never replies).  Requests and replies share the type id, as
on the original hand; a reply travels to address 0.  The same declarations are used by the
firmware models, the host drivers, the capture decoder and the fuzzers.

Field docstrings start with the unit in square brackets (``"[µs] …"``); ``docs/PROTOCOL.md``
is generated from them by :mod:`protocol.docgen`.
"""

from __future__ import annotations

import enum
import hashlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import construct as c

from protocol.enum_field import EnumField
from protocol.errors import PayloadError, UnknownMessageError, wrap_construct
from protocol.flat_codec import FlatCodec, TailCodec, flat_codec, tail_codec
from protocol.framing import encode_frame
from protocol.topology import ADDR_HOST, NodeKind

#: Message namespaces: every hand node kind (:class:`~protocol.topology.NodeKind`) and the
#: bootloader they all run; "common" messages are understood by all of them.
NODES: Final = ("common", *(kind.value for kind in NodeKind), "bootloader")
#: Node kinds whose type ids fall back to the "common" ones.
_FALLS_BACK_TO_COMMON: Final = frozenset(NODES) - {"common"}

REQUEST: Final = "request"
REPLY: Final = "reply"


def _strict(con: c.Construct) -> c.Construct:
    """The declaration plus a check that the payload is consumed exactly."""
    return c.FocusedSeq("v", "v" / con, c.Terminated)


@dataclass(frozen=True)
class Message:
    """One message of the catalogue.

    ``request``/``reply`` are construct declarations of the payloads (``None``: no such
    direction).  ``summary`` is one line for people; field units live in the field docs.
    """

    name: str
    node: str
    type_id: int
    request: c.Construct | None
    reply: c.Construct | None
    summary: str
    original: bool = True
    _strict_request: c.Construct | None = field(default=None, repr=False, compare=False)
    _strict_reply: c.Construct | None = field(default=None, repr=False, compare=False)
    _flat_request: FlatCodec | None = field(default=None, repr=False, compare=False)
    _flat_reply: FlatCodec | None = field(default=None, repr=False, compare=False)
    _tail_request: TailCodec | None = field(default=None, repr=False, compare=False)
    _tail_reply: TailCodec | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.node not in NODES:
            raise ValueError(f"{self.name}: unknown node kind {self.node!r}")
        if not 0 <= self.type_id <= 0xFF:
            raise ValueError(f"{self.name}: type id {self.type_id} outside 0..255")
        object.__setattr__(self, "_strict_request", _strict(self.request) if self.request else None)
        object.__setattr__(self, "_strict_reply", _strict(self.reply) if self.reply else None)
        object.__setattr__(self, "_flat_request", flat_codec(self.request) if self.request else None)
        object.__setattr__(self, "_flat_reply", flat_codec(self.reply) if self.reply else None)
        for direction, con, flat in ((REQUEST, self.request, self._flat_request),
                                     (REPLY, self.reply, self._flat_reply)):
            if con is not None and flat is None:
                object.__setattr__(self, f"_tail_{direction}", tail_codec(con))

    @property
    def replies(self) -> bool:
        """True if the node answers this message."""
        return self.reply is not None

    def declaration(self, direction: str) -> c.Construct:
        """The construct declaration of one direction (``"request"`` or ``"reply"``)."""
        con = self.request if direction == REQUEST else self.reply
        if con is None:
            raise PayloadError(f"{self.name} has no {direction}")
        return con

    def flat_codec(self, direction: str) -> FlatCodec | None:
        """The struct fast path of one direction, or None when its payload is not flat."""
        return self._flat_request if direction == REQUEST else self._flat_reply

    def build(self, direction: str, fields: Mapping[str, Any] | None = None, **kw: Any) -> bytes:
        """Build the payload of ``direction`` from ``fields`` (a dict) and/or keywords."""
        con = self._strict_request if direction == REQUEST else self._strict_reply
        if con is None:
            raise PayloadError(f"{self.name} has no {direction}")
        values = dict(fields or {}, **kw)
        flat = self._flat_request if direction == REQUEST else self._flat_reply
        if flat is not None and (built := flat.build(values)) is not None:
            return built  # the struct fast path; construct below explains any failure
        return wrap_construct(lambda: con.build(values), f"{self.name} {direction}")

    def parse(self, direction: str, payload: bytes) -> dict[str, Any]:
        """Parse a payload of ``direction`` into a plain dict; it must be consumed exactly."""
        con = self._strict_request if direction == REQUEST else self._strict_reply
        if con is None:
            raise PayloadError(f"{self.name} has no {direction}")
        flat = self._flat_request if direction == REQUEST else self._flat_reply
        if flat is not None and (parsed := flat.parse(payload)) is not None:
            return parsed  # the struct fast path; construct below explains any failure
        tail = self._tail_request if direction == REQUEST else self._tail_reply
        if tail is not None and (parsed := tail.parse(payload)) is not None:
            return parsed  # a flat head and a variable last field, likewise
        return to_plain(wrap_construct(lambda: con.parse(payload), f"{self.name} {direction}"))

    def build_request(self, fields: Mapping[str, Any] | None = None, **kw: Any) -> bytes:
        """Request payload bytes (host → node)."""
        return self.build(REQUEST, fields, **kw)

    def build_reply(self, fields: Mapping[str, Any] | None = None, **kw: Any) -> bytes:
        """Reply payload bytes (node → host)."""
        return self.build(REPLY, fields, **kw)

    def request_frame(self, address: int, fields: Mapping[str, Any] | None = None,
                      **kw: Any) -> bytes:
        """The whole hand frame carrying this request to ``address``: sync, address, length,
        type, payload built from ``fields`` and/or keywords, CRC."""
        return encode_frame(address, self.type_id, self.build(REQUEST, fields, **kw))

    def reply_frame(self, fields: Mapping[str, Any] | None = None, **kw: Any) -> bytes:
        """The whole hand frame carrying this reply to the host (address 0)."""
        return encode_frame(ADDR_HOST, self.type_id, self.build(REPLY, fields, **kw))

    def parse_request(self, payload: bytes) -> dict[str, Any]:
        """Request payload → dict."""
        return self.parse(REQUEST, payload)

    def parse_reply(self, payload: bytes) -> dict[str, Any]:
        """Reply payload → dict."""
        return self.parse(REPLY, payload)


def to_plain(value: Any) -> Any:
    """construct Containers and ListContainers → dicts and lists (private keys dropped)."""
    if isinstance(value, dict):
        return {k: to_plain(v) for k, v in value.items() if not str(k).startswith("_")}
    if isinstance(value, list):
        return [to_plain(v) for v in value]
    if isinstance(value, c.EnumIntegerString):
        return str(value)
    return value


class Catalogue:
    """All messages, found by name or by (node kind, type id)."""

    def __init__(self, messages: Iterable[Message] = ()) -> None:
        self._by_name: dict[str, Message] = {}
        self._by_key: dict[tuple[str, int], Message] = {}
        for msg in messages:
            self.add(msg)

    def add(self, msg: Message) -> None:
        """Register ``msg``; names and (node, type id) pairs must be unique."""
        if msg.name in self._by_name:
            raise ValueError(f"duplicate message name {msg.name}")
        key = (msg.node, msg.type_id)
        if key in self._by_key:
            raise ValueError(f"{msg.name}: type 0x{msg.type_id:02x} already used on {msg.node}")
        if msg.node == "common":
            clash = [k for k in self._by_key if k[1] == msg.type_id and k[0] != "common"]
        else:
            clash = [k for k in self._by_key if k == ("common", msg.type_id)]
        if clash:
            raise ValueError(f"{msg.name}: type 0x{msg.type_id:02x} shadows a common message")
        self._by_name[msg.name] = msg
        self._by_key[key] = msg

    def __iter__(self) -> Iterator[Message]:
        return iter(sorted(self._by_name.values(), key=lambda m: (NODES.index(m.node), m.type_id)))

    def __len__(self) -> int:
        return len(self._by_name)

    def __getitem__(self, name: str) -> Message:
        return self.by_name(name)

    def by_name(self, name: str) -> Message:
        """The message called ``name``; :class:`UnknownMessageError` if none."""
        try:
            return self._by_name[name]
        except KeyError:
            raise UnknownMessageError(f"no message called {name!r}") from None

    def lookup(self, node: str, type_id: int) -> Message | None:
        """The message ``type_id`` means on ``node`` (own ids first, then common ones)."""
        msg = self._by_key.get((node, type_id))
        if msg is None and node in _FALLS_BACK_TO_COMMON:
            msg = self._by_key.get(("common", type_id))
        return msg

    def require(self, node: str, type_id: int) -> Message:
        """Like :meth:`lookup` but raising :class:`UnknownMessageError`."""
        msg = self.lookup(node, type_id)
        if msg is None:
            raise UnknownMessageError(f"type 0x{type_id:02x} means nothing on {node}")
        return msg

    def names(self) -> list[str]:
        """All message names, in catalogue order."""
        return [m.name for m in self]

    def fingerprint(self) -> bytes:
        """8-byte hash of the catalogue's shape: names, nodes, ids and field layouts.

        Two builds that agree on every wire format have the same fingerprint; the identify
        exchange carries it so a host detects firmware speaking another catalogue.
        """
        h = hashlib.sha256()
        for msg in self:
            h.update(f"{msg.name}|{msg.node}|{msg.type_id}|".encode())
            for direction in (REQUEST, REPLY):
                con = msg.request if direction == REQUEST else msg.reply
                h.update(f"{direction}:{describe_layout(con)};".encode())
        return h.digest()[:8]


def describe_layout(con: c.Construct | None) -> str:
    """A canonical one-line description of a declaration's fields, types and sizes.

    Nested structs, arrays, switch arms and length expressions are described recursively,
    so any change of a wire format (not only of a top-level size) changes the text.
    """
    if con is None:
        return "-"
    parts = []
    for name, sub, _docs in iter_fields(con):
        parts.append(f"{name}:{_shape(sub)}:{static_size(sub)}")
    return ",".join(parts)


def _unrename(con: c.Construct) -> c.Construct:
    """Strip the Renamed layers that ``"name" / con * "docs"`` wraps around a construct."""
    while isinstance(con, c.Renamed):
        con = con.subcon
    return con


def _expr(value: object) -> str:
    text = repr(value)
    return "<callable>" if " at 0x" in text else text


def _key(value: object) -> str:
    """A Switch case key as text; an IntEnum member reads as its int (the wire value)."""
    return repr(int(value)) if isinstance(value, enum.IntEnum) else repr(value)


def _shape(con: c.Construct) -> str:
    """Canonical, process-independent description of one construct and what it contains.

    An :class:`~protocol.enum_field.EnumField` is described as its integer: naming the codes
    does not change the wire, so it does not change the fingerprint.
    """
    con = _unrename(con)
    while isinstance(con, EnumField):
        con = _unrename(con.subcon)
    kind = type(con).__name__
    if isinstance(con, c.FormatField):
        return con.fmtstr
    if isinstance(con, c.Struct):
        return kind + "{" + ",".join(f"{n}:{_shape(s)}" for n, s, _ in iter_fields(con)) + "}"
    if isinstance(con, c.Switch):
        cases = ",".join(f"{_key(k)}={_shape(v)}"
                         for k, v in sorted(con.cases.items(), key=lambda kv: _key(kv[0])))
        return f"{kind}({_expr(con.keyfunc)};{cases};default={_shape(con.default)})"
    parts = [f"{attr}={_expr(getattr(con, attr))}"
             for attr in ("count", "length", "encoding", "func", "pattern") if hasattr(con, attr)]
    for attr in ("lengthfield", "subcon"):
        sub = getattr(con, attr, None)
        if isinstance(sub, c.Construct):
            parts.append(_shape(sub))
    return f"{kind}({';'.join(parts)})"


def iter_fields(con: c.Construct) -> Iterator[tuple[str, c.Construct, str]]:
    """(name, construct, docs) for each top-level field of a Struct (padding as ``<pad>``).

    The construct is the field's own declaration, without the Renamed layers that carry
    its name and docs.
    """
    subcons = getattr(con, "subcons", None)
    if subcons is None:
        yield ("<value>", con, getattr(con, "docs", "") or "")
        return
    for sub in subcons:
        name = getattr(sub, "name", None) or "<pad>"
        yield (name, _unrename(sub), getattr(sub, "docs", "") or "")


def static_size(con: c.Construct) -> int | None:
    """Fixed size in bytes of ``con``, or None when it depends on the data."""
    try:
        return int(con.sizeof())
    except (c.SizeofError, KeyError, AttributeError, TypeError):
        return None
