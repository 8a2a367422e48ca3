"""Messages of the palm: its own sensors, and the hub functions the motherboard had.

Original: tactile 0x10 and the 100-byte state 0x21.  New (0x62 …): routing of a hand
frame to any fmcb or phalange behind the palm, finger power with stagger, the aggregated
hand status, finger polling, the current governor, and unsolicited finger events
(breakaway, return, breaker trip).
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

import construct as c

from protocol.catalogue import Message
from protocol.enum_field import EnumField
from protocol.messages.fields import EMPTY
from protocol.topology import FINGERS, Hop

PALM_TAXELS = 32
#: Largest routed frame (bytes): a tunnel request with 512 data bytes plus framing.
ROUTE_MAX_FRAME = 540
#: ``palm.finger_power``'s finger index meaning every finger (switched ``stagger_ms`` apart).
ALL_FINGERS: Final = 0xFF

class FingerPower(IntEnum):
    """Power state of a finger's supply: off, low (9 V, current-limited) or full (24 V)."""

    OFF = 0
    LOW = 1
    FULL = 2


class RouteStatus(IntEnum):
    """Outcome of a ``palm.route``: the reply frame came back, or why not."""

    OK = 0
    NO_REPLY = 1
    UNPOWERED = 2
    BAD_DESTINATION = 3
    LINK_DOWN = 4
    BUSY = 5


class FingerEvent(IntEnum):
    """What an unsolicited ``palm.finger_event`` reports about a finger."""

    LOST = 0
    RETURNED = 1
    BREAKER_TRIP = 2
    POWERED = 3
    UNPOWERED = 4


POWER = EnumField(c.Int8ul, FingerPower)

PALM_STATE = c.Struct(
    "time" / c.Int32ul * "[µs] palm timestamp",
    "accel" / c.Array(3, c.Int16sl) * "[mg] palm accelerometer",
    "gyro" / c.Array(3, c.Int16sl) * "[counts] palm gyro",
    "mag" / c.Array(3, c.Int16sl) * "[counts] palm magnetometer",
    "temps" / c.Array(7, c.Int16ul) * "[0.1 °C] palm temperatures",
    "tactile" / c.Array(PALM_TAXELS, c.Int16ul) * "[ADC counts] palm taxels",
)

_FINGER_SUMMARY = c.Struct(
    "present" / c.Int8ul * "[-] 1 if the fmcb answered its last poll",
    "power" / POWER * "[-] power state",
    "current" / c.Int16ul * "[mA] finger supply current",
    "last_seen_ms" / c.Int16ul * "[ms] since the finger last answered (saturates at 65535)",
    "hall_pos" / c.Array(3, c.Int32sl) * "[hall counts] motor positions from the last poll",
    "effort" / c.Array(3, c.Int16sl) * "[1/255 of full PWM] motor efforts from the last poll",
)

HAND_STATUS = c.Struct(
    "time" / c.Int32ul * "[µs] palm timestamp",
    "effort_cap" / c.Int8ul * "[1/255 of full PWM] shared effort cap of the current governor",
    "poll_hz" / c.Int8ul * "[Hz] finger polling rate (0 = off)",
    "bus_voltage" / c.Int16ul * "[mV] hand supply voltage",
    "fingers" / c.Array(FINGERS, _FINGER_SUMMARY) * "[-] one summary per finger",
)

MESSAGES: list[Message] = [
    Message(
        "palm.tactile",
        "palm",
        0x10,
        EMPTY,
        c.Struct("taxels" / c.Array(PALM_TAXELS, c.Int16ul) * "[ADC counts] palm taxels"),
        "Palm taxels.",
    ),
    Message("palm.state", "palm", 0x21, EMPTY, PALM_STATE, "The palm's 100-byte state."),
    Message(
        "palm.route",
        "palm",
        0x62,
        c.Struct(
            "finger" / c.Int8ul * "[-] finger index 0..3",
            "hop" / EnumField(c.Int8ul, Hop) * "[-] the node behind the finger's pogo link",
            "timeout_ms" / c.Int16ul * "[ms] how long to wait for the reply (0: no reply)",
            "frame" / c.GreedyBytes * "[-] a complete hand frame for that node",
        ),
        c.Struct(
            "finger" / c.Int8ul * "[-] finger index 0..3",
            "hop" / EnumField(c.Int8ul, Hop) * "[-] the node behind the finger's pogo link",
            "status" / EnumField(c.Int8ul, RouteStatus) * "[-] outcome of the route",
            "frame" / c.GreedyBytes * "[-] the complete reply frame heard (empty unless ok)",
        ),
        "Deliver a hand frame to a node behind the palm and return its reply, by finger.",
        original=False,
    ),
    Message(
        "palm.finger_power",
        "palm",
        0x63,
        c.Struct(
            "finger" / c.Int8ul * "[-] finger index 0..3, or 0xFF for all",
            "state" / POWER * "[-] power state to switch to",
            "stagger_ms" / c.Int16ul * "[ms] delay between fingers when switching all",
        ),
        c.Struct("states" / c.Array(FINGERS, POWER) * "[-] power state of each finger"),
        "Switch finger power; the reply gives every finger's state.",
        original=False,
    ),
    Message("palm.hand_status", "palm", 0x64, EMPTY, HAND_STATUS, "Aggregated hand status.",
            original=False),
    Message(
        "palm.poll",
        "palm",
        0x65,
        c.Struct("rate_hz" / c.Int8ul * "[Hz] finger polling rate (0 = off, ≤ 200)"),
        EMPTY,
        "Set how often the palm polls every finger's status.",
        original=False,
    ),
    Message(
        "palm.finger_event",
        "palm",
        0x66,
        None,
        c.Struct(
            "finger" / c.Int8ul * "[-] finger index 0..3",
            "event" / EnumField(c.Int8ul, FingerEvent) * "[-] what happened",
            "time" / c.Int32ul * "[µs] palm timestamp of the event",
        ),
        "Unsolicited: a finger vanished (breakaway), came back, or tripped a breaker.",
        original=False,
    ),
    Message(
        "palm.current_limit",
        "palm",
        0x67,
        c.Struct("limit_ma" / c.Int16ul * "[mA] hand current the governor holds below"),
        EMPTY,
        "Set the current governor's limit.",
        original=False,
    ),
]
