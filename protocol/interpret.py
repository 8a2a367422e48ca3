"""Name and decode a hand frame's payload from the catalogue, without knowing the bus.

A frame says only its destination address and type.  Replies go to address 0 and requests
to 1 (f2), 2 (f3) or 10 (fmcb, palm or a bootloader), so :func:`interpret` tries the node
kinds the address allows, in a fixed order, and takes the first whose declaration consumes
the payload exactly.  A caller that knows the node (a driver, or a capture tool that saw
the request) passes it as a hint and it is tried first.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from protocol.catalogue import REPLY, REQUEST, Message
from protocol.errors import PayloadError
from protocol.framing import Frame
from protocol.messages import CATALOGUE
from protocol.topology import ADDR_BROADCAST, ADDR_HOST, NODE_ADDRESS, NodeKind

#: Node kinds in the order they are tried (the bootloader answers at every node's address).
_ALL_NODES = ("fmcb", "palm", "f2", "f3", "bootloader")
#: Node kinds a request to each node address may be for, in :data:`_ALL_NODES` order.
_BY_ADDRESS: dict[int, tuple[str, ...]] = {
    address: tuple(n for n in _ALL_NODES
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
    nodes = _ALL_NODES if address in (ADDR_HOST, ADDR_BROADCAST) else _BY_ADDRESS.get(address, _ALL_NODES)
    if hint:
        nodes = (hint, *[n for n in nodes if n != hint])
    return nodes


def interpret(frame: Frame, hint: str | None = None) -> Interpretation:
    """Decode ``frame`` against the catalogue (never raises for any payload)."""
    direction = REPLY if frame.address == ADDR_HOST else REQUEST
    first_error: str | None = None
    first_message: Message | None = None
    seen: set[str] = set()
    for node in candidate_nodes(frame.address, hint):
        msg = CATALOGUE.lookup(node, frame.type)
        if msg is None or msg.name in seen:
            continue
        seen.add(msg.name)
        con = msg.request if direction == REQUEST else msg.reply
        if con is None:
            continue
        try:
            fields = msg.parse(direction, frame.payload)
        except PayloadError as exc:
            if first_error is None:
                first_error, first_message = str(exc), msg
            continue
        return Interpretation(msg, direction, fields)
    return Interpretation(first_message, direction, None, first_error)
