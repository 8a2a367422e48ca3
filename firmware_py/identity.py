"""A node's identity, kept in the last page of the bootloader region (page 31).

Factory programming (JTAG) writes it; the protocol can never overwrite it because the
bootloader refuses pages 0–31 and locks them.  Words, little-endian::

    0x401FF0  board type (protocol.image.BoardType)
    0x401FF4  unique id
    0x401FF8  hardware version (0xBEEF0041 fingers, 0xBEEF4C41 / 0xBEEF5241 palms)
    0x401FFC  bus address (:data:`protocol.topology.NODE_ADDRESS`)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from firmware_py.hal import Flash
from protocol.image import FLASH, BoardType
from protocol.topology import ADDR_FMCB
from protocol.topology import board as board_row

IDENTITY_ADDRESS = FLASH.identity_address
HW_VERSION_FINGER = 0xBEEF0041
HW_VERSION_PALM_LEFT = 0xBEEF4C41
HW_VERSION_PALM_RIGHT = 0xBEEF5241

_LAYOUT = struct.Struct("<IIII")


@dataclass(frozen=True)
class Identity:
    """Who a node is: board type, unique id, hardware version word and bus address."""

    board: int
    uid: int
    hw_version: int
    address: int

    @property
    def board_type(self) -> BoardType | None:
        """The board type, or None if the stored value is not one."""
        try:
            return BoardType(self.board)
        except ValueError:
            return None

    def to_bytes(self) -> bytes:
        """The 16 bytes stored at :data:`IDENTITY_ADDRESS`."""
        return _LAYOUT.pack(self.board, self.uid, self.hw_version, self.address)


def read_identity(flash: Flash) -> Identity:
    """The identity stored in ``flash``."""
    board, uid, hw, address = _LAYOUT.unpack(flash.read(IDENTITY_ADDRESS, _LAYOUT.size))
    return Identity(board, uid, hw, address & 0xFF)


def default_identity(board: BoardType, uid: int = 0) -> Identity:
    """The identity a factory gives a board of this type (address and hw version)."""
    own = board_row(board).address
    address = ADDR_FMCB if own is None else own  # an arm node keeps the factory default
    hw = HW_VERSION_PALM_RIGHT if board == BoardType.PALM else HW_VERSION_FINGER
    return Identity(int(board), uid, hw, address)
