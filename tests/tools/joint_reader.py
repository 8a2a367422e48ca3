"""Another program on the arm's bus, on its own USB–RS-485 adapter (``hil-emulator
--arm-adapters 2``: the port ``arm2``): READs the seven joints every 20 ms with the stock
dynamixel-sdk, replies and all, until SIGTERM (a monitor, a dashboard: plain READs, no
writes).  ``python -m tests.tools.joint_reader PORT``.

It reads what a host's cycle reads (a stepper's cycle block, an RX-64's position, speed and
load) at normal priority.  On SIGTERM it prints one JSON line: ``polls`` (rounds of seven
READs), ``reads`` and ``answered`` (READs sent and answered whole), ``late_polls`` (rounds
that started more than two periods after the one before) and ``max_gap_ms`` (the longest time between two
rounds' starts), so a test can say what the bus gave it."""

from __future__ import annotations

import json
import signal
import sys
import time
from types import FrameType

import dynamixel_sdk as sdk

from protocol.control_tables import RX64_TABLE, STEPPER_TABLE

#: The reader's period (s).
PERIOD_S = 0.02


def main(port_name: str) -> None:
    """Poll the seven joints of the arm on ``port_name`` every :data:`PERIOD_S` until
    SIGTERM: a line ``reading`` once the port is open, then the counts (see the module)."""
    port = sdk.PortHandler(port_name)
    assert port.openPort() and port.setBaudRate(1_000_000)
    packets = sdk.PacketHandler(1.0)
    stepper = STEPPER_TABLE["cycle_present_position"]
    stepper_len = STEPPER_TABLE["cycle_status_flags"].end - stepper.address
    servo = RX64_TABLE["present_position"]
    servo_len = RX64_TABLE["present_load"].end - servo.address
    counts = {"polls": 0, "reads": 0, "answered": 0, "late_polls": 0, "max_gap_ms": 0.0}
    stop = []

    def on_term(signum: int, frame: FrameType | None) -> None:
        stop.append(signum)

    signal.signal(signal.SIGTERM, on_term)
    due = last = time.monotonic()
    print("reading", flush=True)  # the port is open
    while not stop:
        start = time.monotonic()
        if counts["polls"]:
            counts["max_gap_ms"] = max(counts["max_gap_ms"], (start - last) * 1e3)
            counts["late_polls"] += start - last > 2 * PERIOD_S
        last = start
        for dxl_id in range(1, 8):
            address, length = ((stepper.address, stepper_len) if dxl_id <= 4
                               else (servo.address, servo_len))
            data, result, _ = packets.readTxRx(port, dxl_id, address, length)
            counts["reads"] += 1
            counts["answered"] += result == sdk.COMM_SUCCESS and len(data) == length
        counts["polls"] += 1
        due += PERIOD_S
        if due < time.monotonic() - PERIOD_S:
            due = time.monotonic()  # fell behind: keep the period from now, not catch up
        time.sleep(max(0.0, due - time.monotonic()))
    print(json.dumps(counts), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
