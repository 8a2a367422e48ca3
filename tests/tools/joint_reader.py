"""Another program on the arm's bus: READs the seven joints' ``present_position`` every
20 ms with the stock dynamixel-sdk, until killed (a monitor, a dashboard: plain READs, no
writes).  ``python -m tests.tools.joint_reader PORT``.

A pty gives each byte to one of its clients (docs/EMULATOR.md), so a reader that took its
replies would take the host's too and stop it.  This one sends its READs with the SDK's
``readTx`` and leaves the replies on the port: the host's bus skips a reply it did not ask
for; on the bus the nodes see exactly a second program's READs.  It reads what a host's
cycle reads (a stepper's cycle block, an RX-64's position, speed and load), so a reply the
host takes for its own is one of the same length and range.  It starts polling when a
line comes on its standard input (so a test can start it just before it kills the host: a
host sharing a pty with it loses replies to the line's collisions and, after its retries,
gives up).  It asks for real-time scheduling where allowed (as ``armctl`` does), so that on
a busy machine its polls keep their 20 ms: a monitor that keeps the nodes' watchdog fed is
the case this stands for."""

from __future__ import annotations

import sys
import time

import dynamixel_sdk as sdk

from host.scheduling import request_priority
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE

#: The reader's period (s).
PERIOD_S = 0.02


def main(port_name: str) -> None:
    """Poll the seven joints of the arm on ``port_name`` every :data:`PERIOD_S` for ever."""
    port = sdk.PortHandler(port_name)
    assert port.openPort() and port.setBaudRate(1_000_000)
    packets = sdk.PacketHandler(1.0)
    stepper = STEPPER_TABLE["cycle_present_position"]
    stepper_len = STEPPER_TABLE["cycle_status_flags"].end - stepper.address
    servo = RX64_TABLE["present_position"]
    servo_len = RX64_TABLE["present_load"].end - servo.address
    sys.stdin.readline()
    request_priority("realtime")
    due = time.monotonic()
    while True:
        for dxl_id in range(1, 8):
            port.is_using = False  # no rxPacket follows to free it
            if dxl_id <= 4:
                packets.readTx(port, dxl_id, stepper.address, stepper_len)
            else:
                packets.readTx(port, dxl_id, servo.address, servo_len)
        due += PERIOD_S
        time.sleep(max(0.0, due - time.monotonic()))


if __name__ == "__main__":
    main(sys.argv[1])
