"""The hardware abstraction layer: the only door between firmware and the world.

Firmware sees a :class:`Hal`: a clock with timers, UARTs with automatic transmit-enable,
power switches, flash with the SAM3S's constraints, sensors, motor drivers, a stepper pulse
generator with its counter, a quadrature encoder with index capture, a watchdog and reset.
:mod:`firmware_py.sim.virtual_hal` implements it in memory for tests; the emulator implements
it on the MuJoCo plant and the bus fabric.  Firmware never imports MuJoCo, pyserial or the
emulator.

Units: time in integer microseconds, currents in mA, voltages in mV, accelerations in
accelerometer counts (≈ 1 mg), positions in the sensor's own counts.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Protocol

from mypy_extensions import mypyc_attr

from firmware_py.errors import HalError
from protocol.image import FLASH

ReceiveCallback = Callable[[bytes, int], None]
"""Called with the bytes received and their arrival time (µs)."""


class Timer(Protocol):
    """A scheduled callback."""

    def cancel(self) -> None:
        """Never fire again."""

    @property
    def active(self) -> bool:
        """Still scheduled."""


@mypyc_attr(allow_interpreted_subclasses=True)
class Clock(ABC):
    """Monotonic time and timers (a periodic tick, one-shot timeouts)."""

    @abstractmethod
    def now_us(self) -> int:
        """Microseconds since the node was powered (monotonic)."""

    @abstractmethod
    def call_later(self, delay_us: int, callback: Callable[[], None]) -> Timer:
        """One-shot timer."""

    @abstractmethod
    def call_every(self, period_us: int, callback: Callable[[], None]) -> Timer:
        """Periodic timer (the 1 kHz control tick is ``call_every(1000, …)``)."""


@mypyc_attr(allow_interpreted_subclasses=True)
class Uart(ABC):
    """A UART on an RS-485 transceiver whose transmit-enable follows the transmitter.

    :meth:`send` drives the line for the characters' wire time; on a half-duplex bus a
    node that talks while another does collides, and both frames are corrupted.
    """

    #: Bits per second on the line.
    baud: int = 2_000_000

    @abstractmethod
    def wire_time_us(self, n_bytes: int) -> int:
        """Time ``n_bytes`` occupy the line at this UART's baud and character framing (µs,
        rounded up): the UART knows its own timing."""

    @abstractmethod
    def send(self, data: bytes) -> None:
        """Queue ``data`` for transmission (sent back to back after anything queued)."""

    @abstractmethod
    def set_receiver(self, callback: ReceiveCallback | None) -> None:
        """Deliver received bytes to ``callback`` (None: discard them)."""

    @property
    @abstractmethod
    def tx_busy(self) -> bool:
        """True while bytes are still on their way out."""


@mypyc_attr(allow_interpreted_subclasses=True)
class PowerSwitch(ABC):
    """A switched supply for a downstream bus (finger power, phalange power).

    States: 0 off, 1 low (current-limited), 2 full; on/off switches use 0 and 2.
    """

    @abstractmethod
    def set(self, state: int) -> None:
        """Switch to ``state``."""

    @property
    @abstractmethod
    def state(self) -> int:
        """The commanded state."""

    @abstractmethod
    def current_ma(self) -> int:
        """Measured load current (mA)."""

    def set_current_interrupt(self, callback: Callable[[], None] | None) -> bool:
        """Call ``callback`` whenever the measured load current changes (the current
        sense's window comparator; None: off).  False on a board without one (the
        callback is never called: the firmware must poll :meth:`current_ma`)."""
        return False


@mypyc_attr(native_class=False, allow_interpreted_subclasses=True)  # its emulation is a plain Python class
class Flash(ABC):
    """Flash with SAM3S rules: 256-byte pages, erase before write, lockable regions.

    Writing a page takes time: :meth:`write_page` returns at once and calls ``done`` with
    True when the page is programmed (False if it failed).  A locked page never changes.
    A power cut during a write leaves that page erased or partly programmed.
    """

    page_size: int = FLASH.page_size
    page_count: int = FLASH.page_count
    base_address: int = FLASH.flash_base

    @abstractmethod
    def read(self, address: int, length: int) -> bytes:
        """Bytes at an absolute address."""

    def read_page(self, page: int) -> bytes:
        """One whole page."""
        return self.read(self.base_address + page * self.page_size, self.page_size)

    @abstractmethod
    def write_page(self, page: int, data: bytes, done: Callable[[bool], None]) -> None:
        """Erase and program one page (``data`` is exactly one page)."""

    @property
    @abstractmethod
    def busy(self) -> bool:
        """A write is in progress."""

    @abstractmethod
    def lock(self, first_page: int, count: int) -> None:
        """Lock pages against writing until power is removed (the SAM3S lock bits)."""


@mypyc_attr(allow_interpreted_subclasses=True)
class MotorDriver(ABC):
    """One brushless motor's bridge (L6229-like), commanded by signed PWM duty."""

    @abstractmethod
    def set_duty(self, duty: float) -> None:
        """Signed duty cycle in −1..1 (clamped)."""

    @abstractmethod
    def set_enabled(self, enabled: bool) -> None:
        """Enable the bridge (disabled: coasting)."""

    @abstractmethod
    def set_brake(self, brake: bool) -> None:
        """Short the windings (braking)."""

    @abstractmethod
    def hall_state(self) -> int:
        """The three hall sensor bits, 0..7."""

    @abstractmethod
    def current_ma(self) -> int:
        """Measured motor current (mA)."""

    def set_hall_interrupt(self, callback: Callable[[], None] | None) -> bool:
        """Call ``callback`` whenever the hall state changes (a pin-change interrupt on the
        three hall inputs; None: off).  False on a board without one (the callback is
        never called: the firmware must poll :meth:`hall_state`)."""
        return False


