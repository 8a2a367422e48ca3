"""CRC-16/XMODEM, the checksum of every hand frame.

Poly 0x1021, init 0x0000, MSB first, no reflection, no final XOR; the check value of
``b"123456789"`` is 0x31C3.  Computed by crcmod's C extension.
"""

from __future__ import annotations

from collections.abc import Callable

import crcmod.predefined

_crc16_xmodem: Callable[[bytes | bytearray], int] = crcmod.predefined.mkCrcFun("xmodem")


def crc16_xmodem(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/XMODEM of ``data`` as an int in 0..0xFFFF."""
    return _crc16_xmodem(bytes(data) if isinstance(data, memoryview) else data)


#: The raw crcmod function (accepts bytes and bytearray), for hot loops.
crc16_xmodem_fast: Callable[[bytes | bytearray], int] = _crc16_xmodem
