"""An in-memory HAL on a :class:`~firmware_py.scheduler.Scheduler`: firmware without physics.

Tests drive firmware through it in microseconds; the emulator builds on the same parts and
replaces the sensor values, motor loads and wires with the plant and the bus fabric.
Everything a test sets is a plain attribute (``hal.sensors.values["accel"] = (0, 0, 1000)``);
everything the firmware did is recorded (``uart.sent``, ``motor.duty``, ``flash.writes``).

**Plant side.**  Besides the :mod:`firmware_py.hal` interface the firmware calls, each part
has methods for the world outside the MCU (the emulator's plant), and a plant uses only
those: it drives the inputs and reads the outputs, never the firmware's side nor the
recording attributes.

* :class:`VirtualSensors`: ``set_accel``, ``set_mag``, ``set_gyro`` (3-axis counts),
  ``set_taxels``, ``set_strain``, ``set_temperature(s)``, ``set_thermistors``,
  ``set_supply_mv``, ``set_pot``, ``set_load`` (``set_input`` for any other channel);
* :class:`VirtualMotor`: reads ``commanded_duty``, ``bridge_enabled``, ``braking`` (all
  three at once: ``drive_command``); drives
  ``set_hall_state``, ``set_current_ma`` (both: ``set_hall_and_current``);
* :class:`VirtualStepper`: reads ``position_steps`` (exact), ``commanded_rate``,
  ``commanded_current_ma``;
* :class:`VirtualEncoder`: drives ``set_count``, ``pulse_index``;
* :class:`VirtualPowerSwitch`: reads ``state``; drives ``set_load_ma``.

They run in the emulator's 1 kHz tick for every node: each is one attribute read or write
behind a method (the sensors' also check that the board has the channel), and a plant may
bind them once (``set_hall = motor.set_hall_state``).  Run from source, a call costs more
than that work, so the plant's per-tick hooks may read instead the attribute such a method
returns (a motor's ``duty``, ``enabled``, ``brake``, ``current`` and ``_hall``, a stepper's
``rate`` and ``current``, an encoder's ``_value``, a channel's ``sensors.values``) and skip
a setter whose value is already there (it would store the same and tell no one).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import ClassVar

from mypy_extensions import mypyc_attr

from firmware_py import hal
from firmware_py.errors import FlashMemoryError, HalError
from firmware_py.scheduler import Scheduler, TimerHandle
from protocol.topology import wire_time_us

#: Time to erase and program one flash page (µs); SAM3S datasheet order of magnitude.
PAGE_WRITE_US = 2_000


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualClock(hal.Clock):
    """Node-local time on a shared scheduler; ``cancel_all`` stops the node's timers."""

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        self.epoch_us = scheduler.now_us()
        self._timers: list[TimerHandle] = []
        self._prune_at = 16

    def now_us(self) -> int:
        return self.scheduler.now_us() - self.epoch_us

    def _track(self, handle: TimerHandle) -> TimerHandle:
        timers = self._timers
        timers.append(handle)
        if len(timers) > self._prune_at:  # forget finished timers, amortised O(1)
            self._timers = timers = [t for t in timers if t.active]
            self._prune_at = max(16, 2 * len(timers))
        return handle

    def call_later(self, delay_us: int, callback: Callable[[], None]) -> TimerHandle:
        return self._track(self.scheduler.call_later(delay_us, callback))

    def call_every(self, period_us: int, callback: Callable[[], None]) -> TimerHandle:
        return self._track(self.scheduler.call_every(period_us, callback))

    def cancel_all(self) -> None:
        """Cancel every timer the firmware started (reset, power loss)."""
        for t in self._timers:
            t.cancel()
        self._timers.clear()

    def restart(self) -> None:
        """Power-up: time starts again from zero."""
        self.cancel_all()
        self.epoch_us = self.scheduler.now_us()


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
        now = self.scheduler.now_us()
        free = self._line_free_us
        start = now if now > free else free
        end = start + self.wire_time_us(len(data))
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
                           self.scheduler.now_us())

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


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualPowerSwitch(hal.PowerSwitch):
    """A power switch; ``on_change`` callbacks power the downstream boards."""

    def __init__(self, load_ma: int = 0) -> None:
        self._state = 0
        self._load_ma = load_ma
        self._on_current: Callable[[], None] | None = None
        self.on_change: list[Callable[[int], None]] = []
        self.history: list[int] = []

    def set(self, state: int) -> None:
        if state not in (0, 1, 2):
            raise HalError(f"power state {state} is not 0, 1 or 2")
        if state != self._state:
            self._state = state
            self.history.append(state)
            for cb in list(self.on_change):
                cb(state)

    @property
    def state(self) -> int:
        return self._state

    def current_ma(self) -> int:
        return self._load_ma if self._state else 0

    def set_current_interrupt(self, callback: Callable[[], None] | None) -> bool:
        self._on_current = callback
        return True

    @property
    def load_ma(self) -> int:
        """What the downstream load draws whenever the switch is on (mA); setting it is
        :meth:`set_load_ma`."""
        return self._load_ma

    @load_ma.setter
    def load_ma(self, milliamps: int) -> None:
        self.set_load_ma(milliamps)

    # --- plant side

    def set_load_ma(self, milliamps: int) -> None:
        """The downstream load draws ``milliamps`` (mA) whenever the switch is on; a change
        raises the current interrupt (switching state changes are the firmware's own)."""
        milliamps = int(milliamps)
        if milliamps != self._load_ma:
            self._load_ma = milliamps
            if self._on_current is not None:
                self._on_current()