@mypyc_attr(allow_interpreted_subclasses=True)
class Stepper(ABC):
    """A stepper driver fed by a hardware pulse generator with a hardware step counter."""

    @abstractmethod
    def set_step_rate(self, steps_per_s: float) -> None:
        """Signed step rate (microsteps/s); the generator keeps pulsing until changed."""

    @abstractmethod
    def step_count(self) -> int:
        """Microsteps emitted since power-up, signed (the hardware counter)."""

    @abstractmethod
    def set_current(self, milliamps: int) -> None:
        """Phase current (mA); 0 de-energises the motor."""


@mypyc_attr(allow_interpreted_subclasses=True)
class Encoder(ABC):
    """A joint encoder with an index pulse whose event the hardware timestamps."""

    @abstractmethod
    def count(self) -> int:
        """Encoder counts since power-up (0.036° per count on the arm)."""

    @abstractmethod
    def set_index_callback(self, callback: Callable[[int], None] | None) -> None:
        """Called at each index pulse with the encoder count at that instant."""

    def set_change_interrupt(self, callback: Callable[[], None] | None) -> bool:
        """Call ``callback`` whenever the count changes (the quadrature decoder's
        count-change interrupt; None: off).  False on a board without one (the callback is
        never called: the firmware must poll :meth:`count`)."""
        return False


CanReceiveCallback = Callable[[int, bytes, int], None]
"""Called with a CAN identifier, the data (≤ 8 bytes) and the arrival time (µs)."""


@mypyc_attr(allow_interpreted_subclasses=True)
class CanController(ABC):
    """A CAN 2.0 controller (standard 11-bit identifiers, ≤ 8 data bytes)."""

    @abstractmethod
    def send(self, arbitration_id: int, data: bytes) -> None:
        """Queue one CAN frame."""

    @abstractmethod
    def set_receiver(self, callback: CanReceiveCallback | None) -> None:
        """Deliver received CAN frames to ``callback``."""


