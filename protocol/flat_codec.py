"""A ``struct`` fast path for payloads that are flat records of fixed-size numbers.

Nodes build and parse some payloads hundreds of times a simulated second (the 148-byte
``fmcb.status`` the palm polls, the phalanges' autopoll replies).  Interpreted construct
costs ~200 µs for such a record; ``struct`` costs a few.  :func:`flat_codec` looks at a
construct declaration and, when it is a ``Struct`` whose fields are only little-endian
numbers, fixed-length arrays of numbers and zero padding, returns a :class:`FlatCodec`
that builds and parses the same bytes.  A number may be an
:class:`~protocol.enum_field.EnumField`: parse gives its member for a known code and the int
otherwise, as construct does; build takes ints and members (a member's name goes to the
construct path, which translates it).  The declaration stays the reference: callers use
the fast path only for the well-formed case and let construct produce every error, and a
test checks both agree on every such message of the catalogue.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import construct as c

from protocol.enum_field import EnumField

#: Path of names to the value (None for padding), struct code, element count (None: scalar),
#: and for an EnumField the members by value (None: a plain number).
Field = tuple[tuple[str, ...] | None, str, int | None, Mapping[int, Any] | None]


@dataclass(frozen=True)
class FlatCodec:
    """Build and parse one flat record with one precompiled ``struct.Struct``."""

    fields: tuple[Field, ...]
    codec: struct.Struct

    @property
    def size(self) -> int:
        """Payload length in bytes."""
        return self.codec.size

    def parse(self, payload: bytes) -> dict[str, Any] | None:
        """The record as a plain dict, or None when ``payload`` is not exactly one record."""
        if len(payload) != self.codec.size:
            return None
        values = self.codec.unpack(payload)
        out: dict[str, Any] = {}
        i = 0
        for path, _, count, members in self.fields:
            if path is None:
                continue
            target = out
            for name in path[:-1]:
                target = target.setdefault(name, {})
            if count is None:
                value = values[i]
                target[path[-1]] = value if members is None else members.get(value, value)
                i += 1
            else:
                chunk = values[i : i + count]
                target[path[-1]] = (list(chunk) if members is None
                                    else [members.get(v, v) for v in chunk])
                i += count
        return out

    def build(self, values: Mapping[str, Any]) -> bytes | None:
        """The record's bytes, or None when ``values`` does not fit (missing field, wrong
        array length, out of range): the caller asks construct, which says why."""
        flat: list[Any] = []
        try:
            for path, _, count, _members in self.fields:
                if path is None:
                    continue
                value: Any = values
                for name in path:
                    value = value[name]
                if count is None:
                    flat.append(value)
                elif len(value) != count:
                    return None
                else:
                    flat.extend(value)
            return self.codec.pack(*flat)
        except (KeyError, TypeError, OverflowError, struct.error):
            return None


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


def _fields(struct_con: Any, prefix: tuple[str, ...]) -> list[Field] | None:
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
