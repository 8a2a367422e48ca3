"""Record a hand link to an MCAP file: every frame as it crossed the wire, and the states.

Channels:

=====================  ==============  =======================================================
topic                  encoding        message
=====================  ==============  =======================================================
``/hand/frames/tx``    ``hand-frame``  a complete hand frame the host sent (raw bytes)
``/hand/frames/rx``    ``hand-frame``  a complete hand frame the host decoded (raw bytes)
``/hand/state``        ``json``        :meth:`host.hand_state.HandState.to_dict`
``/hand/events``       ``json``        a ``palm.finger_event`` (finger, event, palm time)
=====================  ==============  =======================================================

Log times are the link's clock (``transport.now()``) in ns: the simulation clock on an
in-process emulator.  Raw frames decode with ``protocol.framing.parse_frame``.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import IO, Any, Final

from mcap.writer import Writer

from host.hand import Hand
from host.hand_session import FingerEvent
from host.hand_state import HandState

#: Message encoding of raw hand frames.
FRAME_ENCODING: Final = "hand-frame"
_STATE_SCHEMA: Final = {
    "type": "object",
    "description": "HandState.to_dict(): joints in rad, hall counts, taxels in ADC counts, mA",
}
_EVENT_SCHEMA: Final = {"type": "object", "description": "palm.finger_event"}


def _ns(t: float) -> int:
    return max(0, int(round(t * 1e9)))


class HandRecorder:
    """Writes a hand link's frames and states to ``path`` while attached (context manager)."""

    def __init__(self, hand: Hand, path: str | Path) -> None:
        self.hand = hand
        self.path = Path(path)
        self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._stream)
        self._writer.start(profile="", library="lowcost-hand host")
        w = self._writer
        self._tx = w.register_channel("/hand/frames/tx", FRAME_ENCODING, 0)
        self._rx = w.register_channel("/hand/frames/rx", FRAME_ENCODING, 0)
        state_schema = w.register_schema("HandState", "jsonschema",
                                         json.dumps(_STATE_SCHEMA).encode())
        event_schema = w.register_schema("FingerEvent", "jsonschema",
                                         json.dumps(_EVENT_SCHEMA).encode())
        self._state = w.register_channel("/hand/state", "json", state_schema)
        self._event = w.register_channel("/hand/events", "json", event_schema)
        self._seq: dict[int, int] = {}
        self.frames = 0
        self.states = 0
        hand.session.taps.append(self._on_frame)
        self._unsubscribe = hand.subscribe(self._on_event)
        self._open = True

    def _add(self, channel: int, t: float, data: bytes) -> None:
        seq = self._seq.get(channel, 0)
        self._seq[channel] = seq + 1
        self._writer.add_message(channel, _ns(t), data, _ns(t), sequence=seq)

    def _on_frame(self, direction: str, t: float, frame: bytes) -> None:
        self.frames += 1
        self._add(self._tx if direction == "tx" else self._rx, t, frame)

    def _on_event(self, event: FingerEvent) -> None:
        self._add(self._event, event.t, json.dumps(asdict(event)).encode())

    def add_state(self, state: HandState) -> None:
        """Write one hand state at its time."""
        self.states += 1
        self._add(self._state, state.t, json.dumps(state.to_dict()).encode())

    def record(self, seconds: float, rate_hz: float = 50.0) -> None:
        """Read the hand's state ``rate_hz`` times a second for ``seconds`` and write it."""
        self.hand.stream(rate_hz, self.add_state, seconds)

    def close(self) -> None:
        """Detach from the link and finish the file (idempotent)."""
        if not self._open:
            return
        self._open = False
        if self._on_frame in self.hand.session.taps:
            self.hand.session.taps.remove(self._on_frame)
        self._unsubscribe()
        self._writer.finish()
        self._stream.close()

    def __enter__(self) -> HandRecorder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
