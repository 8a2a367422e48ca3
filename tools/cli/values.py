"""Turn ``field=value`` command-line words into the dict a construct declaration builds from.

Values: integers (``10``, ``0x2a``), floats, comma lists (``1,2,3``), hex for byte fields
(``data=42ff00``), text for strings, a code's name or number for a coded field
(``mode=joint``, ``mode=2``); dotted names reach nested structs (``args.target=…``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import construct as c

from protocol.enum_field import EnumField
from tools.errors import FieldValueError


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


def _settable(con: c.Construct) -> list[tuple[str, c.Construct]]:
    """(name, unwrapped declaration) of the fields of a Struct a caller gives values for
    (computed, constant and padding fields are left out)."""
    out = []
    for sub in getattr(con, "subcons", ()):
        name = getattr(sub, "name", None)
        inner = _unwrap_renamed(sub)
        if name is None or isinstance(inner, c.Rebuild | c.Const | c.Padded | c.Check):
            continue
        out.append((name, inner))
    return out


def _unwrap_renamed(con: c.Construct) -> c.Construct:
    while isinstance(con, c.Renamed):
        con = con.subcon
    return con


def _int_range(fmtstr: str) -> tuple[int, int] | None:
    code = fmtstr[-1]
    if code in "efd":
        return None
    bits = 8 * struct.calcsize("<" + code)
    if code.isupper() or code == "B":
        return 0, (1 << bits) - 1
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


#: The largest finite float32 (a field declared ``f``).
_FLOAT32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]


def _check_number(con: c.FormatField, value: Any, path: str) -> None:
    bounds = _int_range(con.fmtstr)
    if bounds is None:
        if not _is_number(value):
            raise FieldValueError(f"{path}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise FieldValueError(f"{path}: {value!r} is not a finite number")
        if con.fmtstr[-1] == "f" and abs(value) > _FLOAT32_MAX:
            raise FieldValueError(f"{path}: {value!r} is outside the float32 range "
                                  f"(±{_FLOAT32_MAX:.4g})")
        return
    if not isinstance(value, int) or isinstance(value, bool):
        raise FieldValueError(f"{path}: expected an integer, got {value!r}")
    lo, hi = bounds
    if not lo <= value <= hi:
        raise FieldValueError(f"{path}: {value} is outside {lo}..{hi}")


def _check_value(con: c.Construct, value: Any, path: str, message: str) -> None:
    """Raise :class:`FieldValueError` when ``value`` cannot be what ``con`` declares."""
    con = _unwrap_renamed(con)
    if isinstance(con, c.Struct):
        if not isinstance(value, Mapping):
            raise FieldValueError(f"{path}: expected fields ({path}.NAME=…), got {value!r}")
        check_fields(con, value, message, path)
    elif isinstance(con, EnumField):
        if isinstance(value, str):
            if value.lower() not in con.by_name:
                names = ", ".join(m.name.lower() for m in con.enum_type)
                raise FieldValueError(f"{path}: {value!r} is not a {con.enum_type.__name__} "
                                      f"({names}, or its number)")
        else:
            _check_value(con.subcon, value, path, message)
    elif isinstance(con, c.FormatField):
        _check_number(con, value, path)
    elif isinstance(con, c.Array) and isinstance(con.count, int):
        sub = _unwrap_renamed(con.subcon)
        if not isinstance(value, list):
            value = [value]
        noun = "numbers" if isinstance(sub, c.FormatField) else "values"
        if len(value) != con.count:
            raise FieldValueError(f"{path}: expected {con.count} {noun}, got {len(value)}")
        for i, item in enumerate(value):
            _check_value(sub, item, f"{path}[{i}]", message)
    elif isinstance(con, c.Bytes) and isinstance(con.length, int):
        if isinstance(value, bytes | bytearray) and len(value) != con.length:
            raise FieldValueError(f"{path}: expected {con.length} bytes, got {len(value)}")
    elif isinstance(con, c.StringEncoded):
        if not isinstance(value, str) or not value.isascii():
            raise FieldValueError(f"{path}: expected ASCII text, got {value!r}")
        if len(value) > 255:
            raise FieldValueError(f"{path}: {len(value)} characters, at most 255 fit")


def check_fields(con: c.Construct, values: Mapping[str, Any], message: str,
                 prefix: str = "") -> None:
    """Check ``values`` against the Struct ``con`` before building, in plain words.

    Unknown and missing field names, list lengths, integer ranges and fixed byte lengths
    are checked here (``message`` names the message in the text); anything subtler is left
    to construct, whose error the caller reports.
    """
    fields = dict(_settable(_unwrap_renamed(con)))
    where = f" of {prefix}" if prefix else ""
    listing = f"(fields{where}: {', '.join(fields)})" if fields else f"({prefix or message} has no fields)"
    for name in values:
        if name not in fields:
            dotted = f"{prefix}.{name}" if prefix else name
            raise FieldValueError(f"{message}: unknown field {dotted!r} {listing}")
    coded = _by_code(fields, values)  # what a Switch key or a Check sees once built
    for name, sub in fields.items():
        dotted = f"{prefix}.{name}" if prefix else name
        if name not in values:
            raise FieldValueError(f"{message}: missing field {dotted!r} {listing}")
        if isinstance(sub, c.Switch):
            try:
                case = sub.cases.get(sub.keyfunc(coded))
            except (KeyError, TypeError):
                case = None
            if case is not None:
                _check_value(case, values[name], dotted, message)
            elif sub.default is c.Error and isinstance(key := sub.keyfunc(coded), int):
                declared = ", ".join(str(int(k)) for k in sorted(sub.cases))
                raise FieldValueError(f"{message}: {dotted} is declared only for "
                                      f"{declared}, not for {key!r}")
            continue
        _check_value(sub, values[name], dotted, message)
    _check_checks(con, coded, message, prefix)


def _by_code(fields: Mapping[str, c.Construct], values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with each coded field given by name replaced by its member (names that
    are not members stay as given: :func:`_check_value` reports them)."""
    out = dict(values)
    for name, value in values.items():
        sub = fields.get(name)
        if isinstance(sub, EnumField) and isinstance(value, str):
            out[name] = sub.by_name.get(value.lower(), value)
    return out


def _check_checks(con: c.Construct, values: Mapping[str, Any], message: str,
                  prefix: str) -> None:
    """Evaluate a Struct's ``Check`` fields on ``values`` (computed fields computed first)."""
    context = dict(values)
    for sub in getattr(_unwrap_renamed(con), "subcons", ()):
        inner = _unwrap_renamed(sub)
        try:
            if isinstance(inner, c.Rebuild) and sub.name:
                context[sub.name] = inner.func(context) if callable(inner.func) else inner.func
            elif isinstance(inner, c.Check):
                ok = inner.func(context) if callable(inner.func) else inner.func
                if not ok:
                    shown = ", ".join(f"{k}={v!r}" for k, v in context.items()
                                      if k in str(inner.func) and not isinstance(v, bytes))
                    where = f"{prefix}: " if prefix else ""
                    raise FieldValueError(f"{message}: {where}{shown} fails the declared "
                                          f"check {inner.func}")
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            if isinstance(exc, FieldValueError):
                raise
            return  # cannot evaluate it here: construct will
