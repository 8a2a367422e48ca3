"""Names for people of the hand protocol's coded fields.

The codes themselves are the ``IntEnum`` members declared next to their messages
(:mod:`protocol.messages`: ``RouteStatus``, ``TxnStatus``, ``FingerPower``, ``FingerEvent``,
``ControlMode``, ``Running``); a parsed reply already holds the member for a known code and
the plain ``int`` for any other.  :func:`code_name` turns either into the lower-case name
host output uses (``"unpowered"``, ``"application"``).
"""

from __future__ import annotations

from enum import IntEnum


def code_name(enum_type: type[IntEnum], code: int, unknown: str = "code") -> str:
    """The lower-case name of ``code`` in ``enum_type`` (``RouteStatus``, 2 →
    ``"unpowered"``); a code the enum does not know reads ``"{unknown} {code}"``."""
    try:
        return enum_type(code).name.lower()
    except ValueError:
        return f"{unknown} {int(code)}"
