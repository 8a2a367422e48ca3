"""A ``struct`` fast path for payloads that are flat records of fixed-size numbers.

Nodes build and parse some payloads hundreds of times a simulated second (the 148-byte
``fmcb.status`` the palm polls, the phalanges' autopoll replies).  Interpreted construct
costs ~200 µs for such a record; ``struct`` costs a few.  :func:`flat_codec` looks at a
construct declaration and, when it is a ``Struct`` whose fields are only little-endian
numbers, fixed-length arrays of numbers or of such Structs, fixed-length bytes and zero
padding, returns a :class:`FlatCodec` that builds and parses the same bytes.  A number may be
an :class:`~protocol.enum_field.EnumField`: parse gives its member for a known code and the
int otherwise, as construct does; build takes ints and members (a member's name goes to the
construct path, which translates it).  The declaration stays the reference: callers use
the fast path only for the well-formed case and let construct produce every error, and a
test checks both agree on every such message of the catalogue.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import construct as c

from protocol.enum_field import EnumField

#: Path of names to the value (None for padding), struct code, element count (None: scalar),
#: and for an EnumField the members by value (None: a plain number or bytes).
#: A fixed-length byte field is one scalar whose code is ``"<N>s"``; the elements of an array
#: of flat Structs are reached by an int index in the path (``("fingers", 0, "power")``).
Field = tuple[tuple[str | int, ...] | None, str, int | None, Mapping[int, Any] | None]


@dataclass(frozen=True)
class FlatCodec:
    """Build and parse one flat record with one precompiled ``struct.Struct``."""

    fields: tuple[Field, ...]
    codec: struct.Struct
    _to_dict: Callable[[tuple[Any, ...]], dict[str, Any]] = field(
        init=False, repr=False, compare=False)
    _buildable: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_to_dict", _dict_maker(self.fields))
        # Once, not at every build (the phalanges build a reply every 5 ms each).
        object.__setattr__(self, "_buildable", not any(
            path and any(isinstance(p, int) for p in path) for path, _, _, _ in self.fields))

    @property
    def buildable(self) -> bool:
        """False when the record holds arrays of Structs: :meth:`build` leaves those to
        construct (it would have to check each list's length), :meth:`parse` does them."""
        return self._buildable

    @property
    def size(self) -> int:
        """Payload length in bytes."""
        return self.codec.size

    def parse(self, payload: bytes) -> dict[str, Any] | None:
        """The record as a plain dict, or None when ``payload`` is not exactly one record."""
        if len(payload) != self.codec.size:
            return None
        return self._to_dict(self.codec.unpack(payload))

    def build(self, values: Mapping[str, Any]) -> bytes | None:
        """The record's bytes, or None when ``values`` does not fit (missing field, wrong
        array length, out of range): the caller asks construct, which says why."""
        if not self._buildable:
            return None
        flat: list[Any] = []
        try:
            for path, code, count, _members in self.fields:
                if path is None:
                    continue
                value: Any = values
                for name in path:
                    value = value[name]
                if code[-1] == "s":  # struct would pad or cut; construct refuses
                    if not isinstance(value, bytes | bytearray) or len(value) != int(code[:-1]):
                        return None
                    flat.append(value)
                elif count is None:
                    flat.append(value)
                elif len(value) != count:
                    return None
                else:
                    flat.extend(value)
            return self.codec.pack(*flat)
        except (KeyError, TypeError, OverflowError, struct.error):
            return None


def _dict_maker(fields: tuple[Field, ...]) -> Callable[[tuple[Any, ...]], dict[str, Any]]:
    """A function from the unpacked values to the record's (nested) dict.

    It is one dict display compiled from the field list (``lambda v: {'a': v[0],
    'b': [v[1], v[2]], 'c': {'d': m0.get(v[3], v[3])}}``): a parse then costs the unpack and
    one expression instead of a loop over the fields.  A coded (EnumField) value goes through
    its members by value, bound as ``m0``, ``m1``, … in the expression's namespace: a known
    code becomes its member, an unknown one stays the int, as construct parses it.  Names
    enter the source only as string literals (``repr``), so no declaration can inject code.
    """
    tree: dict[str | int, Any] = {}
    namespace: dict[str, Any] = {"__builtins__": {}}
    member_names: dict[int, str] = {}  # id of a members mapping → its name in namespace
    i = 0

    def leaf(j: int, members: Mapping[int, Any] | None) -> str:
        if members is None:
            return f"v[{j}]"
        name = member_names.get(id(members))
        if name is None:
            name = member_names[id(members)] = f"m{len(member_names)}"
            namespace[name] = members
        return f"{name}.get(v[{j}], v[{j}])"

    for path, _, count, members in fields:
        if path is None:
            continue
        node = tree
        for name in path[:-1]:
            node = node.setdefault(name, {})
        if count is None:
            node[path[-1]] = leaf(i, members)
            i += 1
        else:
            node[path[-1]] = "[" + ", ".join(leaf(j, members) for j in range(i, i + count)) + "]"
            i += count

    def render(node: dict[str | int, Any]) -> str:
        def value(sub: Any) -> str:
            return render(sub) if isinstance(sub, dict) else str(sub)

        if node and all(isinstance(name, int) for name in node):  # an array of Structs
            return "[" + ", ".join(value(node[k]) for k in sorted(node)) + "]"  # type: ignore[type-var]
        return "{" + ", ".join(f"{name!r}: {value(sub)}" for name, sub in node.items()) + "}"

    maker: Callable[[tuple[Any, ...]], dict[str, Any]] = eval(  # noqa: S307 - see above
        f"lambda v: {render(tree)}", namespace)
    return maker


def _unwrap(con: Any) -> Any:
    while isinstance(con, c.Renamed):
        con = con.subcon
    return con


def _number(con: Any) -> str | None:
    """The struct code of a little-endian (or one-byte) number field, else None."""
    con = _unwrap(con)
    if isinstance(con, EnumField):
        return _number(con.subcon)
    if not isinstance(con, c.FormatField):
        return None
    order, code = con.fmtstr[0], con.fmtstr[1:]
    if len(code) != 1 or (order != "<" and struct.calcsize(code) != 1):
        return None
    return code


def _members(con: Any) -> Mapping[int, Any] | None:
    """The members by value of an EnumField number, else None."""
    con = _unwrap(con)
    return con.by_value if isinstance(con, EnumField) else None


def _fields(struct_con: Any, prefix: tuple[str | int, ...]) -> list[Field] | None:
    """The leaves of a flat Struct (nested flat Structs included), or None."""
    fields: list[Field] = []
    for sub in struct_con.subcons:
        name = sub.name
        inner = _unwrap(sub)
        code = _number(inner)
        if code is not None and name is not None:
            fields.append(((*prefix, name), code, None, _members(inner)))
        elif (isinstance(inner, c.Array) and isinstance(inner.count, int)
              and name is not None and (code := _number(inner.subcon)) is not None):
            fields.append(((*prefix, name), code, inner.count, _members(inner.subcon)))
        elif (isinstance(inner, c.Array) and isinstance(inner.count, int) and name is not None
              and isinstance(element := _unwrap(inner.subcon), c.Struct)):
            for index in range(inner.count):
                nested = _fields(element, (*prefix, name, index))
                if not nested:
                    return None
                fields.extend(nested)
        elif (isinstance(inner, c.Bytes) and isinstance(inner.length, int)
              and name is not None):
            fields.append(((*prefix, name), f"{inner.length}s", None, None))
        elif isinstance(inner, c.Struct) and name is not None:
            nested = _fields(inner, (*prefix, name))
            if nested is None or not nested:
                return None
            fields.extend(nested)
        elif (isinstance(inner, c.Padded) and isinstance(inner.length, int)
              and _unwrap(inner.subcon) is c.Pass and inner.pattern == b"\x00" and name is None):
            fields.append((None, "x", inner.length, None))
        else:
            return None
    return fields


def flat_codec(declaration: Any) -> FlatCodec | None:
    """A :class:`FlatCodec` equivalent to ``declaration``, or None if it is not flat."""
    struct_con = _unwrap(declaration)
    if not isinstance(struct_con, c.Struct):
        return None
    fields = _fields(struct_con, ())
    if fields is None:
        return None
    fmt = "<" + "".join(code if count is None else f"{count}{code}"
                        for _, code, count, _ in fields)
    return FlatCodec(tuple(fields), struct.Struct(fmt))


@dataclass(frozen=True)
class TailCodec:
    """Parse a flat head followed by one variable last field, without construct.

    The last field is one of: ``GreedyBytes`` (the rest of the payload, as bytes), an
    ASCII ``PascalString`` with a one-byte length (it must end the payload exactly), or a
    ``Switch`` keyed on head fields whose cases are flat records (the case must end the
    payload exactly; a key without a case is left to construct).  Parsing only: anything
    that does not fit returns None and construct parses it (and explains any error).
    """

    head: FlatCodec
    name: str
    kind: str  # "greedy", "pascal" or "switch"
    switch: Any = None  # the construct Switch, for its key function
    cases: dict[Any, FlatCodec] = field(default_factory=dict)

    def parse(self, payload: bytes) -> dict[str, Any] | None:
        """The record as a plain dict, or None when ``payload`` is not one well-formed record."""
        size = self.head.size
        if len(payload) < size:
            return None
        out = self.head.parse(payload[:size])
        if out is None:
            return None
        rest = payload[size:]
        if self.kind == "greedy":
            out[self.name] = rest
        elif self.kind == "pascal":
            if not rest or rest[0] != len(rest) - 1 or not rest[1:].isascii():
                return None
            out[self.name] = rest[1:].decode("ascii")
        else:
            try:
                case = self.cases.get(self.switch.keyfunc(out))
            except (KeyError, TypeError):
                return None
            parsed = case.parse(rest) if case is not None else None
            if parsed is None:
                return None
            out[self.name] = parsed
        return out


def tail_codec(declaration: Any) -> TailCodec | None:
    """A :class:`TailCodec` for ``declaration``, or None if it is not of that shape."""
    struct_con = _unwrap(declaration)
    if not isinstance(struct_con, c.Struct) or not struct_con.subcons:
        return None
    *head_subcons, last = struct_con.subcons
    head = flat_codec(c.Struct(*head_subcons))
    name = last.name
    inner = _unwrap(last)
    if head is None or name is None:
        return None
    if inner is c.GreedyBytes:
        return TailCodec(head, name, "greedy")
    if (isinstance(inner, c.StringEncoded) and inner.encoding == "ascii"
            and isinstance(inner.subcon, c.Prefixed) and inner.subcon.subcon is c.GreedyBytes
            and _unwrap(inner.subcon.lengthfield) is c.Int8ul):
        return TailCodec(head, name, "pascal")
    if isinstance(inner, c.Switch) and inner.default is c.Error:
        cases = {key: flat_codec(case) for key, case in inner.cases.items()}
        if any(codec is None for codec in cases.values()):
            return None
        return TailCodec(head, name, "switch", inner,
                         {k: v for k, v in cases.items() if v is not None})
    return None
