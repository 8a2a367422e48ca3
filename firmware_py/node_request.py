"""A request a hand-protocol program is handling, and how its handler answers.

A handler gets a :class:`Request` and returns the reply fields (a dict), ``None`` when the
message has no reply, or :data:`DEFERRED` when it will call :meth:`Request.respond` later
(a tunnel, a routed frame waiting for a downstream reply, a flash write in progress).
:class:`~firmware_py.hand_node.HandNode` dispatches to handlers; services a node carries
(:mod:`firmware_py.slot_service`) register theirs on it without knowing it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

from firmware_py.hal import Uart
from protocol.catalogue import Message
from protocol.framing import Frame
from protocol.messages.common import TxnStatus

#: Returned by a handler that will answer later through :meth:`Request.respond`.
DEFERRED: Final = object()


@dataclass
class Request:
    """A request being handled: its message, fields, frame and where to answer."""

    message: Message
    fields: dict[str, Any]
    frame: Frame
    uart: Uart
    _send: Callable[[bytes | None, int], None] = field(repr=False)

    # Written out: a dataclass's generated __init__ stays interpreted in the compiled core
    # (mypyc), and every request a node handles makes one.
    def __init__(self, message: Message, fields: dict[str, Any], frame: Frame, uart: Uart,
                 _send: Callable[[bytes | None, int], None]) -> None:
        self.message = message
        self.fields = fields
        self.frame = frame
        self.uart = uart
        self._send = _send

    def respond(self, reply: dict[str, Any] | bytes | None, status: int = TxnStatus.OK) -> None:
        """Send the reply now (fields, raw payload, or None for an error status)."""
        if isinstance(reply, dict):
            payload: bytes | None = self.message.build_reply(reply)
        else:
            payload = reply
        self._send(payload, status)


Handler = Callable[[Request], Any]
