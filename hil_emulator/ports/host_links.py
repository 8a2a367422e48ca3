"""Host-facing links: what a program on this machine opens to reach the emulated robot.

* :class:`SerialLink` — a :class:`~hil_emulator.ports.pty_port.PtyPort` bridged to a device-side
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

Host input is bounded like a real adapter's: a serial link holds at most
:data:`ADAPTER_BUFFER_BYTES` of host bytes not yet on its wire (a USB-serial adapter's
buffer; the SLCAN link :data:`INPUT_FIFO_US` of CAN frames), tracked by an
:class:`InputFifo`; what a host writes beyond that is lost as a UART overrun would lose it,
and counted (:attr:`InputFifo.overrun`, ``--stats``).  However fast a host writes, memory
stays flat.  In real time each pty is read by a :class:`~hil_emulator.ports.port_reader.PortReader`
thread the moment bytes arrive (:meth:`PtyBacked.start_reader`), and each chunk enters the
wire model at the simulation time of its arrival; in fast mode and in process the
simulation thread reads the ptys itself when it polls (deterministic).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, Final, Protocol

from firmware_py.sim.virtual_ports import VirtualCan, VirtualUart
from hil_emulator.errors import PortError
from hil_emulator.ports.link_tap import LinkTap
from hil_emulator.ports.port_reader import PortReader
from hil_emulator.ports.pty_port import PtyPort, make_link, remove_link
from hil_emulator.ports.slcan_adapter import SlcanAdapter
from protocol.topology import wire_time_us

EmitObserver = Callable[[int], None]
#: How a link hands host input to the simulation: called with a thunk that applies it and
#: the simulation time (µs) it enters at (the link's ``input_clock``).  The real-time runner
#: schedules the thunk then; by default it is applied at once.
InputScheduler = Callable[[Callable[[], None], int], None]


#: Host bytes a serial link holds ahead of its wire: a USB-serial adapter's buffer (the
#: Linux usb-serial driver's 4 KiB write FIFO).  More is an overrun: dropped and counted.
ADAPTER_BUFFER_BYTES: Final = 4096
#: Wire time of CAN frames the SLCAN link accepts ahead of the bus (µs).  More is an
#: overrun: those frames are dropped and counted.
INPUT_FIFO_US: Final = 5_000

Clock = Callable[[], int]
#: The simulation time (µs) at which host input enters, given its arrival on the wall clock
#: (``time.monotonic()`` s) or None for "now".
InputClock = Callable[[float | None], int]


class Port(Protocol):
    """What the emulator serves beside the simulation: a host link, or the fault control
    channel.  The loop calls :meth:`poll` to take what arrived and waits on :meth:`fileno`."""

    name: str

    def poll(self) -> int:
        """Take what arrived (host input, requests); returns how much."""
        ...

    def fileno(self) -> int:
        """A descriptor that becomes readable when something arrives; -1 for none."""
        ...

    def stats(self) -> dict[str, int]:
        """Counters for ``--stats``."""
        ...

    def close(self) -> None:
        """Close it (idempotent)."""
        ...


def _apply_now(apply: Callable[[], None], t_us: int) -> None:
    apply()


def _clock_input(clock: Clock) -> InputClock:
    """An :data:`InputClock` that ignores the arrival time: the simulation's now."""
    def input_clock(arrived: float | None = None) -> int:
        return clock()
    return input_clock


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


