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

**Where each part is.**  This module holds the board (:class:`VirtualHal`) and the MCU's own
parts every board has: its clock and timers (:class:`VirtualClock`, times in µs since the
node's power-up), its watchdog (:class:`VirtualWatchdog`) and its flash
(:class:`VirtualFlash`, page writes of ``PAGE_WRITE_US`` µs).  The rest is declared by what
it is, and importable from here as well:

* :mod:`firmware_py.sim.virtual_ports`: UARTs and CAN controllers (``VirtualUart``,
  ``VirtualCan``, ``SentChunk``, ``connect``, ``line_delivers``);
* :mod:`firmware_py.sim.virtual_drives`: ``VirtualMotor``, ``VirtualStepper``,
  ``VirtualEncoder``, ``VirtualPowerSwitch``;
* :mod:`firmware_py.sim.virtual_sensors`: ``VirtualSensors``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

from mypy_extensions import mypyc_attr

from firmware_py import hal
from firmware_py.errors import FlashMemoryError, HalError
from firmware_py.scheduler import Scheduler, TimerHandle
from firmware_py.sim.virtual_drives import (
    VirtualEncoder,
    VirtualMotor,
    VirtualPowerSwitch,
    VirtualStepper,
)
from firmware_py.sim.virtual_ports import (
    SentChunk,
    VirtualCan,
    VirtualUart,
    connect,
    line_delivers,
)
from firmware_py.sim.virtual_sensors import VirtualSensors

__all__ = [
    "PAGE_WRITE_US", "VirtualClock", "VirtualFlash", "VirtualHal", "VirtualWatchdog",
    # declared by what they are, and offered here too (the import users know)
    "SentChunk", "VirtualCan", "VirtualUart", "connect", "line_delivers",
    "VirtualEncoder", "VirtualMotor", "VirtualPowerSwitch", "VirtualStepper",
    "VirtualSensors",
]

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
        return self.scheduler.now - self.epoch_us

    def _track(self, handle: TimerHandle) -> TimerHandle:
        timers = self._timers
        timers.append(handle)
        if len(timers) > self._prune_at:
            self._prune()
        return handle

    def _prune(self) -> None:
        """Forget finished timers (amortised O(1): the list doubles between prunes)."""
        self._timers = timers = [t for t in self._timers if t.callback is not None]
        self._prune_at = max(16, 2 * len(timers))

    def call_later(self, delay_us: int, callback: Callable[[], None]) -> TimerHandle:
        # _track(), written out: every frame the firmware sends comes this way.
        handle = self.scheduler.call_later(delay_us, callback)
        timers = self._timers
        timers.append(handle)
        if len(timers) > self._prune_at:
            self._prune()
        return handle

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
