"""An fmcb's parameter table by name: read, set, commit (``fmcb.param_*``).

The board numbers its parameters and names each (``fmcb.param_count``,
``fmcb.param_name``); values travel as 4 bytes, a little-endian f32 or u32 per parameter.
The names are read once and cached; which are floats is known here (gains and joint limits),
the others are unsigned integers.  :meth:`FingerParams.cached` keeps a value once read (the
host's settle test reads the ``deadband`` once per finger); setting, reloading or restoring
defaults through the same object keeps the kept values true.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, Final

from host.errors import UsageError

#: Parameters whose 4 bytes are an f32 (the others are u32).
FLOAT_PARAMS: Final = frozenset(
    {"kp", "kd", *(f"joint_{side}_{j}" for side in ("lower", "upper") for j in range(3))})
#: How long the fmcb may take to write its parameter page (ms), beyond a normal reply.
COMMIT_MS: Final = 60

Request = Callable[..., dict[str, Any]]
"""``request(name, fields, **options)`` to the fmcb, as :meth:`host.hand.facade.Node.request`."""

Value = float | int


def pack(name: str, value: Value) -> bytes:
    """The 4 value bytes of parameter ``name``."""
    if name in FLOAT_PARAMS:
        return struct.pack("<f", float(value))
    if int(value) != value or not 0 <= int(value) <= 0xFFFFFFFF:
        raise UsageError(f"parameter {name} takes an unsigned 32-bit integer, got {value}")
    return struct.pack("<I", int(value))


def unpack(name: str, bits: bytes) -> Value:
    """The value parameter ``name`` holds in ``bits``."""
    if name in FLOAT_PARAMS:
        return float(struct.unpack("<f", bits)[0])
    return int(struct.unpack("<I", bits)[0])


class FingerParams:
    """The parameters of one fmcb, reached through ``request``."""

    def __init__(self, request: Request) -> None:
        self._request = request
        self._names: list[str] | None = None
        self._values: dict[str, Value] = {}

    def names(self) -> list[str]:
        """Every parameter name in index order (read once from the board)."""
        if self._names is None:
            count = self._request("fmcb.param_count", {})["count"]
            self._names = [self._request("fmcb.param_name", {"index": i})["name"]
                           for i in range(count)]
        return list(self._names)

    def index(self, name: str) -> int:
        """The board's index of parameter ``name``."""
        names = self.names()
        if name not in names:
            raise UsageError(f"the fmcb has no parameter {name!r}; it has {', '.join(names)}")
        return names.index(name)

    def get(self, name: str) -> Value:
        """The value of parameter ``name`` (RAM copy)."""
        bits = self._request("fmcb.param_get", {"index": self.index(name)})["value"]
        value = unpack(name, bytes(bits))
        self._values[name] = value
        return value

    def cached(self, name: str) -> Value:
        """The value of parameter ``name``, read from the board the first time only."""
        if name in self._values:
            return self._values[name]
        return self.get(name)

    def set(self, name: str, value: Value) -> None:
        """Set parameter ``name`` in RAM (:meth:`commit` keeps it over a reset)."""
        bits = pack(name, value)
        self._values.pop(name, None)
        self._request("fmcb.param_set", {"index": self.index(name), "value": bits})
        self._values[name] = unpack(name, bits)

    def all(self) -> dict[str, Value]:
        """Every parameter and its value."""
        return {name: self.get(name) for name in self.names()}

    def commit(self) -> None:
        """Write the parameters to the board's flash."""
        self._request("fmcb.param_commit", {}, extra_ms=COMMIT_MS)

    def reload(self) -> None:
        """Throw away RAM changes: reload the parameters from flash."""
        self._values.clear()
        self._request("fmcb.param_reload", {})

    def restore_defaults(self) -> None:
        """Set every parameter to the firmware's default (in RAM)."""
        self._values.clear()
        self._request("fmcb.param_defaults", {})
