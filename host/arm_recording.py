"""Record the arm's bus to MCAP: every raw byte chunk and every decoded cycle state.

Channels (log times in ns on the transport's clock: monotonic time, or the simulation's):

=================  ==========================  ===========================================
topic              message encoding            payload
=================  ==========================  ===========================================
``/arm/bus/tx``    ``application/octet-stream``  bytes the host sent (whole packets)
``/arm/bus/rx``    ``application/octet-stream``  bytes received, as they arrived
``/arm/state``     ``json`` (JSON Schema)       :meth:`~host.arm_state.ArmState.as_dict`
=================  ==========================  ===========================================

Replay the raw channels through :class:`~protocol.dynamixel.DynamixelStreamDecoder` to get
the packets back.  :func:`record` cycles the arm itself for a while; :class:`ArmRecorder`
writes whatever another program does with the arm (every cycle's state, every byte) while
it is attached.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import IO, Any, Final

from mcap.writer import Writer

from host.arm import Arm
from host.arm_state import ArmState

RAW_ENCODING: Final = "application/octet-stream"
STATE_TOPIC: Final = "/arm/state"
TX_TOPIC: Final = "/arm/bus/tx"
RX_TOPIC: Final = "/arm/bus/rx"

_NUMBERS = {"type": "array", "items": {"type": "number"}}
#: JSON Schema of the state messages.
STATE_SCHEMA: Final = {
    "type": "object",
    "properties": {
        "t": {"type": "number"}, "joints": _NUMBERS, "motor_joints": _NUMBERS,
        "torques": _NUMBERS, "slip": {"type": "array", "items": {"type": "boolean"}},
        "errors": {"type": "object"},
    },
}


class ArmRecorder:
    """Writes ``arm``'s bus bytes and every cycle's state to the MCAP file ``path`` while
    attached (a context manager; :meth:`close` detaches and finishes the file)."""

    def __init__(self, arm: Arm, path: str | Path) -> None:
        self.arm = arm
        self.path = Path(path)
        self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._stream)
        self._writer.start(profile="", library="lowcost-hand-stack host.arm_recording")
        schema = self._writer.register_schema(name="ArmState", encoding="jsonschema",
                                              data=json.dumps(STATE_SCHEMA).encode())
        self._state_ch = self._writer.register_channel(STATE_TOPIC, "json", schema)
        self._raw_ch = {"tx": self._writer.register_channel(TX_TOPIC, RAW_ENCODING, 0),
                        "rx": self._writer.register_channel(RX_TOPIC, RAW_ENCODING, 0)}
        self.states = 0
        self._previous = arm.bus.on_bytes
        arm.bus.on_bytes = self._on_bytes
        arm.state_taps.append(self._on_state)
        self._open = True

    def _on_bytes(self, direction: str, data: bytes, t: float) -> None:
        ns = max(0, int(t * 1e9))
        self._writer.add_message(self._raw_ch[direction], log_time=ns, data=data,
                                 publish_time=ns)
        if self._previous is not None:
            self._previous(direction, data, t)

    def _on_state(self, state: ArmState) -> None:
        ns = max(0, int(state.t * 1e9))
        self._writer.add_message(self._state_ch, log_time=ns, publish_time=ns,
                                 sequence=self.states,
                                 data=json.dumps(state.as_dict()).encode())
        self.states += 1

    def close(self) -> None:
        """Detach from the arm and finish the file (idempotent)."""
        if not self._open:
            return
        self._open = False
        if self._on_state in self.arm.state_taps:
            self.arm.state_taps.remove(self._on_state)
        self.arm.bus.on_bytes = self._previous
        self._writer.finish()
        self._stream.close()

    def __enter__(self) -> ArmRecorder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def record(arm: Arm, path: str | Path, *, seconds: float, rate_hz: float = 100.0) -> int:
    """Cycle ``arm`` at ``rate_hz`` for ``seconds`` (its transport's clock), writing raw
    bytes and states to the MCAP file ``path``; returns the number of cycles."""
    transport = arm.transport
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="lowcost-hand-stack host.arm_recording")
        schema = writer.register_schema(name="ArmState", encoding="jsonschema",
                                        data=json.dumps(STATE_SCHEMA).encode())
        state_ch = writer.register_channel(STATE_TOPIC, "json", schema)
        raw_ch = {"tx": writer.register_channel(TX_TOPIC, RAW_ENCODING, 0),
                  "rx": writer.register_channel(RX_TOPIC, RAW_ENCODING, 0)}

        def on_bytes(direction: str, data: bytes, t: float) -> None:
            ns = int(t * 1e9)
            writer.add_message(raw_ch[direction], log_time=ns, data=data, publish_time=ns)

        previous = arm.bus.on_bytes
        arm.bus.on_bytes = on_bytes
        count = cycle_count(seconds, rate_hz)
        try:
            start = transport.now()
            period = 1.0 / rate_hz
            for k in range(count):
                transport.sleep(start + k * period - transport.now())
                state = arm.cycle()
                ns = int(state.t * 1e9)
                writer.add_message(state_ch, log_time=ns, publish_time=ns,
                                   data=json.dumps(state.as_dict()).encode())
        finally:
            arm.bus.on_bytes = previous
            writer.finish()
    return count


def cycle_count(seconds: float, rate_hz: float) -> int:
    """Cycles at ``rate_hz`` that start within ``seconds`` (s) of the first: ⌈s·rate⌉, by the
    count, not by comparing clock readings (``start + k·period − start`` can come out below
    ``seconds`` when it should equal it, and add a cycle)."""
    return max(0, math.ceil(seconds * rate_hz - 1e-9))
