"""Record the arm's bus to MCAP: every raw byte chunk and every decoded cycle state.

Channels:

=================  ============================  =========================================
topic              message encoding              payload
=================  ============================  =========================================
``/arm/bus/tx``    ``application/octet-stream``  bytes the host sent (whole packets)
``/arm/bus/rx``    ``application/octet-stream``  bytes received, as they arrived
``/arm/bus/tx/earlier``  ``application/octet-stream``  what other programs sent on the link
                                                 before this one opened it (when known)
``/arm/bus/tx/others``  ``application/octet-stream``  what other programs sent on the link
                                                 while it recorded (when known)
``/arm/state``     ``json`` (:data:`STATE_SCHEMA`)  every cycle's
                                                 :meth:`~host.arm.state.ArmState.as_dict`
=================  ============================  =========================================

Log times are the wall clock; the link's clock (the simulation's with the in-process
emulator, a monotonic clock on a serial port) is each message's publish time and, in the
state, its field ``t`` (s) (:mod:`host.recording.writer`).  Replay the raw channels through
:class:`~protocol.dynamixel.DynamixelStreamDecoder` (or ``handbus decode --dynamixel``) to
get the packets back.  :func:`record` cycles the arm itself for a while; :class:`ArmRecorder`
writes whatever another program does with the arm (every cycle's state, every byte) while
it is attached.  The file is written as it goes (at least every
:data:`host.recording.writer.FLUSH_INTERVAL_S`).

The file's ``source`` metadata record says the link, its URL, the link's clock when the
recorder attached and whether the bus's first chunks since it opened (its prologue,
:mod:`host.recording.prologue`: what the Arm sent as it opened) are all in it; they are
written first, at their own times, so ``hil-bench replay`` starts from the same robot.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Final

from host.arm.interface import WatchedArm
from host.arm.state import ArmState
from host.recording.topics import ARM_STATE
from host.recording.writer import (
    JSON_ENCODING,
    SOURCE_METADATA,
    Recording,
    Sink,
    Topic,
    source_metadata,
)

RAW_ENCODING: Final = "application/octet-stream"
STATE_TOPIC: Final = ARM_STATE
TX_TOPIC: Final = "/arm/bus/tx"
RX_TOPIC: Final = "/arm/bus/rx"
EARLIER_TOPIC: Final = "/arm/bus/tx/earlier"
OTHERS_TOPIC: Final = "/arm/bus/tx/others"


def _array(description: str, kind: str, n: int) -> dict[str, Any]:
    return {"type": "array", "items": {"type": kind}, "minItems": n, "maxItems": n,
            "description": description}


#: JSON Schema of the state messages (:meth:`host.arm.state.ArmState.as_dict`).
STATE_SCHEMA: Final = {
    "type": "object",
    "description": "the arm at one cycle",
    "properties": {
        "t": {"type": "number", "description": "the link's clock when the replies were in "
                                               "(s): simulation time in process"},
        "joints": _array("joint angles J1..J7 (rad; steppers from their joint encoders)",
                         "number", 7),
        "motor_joints": _array("stepper J1..J4 motor angles at the joint (rad, from the step "
                               "counts)", "number", 4),
        "goals": _array("stepper J1..J4 goals for the motor as the host last set them (rad)",
                        "number", 4),
        "torques": _array("stepper J1..J4 series-elastic torques (N·m)", "number", 4),
        "slip": _array("stepper J1..J4 SLIP latched (steps lost)", "boolean", 4),
        "stalled": _array("stepper J1..J4 STALLED latched (over-deflection)", "boolean", 4),
        "moving": _array("stepper J1..J4 stepping towards their goals", "boolean", 4),
        "watchdog": _array("stepper J1..J4 stopped and held by their command watchdog (no "
                           "goal or keep-alive within its timeout)", "boolean", 4),
        "deflection_counts": _array("stepper J1..J4 elastic deflection (joint encoder counts)",
                                    "integer", 4),
        "step_counts": _array("stepper J1..J4 motor positions (microsteps)", "integer", 4),
        "servo_load": _array("servo J5..J7 load (fraction of maximum torque, "
                             "counter-clockwise > 0)", "number", 3),
        "servo_temperature_c": _array("servo J5..J7 temperatures (°C)", "number", 3),
        "errors": {"type": "object", "description": "alarm bits by joint name (J1..J7), for "
                                                    "the joints reporting any",
                   "additionalProperties": {"type": "array", "items": {"type": "string"}}},
    },
    "required": ["t", "joints", "motor_joints", "goals", "torques", "slip", "stalled",
                 "moving", "watchdog", "deflection_counts", "step_counts", "servo_load", "servo_temperature_c",
                 "errors"],
    "additionalProperties": False,
}

TX: Final = Topic(TX_TOPIC, RAW_ENCODING)
RX: Final = Topic(RX_TOPIC, RAW_ENCODING)
STATE: Final = Topic(STATE_TOPIC, JSON_ENCODING, "ArmState", STATE_SCHEMA)
EARLIER: Final = Topic(EARLIER_TOPIC, RAW_ENCODING)
OTHERS: Final = Topic(OTHERS_TOPIC, RAW_ENCODING)
TOPICS: Final = (TX, RX, STATE, EARLIER, OTHERS)


class ArmRecorder(Recording):
    """Writes ``arm``'s bus bytes and every cycle's state to the MCAP file ``path`` (None:
    only to ``sinks``) while attached (a context manager; :meth:`close` detaches and
    finishes the file).  :class:`~host.errors.RecordingError` if ``path`` cannot be
    created."""

    def __init__(self, arm: WatchedArm, path: str | Path | None, *, sinks: tuple[Sink, ...] = ()
                 ) -> None:
        transport = arm.transport
        prologue = arm.bus.prologue
        earlier = transport.sent_before()
        watched = transport.watch_others()
        super().__init__(path, TOPICS, library="lowcost-hand-stack host.arm.recording",
                         sinks=sinks, metadata={SOURCE_METADATA: source_metadata(
                             "arm", transport.url, transport.now(), prologue.state(),
                             None if earlier is None else len(earlier), watched)})
        for t, data in earlier or ():
            self.log(EARLIER, t, data)
        for direction, t, data in prologue.messages:
            self.log(TX if direction == "tx" else RX, t, data)
        self.arm = arm
        self.states = 0
        self._previous = arm.bus.on_bytes
        arm.bus.on_bytes = self._on_bytes
        arm.state_taps.append(self._on_state)
        self._attached = True

    def _take_others(self) -> None:
        """Write what other programs sent on the link since the last look."""
        for t, data in self.arm.transport.take_others():
            self.log(OTHERS, t, data)

    def _on_bytes(self, direction: str, data: bytes, t: float) -> None:
        self._take_others()  # first: they went out before these bytes
        self.log(TX if direction == "tx" else RX, t, data)
        if self._previous is not None:
            self._previous(direction, data, t)

    def _on_state(self, state: ArmState) -> None:
        self.states += 1
        self.log_json(STATE, state.t, state.as_dict())

    def close(self) -> None:
        """Detach from the arm and finish the file (idempotent)."""
        if self._attached:
            self._attached = False
            self._take_others()
            if self._on_state in self.arm.state_taps:
                self.arm.state_taps.remove(self._on_state)
            self.arm.bus.on_bytes = self._previous
        self.close_sinks()

    def __enter__(self) -> ArmRecorder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def record(arm: WatchedArm, path: str | Path, *, seconds: float, rate_hz: float = 100.0) -> int:
    """Cycle ``arm`` at ``rate_hz`` for ``seconds`` (its transport's clock), writing raw
    bytes and states to the MCAP file ``path``; returns the number of cycles.
    :class:`~host.errors.RecordingError` stops it when the file cannot be written (what was
    written stays)."""
    transport = arm.transport
    count = cycle_count(seconds, rate_hz)
    with ArmRecorder(arm, path) as recorder:
        recorder.check()
        start = transport.now()
        period = 1.0 / rate_hz
        for k in range(count):
            transport.sleep(start + k * period - transport.now())
            arm.cycle()
            recorder.check()
    return count


def cycle_count(seconds: float, rate_hz: float) -> int:
    """Cycles at ``rate_hz`` that start within ``seconds`` (s) of the first: ⌈s·rate⌉, by the
    count, not by comparing clock readings (``start + k·period − start`` can come out below
    ``seconds`` when it should equal it, and add a cycle)."""
    return max(0, math.ceil(seconds * rate_hz - 1e-9))
