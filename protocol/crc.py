"""CRC-16/XMODEM, the checksum of every hand frame.

Poly 0x1021, init 0x0000, MSB first, no reflection, no final XOR; the check value of
``b"123456789"`` is 0x31C3.  Computed by crcmod's C extension.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import crcmod.predefined

_crc16_xmodem: Callable[[bytes | bytearray], int] = crcmod.predefined.mkCrcFun("xmodem")


def crc16_xmodem(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/XMODEM of ``data`` as an int in 0..0xFFFF."""
    return _crc16_xmodem(bytes(data) if isinstance(data, memoryview) else data)


# crcmod's function is a Python wrapper, ``crcfun(data, crc=init, table=..., fun=...)``,
# around its C routine ``fun(data, crc, table)``: the hot path calls the routine itself.
_DEFAULTS: Any = getattr(_crc16_xmodem, "__defaults__")  # noqa: B009 - typed as Any
_INIT: int = _DEFAULTS[0]
_TABLE: Any = _DEFAULTS[1]
_ROUTINE: Callable[[bytes | bytearray, int, Any], int] = _DEFAULTS[2]


def crc16_xmodem_fast(data: bytes | bytearray) -> int:
    """CRC-16/XMODEM of bytes or a bytearray (no memoryview), for hot loops: crcmod's C
    routine called without its Python wrapper (xmodem has no final XOR)."""
    return _ROUTINE(data, _INIT, _TABLE)
