"""Turn ``field=value`` command-line words into the dict a construct declaration builds from.

Values: integers (``10``, ``0x2a``), floats, comma lists (``1,2,3``), hex for byte fields
(``data=42ff00``), text for strings; dotted names reach nested structs (``args.target=…``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import construct as c


class FieldValueError(ValueError):
    """A ``field=value`` word that cannot be used."""


def parse_scalar(text: str) -> Any:
    """An int, a float, or the text itself."""
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def parse_value(text: str) -> Any:
    """A scalar, or a list of scalars when the text has commas."""
    if "," in text:
        return [parse_scalar(t) for t in text.split(",") if t != ""]
    return parse_scalar(text)


def _unwrap(con: c.Construct) -> c.Construct:
    while isinstance(con, c.Renamed | c.Rebuild):
        con = con.subcon
    return con


def _find_field(con: c.Construct, name: str) -> c.Construct | None:
    for sub in getattr(con, "subcons", ()):
        if getattr(sub, "name", None) == name:
            return _unwrap(sub)
    return None


def _is_bytes(con: c.Construct | None) -> bool:
    return isinstance(con, c.Bytes) or con is c.GreedyBytes


def _coerce(con: c.Construct | None, text: str, name: str) -> Any:
    if isinstance(con, c.StringEncoded):
        return text  # text fields keep digits as text ("name=123")
    if _is_bytes(con):
        try:
            return bytes.fromhex(text.removeprefix("0x").replace(":", ""))
        except ValueError:
            raise FieldValueError(f"{name}: {text!r} is not hex bytes") from None
    value = parse_value(text)
    if isinstance(con, c.Array) and not isinstance(value, list):
        return [value]
    return value


def build_fields(con: c.Construct, words: Sequence[str]) -> dict[str, Any]:
    """``["a=1", "b.c=1,2"]`` → ``{"a": 1, "b": {"c": [1, 2]}}`` typed by ``con``.

    Switch-dependent structs (``args`` of a control message) are left as given.
    """
    fields: dict[str, Any] = {}
    for word in words:
        if "=" not in word:
            raise FieldValueError(f"{word!r} is not field=value")
        name, text = word.split("=", 1)
        path = name.split(".")
        target = fields
        sub: c.Construct | None = con
        for part in path[:-1]:
            target = target.setdefault(part, {})
            sub = _find_field(sub, part) if sub is not None else None
        leaf = _find_field(sub, path[-1]) if sub is not None else None
        target[path[-1]] = _coerce(leaf, text, name)
    # Switch arms: empty struct when none given (e.g. mode=0 needs no args).
    for sub_con in getattr(con, "subcons", ()):
        if getattr(sub_con, "name", None) and isinstance(_unwrap(sub_con), c.Switch):
            fields.setdefault(sub_con.name, {})
    return fields