class PtyBacked:
    """Common life cycle of a link that owns a pty: open, symlink, close."""

    def __init__(self, name: str, baud: int, clock: Clock,
                 fifo_us: int = INPUT_FIFO_US) -> None:
        self.name = name
        #: Simulation time (µs) at which host input enters the line, from its arrival time
        #: (or None: now); the real-time runner replaces it with its wall-clock mapping.
        self.input_clock: InputClock = _clock_input(clock)
        self.fifo = InputFifo(fifo_us)
        #: The thread reading the pty as bytes arrive (real time), or None.
        self.reader: PortReader | None = None
        self._reading = False
        self.port = PtyPort(baud)
        try:
            self.port.open()
        except OSError as exc:
            raise PortError(f"cannot create a pty for {name}: {exc}") from exc
        self.port.on_host_flush = self._host_flushed
        #: Times the host flushed its output on this port (bytes it wrote may be lost).
        self.host_flushes = 0
        #: Told once (one line of text) the first time the host flushes its output; the
        #: ``hil-emulator`` command prints it.
        self.on_notice: Callable[[str], None] | None = None
        self.on_emit: EmitObserver | None = None
        self.schedule_input: InputScheduler = _apply_now
        self._leftover: list[tuple[float, bytes]] = []
        self.reader_overrun = 0  #: bytes earlier readers could not hold
        self._link_dir: str | None = None
        self._link_name: str | None = None
        #: The link's fault stages (:mod:`hil_emulator.ports.link_tap`), or None.
        self.tap: LinkTap | None = None

    @property
    def path(self) -> str:
        """The pty a host program opens."""
        return self.port.path

    def fileno(self) -> int:
        """What the runner waits on for host input (``select``): the reader's wake-up pipe
        while one runs, else the master descriptor (-1 while the port has vanished)."""
        if self.reader is not None:
            return self.reader.fileno()
        return self.port.fileno() if self.port.is_open else -1

    def _host_flushed(self) -> None:
        """The host flushed its output (``tcflush(TCOFLUSH)``): count it; say it once."""
        self.host_flushes += 1
        if self.host_flushes == 1 and self.on_notice is not None:
            self.on_notice(f"the host program flushed its output on the {self.name} port "
                           "(tcflush / reset_output_buffer() after writing): Linux's pty may "
                           "have thrown away bytes it wrote that a USB adapter would have "
                           "sent; leave out that flush (--stats counts host_flushes)")

    def room(self) -> int:
        """Host bytes the link accepts now (its reader's bound)."""
        return 1 << 30

    def start_reader(self) -> None:
        """Read the pty on a :class:`PortReader` thread from now on (real time)."""
        self._reading = True
        if self.reader is None and self.port.is_open:
            self.reader = PortReader(self.port.fileno(), self.room, self.name,
                                     self.port.unpacket)

    def stop_reader(self) -> None:
        """Back to reading the pty when polled (idempotent); what the reader queued is
        taken first by :meth:`take_input`."""
        self._reading = False
        self._end_reader()

    def _end_reader(self) -> None:
        reader, self.reader = self.reader, None
        if reader is not None:
            reader.stop()
            self._leftover = reader.take()
            self.reader_overrun += reader.overrun

    def take_input(self) -> list[tuple[float | None, bytes]]:
        """What the host wrote since the last call, as (arrival time s or None, bytes)."""
        chunks: list[tuple[float | None, bytes]] = list(self._leftover)
        self._leftover = []
        if self.reader is not None:
            chunks.extend(self.reader.take())
        elif self.port.is_open:
            data = self.port.read_available()
            if data:
                chunks.append((None, data))
        return chunks

    def input_overrun(self) -> int:
        """Host bytes its reader could not hold (with the FIFO's :attr:`InputFifo.overrun`)."""
        reader = self.reader.overrun if self.reader is not None else 0
        return self.reader_overrun + reader

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
        self._end_reader()
        self._unlink()
        self.port.close()

    def _unlink(self) -> None:
        """Remove the one symlink this link made, if it still points at its pty (a link
        the user or another program made, or re-pointed, is left alone)."""
        if self._link_dir is not None and self._link_name is not None and self.port.is_open:
            remove_link(self._link_dir, self._link_name, self.port)

    def reappear(self) -> None:
        """The port comes back: a new pty, linked at the same ``--link-dir`` path."""
        if self.port.is_open:
            return
        self.port = PtyPort(self.port.baud)
        self.port.on_host_flush = self._host_flushed
        try:
            self.port.open()
            if self._link_dir is not None and self._link_name is not None:
                make_link(self._link_dir, self._link_name, self.port)
        except OSError as exc:
            raise PortError(f"cannot re-create the pty for {self.name}: {exc}") from exc
        if self._reading:
            self.start_reader()

    def close(self) -> None:
        """Remove the symlinks this link made and close the pty (idempotent)."""
        self._end_reader()
        self._unlink()
        self._link_dir = None
        self.port.close()


