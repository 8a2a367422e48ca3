"""Hand frames over CAN through python-can (socketcan, slcan, virtual, … any interface).

The palm carries hand frames in CAN 2.0A frames of at most 8 bytes (``protocol.canlink``):
identifier ``0x100 + node`` towards the palm, ``0x180 + node`` back.  This transport cuts
each frame it sends into CAN frames and returns the data of the palm's identifier as one
byte stream, which the session's stream decoder reassembles as on a serial line.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from host.errors import TransportError, UsageError
from host.transports.base import LinkKind, Transport, url_options
from protocol.canlink import DEFAULT_PALM_NODE, can_id, segment

if TYPE_CHECKING:
    import can

#: What a user reads when the bus fails under an open transport.
_GONE = ("the CAN adapter is gone or the bus is off (adapter unplugged, cable, "
         "termination); fix it and call reopen(), or open it again")
#: Default CAN bit rate of the palm (bit/s).
DEFAULT_BITRATE = 1_000_000


def _hint(interface: str, channel: str) -> str:
    """What to check when ``interface`` will not open ``channel``."""
    if interface == "socketcan":
        return (f" (is {channel} a CAN network interface, and up? `ip link show {channel}`; "
                f"`sudo ip link set {channel} up type can bitrate {DEFAULT_BITRATE}`)")
    if interface == "slcan":
        return f" (is {channel} the USB-CAN adapter's serial port?)"
    return ""


class CanTransport(Transport):
    """One palm on a CAN bus: ``interface`` and ``channel`` as python-can names them.

    python-can is imported when the first such transport opens (importing it costs about
    0.12 s of CPU time), not when the scheme is looked up."""

    #: CAN adapters buffer frames as a USB serial adapter does.
    schemes: ClassVar[Mapping[str, LinkKind]] = {"can": LinkKind("can", budget_s=0.100)}

    def __init__(self, interface: str, channel: str, *, bitrate: int = DEFAULT_BITRATE,
                 node: int = DEFAULT_PALM_NODE, url: str | None = None, **bus_options: Any):
        super().__init__(url or f"can://{interface}/{channel}")
        self.interface = interface
        self.channel = channel
        self.bitrate = int(bitrate)
        self.node = int(node)
        self._to_node = can_id(self.node, to_host=False)
        self._to_host = can_id(self.node, to_host=True)
        self._bus_options = bus_options
        import can  # here, not at the module's top: see the class docstring

        self._can = can
        self.bus = self._open()

    @classmethod
    def from_url(cls, url: str, **options: Any) -> CanTransport:
        """``can://INTERFACE/CHANNEL?bitrate=1000000&node=10``."""
        rest = url.split("://", 1)[1].split("?", 1)[0]
        interface, _, channel = rest.partition("/")
        if not interface or not channel:
            raise UsageError(f"{url}: expected can://INTERFACE/CHANNEL, e.g. "
                                 "can://socketcan/can0 or can://slcan//dev/ttyACM0")
        merged: dict[str, Any] = {**url_options(url), **options}
        try:
            bitrate = int(merged.pop("bitrate", DEFAULT_BITRATE))
            node = int(str(merged.pop("node", DEFAULT_PALM_NODE)), 0)
        except ValueError:
            raise UsageError(f"{url}: bitrate and node must be numbers") from None
        return cls(interface, channel, bitrate=bitrate, node=node, url=url, **merged)

    def _open(self) -> can.BusABC:
        can = self._can
        options = dict(self._bus_options)
        if self.interface == "slcan":
            options.setdefault("sleep_after_open", 0)
        if self.interface != "virtual":
            options.setdefault("bitrate", self.bitrate)
        try:
            return can.Bus(interface=self.interface, channel=self.channel, **options)
        except can.CanInterfaceNotImplementedError as exc:
            if self.interface not in can.VALID_INTERFACES:
                raise UsageError(
                    f"{self.url}: no CAN interface {self.interface!r}; python-can knows "
                    f"{', '.join(sorted(can.VALID_INTERFACES))}") from exc
            raise TransportError(f"cannot open CAN {self.interface} {self.channel}: {exc}"
                                 f"{_hint(self.interface, self.channel)}") from exc
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise TransportError(f"cannot open CAN {self.interface} {self.channel}: {exc}"
                                 f"{_hint(self.interface, self.channel)}") from exc

    def _send(self, data: bytes) -> None:
        can = self._can
        try:
            for chunk in segment(data):
                self.bus.send(can.Message(arbitration_id=self._to_node, data=chunk,
                                          is_extended_id=False))
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.url}: CAN send failed ({exc}): {_GONE}") from exc

    def _recv(self, timeout: float | None) -> bytes:
        can = self._can
        deadline = None if timeout is None else time.monotonic() + timeout
        out = bytearray()
        try:
            while True:
                wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                message = self.bus.recv(0.0 if out else wait)
                if message is None:
                    return bytes(out)
                if message.arbitration_id == self._to_host and not message.is_extended_id:
                    out += message.data
                elif deadline is not None and time.monotonic() >= deadline and not out:
                    return b""
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.url}: CAN receive failed ({exc}): {_GONE}") from exc

    def _close(self) -> None:
        can = self._can
        try:
            self.bus.shutdown()
        except (can.CanError, OSError):
            pass

    def _reopen(self) -> None:
        self.bus = self._open()
