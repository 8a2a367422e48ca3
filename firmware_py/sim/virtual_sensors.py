"""The virtual HAL's sensors: every ADC and digital sensor channel of a board, by name.

:class:`VirtualSensors` holds one value per channel the board has (the board's factory,
:mod:`firmware_py.sim.boards`, declares them), in the counts
:meth:`firmware_py.hal.Sensors.read` documents: 3-axis accelerometer (≈ 1 mg a count),
magnetometer and gyroscope (0.01 °/s a count), taxels and thermistors (ADC counts), the strain
bridge (24-bit signed counts), temperatures (0.1 °C), the supply (mV), a servo's potentiometer
(0..1023 over 300°) and load (1/1023 of the maximum torque).  The plant sets them through the
named setters (plant side), which refuse a channel the board lacks; the firmware reads them
(singly, or summed over a burst of conversions) and may ask to hear of a change.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from mypy_extensions import mypyc_attr

from firmware_py import hal
from firmware_py.errors import HalError

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

    # The one-channel setters below are written out each, not through a shared helper: the
    # plant calls them every few ms per board, and in pure Python a call costs more than
    # the work (docs/decisions/emulator-performance-history.md).

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