class SerialLink(PtyBacked):
    """A pty bridged to a device UART.

    ``to_device`` puts host bytes into the simulation (called at the simulation's current
    time); :meth:`emit` is the device side's sink (bytes, arrival time in µs).
    """

    def __init__(self, name: str, baud: int, to_device: Callable[[bytes], None],
                 clock: Clock) -> None:
        super().__init__(name, baud, clock, wire_time_us(ADAPTER_BUFFER_BYTES, baud))
        self._to_device = to_device
        self._us_per_byte = wire_time_us(1_000_000, baud) / 1_000_000
        self._backlog = 0  # bytes ahead of the wire at the last admission
        self.bytes_in = 0
        self.bytes_out = 0

    def room(self) -> int:
        """Host bytes the adapter buffer takes now: :data:`ADAPTER_BUFFER_BYTES` less what
        waited for the wire at the last admission (called on the reader's thread)."""
        return ADAPTER_BUFFER_BYTES - self._backlog

    def poll(self) -> int:
        """Move what the host wrote into the simulation, each chunk at the simulation time
        of its arrival, up to the adapter buffer's room (the rest is an overrun); returns
        the byte count admitted."""
        return sum(self._admit(data, arrived) for arrived, data in self.take_input())

    def _admit(self, data: bytes, arrived: float | None) -> int:
        if self.tap is not None:
            data = self.tap.down(data)
        if not data:
            return 0
        now = self.input_clock(arrived)
        fit = max(0, int(self.fifo.room_us(now) / self._us_per_byte))
        if len(data) > fit:
            self.fifo.overrun += len(data) - fit
            data = data[:fit]
        if data:
            self.fifo.claim(now, wire_time_us(len(data), self.port.baud))
            self.bytes_in += len(data)
            self.schedule_input(partial(self._to_device, data), now)
        self._backlog = int(max(0, self.fifo.free_us - now) / self._us_per_byte)
        return len(data)

    def stats(self) -> dict[str, int]:
        """Byte counts and FIFO figures, for ``--stats`` (``overrun``: bytes)."""
        fifo = self.fifo.stats()
        fifo["overrun"] += self.input_overrun()
        return {"bytes_in": self.bytes_in, "bytes_out": self.bytes_out,
                "dropped_out": self.port.dropped, "host_flushes": self.host_flushes, **fifo}

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


class SlcanLink(PtyBacked):
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

    def room(self) -> int:
        """SLCAN text the reader holds for the adapter (a USB adapter's buffer)."""
        return ADAPTER_BUFFER_BYTES

    def poll(self) -> int:
        """Handle the host's SLCAN commands; frames it transmits reach the bus at their
        arrival, as many as the adapter's FIFO holds (the rest are an overrun)."""
        count = 0
        for arrived, data in self.take_input():
            frames = self.adapter.poll(data)
            if not frames:
                continue
            now = self.input_clock(arrived)
            fit = max(0, self.fifo.room_us(now) // VirtualCan.FRAME_US)
            if len(frames) > fit:
                self.fifo.overrun += len(frames) - fit
                frames = frames[:fit]
            if frames:
                self.fifo.claim(now, len(frames) * VirtualCan.FRAME_US)
                self.schedule_input(partial(self._deliver, frames), now)
                count += len(frames)
        return count

    def stats(self) -> dict[str, int]:
        """Adapter errors, bytes the host did not read, FIFO figures (``overrun``: frames
        the FIFO refused; ``overrun_bytes``: SLCAN text the reader could not hold), for
        ``--stats``."""
        return {"errors": self.adapter.errors, "dropped_out": self.port.dropped,
                **self.fifo.stats(), "overrun_bytes": self.input_overrun(),
                "host_flushes": self.host_flushes}

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
        self.input_clock: InputClock = _clock_input(can.scheduler.now_us)
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
            self.schedule_input(partial(self._deliver, frames), self.input_clock(None))
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


#: A host link proper (not the control channel): it takes the real-time runner's input
#: clock and reports its deliveries.
HostLink = SerialLink | SlcanLink | VirtualCanLink
