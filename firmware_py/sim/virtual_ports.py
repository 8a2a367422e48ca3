"""The virtual HAL's links: UARTs and CAN controllers that carry bytes in simulated time.

A :class:`VirtualUart` holds its line for the wire time of what it sends (10 bits a byte at
its baud, rounded up to whole µs: :func:`protocol.topology.wire_time_us`); the bytes arrive at
its ``peer`` (point to point, :func:`connect`) or its ``sink`` when the last bit is in, or a
line model sees them leave (``on_transmit``) and delivers them itself (:func:`line_delivers`).
A :class:`VirtualCan` holds a 1 Mbit/s bus for one frame's time (``FRAME_US``).  Both record
what the firmware sent (``sent``, times in µs since the scheduler's start) while
``keep_sent`` is on; the emulator turns it off.  :class:`~firmware_py.sim.virtual_hal.VirtualHal`
builds them; the emulator's buses (:mod:`hil_emulator.lines.rs485_bus`) and host links wire them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

from mypy_extensions import mypyc_attr

from firmware_py import hal
from firmware_py.errors import HalError
from firmware_py.scheduler import Scheduler
from protocol.topology import wire_time_us


@dataclass(slots=True)
class SentChunk:
    """Bytes a UART transmitted: when the first bit left and when the last arrived (µs)."""

    data: bytes
    start_us: int
    end_us: int

    # Written out: a dataclass's generated __init__ stays interpreted in the compiled core.
    def __init__(self, data: bytes, start_us: int, end_us: int) -> None:
        self.data = data
        self.start_us = start_us
        self.end_us = end_us


def line_delivers(data: bytes, t_us: int) -> None:
    """The ``sink`` of a UART on a line model that delivers its frames itself (a bus seeing
    them through ``on_transmit``): nothing happens at the frame's end, so
    :meth:`VirtualUart.send` schedules no arrival for it."""


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualUart(hal.Uart):
    """A UART whose output reaches ``peer`` after the wire time; ``sent`` records it all."""

    def __init__(self, scheduler: Scheduler, baud: int = 2_000_000, name: str = "") -> None:
        self.scheduler = scheduler
        self.baud = baud
        self.name = name
        self.sent: list[SentChunk] = []
        self.peer: VirtualUart | None = None
        self.sink: Callable[[bytes, int], None] | None = None
        self._receiver: hal.ReceiveCallback | None = None
        self._line_free_us = 0
        self.enabled = True
        #: Record every transmission in :attr:`sent` (tests); the emulator turns it off.
        self.keep_sent = True
        #: Called with each chunk's bytes and the time its first bit leaves (µs): a bus
        #: model sees frames start.
        self.on_transmit: Callable[[bytes, int], None] | None = None

    def wire_time_us(self, n_bytes: int) -> int:
        """Time ``n_bytes`` occupy the line (µs, rounded up)."""
        return wire_time_us(n_bytes, self.baud)

    def send(self, data: bytes) -> None:
        """Transmit ``data``; it arrives (``sink``, ``peer``) after its wire time.  A UART
        with no peer whose sink is :func:`line_delivers` (or None) schedules no arrival."""
        if not data or not self.enabled:
            return
        now = self.scheduler.now
        free = self._line_free_us
        start = now if now > free else free
        end = start + wire_time_us(len(data), self.baud)  # self.wire_time_us(), one call less
        self._line_free_us = end
        # bytes(data) is data for bytes, but compiled (mypyc) it is a generic call.
        chunk = data if type(data) is bytes else bytes(data)
        if self.keep_sent:
            self.sent.append(SentChunk(chunk, start, end))
        if self.on_transmit is not None:
            self.on_transmit(chunk, start)
        sink = self.sink
        if self.peer is not None or (sink is not None and sink is not line_delivers):
            self.scheduler.call_at(end, lambda: self._arrive(chunk, end))

    def _arrive(self, data: bytes, t_us: int) -> None:
        if self.sink is not None:
            self.sink(data, t_us)
        if self.peer is not None:
            self.peer.deliver(data)

    def deliver(self, data: bytes) -> None:
        """Bytes arriving from the line now (what a peer or a test injects)."""
        if self._receiver is not None and self.enabled:
            self._receiver(data if type(data) is bytes else bytes(data),
                           self.scheduler.now)

    def set_receiver(self, callback: hal.ReceiveCallback | None) -> None:
        self._receiver = callback

    @property
    def tx_busy(self) -> bool:
        return self.scheduler.now_us() < self._line_free_us

    def take_sent(self) -> list[bytes]:
        """The chunks sent so far (and forget them)."""
        out = [c.data for c in self.sent]
        self.sent.clear()
        return out


def connect(a: VirtualUart, b: VirtualUart) -> None:
    """Wire two UARTs point to point (full duplex, no collisions)."""
    a.peer, b.peer = b, a


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualCan(hal.CanController):
    """A CAN controller: ``sent`` records (id, data, time µs); :meth:`deliver` injects."""

    #: Time one 8-byte standard frame occupies a 1 Mbit/s bus, roughly (µs).
    FRAME_US: ClassVar[int] = 111

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        self.sent: list[tuple[int, bytes, int]] = []
        #: Record every frame in :attr:`sent` (tests); the emulator turns it off.
        self.keep_sent = True
        self.sink: Callable[[int, bytes, int], None] | None = None
        self._receiver: hal.CanReceiveCallback | None = None
        self._free_us = 0

    def send(self, arbitration_id: int, data: bytes) -> None:
        if len(data) > 8:
            raise HalError(f"a CAN frame carries at most 8 bytes, got {len(data)}")
        start = max(self.scheduler.now_us(), self._free_us)
        end = start + self.FRAME_US
        self._free_us = end
        frame = (arbitration_id, bytes(data), end)
        if self.keep_sent:
            self.sent.append(frame)
        if self.sink is not None:
            sink = self.sink
            self.scheduler.call_at(end, lambda: sink(frame[0], frame[1], end))

    def set_receiver(self, callback: hal.CanReceiveCallback | None) -> None:
        self._receiver = callback

    def deliver(self, arbitration_id: int, data: bytes) -> None:
        """A CAN frame arriving now."""
        if self._receiver is not None:
            self._receiver(arbitration_id, bytes(data), self.scheduler.now_us())

