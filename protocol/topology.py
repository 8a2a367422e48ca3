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

# --- hand addresses -------------------------------------------------------------------------

#: Replies go to the host.
ADDR_HOST: Final = 0x00
ADDR_F2: Final = 0x01
ADDR_F3: Final = 0x02
ADDR_FMCB: Final = 0x0A
ADDR_PALM: Final = 0x0A
#: Every node on the bus takes a frame to this address.
ADDR_BROADCAST: Final = 0xFF

#: Finger modules on a hand (the palm's pogo links ``finger0`` .. ``finger3``).
FINGERS: Final = 4


# --- the board table ------------------------------------------------------------------------
#
# A board is its name in three enumerations (the image header's byte, the catalogue's node
# kind, the hop behind a finger's pogo link: wire values, so declared as enums) and one row of
# BOARDS with its facts.  Every list of boards elsewhere is derived from BOARDS; a test
# (tests/protocol/test_board_table.py) checks the enums and the rows agree, and another that
# every board has its firmware, a factory and a rig (tests/hil_emulator/test_board_coverage.py).


class BoardType(IntEnum):
    """Which board an image is built for (image header byte 5; a node's identity names it too)."""

    PALM = 1
    FMCB = 2
    F2 = 3
    F3 = 4
    ARM_STEPPER = 5
    RX64 = 6


class NodeKind(StrEnum):
    """The hand boards that speak hand frames (the catalogue's node kinds, in its order)."""

    PALM = "palm"
    FMCB = "fmcb"
    F2 = "f2"
    F3 = "f3"


class Hop(IntEnum):
    """A node behind a finger's pogo link, as ``palm.route`` names it."""

    FMCB = 0
    F2 = 1
    F3 = 2


@dataclass(frozen=True)
class Board:
    """One board of the robot and what the rest of the code needs to know about it.

    ``app`` is the application name its images carry (the header's app name, the program a
    node boots); for a hand board it is also its node kind.  ``address`` is its hand-bus
    address (None: a Dynamixel arm node, addressed by its bus ID).  ``hop`` is its place
    behind a finger's pogo link (None: not in a finger).  ``upstream`` names its UART toward
    the host (its bootloader listens there).  ``self_test`` lists the requests its
    application must answer after a slot swap.  ``title`` names it in docs/PROTOCOL.md,
    ``role`` in a few words (command-line help: "image for the motor boards").
    """

    board_type: BoardType
    app: str
    title: str
    role: str
    upstream: str
    address: int | None = None
    hop: Hop | None = None
    self_test: tuple[str, ...] = ()

    @property
    def node_kind(self) -> NodeKind | None:
        """The catalogue's node kind of a hand board; None for an arm node."""
        return None if self.address is None else NodeKind(self.app)

    @property
    def name(self) -> str:
        """The board's name for people and command lines (``"fmcb"``, ``"arm_stepper"``)."""
        return self.app


#: Every board, hand boards first in :class:`NodeKind` order.
BOARDS: Final = (
    Board(BoardType.PALM, "palm", "Palm", "palm", "host", ADDR_PALM),
    Board(BoardType.FMCB, "fmcb", "Finger motor control board (fmcb)", "motor board", "pogo",
          ADDR_FMCB, Hop.FMCB, ("fmcb.status", "fmcb.imu")),
    Board(BoardType.F2, "f2", "Proximal phalange (f2)", "proximal phalange", "tendon",
          ADDR_F2, Hop.F2, ("f2.imu", "f2.tactile")),
    Board(BoardType.F3, "f3", "Distal phalange (f3)", "distal phalange", "tendon",
          ADDR_F3, Hop.F3, ("f3.imu", "f3.tactile")),
    Board(BoardType.ARM_STEPPER, "arm_stepper", "Series-elastic stepper node (J1–J4)",
          "stepper joint", "bus"),
    Board(BoardType.RX64, "rx64", "RX-64 servo (J5–J7)", "servo joint", "bus"),
)

#: The board of each board type.
BOARD_OF_TYPE: Final[dict[BoardType, Board]] = {b.board_type: b for b in BOARDS}
#: The boards that speak hand frames and run the hand bootloader, in :class:`NodeKind` order.
HAND_BOARDS: Final = tuple(b for b in BOARDS if b.address is not None)
#: The boards of a finger module, in hop order (the order a finger is flashed: the fmcb
#: first, whose running application reaches the phalanges).
FINGER_BOARDS: Final = tuple(sorted((b for b in BOARDS if b.hop is not None),
                                    key=lambda b: int(b.hop or 0)))
#: The Dynamixel arm nodes.
ARM_BOARDS: Final = tuple(b for b in BOARDS if b.address is None)


def board(name: str | BoardType) -> Board:
    """The board called ``name`` (its app name, ``"fmcb"``) or of board type ``name``.

    Raises KeyError for neither."""
    if isinstance(name, BoardType):
        return BOARD_OF_TYPE[name]
    for b in BOARDS:
        if b.app == name:
            return b
    raise KeyError(name)


#: Bus address of each hand node kind (a node's bootloader answers at the same address).
NODE_ADDRESS: Final[dict[NodeKind, int]] = {
    NodeKind(b.app): b.address for b in HAND_BOARDS if b.address is not None}
#: The node kind at each hop.
HOP_NODE: Final[dict[Hop, NodeKind]] = {
    b.hop: NodeKind(b.app) for b in FINGER_BOARDS if b.hop is not None}
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
