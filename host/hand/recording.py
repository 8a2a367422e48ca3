"""Record a hand link to an MCAP file: every frame as it crossed the wire, and the states.

Channels:

=====================  ==============  =======================================================
topic                  encoding        message
=====================  ==============  =======================================================
``/hand/frames/tx``    ``hand-frame``  a complete hand frame the host sent (raw bytes)
``/hand/frames/rx``    ``hand-frame``  a complete hand frame the host decoded (raw bytes)
``/hand/state``        ``json``        every :meth:`host.hand.facade.Hand.status` read
                                       (:data:`HAND_STATE_SCHEMA`)
``/hand/fingers``      ``json``        every :meth:`host.hand.facade.Hand.finger_states` read (the
                                       fingers a move, grasp or homing polled;
                                       :data:`FINGER_READING_SCHEMA`)
``/hand/events``       ``json``        every ``palm.finger_event`` (:data:`EVENT_SCHEMA`)
``/hand/frames/tx/earlier``  ``hand-frame``  what other programs sent on the link before this
                                       one opened it (when the transport knows)
``/hand/frames/tx/others``  ``hand-frame``  what other programs sent on the link while it
                                       recorded (a flasher beside it; when the transport knows)
=====================  ==============  =======================================================

Log times are the wall clock; the link's clock (the simulation's with the in-process
emulator) is each message's publish time and, in JSON, its field ``t`` (s)
(:mod:`host.recording.writer`).  Raw frames decode with ``protocol.framing.parse_frame`` or
``handbus decode``.  The file is written as it goes (at least every
:data:`host.recording.writer.FLUSH_INTERVAL_S`); a full disk stops it with
:class:`~host.errors.RecordingError` at the next state :meth:`HandRecorder.record` writes.

The file's ``source`` metadata record says the link, its URL, the link's clock when the
recorder attached and whether the session's first frames since it opened (its prologue,
:mod:`host.recording.prologue`) are all in it; they are written first, at their own times.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any, Final

from host.hand.interface import WatchedHand
from host.hand.session import FingerEvent
from host.hand.state import FingerState, HandState
from host.recording.topics import HAND_EVENTS, HAND_STATE
from host.recording.writer import (
    JSON_ENCODING,
    SOURCE_METADATA,
    Recording,
    Sink,
    Topic,
    source_metadata,
)

#: Message encoding of raw hand frames.
FRAME_ENCODING: Final = "hand-frame"


def _number(description: str) -> dict[str, Any]:
    return {"type": "number", "description": description}


def _numbers(description: str, n: int | None = None, kind: str = "number",
             nullable: bool = False) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": ["array", "null"] if nullable else "array",
                              "items": {"type": kind}, "description": description}
    if n is not None:
        schema["minItems"] = schema["maxItems"] = n
    return schema


def _nullable(kind: str, description: str) -> dict[str, Any]:
    return {"type": [kind, "null"], "description": description}


def _object(description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {"type": "object", "description": description, "properties": properties,
            "required": list(properties), "additionalProperties": False}


#: JSON Schema of one finger (:meth:`host.hand.state.FingerState.to_dict`).
FINGER_SCHEMA: Final = _object("one finger module", {
    "index": {"type": "integer", "description": "finger index 0..3"},
    "present": {"type": "boolean", "description": "its fmcb answered this reading"},
    "power": {"type": "string", "description": "finger supply as the palm switched it: off, "
                                               "low, full"},
    "joints": _numbers("joint angles J0 (spread), J1, J2 (rad), from the motor hall counts", 3),
    "joints_hall": _numbers("motor positions (hall counts, homing-relative)", 3, "integer"),
    "targets_hall": _numbers("the fmcb's motor targets (hall counts); null when not read", 3,
                             "integer", nullable=True),
    "effort": _numbers("motor efforts (1/255 of full PWM, signed)", 3, "integer"),
    "tactile": {"type": "object", "description": "taxels (ADC counts)",
                "properties": {
                    "proximal": _numbers("proximal phalange's 6 taxels (ADC counts)", 6,
                                         "integer"),
                    "distal": _numbers("distal phalange's 12 taxels (ADC counts)", 12,
                                       "integer")},
                "additionalProperties": False},
    "currents": _object("currents (mA)", {
        "supply": _nullable("integer", "finger supply current from the palm (mA)"),
        "phalange_bus": _nullable("integer", "phalange bus current from the fmcb (mA)")}),
    "breaker_tripped": {"type": "boolean", "description": "the phalange bus breaker tripped"},
    "supply_v": _nullable("number", "the fmcb's logic supply (V)"),
    "temperatures_c": _numbers("motor temperatures (°C)", 3, nullable=True),
    "problem": _nullable("string", "why the fmcb did not answer (unpowered, no_reply, …)"),
})
#: JSON Schema of ``/hand/state`` (:meth:`host.hand.state.HandState.to_dict`).
HAND_STATE_SCHEMA: Final = _object("the hand: the palm's summary and every finger", {
    "t": _number("the link's clock (s): simulation time with the in-process emulator"),
    "palm_time_us": _nullable("integer", "the palm's clock (µs)"),
    "effort_cap": _nullable("integer", "the palm's effort cap (1/255 of full PWM)"),
    "poll_hz": _nullable("integer", "how often the palm polls the fingers (Hz)"),
    "bus_voltage_mv": _nullable("integer", "the hand's supply bus (mV)"),
    "fingers": {"type": "array", "items": FINGER_SCHEMA, "minItems": 4, "maxItems": 4,
                "description": "fingers 0..3"},
})
#: JSON Schema of ``/hand/fingers``: some fingers' ``fmcb.status``, read together.
FINGER_READING_SCHEMA: Final = _object("fingers' status read together (a move, grasp, homing)", {
    "t": _number("the link's clock after the reading (s)"),
    "fingers": {"type": "array", "items": FINGER_SCHEMA, "description": "the fingers read"},
})
#: JSON Schema of ``/hand/events`` (:class:`host.hand.session.FingerEvent`).
EVENT_SCHEMA: Final = _object("an unsolicited palm.finger_event", {
    "finger": {"type": "integer", "description": "finger index 0..3"},
    "event": {"type": "string", "description": "lost, returned, breaker_trip, powered, "
                                               "unpowered (or the code's number)"},
    "code": {"type": "integer", "description": "the event's code on the wire"},
    "palm_time_us": {"type": "integer", "description": "the palm's clock at the event (µs)"},
    "t": _number("the link's clock when it arrived (s)"),
})

FRAMES_TX: Final = Topic("/hand/frames/tx", FRAME_ENCODING)
FRAMES_RX: Final = Topic("/hand/frames/rx", FRAME_ENCODING)
STATE: Final = Topic(HAND_STATE, JSON_ENCODING, "HandState", HAND_STATE_SCHEMA)
FINGERS_READ: Final = Topic("/hand/fingers", JSON_ENCODING, "FingerReading",
                            FINGER_READING_SCHEMA)
EVENTS: Final = Topic(HAND_EVENTS, JSON_ENCODING, "FingerEvent", EVENT_SCHEMA)
FRAMES_EARLIER: Final = Topic("/hand/frames/tx/earlier", FRAME_ENCODING)
FRAMES_OTHERS: Final = Topic("/hand/frames/tx/others", FRAME_ENCODING)
TOPICS: Final = (FRAMES_TX, FRAMES_RX, STATE, FINGERS_READ, EVENTS, FRAMES_EARLIER,
                 FRAMES_OTHERS)


class HandRecorder(Recording):
    """Writes a hand link's frames, state reads and events to the MCAP file ``path`` (None:
    only to ``sinks``) while attached (a context manager; :meth:`close` detaches and
    finishes the file).  :class:`~host.errors.RecordingError` if ``path`` cannot be
    created."""

    def __init__(self, hand: WatchedHand, path: str | Path | None, *, sinks: tuple[Sink, ...] = ()
                 ) -> None:
        transport = hand.session.transport
        prologue = hand.session.prologue
        earlier = transport.sent_before()
        watched = transport.watch_others()
        super().__init__(path, TOPICS, library="lowcost-hand-stack host.hand.recording",
                         sinks=sinks, metadata={SOURCE_METADATA: source_metadata(
                             hand.session.link, transport.url, transport.now(),
                             prologue.state(), None if earlier is None else len(earlier),
                             watched)})
        self._watched = watched
        for t, data in earlier or ():
            self.log(FRAMES_EARLIER, t, data)
        for direction, t, frame in prologue.messages:
            self.log(FRAMES_TX if direction == "tx" else FRAMES_RX, t, frame)
        self.frames = 0
        self.states = 0
        self._attached = False
        self.hand = hand
        self.attach(hand)

    def attach(self, hand: WatchedHand) -> None:
        """Record ``hand`` from now on (detached from the one before: a link closed and
        opened again goes on in the same file)."""
        self._detach()
        if hand is not self.hand and self._watched:
            self._watched = hand.session.transport.watch_others()
        self.hand = hand
        hand.session.taps.append(self._on_frame)
        hand.state_taps.append(self.add_state)
        hand.finger_taps.append(self._on_fingers)
        self._unsubscribe = hand.subscribe(self._on_event)
        self._attached = True

    def _take_others(self) -> None:
        """Write what other programs sent on the link since the last look."""
        for t, data in self.hand.session.transport.take_others():
            self.log(FRAMES_OTHERS, t, data)

    def _detach(self) -> None:
        if self._attached:
            self._take_others()
            self._attached = False
            for taps, tap in ((self.hand.session.taps, self._on_frame),
                              (self.hand.state_taps, self.add_state),
                              (self.hand.finger_taps, self._on_fingers)):
                if tap in taps:
                    taps.remove(tap)  # type: ignore[arg-type]
            self._unsubscribe()

    def _on_frame(self, direction: str, t: float, frame: bytes) -> None:
        self._take_others()  # first: they went out before this frame
        self.frames += 1
        self.log(FRAMES_TX if direction == "tx" else FRAMES_RX, t, frame)

    def _on_event(self, event: FingerEvent) -> None:
        self.log_json(EVENTS, event.t, asdict(event))

    def _on_fingers(self, t: float, states: dict[int, FingerState]) -> None:
        self.log_json(FINGERS_READ, t, {"t": round(t, 6),
                                        "fingers": [s.to_dict() for s in states.values()]})

    def add_state(self, state: HandState) -> None:
        """Write one hand state at its time (every :meth:`Hand.status` read comes here)."""
        self.states += 1
        self.log_json(STATE, state.t, state.to_dict())

    def record(self, seconds: float, rate_hz: float = 50.0) -> None:
        """Read the hand's state ``rate_hz`` times a second for ``seconds`` (the link's
        clock); each read is written.  :class:`~host.errors.RecordingError` stops it when
        the file cannot be written."""
        self.check()
        for _state in self.hand.states(rate_hz, seconds):
            self.check()

    def close(self) -> None:
        """Detach from the link and finish the file (idempotent)."""
        self._detach()
        self.close_sinks()

    def __enter__(self) -> HandRecorder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
