"""Who is on which bus, at what address and rate: the robot's topology, declared once.

Hand (hand frames, :mod:`protocol.framing`)::

    host ══ USB serial 2 Mbaud (or CAN 1 Mbit/s) ══ palm (10)
    palm ══ pogo RS-485 2 Mbaud, one per finger ══ fmcb (10)            hop 0
    fmcb ══ tendon bus 2 Mbaud data, Manchester ══ f2 (1), f3 (2)      hops 1, 2

Replies travel to address 0 (the host); 0xFF is the broadcast address.  The palm and every
fmcb share address 10: they are never on the same bus.  A loose finger on the bench cable
is its fmcb's pogo bus at the host.

Arm (Dynamixel 1.0, :mod:`protocol.dynamixel`): one RS-485 bus at 1 Mbaud; IDs 1–4 are the
series-elastic stepper nodes (joints J1–J4), IDs 5–7 RX-64 servos (J5–J7).

:func:`wire_time_us` is the one formula for the time bytes occupy a UART line.  Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Final

from protocol.control_tables import RX64_TABLE, STEPPER_TABLE


class NodeKind(StrEnum):
    """The hand boards that speak hand frames (the catalogue's node kinds, in its order)."""

    PALM = "palm"
    FMCB = "fmcb"
    F2 = "f2"
    F3 = "f3"


# --- hand addresses -------------------------------------------------------------------------

#: Replies go to the host.
ADDR_HOST: Final = 0x00
ADDR_F2: Final = 0x01
ADDR_F3: Final = 0x02
ADDR_FMCB: Final = 0x0A
ADDR_PALM: Final = 0x0A
#: Every node on the bus takes a frame to this address.
ADDR_BROADCAST: Final = 0xFF

#: Bus address of each hand node kind (a node's bootloader answers at the same address).
NODE_ADDRESS: Final[dict[NodeKind, int]] = {
    NodeKind.PALM: ADDR_PALM,
    NodeKind.FMCB: ADDR_FMCB,
    NodeKind.F2: ADDR_F2,
    NodeKind.F3: ADDR_F3,
}

#: Finger modules on a hand (the palm's pogo links ``finger0`` .. ``finger3``).
FINGERS: Final = 4


class Hop(IntEnum):
    """A node behind a finger's pogo link, as ``palm.route`` names it."""

    FMCB = 0
    F2 = 1
    F3 = 2


#: The node kind at each hop.
HOP_NODE: Final[dict[Hop, NodeKind]] = {Hop.FMCB: NodeKind.FMCB, Hop.F2: NodeKind.F2,
                                        Hop.F3: NodeKind.F3}
#: The bus address of the node at each hop.
HOP_ADDRESS: Final[dict[Hop, int]] = {hop: NODE_ADDRESS[kind] for hop, kind in HOP_NODE.items()}


# --- arm ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ArmJoint:
    """One arm joint's node: joint name, Dynamixel bus ID and the model number it reports."""

    name: str
    dxl_id: int
    model_number: int

    @property
    def is_stepper(self) -> bool:
        """True for a series-elastic stepper node, False for an RX-64 servo."""
        return self.model_number == STEPPER_TABLE.model_number


#: Bus IDs of the series-elastic stepper nodes (J1–J4) and of the RX-64 servos (J5–J7).
STEPPER_IDS: Final = (1, 2, 3, 4)
SERVO_IDS: Final = (5, 6, 7)
#: The arm's joints, proximal first.
ARM_JOINTS: Final = tuple(
    ArmJoint(f"J{dxl_id}", dxl_id,
             STEPPER_TABLE.model_number if dxl_id in STEPPER_IDS else RX64_TABLE.model_number)
    for dxl_id in (*STEPPER_IDS, *SERVO_IDS)
)
#: Model number by bus ID.
ARM_MODEL_BY_ID: Final[dict[int, int]] = {j.dxl_id: j.model_number for j in ARM_JOINTS}


# --- link rates -----------------------------------------------------------------------------

#: The palm's host link (USB serial), bit/s; a loose finger's bench cable runs at the same.
HOST_LINK_BAUD: Final = 2_000_000
#: Each finger's pogo RS-485 link (palm ↔ fmcb), bit/s.
POGO_BAUD: Final = 2_000_000
#: The tendon bus's *data* bit rate (fmcb ↔ f2, f3), bit/s; it is Manchester coded, so
#: twice as many chips per second are on the wire.
TENDON_BAUD: Final = 2_000_000
#: True: the tendon bus carries Manchester chips (:mod:`protocol.manchester`).
TENDON_MANCHESTER: Final = True
#: The arm's Dynamixel RS-485 bus, bit/s.
ARM_BUS_BAUD: Final = 1_000_000
#: The palm's CAN bus (the alternative host link), bit/s.
CAN_BITRATE: Final = 1_000_000


# --- wire time ------------------------------------------------------------------------------

#: Bits on the wire per UART character: start, 8 data, stop (8N1).
BITS_PER_CHAR: Final = 10


def wire_time_us(n_bytes: int, baud: int, *, manchester: bool = False,
                 bits_per_char: int = BITS_PER_CHAR) -> int:
    """Time ``n_bytes`` UART characters occupy a line at ``baud`` data bits/s (µs, rounded up).

    Each character is ``bits_per_char`` bits (10 for 8N1); a Manchester line sends two chips
    per bit at twice the bit rate, doubling the time.  Integer arithmetic throughout, so every
    caller's simulation clock gets the same integer.
    """
    bits = n_bytes * bits_per_char * 2 if manchester else n_bytes * bits_per_char
    return -(-bits * 1_000_000 // baud)