# Faults and tests replace write_page on an instance: a plain Python class in the compiled core.
@mypyc_attr(native_class=False, allow_interpreted_subclasses=True)
class VirtualFlash(hal.Flash):
    """Flash memory as a bytearray, erased to 0xFF, with timed page writes and lock bits."""

    def __init__(self, scheduler: Scheduler, page_size: int = hal.Flash.page_size,
                 page_count: int = hal.Flash.page_count,
                 base_address: int = hal.Flash.base_address,
                 page_write_us: int = PAGE_WRITE_US) -> None:
        self.scheduler = scheduler
        self.page_size = page_size
        self.page_count = page_count
        self.base_address = base_address
        self.page_write_us = page_write_us
        self.memory = bytearray(b"\xff" * (page_size * page_count))
        self.locked: set[int] = set()
        self.writes: list[int] = []
        self._pending: tuple[int, bytes, TimerHandle] | None = None

    def _offset(self, address: int, length: int) -> int:
        off = address - self.base_address
        if off < 0 or length < 0 or off + length > len(self.memory):
            raise FlashMemoryError(f"address 0x{address:x}+{length} is outside flash")
        return off

    def read(self, address: int, length: int) -> bytes:
        off = self._offset(address, length)
        return bytes(self.memory[off : off + length])

    def write_page(self, page: int, data: bytes, done: Callable[[bool], None]) -> None:
        if not 0 <= page < self.page_count:
            raise FlashMemoryError(f"page {page} is outside 0..{self.page_count - 1}")
        if len(data) != self.page_size:
            raise FlashMemoryError(f"a page is {self.page_size} bytes, got {len(data)}")
        if self._pending is not None:
            raise FlashMemoryError("flash is busy")
        if page in self.locked:
            self.scheduler.call_later(1, partial(done, False))
            return
        off = page * self.page_size
        self.memory[off : off + self.page_size] = b"\xff" * self.page_size  # erase
        payload = bytes(data)
        # (partial, not a closure: the compiled core cannot compile closures in a plain
        # Python class's methods)
        self._pending = (page, payload, self.scheduler.call_later(
            self.page_write_us, partial(self._finish_write, page, payload, done)))

    def _finish_write(self, page: int, payload: bytes, done: Callable[[bool], None]) -> None:
        """The page write started by :meth:`write_page` is done."""
        off = page * self.page_size
        self.memory[off : off + self.page_size] = payload
        self._pending = None
        self.writes.append(page)
        done(True)

    @property
    def busy(self) -> bool:
        return self._pending is not None

    def lock(self, first_page: int, count: int) -> None:
        self.locked.update(range(first_page, first_page + count))

    def power_loss(self) -> None:
        """Power removed: an unfinished write leaves its page half programmed; locks clear."""
        if self._pending is not None:
            page, payload, handle = self._pending
            handle.cancel()
            off = page * self.page_size
            half = self.page_size // 2
            self.memory[off : off + half] = payload[:half]
            self._pending = None
        self.locked.clear()

    def load(self, address: int, data: bytes) -> None:
        """Put bytes into flash directly (factory programming over JTAG)."""
        off = self._offset(address, len(data))
        self.memory[off : off + len(data)] = data


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualMotor(hal.MotorDriver):
    """Records the commands; hall state and current are set by the test or the plant."""

    def __init__(self) -> None:
        self.duty = 0.0
        self.enabled = False
        self.brake = False
        self._hall = 0
        self._on_hall: Callable[[], None] | None = None
        self.current = 0

    def set_duty(self, duty: float) -> None:
        # max(-1.0, min(1.0, duty)) written out (the fmcbs call it 12 000 times a second);
        # NaN gives 1.0 as there.
        d = float(duty)
        d = d if d < 1.0 else 1.0
        self.duty = d if d > -1.0 else -1.0

    def set_enabled(self, enabled: bool) -> None:
        self.enabled = bool(enabled)

    def set_brake(self, brake: bool) -> None:
        self.brake = bool(brake)

    def hall_state(self) -> int:
        return self._hall

    def current_ma(self) -> int:
        return self.current

    def set_hall_interrupt(self, callback: Callable[[], None] | None) -> bool:
        self._on_hall = callback
        return True

    @property
    def hall(self) -> int:
        """The hall state the sensors give now (0..7); setting it is :meth:`set_hall_state`
        (a test's way of turning the rotor)."""
        return self._hall

    @hall.setter
    def hall(self, state: int) -> None:
        self.set_hall_state(state)

    # --- plant side

    def commanded_duty(self) -> float:
        """The signed duty the firmware commands, −1..1 (whether or not the bridge is on)."""
        return self.duty

    def bridge_enabled(self) -> bool:
        """The bridge drives the windings (else they coast, unless :meth:`braking`)."""
        return self.enabled

    def braking(self) -> bool:
        """The windings are shorted (braking wins over the duty)."""
        return self.brake

    def drive_command(self) -> tuple[bool, bool, float]:
        """:meth:`braking`, :meth:`bridge_enabled` and :meth:`commanded_duty` in one call
        (the finger plant reads twelve motors every tick)."""
        return self.brake, self.enabled, self.duty

    def set_hall_state(self, state: int) -> None:
        """The three hall sensor bits the rotor angle gives now, 0..7; a change raises the
        hall interrupt."""
        if state != self._hall:
            self._hall = state
            if self._on_hall is not None:
                self._on_hall()

    def set_current_ma(self, milliamps: int) -> None:
        """The winding current the current sense measures (mA, signed)."""
        self.current = milliamps

    def set_hall_and_current(self, state: int, milliamps: int) -> None:
        """:meth:`set_hall_state` and :meth:`set_current_ma` in one call (the finger plant
        writes twelve motors every tick)."""
        if state != self._hall:
            self._hall = state
            if self._on_hall is not None:
                self._on_hall()
        self.current = milliamps


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualStepper(hal.Stepper):
    """A pulse generator whose counter integrates the commanded rate exactly over time."""

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        self.rate = 0.0
        self.current = 0
        self._count0 = 0.0
        self._t0 = scheduler.now_us()

    # set_step_rate and step_count run every tick of every stepper node: position_steps()
    # is written out in both.
    def set_step_rate(self, steps_per_s: float) -> None:
        now = self.scheduler.now_us()
        self._count0 = self._count0 + self.rate * (now - self._t0) / 1e6
        self._t0 = now
        self.rate = float(steps_per_s)

    def step_count(self) -> int:
        return int(self._count0 + self.rate * (self.scheduler.now_us() - self._t0) / 1e6)

    def set_current(self, milliamps: int) -> None:
        self.current = int(milliamps)

    # --- plant side

    def position_steps(self) -> float:
        """Microsteps emitted so far, exactly (fractional): the rotor's commanded position,
        which :meth:`step_count` truncates.  Positive steps turn the shaft positive."""
        return self._count0 + self.rate * (self.scheduler.now_us() - self._t0) / 1e6

    def commanded_rate(self) -> float:
        """The signed step rate the firmware commands (microsteps/s)."""
        return self.rate

    def commanded_current_ma(self) -> int:
        """The phase current the firmware commands (mA; 0: de-energised)."""
        return self.current


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualEncoder(hal.Encoder):
    """An encoder whose count the plant sets (:meth:`set_count`); :meth:`pulse_index` fires
    the index.  A change of the count (by the plant or a test setting :attr:`value`) raises
    the count-change interrupt.  With :attr:`index_blind` (a dirty code wheel: a fault) the
    index pulses do not reach the firmware; :attr:`missed` counts them."""

    def __init__(self) -> None:
        self._value = 0
        self._callback: Callable[[int], None] | None = None
        self._on_change: Callable[[], None] | None = None
        self.index_blind = False
        self.missed = 0

    def count(self) -> int:
        return self._value

    def set_index_callback(self, callback: Callable[[int], None] | None) -> None:
        self._callback = callback

    def set_change_interrupt(self, callback: Callable[[], None] | None) -> bool:
        self._on_change = callback
        return True

    # --- plant side

    @property
    def value(self) -> int:
        """The count now; setting it is :meth:`set_count`."""
        return self._value

    @value.setter
    def value(self, count: int) -> None:
        self.set_count(count)

    def set_count(self, count: int) -> None:
        """The reader's count now (counts since power-up)."""
        if count != self._value:
            self._value = count
            if self._on_change is not None:
                self._on_change()

    def pulse_index(self, count: int | None = None) -> None:
        """The index mark passes the reader now, at ``count`` (which becomes the count;
        None: the present count); the firmware's index callback gets it."""
        if count is not None:
            self.set_count(count)
        if self.index_blind:
            self.missed += 1
        elif self._callback is not None:
            self._callback(self._value)


