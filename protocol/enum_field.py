"""Coded integer fields whose known values are the members of an ``IntEnum``.

``"status" / EnumField(c.Int8ul, RouteStatus) * "[-] outcome"`` declares a one-byte field
whose codes are :class:`~protocol.messages.palm.RouteStatus` members:

- parsing yields the member for a known code and the plain ``int`` for any other, and never
  raises for the code itself (capture decoders and fuzzers meet every value; an unknown code
  is data, not an error).  A member compares and hashes equal to its int, so handlers that
  compare with ints, and ``Switch`` cases keyed by ints, keep working;
- building accepts a member, any int the underlying field holds, or a member's name
  (case-insensitive: ``"no_reply"`` or ``"NO_REPLY"``); an unknown name is a
  ``construct.MappingError``.

The wire is the underlying field's: the catalogue fingerprint describes an ``EnumField``
exactly like its integer (:func:`protocol.catalogue.describe_layout`), the struct fast path
(:mod:`protocol.flat_codec`) decodes it the same way, and :mod:`protocol.docgen` lists the
members.  Chosen over construct's ``Enum``, whose parse gives ``EnumIntegerString`` (neither
the member nor an int) and whose build returns the name to the context, which breaks a
``Switch`` keyed by the field.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

import construct as c


class EnumField(c.Adapter):
    """An integer field decoded to members of ``enum_type`` when the code is known."""

    def __init__(self, subcon: c.Construct, enum_type: type[IntEnum]) -> None:
        super().__init__(subcon)
        self.enum_type = enum_type
        self.by_value: dict[int, IntEnum] = {m.value: m for m in enum_type}
        self.by_name: dict[str, IntEnum] = {m.name.lower(): m for m in enum_type}

    def decode_code(self, value: int) -> int:
        """The member whose value is ``value``, else ``value`` itself."""
        return self.by_value.get(value, value)

    def encode_code(self, value: Any, path: str | None = None) -> Any:
        """A name → its member; anything else is left for the integer field to check."""
        if isinstance(value, str):
            member = self.by_name.get(value.lower())
            if member is None:
                names = ", ".join(m.name for m in self.enum_type)
                raise c.MappingError(
                    f"{value!r} is not a {self.enum_type.__name__} ({names})", path=path)
            return member
        return value

    def _decode(self, obj: int, context: Any, path: str) -> int:
        return self.decode_code(obj)

    def _encode(self, obj: Any, context: Any, path: str) -> Any:
        return self.encode_code(obj, path)

    def _build(self, obj: Any, stream: Any, context: Any, path: str) -> Any:
        # Adapter._build returns ``obj`` as given; return the code instead, so a Switch
        # keyed by this field (``fmcb.control``'s mode) finds its case when built by name.
        value = self._encode(obj, context, path)
        self.subcon._build(value, stream, context, path)
        return self.decode_code(value) if isinstance(value, int) else value


__all__ = ["EnumField"]
