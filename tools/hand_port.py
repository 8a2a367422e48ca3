"""A minimal blocking client of the hand protocol on a serial port (pyserial).

Enough for the demo, the emulator's tests and a person at a terminal: send a request by its
catalogue name, wait for the reply of the same type, parse it; reach nodes behind the palm
with ``palm.route``.  The full host driver library (transactions, CAN, reconnects) is the
host package's job.
"""

from __future__ import annotations

import time
from typing import Any

import serial

from protocol.framing import parse_frame
from protocol.messages import CATALOGUE
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_HOST, ADDR_PALM, HOP_ADDRESS, HOST_LINK_BAUD, Hop

#: Unsolicited messages a reply wait skips over (finger events).
_UNSOLICITED = {CATALOGUE["palm.finger_event"].type_id}


class ReplyTimeout(TimeoutError):
    """No reply of the expected type arrived in time."""


class HandPort:
    """A hand node (the palm, or a loose finger's fmcb) on serial port ``path``."""

    def __init__(self, path: str, baud: int = HOST_LINK_BAUD) -> None:
        self.serial = serial.Serial(path, baud, timeout=0.005)
        self.decoder = StreamDecoder()
        self.events: list[dict[str, Any]] = []  # unsolicited palm.finger_event replies

    def close(self) -> None:
        self.serial.close()

    def __enter__(self) -> HandPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def request(self, name: str, address: int = ADDR_PALM, timeout_s: float = 0.5,
                **fields: Any) -> dict[str, Any]:
        """Send request ``name`` with ``fields`` to ``address``; return the parsed reply."""
        msg = CATALOGUE[name]
        self.serial.reset_input_buffer()
        self.decoder.reset()
        self.serial.write(msg.request_frame(address, fields))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for frame in self.decoder.feed(self.serial.read(4096)):
                if frame.address != ADDR_HOST:
                    continue
                if frame.type == msg.type_id:
                    return msg.parse_reply(frame.payload)
                if frame.type in _UNSOLICITED:
                    self.events.append(CATALOGUE["palm.finger_event"].parse_reply(frame.payload))
        raise ReplyTimeout(f"no reply to {name} at address {address} within {timeout_s} s")

    def route(self, finger: int, hop: int, name: str, timeout_ms: int = 50,
              **fields: Any) -> dict[str, Any]:
        """Send ``name`` to the node at ``hop`` of ``finger`` through the palm; return its
        parsed reply (raises :class:`ReplyTimeout` when the palm reports no answer)."""
        msg = CATALOGUE[name]
        inner = msg.request_frame(HOP_ADDRESS[Hop(hop)], fields)
        reply = self.request("palm.route", timeout_s=timeout_ms / 1000 + 0.5, finger=finger,
                             hop=hop, timeout_ms=timeout_ms, frame=inner)
        if reply["status"] != 0:
            raise ReplyTimeout(f"{name} to finger {finger} hop {hop}: route status "
                               f"{reply['status']}")
        frame = parse_frame(reply["frame"])
        return msg.parse_reply(frame.payload)