#: Channel names of numbered series (``taxel0`` …), longer than any board's series.
_SERIES_LENGTH = 64
_TAXEL_KEYS = tuple(f"taxel{k}" for k in range(_SERIES_LENGTH + 1))
_TEMPERATURE_KEYS = tuple(f"temperature{k}" for k in range(_SERIES_LENGTH + 1))
_THERMISTOR_KEYS = tuple(f"thermistor{k}" for k in range(_SERIES_LENGTH + 1))


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualSensors(hal.Sensors):
    """Sensor values by channel name, set by the test or the plant.

    The plant side sets only channels the board has (else :class:`HalError`), in the counts
    :meth:`firmware_py.hal.Sensors.read` documents; a numbered series (taxels,
    temperatures, thermistors) is set whole, exactly as many values as the board has.
    :attr:`faults` (the emulator's sensor faults) changes what :meth:`read` returns for
    some channels while the plant keeps setting the true values.  (A plain class, not a
    dataclass: the compiled core cannot compile a dataclass Python subclasses.)
    """

    def __init__(self, values: dict[str, int | tuple[int, ...]] | None = None) -> None:
        #: The value of each channel the board has.
        self.values: dict[str, int | tuple[int, ...]] = {} if values is None else values
        #: Per series prefix, what to call before the plant side sets the series
        #: (:meth:`watch_series`).  Writing :attr:`values` directly announces nothing.
        self.watchers: dict[str, Callable[[], None]] = {}
        #: Per scalar channel, what to call after it changes (:meth:`watch_channel`).
        #: Writing :attr:`values` directly calls nothing.
        self.channel_watchers: dict[str, Callable[[], None]] = {}
        #: Per faulty channel, what a read returns for the true value.  A faulty channel may
        #: read differently at every read (noise): its channel watcher hears of a change at
        #: each, so no program sleeps on it.
        self.faults: dict[str, Callable[[int | tuple[int, ...]], int | tuple[int, ...]]] = {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(values={self.values!r})"

    def read(self, channel: str) -> int | tuple[int, ...]:
        try:
            value = self.values[channel]
        except KeyError:
            raise HalError(f"this board has no sensor channel {channel!r}") from None
        if self.faults:
            fault = self.faults.get(channel)
            if fault is not None:
                self._changed(channel)
                return fault(value)
        return value

    def read_burst(self, channel: str, count: int) -> int:
        """The plant holds one value per channel, so a burst is ``count`` times it (a
        subclass that overrides :meth:`read`, or a fault, gets one :meth:`read` per
        conversion)."""
        if type(self).read is not VirtualSensors.read or self.faults:
            return super().read_burst(channel, count)
        try:
            value = self.values[channel]  # what read() does, without the call
        except KeyError:
            raise HalError(f"this board has no sensor channel {channel!r}") from None
        if isinstance(value, tuple):
            raise HalError(f"sensor {channel!r} is not a scalar")
        return value * count

    def read_bursts(self, channels: Sequence[str], count: int) -> list[int]:
        """:meth:`read_burst` of each channel, in one call (the phalanges' taxel scans)."""
        if (type(self).read is not VirtualSensors.read
                or type(self).read_burst is not VirtualSensors.read_burst or self.faults):
            return super().read_bursts(channels, count)
        values = self.values
        totals = []
        for channel in channels:
            try:
                value = values[channel]
            except KeyError:
                raise HalError(f"this board has no sensor channel {channel!r}") from None
            if isinstance(value, tuple):
                raise HalError(f"sensor {channel!r} is not a scalar")
            totals.append(value * count)
        return totals

    # --- plant side (each named setter checks and stores itself, without a nested call:
    # the arm plant calls some every tick)

    def set_input(self, channel: str, value: int | tuple[int, ...]) -> None:
        """Channel ``channel`` reads ``value`` from now on (the board must have it)."""
        values = self.values
        if channel not in values:
            _no_channel(channel)
        if self.channel_watchers and values[channel] != value:
            values[channel] = value
            self._changed(channel)
        else:
            values[channel] = value

    def watch_series(self, prefix: str, before_change: Callable[[], None] | None) -> bool:
        if before_change is None:
            self.watchers.pop(prefix, None)
        else:
            self.watchers[prefix] = before_change
        return True

    def watch_channel(self, channel: str, on_change: Callable[[], None] | None) -> bool:
        if on_change is None:
            self.channel_watchers.pop(channel, None)
        else:
            self.channel_watchers[channel] = on_change
        return True

    def _changed(self, channel: str) -> None:
        """Scalar ``channel`` reads differently now: its watcher (:meth:`watch_channel`)."""
        on_change = self.channel_watchers.get(channel)
        if on_change is not None:
            on_change()

    def announce_change(self, channel: str) -> None:
        """``channel`` is about to read differently (a fault switched on or off): whoever
        watches its series (:meth:`watch_series`) reads what is due first, and its channel
        watcher (:meth:`watch_channel`) is told."""
        if self.channel_watchers:
            self._changed(channel)
        if self.watchers:
            before_change = self.watchers.get(channel.rstrip("0123456789"))
            if before_change is not None:
                before_change()

    def _set_series(self, keys: tuple[str, ...], counts: Sequence[int]) -> None:
        values, n = self.values, len(counts)
        if n > _SERIES_LENGTH or (n and keys[n - 1] not in values) or keys[n] in values:
            raise HalError(f"this board has no series of {n} {keys[0][:-1]!r} channels")
        if self.watchers:
            before_change = self.watchers.get(keys[0][:-1])
            if before_change is not None:
                before_change()
        values.update(zip(keys, counts, strict=False))  # keys run past the series

    def set_accel(self, x: int, y: int, z: int) -> None:
        """Accelerometer, board axes (counts, ≈ 1 mg each)."""
        values = self.values
        if "accel" not in values:
            _no_channel("accel")
        values["accel"] = (x, y, z)

    def set_mag(self, x: int, y: int, z: int) -> None:
        """Magnetometer, board axes (counts)."""
        values = self.values
        if "mag" not in values:
            _no_channel("mag")
        values["mag"] = (x, y, z)

    def set_gyro(self, x: int, y: int, z: int) -> None:
        """Gyroscope, board axes (counts, 0.01 °/s each)."""
        values = self.values
        if "gyro" not in values:
            _no_channel("gyro")
        values["gyro"] = (x, y, z)

    def set_taxels(self, counts: Sequence[int]) -> None:
        """Every taxel ``taxel0`` … of the board, in order (ADC counts)."""
        self._set_series(_TAXEL_KEYS, counts)

    def set_strain(self, counts: int) -> None:
        """Strain gauge bridge (24-bit signed ADC counts)."""
        values = self.values
        if "strain" not in values:
            _no_channel("strain")
        if self.channel_watchers and values["strain"] != counts:
            values["strain"] = counts
            self._changed("strain")
        else:
            values["strain"] = counts

    def set_temperature(self, decidegrees: int) -> None:
        """The board's one temperature sensor ``temperature`` (0.1 °C; the arm nodes)."""
        values = self.values
        if "temperature" not in values:
            _no_channel("temperature")
        if self.channel_watchers and values["temperature"] != decidegrees:
            values["temperature"] = decidegrees
            self._changed("temperature")
        else:
            values["temperature"] = decidegrees

    def set_temperatures(self, decidegrees: Sequence[int]) -> None:
        """Every temperature channel ``temperature0`` … of the board, in order (0.1 °C)."""
        self._set_series(_TEMPERATURE_KEYS, decidegrees)

    def set_thermistors(self, counts: Sequence[int]) -> None:
        """Every thermistor ``thermistor0`` … of the board, in order (ADC counts)."""
        self._set_series(_THERMISTOR_KEYS, counts)

    def set_supply_mv(self, millivolts: int) -> None:
        """The board's supply (bus) voltage (mV)."""
        values = self.values
        if "supply_mv" not in values:
            _no_channel("supply_mv")
        if self.channel_watchers and values["supply_mv"] != millivolts:
            values["supply_mv"] = millivolts
            self._changed("supply_mv")
        else:
            values["supply_mv"] = millivolts

    def set_pot(self, units: int) -> None:
        """Servo potentiometer (0..1023 over 300°)."""
        values = self.values
        if "pot" not in values:
            _no_channel("pot")
        if self.channel_watchers and values["pot"] != units:
            values["pot"] = units
            self._changed("pot")
        else:
            values["pot"] = units

    def set_load(self, units: int) -> None:
        """Servo load (1/1023 of the maximum torque, signed, + = counter-clockwise)."""
        values = self.values
        if "load" not in values:
            _no_channel("load")
        if self.channel_watchers and values["load"] != units:
            values["load"] = units
            self._changed("load")
        else:
            values["load"] = units


def _no_channel(channel: str) -> None:
    raise HalError(f"this board has no sensor channel {channel!r}")


@mypyc_attr(allow_interpreted_subclasses=True)
class VirtualWatchdog(hal.Watchdog):
    """Calls ``on_expire`` when not kicked within the timeout."""

    def __init__(self, clock: VirtualClock, on_expire: Callable[[], None]) -> None:
        self.clock = clock
        self.on_expire = on_expire
        self.timeout_us = 0
        self._timer: TimerHandle | None = None
        self.expired = 0

    def start(self, timeout_us: int) -> None:
        self.timeout_us = int(timeout_us)
        self.kick()

    def kick(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self.timeout_us:
            self._timer = self.clock.call_later(self.timeout_us, self._expire)

    def _expire(self) -> None:
        self.expired += 1
        self.on_expire()


@mypyc_attr(native_class=False, allow_interpreted_subclasses=True)  # a plain Python class, as Hal
class VirtualHal(hal.Hal):
    """A whole board's HAL in memory.

    ``uarts`` and ``power_switches`` name the board's peripherals; ``motors`` and the
    stepper/encoder are present when asked for.  ``on_reset`` is set by the
    :class:`~firmware_py.mcu.Mcu` that runs on this HAL.
    """

    clock: VirtualClock
    flash: VirtualFlash
    sensors: VirtualSensors
    watchdog: VirtualWatchdog

    def __init__(
        self,
        scheduler: Scheduler,
        uarts: dict[str, int] | None = None,
        power_switches: tuple[str, ...] = (),
        motors: int = 0,
        stepper: bool = False,
        encoder: bool = False,
        can: bool = False,
    ) -> None:
        self.scheduler = scheduler
        self.clock = VirtualClock(scheduler)
        self.flash = VirtualFlash(scheduler)
        self.sensors = VirtualSensors()
        self.uarts = {n: VirtualUart(scheduler, b, n) for n, b in (uarts or {}).items()}
        self.power_switches = {n: VirtualPowerSwitch() for n in power_switches}
        self.motors = [VirtualMotor() for _ in range(motors)]
        self._stepper = VirtualStepper(scheduler) if stepper else None
        self._encoder = VirtualEncoder() if encoder else None
        self._can = VirtualCan(scheduler) if can else None
        self.on_reset: Callable[[], None] | None = None
        self.watchdog = VirtualWatchdog(self.clock, self.reset)
        self.resets = 0

    def uart(self, name: str) -> VirtualUart:
        try:
            return self.uarts[name]
        except KeyError:
            raise HalError(f"this board has no UART {name!r}") from None

    def power(self, name: str) -> VirtualPowerSwitch:
        try:
            return self.power_switches[name]
        except KeyError:
            raise HalError(f"this board has no power switch {name!r}") from None

    def motor(self, index: int) -> VirtualMotor:
        if not 0 <= index < len(self.motors):
            raise HalError(f"this board has no motor {index}")
        return self.motors[index]

    def can(self) -> VirtualCan:
        if self._can is None:
            raise HalError("this board has no CAN controller")
        return self._can

    def stepper(self) -> VirtualStepper:
        if self._stepper is None:
            raise HalError("this board has no stepper")
        return self._stepper

    def encoder(self) -> VirtualEncoder:
        if self._encoder is None:
            raise HalError("this board has no encoder")
        return self._encoder

    def halt(self, restart_clock: bool) -> None:
        self.clock.cancel_all()
        if restart_clock:
            self.clock.restart()
        for uart in self.uarts.values():
            uart.set_receiver(None)
        for motor in self.motors:
            motor.set_duty(0.0)
            motor.set_enabled(False)
            motor.set_brake(False)
            motor.set_hall_interrupt(None)
        for switch in self.power_switches.values():
            switch.set_current_interrupt(None)
        self.sensors.watchers.clear()
        self.sensors.channel_watchers.clear()
        if self._stepper is not None:
            self._stepper.set_step_rate(0.0)
            self._stepper.set_current(0)
        if self._encoder is not None:
            self._encoder.set_index_callback(None)
            self._encoder.set_change_interrupt(None)
        if self._can is not None:
            self._can.set_receiver(None)
        self.watchdog.timeout_us = 0
        if restart_clock:
            for switch in self.power_switches.values():
                switch.set(0)

    def reset(self) -> None:
        self.resets += 1
        if self.on_reset is not None:
            self.on_reset()
