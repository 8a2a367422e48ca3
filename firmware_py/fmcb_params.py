"""The fmcb's parameter table and its flash page (page 1020, kept across image updates).

Each parameter has a name, a kind (``f32`` or ``u32``, 4 bytes little-endian on the wire
and in flash) and a default.  The host addresses parameters by index (messages 0x16–0x1c:
count, name, get, set, commit, reload, defaults).

Flash page layout (256 B, little-endian)::

    offset  size   field
    0       4      sentinel 0xDEADBEEF (as the original hand)
    4       2      parameter count N
    6       2      layout version (1)
    8       4      schema: CRC-32 of the parameter names and kinds, in table order
    12      4·N    value bits, in table order
    12+4N   4      CRC-32 (zlib) of bytes 0 .. 11+4N
    …              0xFF

A page whose sentinel, count, version, schema or CRC does not match is ignored and the
defaults are used: a blank (erased) page, a torn write, or a page written by a firmware
with another table never yields wrong gains.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from protocol.robot import FINGER_JOINT_LIMITS

PARAM_SENTINEL: Final = 0xDEADBEEF
PARAM_LAYOUT_VERSION: Final = 1
_HEADER = struct.Struct("<IHHI")
_CRC = struct.Struct("<I")

Value = float | int


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ``kind`` is ``"f32"`` or ``"u32"``; ``doc`` starts with the unit."""

    name: str
    kind: str
    default: Value
    doc: str

    def __post_init__(self) -> None:
        if self.kind not in ("f32", "u32"):
            raise ValueError(f"{self.name}: kind {self.kind!r} is not f32 or u32")
        if not 0 < len(self.name) < 256 or not self.name.isascii():
            raise ValueError(f"{self.name!r}: a name is 1..255 ASCII characters")

    def pack(self, value: Value) -> bytes:
        """The 4 value bytes of ``value``."""
        if self.kind == "f32":
            return struct.pack("<f", float(value))
        return struct.pack("<I", int(value) & 0xFFFFFFFF)

    def unpack(self, bits: bytes) -> Value:
        """The value held in 4 bytes."""
        if self.kind == "f32":
            return float(struct.unpack("<f", bits)[0])
        return int(struct.unpack("<I", bits)[0])


def _joint_limits() -> list[ParamSpec]:
    specs = []
    for j, (lower, upper) in enumerate(FINGER_JOINT_LIMITS):
        specs.append(ParamSpec(f"joint_lower_{j}", "f32", lower, f"[rad] lower limit of joint {j}"))
        specs.append(ParamSpec(f"joint_upper_{j}", "f32", upper, f"[rad] upper limit of joint {j}"))
    return specs


#: The parameter table of this firmware, in index order.
FMCB_PARAMS: Final[tuple[ParamSpec, ...]] = (
    ParamSpec("kp", "f32", 1.0, "[PWM/255 per hall count] proportional gain"),
    ParamSpec("kd", "f32", 0.002, "[PWM/255 per hall count/s] derivative gain"),
    ParamSpec("deadband", "u32", 2, "[hall counts] no effort while |error| is within it "
              "(2: at most 0.44° of J0, 0.19° of J1, 0.09° of J2 through the coupling)"),
    ParamSpec("max_effort", "u32", 255, "[1/255 of full PWM] board-wide effort clamp"),
    *_joint_limits(),
    ParamSpec("breaker_ma", "u32", 200, "[mA] phalange-bus breaker threshold"),
    ParamSpec("breaker_ms", "u32", 10, "[ms] overcurrent longer than this trips the breaker"),
    ParamSpec("tendon_timeout_us", "u32", 2000, "[µs] phalange reply timeout (autopoll)"),
)


def schema_crc(specs: Sequence[ParamSpec]) -> int:
    """CRC-32 of the names and kinds: identifies a table layout."""
    text = ";".join(f"{s.name}:{s.kind}" for s in specs)
    return zlib.crc32(text.encode("ascii"))


class ParamTable:
    """Parameter values in RAM, with their flash page codec.

    ``table["kp"]`` reads a value by name; index-based access serves the messages.
    """

    def __init__(self, specs: Sequence[ParamSpec] = FMCB_PARAMS, page_size: int = 256) -> None:
        if _HEADER.size + 4 * len(specs) + _CRC.size > page_size:
            raise ValueError(f"{len(specs)} parameters do not fit a {page_size}-byte page")
        self.specs = tuple(specs)
        self.page_size = page_size
        self._index = {s.name: i for i, s in enumerate(self.specs)}
        self.values: list[Value] = [s.default for s in self.specs]

    def __len__(self) -> int:
        return len(self.specs)

    def __getitem__(self, name: str) -> Value:
        return self.values[self._index[name]]

    def index(self, name: str) -> int:
        """Index of the parameter called ``name`` (KeyError if none)."""
        return self._index[name]

    def name(self, index: int) -> str:
        """Name of parameter ``index``; the empty string outside the table."""
        return self.specs[index].name if 0 <= index < len(self.specs) else ""

    def get_bits(self, index: int) -> bytes:
        """The 4 value bytes of parameter ``index``; zeros outside the table."""
        if not 0 <= index < len(self.specs):
            return bytes(4)
        return self.specs[index].pack(self.values[index])

    def set_bits(self, index: int, bits: bytes) -> bool:
        """Set parameter ``index`` from 4 value bytes (RAM only).

        Returns False (and changes nothing) for an index outside the table, a length other
        than 4, or an f32 value that is not finite.
        """
        if not 0 <= index < len(self.specs) or len(bits) != 4:
            return False
        value = self.specs[index].unpack(bits)
        if isinstance(value, float) and not math.isfinite(value):
            return False
        self.values[index] = value
        return True

    def set(self, name: str, value: Value) -> None:
        """Set a parameter by name (RAM only), through its 4-byte representation."""
        i = self._index[name]
        if not self.set_bits(i, self.specs[i].pack(value)):
            raise ValueError(f"{name}: {value!r} is not a valid value")

    def restore_defaults(self) -> None:
        """Every parameter back to its default (RAM only)."""
        self.values = [s.default for s in self.specs]

    def to_page(self) -> bytes:
        """The table as one flash page (see the module docstring)."""
        body = _HEADER.pack(PARAM_SENTINEL, len(self.specs), PARAM_LAYOUT_VERSION,
                            schema_crc(self.specs))
        body += b"".join(s.pack(v) for s, v in zip(self.specs, self.values, strict=True))
        body += _CRC.pack(zlib.crc32(body))
        return body + b"\xff" * (self.page_size - len(body))

    def decode_page(self, page: bytes) -> list[Value] | None:
        """The values a flash page holds for this table, or None if it holds none."""
        if len(page) < _HEADER.size:
            return None
        sentinel, count, version, schema = _HEADER.unpack_from(page)
        if (sentinel != PARAM_SENTINEL or count != len(self.specs)
                or version != PARAM_LAYOUT_VERSION or schema != schema_crc(self.specs)):
            return None
        end = _HEADER.size + 4 * count
        if len(page) < end + _CRC.size:
            return None
        (crc,) = _CRC.unpack_from(page, end)
        if zlib.crc32(page[:end]) != crc:
            return None
        values = []
        for i, spec in enumerate(self.specs):
            off = _HEADER.size + 4 * i
            values.append(spec.unpack(page[off : off + 4]))
        return values

    def load_page(self, page: bytes) -> bool:
        """Take the values from ``page``; on a blank or corrupt page restore the defaults.

        Returns True if the page was valid.
        """
        values = self.decode_page(page)
        if values is None:
            self.restore_defaults()
            return False
        self.values = values
        return True
