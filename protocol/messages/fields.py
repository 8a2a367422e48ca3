"""Field building blocks shared by the message declarations (units in the docs)."""

from __future__ import annotations

import construct as c

#: Empty payload.
EMPTY = c.Struct()

#: IMU sample as the LSM303 reports it: accelerometer x, y, z then magnetometer x, y, z.
IMU6 = c.Struct(
    "accel" / c.Array(3, c.Int16sl) * "[mg] accelerometer x, y, z (±2 g range, ~1 mg/count)",
    "mag" / c.Array(3, c.Int16sl) * "[counts] magnetometer x, y, z",
)

#: Firmware version triple.
VERSION = c.Struct(
    "major" / c.Int8ul * "[-] major version",
    "minor" / c.Int8ul * "[-] minor version",
    "patch" / c.Int16ul * "[-] patch number",
)


def counted_bytes(max_len: int, doc: str) -> c.Struct:
    """A u16 LE byte count followed by that many bytes, at most ``max_len``."""
    return c.Struct(
        "length" / c.Rebuild(c.Int16ul, c.len_(c.this.data)) * "[bytes] length of data",
        c.Check(c.this.length <= max_len),
        "data" / c.Bytes(c.this.length) * doc,
    )