@mypyc_attr(allow_interpreted_subclasses=True)
class Sensors(ABC):
    """Analog and digital sensors, read on demand."""

    @abstractmethod
    def read(self, channel: str) -> int | tuple[int, ...]:
        """Read a sensor channel by name, in its own counts.

        Channels used by the hand firmware: ``accel`` and ``mag`` (3-tuples, ≈1 mg/count),
        ``taxel0`` …, ``strain`` (24-bit signed), ``thermistor0`` …, ``supply_mv``,
        ``temperature0`` … (0.1 °C), ``gyro`` (3-tuple), ``pot`` (servo potentiometer 0..1023).
        Raises :class:`HalError` for a channel the board does not have.
        """

    def read_burst(self, channel: str, count: int) -> int:
        """The sum of ``count`` back-to-back conversions of scalar ``channel`` (an ADC
        burst, for averaging).  Raises :class:`HalError` for a vector channel."""
        total = 0
        for _ in range(count):
            value = self.read(channel)
            if isinstance(value, tuple):
                raise HalError(f"sensor {channel!r} is not a scalar")
            total += value
        return total

    def read_bursts(self, channels: Sequence[str], count: int) -> list[int]:
        """:meth:`read_burst` of each of ``channels`` in turn (a scan of several inputs)."""
        return [self.read_burst(channel, count) for channel in channels]

    def watch_series(self, prefix: str, before_change: Callable[[], None] | None) -> bool:
        """Call ``before_change`` just before the numbered series ``prefix`` (``"taxel"``:
        ``taxel0`` …) takes new values, while it still reads the old ones (None: stop).

        An emulation aid, not a peripheral: a program that reads such inputs at fixed
        instants may then read them late, exactly as they were at those instants, instead
        of waking at each one.  False where the inputs change unannounced (real hardware):
        the program must read them when due.
        """
        return False

    def watch_channel(self, channel: str, on_change: Callable[[], None] | None) -> bool:
        """Call ``on_change`` whenever scalar ``channel`` may read differently from before
        (an ADC window comparator's interrupt; None: stop).  False where the board has no
        such interrupt: the program must poll :meth:`read`."""
        return False


@mypyc_attr(allow_interpreted_subclasses=True)
class Watchdog(ABC):
    """Resets the node when not kicked in time."""

    @abstractmethod
    def start(self, timeout_us: int) -> None:
        """Arm with a timeout (µs)."""

    @abstractmethod
    def kick(self) -> None:
        """Restart the timeout."""


@mypyc_attr(native_class=False, allow_interpreted_subclasses=True)  # implementations narrow its attributes' types
class Hal(ABC):
    """Everything a node's firmware may touch.  Peripherals a board lacks raise HalError."""

    clock: Clock
    flash: Flash
    sensors: Sensors
    watchdog: Watchdog

    @abstractmethod
    def uart(self, name: str) -> Uart:
        """A UART by name: ``host``, ``finger0``…``finger3``, ``pogo``, ``tendon``, ``bus``."""

    @abstractmethod
    def power(self, name: str) -> PowerSwitch:
        """A power switch by name: ``finger0``…``finger3``, ``phalange``."""

    def motor(self, index: int) -> MotorDriver:
        """Motor driver ``index`` (0-based)."""
        raise HalError(f"this board has no motor {index}")

    def can(self) -> CanController:
        """The CAN controller."""
        raise HalError("this board has no CAN controller")

    def stepper(self) -> Stepper:
        """The stepper driver."""
        raise HalError("this board has no stepper")

    def encoder(self) -> Encoder:
        """The joint encoder."""
        raise HalError("this board has no encoder")

    @abstractmethod
    def reset(self) -> None:
        """Reset the microcontroller (the firmware stops; the bootloader starts again)."""

    @abstractmethod
    def halt(self, restart_clock: bool) -> None:
        """Stop the CPU: cancel every timer, detach every receiver and index callback, and
        put outputs in their reset state (motors disabled, steppers stopped, power switches
        off).  With ``restart_clock`` the node's uptime starts again from zero.  Used by the
        :class:`~firmware_py.mcu.Mcu` on reset, power loss, and the jump to an application
        (which keeps the clock and the power switches: ``restart_clock=False``)."""
