"""Host-facing links: what a program on this machine opens to reach the emulated robot.

* :class:`SerialLink` — a :class:`~hil_emulator.pty_port.PtyPort` bridged to a device-side
  UART.  Bytes the host writes enter the simulation when the emulator polls, through a
  sending function that models their own wire time (a UART of the host adapter, or the
  arm's RS-485 line); bytes a device sends are written to the pty when the simulation
  reaches the time their last bit arrives (frames are delivered whole, at their end).
* :class:`SlcanLink` — the palm's CAN controller behind an emulated SLCAN USB-CAN adapter
  on a pty (python-can's ``slcan`` interface opens it unmodified).
* :class:`VirtualCanLink` — the same CAN controller on a python-can ``virtual`` channel, for
  host code in the same process.

Each link reports, through ``on_emit``, the simulation time (µs) of every chunk it writes,
so the real-time runner can measure how late delivery was.

Host input is bounded like a real adapter's: a link takes from its pty only what its wire
carries within :data:`INPUT_FIFO_US` of now (an :class:`InputFifo`); what a host writes
beyond that is lost as a UART overrun would lose it, and counted (:attr:`InputFifo.overrun`,
``--stats``).  However fast a host writes, memory stays flat and a request written after the
flood is on the wire within :data:`INPUT_FIFO_US`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

from firmware_py.sim.virtual_hal import VirtualCan, VirtualUart
from hil_emulator.errors import PortError
from hil_emulator.pty_port import PtyPort, make_link, remove_links
from hil_emulator.slcan_adapter import SlcanAdapter
from protocol.topology import wire_time_us

EmitObserver = Callable[[int], None]
#: How a link hands host input to the simulation: called with a thunk that applies it.  The
#: real-time runner schedules the thunk at the simulation time matching the wall clock when
#: the input was read; by default it is applied at once.
InputScheduler = Callable[[Callable[[], None]], None]


#: Wire time of host input a link accepts ahead of its line (µs): a USB-serial adapter's
#: small FIFO.  More is an overrun: those bytes (or SLCAN frames) are dropped and counted.
INPUT_FIFO_US: Final = 5_000

Clock = Callable[[], int]


def _apply_now(apply: Callable[[], None]) -> None:
    apply()


class InputFifo:
    """How much wire time host input has claimed ahead of the simulation clock (µs).

    :meth:`room_us` is what is left of :data:`INPUT_FIFO_US`; :meth:`claim` books wire time
    for what was admitted; :attr:`overrun` counts what did not fit (bytes or frames);
    :attr:`peak_us` is the longest queue seen.
    """

    def __init__(self, capacity_us: int = INPUT_FIFO_US) -> None:
        self.capacity_us = capacity_us
        self.free_us = 0  # when the wire has carried everything admitted so far
        self.overrun = 0
        self.peak_us = 0

    def room_us(self, now_us: int) -> int:
        """Wire time (µs) still free in the FIFO at ``now_us``."""
        return self.capacity_us - max(0, self.free_us - now_us)

    def claim(self, now_us: int, wire_us: int) -> None:
        """Book ``wire_us`` µs of the line after what is queued."""
        self.free_us = max(self.free_us, now_us) + wire_us
        self.peak_us = max(self.peak_us, self.free_us - now_us)

    def stats(self) -> dict[str, int]:
        """``overrun`` (count) and ``queue_peak_us`` (µs), for ``--stats``."""
        return {"overrun": self.overrun, "queue_peak_us": self.peak_us}


class _PtyBacked:
    """Common life cycle of a link that owns a pty: open, symlink, close."""

    def __init__(self, name: str, baud: int, clock: Clock) -> None:
        self.name = name
        #: Simulation time (µs) at which host input read now enters the line; the
        #: real-time runner replaces it with its wall-clock mapping.
        self.input_clock = clock
        self.fifo = InputFifo()
        self.port = PtyPort(baud)
        try:
            self.port.open()
        except OSError as exc:
            raise PortError(f"cannot create a pty for {name}: {exc}") from exc
        self.on_emit: EmitObserver | None = None
        self.schedule_input: InputScheduler = _apply_now
        self._link_dir: str | None = None
        self._link_name: str | None = None
        #: The link's fault stages (:mod:`hil_emulator.faults.host_link`), or None.
        self.tap: Any = None

    @property
    def path(self) -> str:
        """The pty a host program opens."""
        return self.port.path

    def fileno(self) -> int:
        """The master descriptor, for ``select`` (-1 while the port has vanished)."""
        return self.port.fileno() if self.port.is_open else -1

    def link(self, link_dir: str, name: str | None = None) -> str:
        """Make ``link_dir/name`` (default: the link's name) point at the pty."""
        try:
            made = make_link(link_dir, name or self.name, self.port)
        except OSError as exc:
            reason = exc.strerror if exc.strerror and exc.filename else str(exc)
            raise PortError(f"cannot make the link {name or self.name!r} in the link "
                            f"directory {link_dir}: {reason}") from exc
        self._link_dir = link_dir
        self._link_name = name or self.name
        return str(made)

    def vanish(self) -> None:
        """The port disappears (a USB adapter unplugged): the pty is closed and the
        symlink removed; output meanwhile is lost."""
        if self._link_dir is not None and self.port.is_open:
            remove_links(self._link_dir, self.port)
        self.port.close()

    def reappear(self) -> None:
        """The port comes back: a new pty, linked at the same ``--link-dir`` path."""
        if self.port.is_open:
            return
        self.port = PtyPort(self.port.baud)
        try:
            self.port.open()
            if self._link_dir is not None and self._link_name is not None:
                make_link(self._link_dir, self._link_name, self.port)
        except OSError as exc:
            raise PortError(f"cannot re-create the pty for {self.name}: {exc}") from exc

    def close(self) -> None:
        """Remove the symlinks this link made and close the pty (idempotent)."""
        if self._link_dir is not None and self.port.is_open:
            remove_links(self._link_dir, self.port)
            self._link_dir = None
        self.port.close()


class SerialLink(_PtyBacked):
    """A pty bridged to a device UART.

    ``to_device`` puts host bytes into the simulation (called at the simulation's current
    time); :meth:`emit` is the device side's sink (bytes, arrival time in µs).
    """

    def __init__(self, name: str, baud: int, to_device: Callable[[bytes], None],
                 clock: Clock) -> None:
        super().__init__(name, baud, clock)
        self._to_device = to_device
        self._us_per_byte = wire_time_us(1_000_000, baud) / 1_000_000
        self.bytes_in = 0
        self.bytes_out = 0

    def poll(self) -> int:
        """Move what the host wrote into the simulation, up to the FIFO's room (the rest is
        an overrun); returns the byte count admitted."""
        if not self.port.is_open:
            return 0
        data = self.port.read_available()
        if data and self.tap is not None:
            data = self.tap.down(data)
        if not data:
            return 0
        now = self.input_clock()
        fit = max(0, int(self.fifo.room_us(now) / self._us_per_byte))
        if len(data) > fit:
            self.fifo.overrun += len(data) - fit
            data = data[:fit]
        if data:
            self.fifo.claim(now, wire_time_us(len(data), self.port.baud))
            self.bytes_in += len(data)
            self.schedule_input(lambda: self._to_device(data))
        return len(data)

    def stats(self) -> dict[str, int]:
        """Byte counts and FIFO figures, for ``--stats``."""
        return {"bytes_in": self.bytes_in, "bytes_out": self.bytes_out,
                "dropped_out": self.port.dropped, **self.fifo.stats()}

    def emit(self, data: bytes, t_us: int) -> None:
        """A device's bytes, complete at simulation time ``t_us``, go to the host."""
        self.bytes_out += len(data)
        if self.port.is_open:
            self.port.write(data)
        if self.on_emit is not None:
            self.on_emit(t_us)

    @classmethod
    def to_uart(cls, name: str, device_uart: VirtualUart) -> SerialLink:
        """A point-to-point link: a host-adapter UART at the device's baud rate wired to
        ``device_uart`` (host bytes take their wire time to arrive; the device's
        transmissions are emitted at their end)."""
        adapter = VirtualUart(device_uart.scheduler, device_uart.baud, name=f"{name}-host")
        adapter.keep_sent = False
        adapter.peer = device_uart
        link = cls(name, device_uart.baud, adapter.send, device_uart.scheduler.now_us)
        device_uart.sink = link.emit
        return link


class SlcanLink(_PtyBacked):
    """The palm's CAN controller behind an emulated SLCAN adapter on a pty."""

    def __init__(self, name: str, can: VirtualCan) -> None:
        super().__init__(name, 115_200, can.scheduler.now_us)
        self.adapter = SlcanAdapter(self.port)
        self._can = can
        can.sink = self._from_bus

    def _from_bus(self, arbitration_id: int, data: bytes, t_us: int) -> None:
        self.adapter.send_frame(arbitration_id, data)
        if self.on_emit is not None:
            self.on_emit(t_us)

    def poll(self) -> int:
        """Handle the host's SLCAN commands; frames it transmits reach the bus now, as
        many as the adapter's FIFO holds (the rest are an overrun)."""
        frames = self.adapter.poll()
        if not frames:
            return 0
        now = self.input_clock()
        fit = max(0, self.fifo.room_us(now) // VirtualCan.FRAME_US)
        if len(frames) > fit:
            self.fifo.overrun += len(frames) - fit
            frames = frames[:fit]
        if frames:
            self.fifo.claim(now, len(frames) * VirtualCan.FRAME_US)
            self.schedule_input(lambda: self._deliver(frames))
        return len(frames)

    def stats(self) -> dict[str, int]:
        """Adapter errors, bytes the host did not read, FIFO figures, for ``--stats``."""
        return {"errors": self.adapter.errors, "dropped_out": self.port.dropped,
                **self.fifo.stats()}

    def _deliver(self, frames: list[tuple[int, bytes]]) -> None:
        for arbitration_id, data in frames:
            self._can.deliver(arbitration_id, data)


class VirtualCanLink:
    """The palm's CAN controller on a python-can ``virtual`` channel (same process only)."""

    def __init__(self, name: str, can: VirtualCan, channel: str) -> None:
        import can as python_can  # imported here: only this link needs python-can

        self.name = name
        self.channel = channel
        self._python_can: Any = python_can
        self.bus = python_can.Bus(interface="virtual", channel=channel,
                                  receive_own_messages=False)
        self._can = can
        self.on_emit: EmitObserver | None = None
        self.schedule_input: InputScheduler = _apply_now
        can.sink = self._from_bus

    @property
    def path(self) -> str:
        """How a host names it: ``virtual:<channel>``."""
        return f"virtual:{self.channel}"

    def _from_bus(self, arbitration_id: int, data: bytes, t_us: int) -> None:
        message = self._python_can.Message(arbitration_id=arbitration_id, data=data,
                                           is_extended_id=False)
        self.bus.send(message)
        if self.on_emit is not None:
            self.on_emit(t_us)

    def poll(self) -> int:
        """Frames host code sent on the channel reach the bus now."""
        frames: list[tuple[int, bytes]] = []
        while (message := self.bus.recv(0.0)) is not None:
            frames.append((message.arbitration_id, bytes(message.data)))
        if frames:
            self.schedule_input(lambda: self._deliver(frames))
        return len(frames)

    def _deliver(self, frames: list[tuple[int, bytes]]) -> None:
        for arbitration_id, data in frames:
            self._can.deliver(arbitration_id, data)

    def fileno(self) -> int:
        """No descriptor to wait on (the runner polls it every loop)."""
        return -1

    def stats(self) -> dict[str, int]:
        """Nothing to count: the channel is in-process and unbounded by design."""
        return {}

    def close(self) -> None:
        """Shut the python-can bus down (idempotent)."""
        self.bus.shutdown()
