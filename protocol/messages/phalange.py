"""Messages of the phalange boards on the tendon bus: f2 (proximal) and f3 (distal).

Original ids and layouts; f2 has 6 taxels and a strain gauge, f3 12 taxels and four
thermistors.  New: the f2 strain-gauge reading (the original never delivered it).
"""

from __future__ import annotations

import construct as c

from protocol.catalogue import Message
from protocol.messages.fields import EMPTY, IMU6

F2_TAXELS = 6
F3_TAXELS = 12


def _tactile(n: int) -> c.Struct:
    return c.Struct(
        "taxels" / c.Array(n, c.Int16ul) * "[ADC counts] taxel readings (16-bit ADC)",
        "imu" / IMU6 * "[mg, counts] phalange accelerometer and magnetometer",
    )


def _phalange(node: str) -> list[Message]:
    n = F2_TAXELS if node == "f2" else F3_TAXELS
    return [
        Message(f"{node}.tactile", node, 0x10, EMPTY, _tactile(n), "Taxels and IMU sample."),
        Message(
            f"{node}.imu_power",
            node,
            0x11,
            c.Struct("on" / c.Int8ul * "[-] bit0: IMU power"),
            EMPTY,
            "Switch the IMU power.",
        ),
        Message(f"{node}.imu", node, 0x12, EMPTY, IMU6, "IMU sample."),
        Message(
            f"{node}.temperatures",
            node,
            0x22,
            EMPTY,
            c.Struct("temp" / c.Array(4, c.Int16ul) * "[ADC counts] thermistors"),
            "Thermistor readings (f3 has four; f2 reports zeros).",
        ),
    ]


MESSAGES: list[Message] = [
    *_phalange("f2"),
    *_phalange("f3"),
    Message(
        "f2.strain",
        "f2",
        0x13,
        EMPTY,
        c.Struct("strain" / c.Int32sl * "[counts] strain gauge (24-bit ADC, sign-extended)"),
        "Proximal strain gauge reading.",
        original=False,
    ),
]
