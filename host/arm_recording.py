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
the packets back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Final

from mcap.writer import Writer

from host.arm import Arm

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
        cycles = 0
        try:
            start = transport.now()
            period = 1.0 / rate_hz
            while True:
                due = start + cycles * period
                if due - start >= seconds:
                    break
                transport.sleep(due - transport.now())
                state = arm.cycle()
                ns = int(state.t * 1e9)
                writer.add_message(state_ch, log_time=ns, publish_time=ns,
                                   data=json.dumps(state.as_dict()).encode())
                cycles += 1
        finally:
            arm.bus.on_bytes = previous
            writer.finish()
    return cycles
