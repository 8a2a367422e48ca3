"""How hand frames ride on the palm's CAN bus (CAN 2.0A, at most 8 data bytes per frame).

A hand frame is cut into CAN frames of up to 8 bytes, in order, all with one 11-bit
identifier that says the direction and the node::

    host → node  0x100 + node   (node 0..0x7F; the palm of a hand is node 0x0A by default)
    node → host  0x180 + node

The receiver concatenates the data of each identifier and runs the same
:class:`~protocol.stream.StreamDecoder` as on a serial line, so resynchronisation, the gap
rule and CRC checking are the serial link's.  CAN's own CRC and in-order delivery per
identifier make corruption rare; the gap rule recovers from a lost CAN frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from protocol.errors import FrameError
from protocol.framing import DEFAULT_MAX_PAYLOAD, Frame
from protocol.stream import StreamDecoder

CAN_MAX_DATA: Final = 8
TO_NODE_BASE: Final = 0x100
TO_HOST_BASE: Final = 0x180
MAX_NODE: Final = 0x7F
#: Default CAN node number of a palm.
DEFAULT_PALM_NODE: Final = 0x0A


@dataclass(frozen=True)
class CanId:
    """A decoded identifier: ``to_host`` is the direction, ``node`` the palm's CAN node."""

    to_host: bool
    node: int


def can_id(node: int, to_host: bool) -> int:
    """The 11-bit identifier for traffic to (``to_host=False``) or from a node."""
    if not 0 <= node <= MAX_NODE:
        raise FrameError(f"CAN node {node} is outside 0..{MAX_NODE}")
    return (TO_HOST_BASE if to_host else TO_NODE_BASE) + node


def parse_can_id(arbitration_id: int) -> CanId | None:
    """The direction and node of an identifier, or None if it is not hand traffic."""
    if TO_NODE_BASE <= arbitration_id < TO_NODE_BASE + 0x80:
        return CanId(False, arbitration_id - TO_NODE_BASE)
    if TO_HOST_BASE <= arbitration_id < TO_HOST_BASE + 0x80:
        return CanId(True, arbitration_id - TO_HOST_BASE)
    return None


def segment(frame: bytes) -> list[bytes]:
    """Cut a complete hand frame into CAN data fields of at most 8 bytes, in order."""
    return [bytes(frame[i : i + CAN_MAX_DATA]) for i in range(0, len(frame), CAN_MAX_DATA)]


class CanReassembler:
    """Hand frames back from CAN data, one stream decoder per identifier.

    ``gap_s`` (seconds) drops a partial frame when its next CAN frame comes later than that.
    """

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD, gap_s: float | None = 0.010):
        self._max_payload = max_payload
        self._gap_s = gap_s
        self._streams: dict[int, StreamDecoder] = {}

    def decoder(self, arbitration_id: int) -> StreamDecoder:
        """The stream decoder of one identifier (made on first use)."""
        dec = self._streams.get(arbitration_id)
        if dec is None:
            dec = StreamDecoder(max_payload=self._max_payload, gap_s=self._gap_s)
            self._streams[arbitration_id] = dec
        return dec

    def feed(self, arbitration_id: int, data: bytes, t: float | None = None) -> list[Frame]:
        """Add one CAN frame's data; returns the hand frames it completed."""
        if len(data) > CAN_MAX_DATA:
            raise FrameError(f"a CAN 2.0 frame carries at most 8 bytes, got {len(data)}")
        return self.decoder(arbitration_id).feed(data, t)
