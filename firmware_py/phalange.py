"""The phalange applications: f2 (proximal) and f3 (distal), slaves on a finger's tendon bus.

Each phalange is powered and addressed over the two steel tendons of its finger: the fmcb is
the bus master and a phalange speaks only when spoken to (its own address, never broadcast),
:data:`TURNAROUND_US` after the request ended so the master's transceiver is off the line.

What a phalange measures, and when:

- **Tactile.** One LED/phototransistor taxel per millisecond, :data:`ADC_SAMPLES` ADC reads
  averaged; a full scan takes 6 ms on f2 (6 taxels) and 12 ms on f3 (12 taxels).  The scan
  fills a working array and *publishes* it as a whole when its last taxel is read, so a reply
  never mixes taxels of two scans.  Until the first scan completes the published taxels are 0.
  Where the HAL announces changes of the taxel inputs (``Sensors.watch_series``: the
  emulator's plant does), the scan is one timer per scan: the taxels due before a change
  are read when it is announced, the rest when the scan ends, each as it was in its own
  millisecond (a taxel due at the very microsecond of a change reads the value before it).
- **IMU** (LSM303: accelerometer ±2 g at ≈1 mg/count, magnetometer in its own counts),
  sampled at 100 Hz (:data:`IMU_PERIOD_US`) while powered.  Its power is switched by
  ``f*.imu_power`` and is **on at boot** (the host gets useful data without a set-up step).
  **While it is off, replies carry zeros**, never the last value: an unpowered chip has no
  reading, and zeros cannot be mistaken for a live sample (a resting accelerometer always
  sees gravity).  Switched back on, it delivers its first sample at the next 100 Hz tick.
- **f2 strain gauge** (24-bit signed ADC, clamped to −2²³ … 2²³−1, sign-extended in the
  reply) read on request; **f2 temperatures** are zeros (the board has no thermistors).
- **f3 thermistors** ``thermistor0..3`` in ADC counts, read on request.

Power: the tendons carry the supply and the contact is intermittent.  A node rides through
an interruption shorter than its hold-up time (:data:`HOLD_UP_US`, ≈2 ms of bulk capacitance)
and browns out on a longer one, restarting cleanly from its bootloader when the supply
returns.  :func:`supply_interrupted` (one glitch of known length) and :class:`PowerMonitor`
(supply lost / restored as they happen) model that for the emulator and the fault injector.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, ClassVar, Final, Protocol

from mypy_extensions import mypyc_attr

from firmware_py.errors import HalError
from firmware_py.hal import Hal, Timer, Uart
from firmware_py.hand_node import HandNode, Request
from protocol.framing import encode_frame
from protocol.messages.phalange import F2_TAXELS, F3_TAXELS
from protocol.topology import ADDR_HOST

#: Delay between the end of a request and the start of the reply (µs): the master's
#: RS-485 driver must be off the line before the slave's turns on.
TURNAROUND_US: Final = 20
#: One taxel is lit and read per tick (µs).
TAXEL_PERIOD_US: Final = 1_000
#: ADC conversions averaged per taxel reading.
ADC_SAMPLES: Final = 10
#: IMU sampling period (µs): 100 Hz.
IMU_PERIOD_US: Final = 10_000
#: Time the node keeps running on its bulk capacitance with no supply (µs).
HOLD_UP_US: Final = 2_000

#: Range of the strain gauge's 24-bit signed ADC (counts).
STRAIN_MIN: Final = -(1 << 23)
STRAIN_MAX: Final = (1 << 23) - 1
#: Thermistor channels of f3.
THERMISTORS: Final = 4

_U16_MAX: Final = 0xFFFF
_I16_MIN: Final = -0x8000
_I16_MAX: Final = 0x7FFF


def _clamp(value: int, lo: int, hi: int) -> int:
    return lo if value < lo else hi if value > hi else value


@mypyc_attr(allow_interpreted_subclasses=True)
class _PhalangeApp(HandNode):
    """What f2 and f3 share: tendon-bus slave, tactile scan, IMU, turnaround."""

    #: Number of taxels this phalange scans.
    n_taxels: ClassVar[int] = 0

    def __init__(self, hal: Hal, mcu: object | None = None) -> None:
        super().__init__(hal)
        self.mcu = mcu
        self.uart: Uart = hal.uart("tendon")
        #: The taxels of the last complete scan (ADC counts); what replies carry.
        self.taxels: tuple[int, ...] = (0,) * self.n_taxels
        #: Completed scans since start.
        self.scans = 0
        self._scan_buffer = [0] * self.n_taxels
        self._taxel_channels = tuple(f"taxel{i}" for i in range(self.n_taxels))
        self._next_taxel = 0
        #: When the present scan started (µs, node clock; one timer per scan only).
        self._scan_start_us = 0
        #: IMU supply state (on at boot).
        self.imu_powered = True
        self._accel: tuple[int, int, int] = (0, 0, 0)
        self._mag: tuple[int, int, int] = (0, 0, 0)
        self._timers: list[Timer] = []
        kind = self.node_kind
        self.handle(f"{kind}.tactile", self._on_tactile)
        self.handle(f"{kind}.imu", lambda req: self.imu_fields())
        self.handle(f"{kind}.imu_power", self._on_imu_power)
        self.handle(f"{kind}.temperatures", lambda req: {"temp": list(self.temperatures())})

    # --- program --------------------------------------------------------------------------
    def start(self) -> None:
        """Listen on the tendon bus; start the taxel scan and the IMU sampling."""
        self.listen(self.uart)
        clock = self.hal.clock
        if self.hal.sensors.watch_series("taxel", self._read_due_taxels):
            # One timer per scan; taxel i of the scan is due (i + 1) ms after it starts.
            self._scan_start_us = clock.now_us()
            scan = clock.call_every(self.n_taxels * TAXEL_PERIOD_US, self._end_scan)
        else:
            scan = clock.call_every(TAXEL_PERIOD_US, self._scan_step)
        self._timers = [scan, clock.call_every(IMU_PERIOD_US, self._sample_imu)]
        self._sample_imu()

    def send_reply(self, uart: Uart, msg_type: int, payload: bytes) -> None:
        """Send the reply after the bus turnaround (:data:`TURNAROUND_US`)."""
        self.counters.replies += 1
        frame = encode_frame(ADDR_HOST, msg_type, payload)
        self.hal.clock.call_later(TURNAROUND_US, partial(uart.send, frame))

    # --- sensors --------------------------------------------------------------------------
    def _read_int(self, channel: str) -> int:
        value = self.hal.sensors.read(channel)
        if isinstance(value, tuple):
            raise HalError(f"sensor {channel!r} is not a scalar")
        return int(value)

    def _read_vec3(self, channel: str) -> tuple[int, int, int]:
        value = self.hal.sensors.read(channel)
        if not isinstance(value, tuple) or len(value) != 3:
            raise HalError(f"sensor {channel!r} is not a 3-vector")
        # _clamp(int(v), _I16_MIN, _I16_MAX) of each, without the calls (eight phalanges,
        # 100 times a second); int() only for what is not an int already (it costs more
        # than the rest of this from source).
        x, y, z = value
        if type(x) is not int or type(y) is not int or type(z) is not int:
            x, y, z = int(x), int(y), int(z)
        return (_I16_MIN if x < _I16_MIN else _I16_MAX if x > _I16_MAX else x,
                _I16_MIN if y < _I16_MIN else _I16_MAX if y > _I16_MAX else y,
                _I16_MIN if z < _I16_MIN else _I16_MAX if z > _I16_MAX else z)

    def read_taxel(self, index: int) -> int:
        """Light taxel ``index`` and average :data:`ADC_SAMPLES` conversions (ADC counts)."""
        total = self.hal.sensors.read_burst(self._taxel_channels[index], ADC_SAMPLES)
        value = (total + ADC_SAMPLES // 2) // ADC_SAMPLES
        return 0 if value < 0 else _U16_MAX if value > _U16_MAX else value

    def _scan_step(self) -> None:
        # read_taxel(i), written out: eight phalanges run this 1000 times a second.
        i = self._next_taxel
        total = self.hal.sensors.read_burst(self._taxel_channels[i], ADC_SAMPLES)
        value = (total + ADC_SAMPLES // 2) // ADC_SAMPLES
        self._scan_buffer[i] = 0 if value < 0 else _U16_MAX if value > _U16_MAX else value
        i += 1
        if i == self.n_taxels:
            # Publish the whole scan at once: a reply never mixes two scans.
            self.taxels = tuple(self._scan_buffer)
            self.scans += 1
            i = 0
        self._next_taxel = i

    def _read_due_taxels(self) -> None:
        """The taxel inputs are about to change: read, as they are, the taxels of this
        scan due by now (those read in their own millisecond would have seen this)."""
        due = (self.hal.clock.now_us() - self._scan_start_us) // TAXEL_PERIOD_US
        n = self.n_taxels
        self._read_taxels(due if due < n else n)

    def _end_scan(self) -> None:
        """The last taxel's millisecond: read the taxels not read yet, publish the scan."""
        self._read_taxels(self.n_taxels)
        self.taxels = tuple(self._scan_buffer)
        self.scans += 1
        self._next_taxel = 0
        self._scan_start_us += self.n_taxels * TAXEL_PERIOD_US

    def _read_taxels(self, end: int) -> None:
        """Read taxels ``_next_taxel`` … ``end - 1`` into the scan buffer (as
        :meth:`read_taxel`)."""
        start = self._next_taxel
        if end <= start:
            return
        buffer = self._scan_buffer
        totals = self.hal.sensors.read_bursts(self._taxel_channels[start:end], ADC_SAMPLES)
        i = start
        for total in totals:
            value = (total + ADC_SAMPLES // 2) // ADC_SAMPLES
            buffer[i] = 0 if value < 0 else _U16_MAX if value > _U16_MAX else value
            i += 1
        self._next_taxel = end

    def _sample_imu(self) -> None:
        if not self.imu_powered:
            return
        self._accel = self._read_vec3("accel")
        self._mag = self._read_vec3("mag")

    def imu_fields(self) -> dict[str, Any]:
        """The IMU reply fields: accelerometer (≈mg) and magnetometer (counts); zeros if off."""
        if not self.imu_powered:
            return {"accel": [0, 0, 0], "mag": [0, 0, 0]}
        return {"accel": list(self._accel), "mag": list(self._mag)}

    def temperatures(self) -> tuple[int, int, int, int]:
        """Four thermistor readings (ADC counts); boards without thermistors report zeros."""
        return (0, 0, 0, 0)

    # --- handlers -------------------------------------------------------------------------
    def _on_tactile(self, req: Request) -> dict[str, Any]:
        return {"taxels": list(self.taxels), "imu": self.imu_fields()}

    def _on_imu_power(self, req: Request) -> dict[str, Any]:
        on = bool(req.fields["on"] & 1)
        if on != self.imu_powered:
            self.imu_powered = on
            # A chip that was off has no reading until its first sample after power-up.
            self._accel = (0, 0, 0)
            self._mag = (0, 0, 0)
        return {}


@mypyc_attr(allow_interpreted_subclasses=True)
class F2App(_PhalangeApp):
    """The proximal phalange: 6 taxels, IMU, strain gauge; no thermistors (address 1)."""

    node_kind = "f2"
    n_taxels = F2_TAXELS

    def __init__(self, hal: Hal, mcu: object | None = None) -> None:
        super().__init__(hal, mcu)
        self.handle("f2.strain", lambda req: {"strain": self.read_strain()})

    def read_strain(self) -> int:
        """The strain gauge in counts of its 24-bit signed ADC (clamped to its range)."""
        return _clamp(self._read_int("strain"), STRAIN_MIN, STRAIN_MAX)


@mypyc_attr(allow_interpreted_subclasses=True)
class F3App(_PhalangeApp):
    """The distal phalange: 12 taxels, IMU, four thermistors (address 2)."""

    node_kind = "f3"
    n_taxels = F3_TAXELS

    def temperatures(self) -> tuple[int, int, int, int]:
        """``thermistor0..3`` in ADC counts (clamped to 0..65535)."""
        a, b, c, d = (
            _clamp(self._read_int(f"thermistor{i}"), 0, _U16_MAX) for i in range(THERMISTORS)
        )
        return (a, b, c, d)


# --- power over the tendons -------------------------------------------------------------
class PoweredNode(Protocol):
    """What a supply glitch acts on: a node that can lose and regain power (an Mcu)."""

    def power_off(self) -> None:
        """Supply gone."""

    def power_on(self) -> None:
        """Supply back: the bootloader starts with the clock at zero."""


def supply_interrupted(node: PoweredNode, duration_us: int, hold_up_us: int = HOLD_UP_US
                       ) -> bool:
    """The tendon supply was interrupted for ``duration_us`` µs and is back now.

    Shorter than or equal to ``hold_up_us`` the node rides through on its hold-up
    capacitance and nothing happens; longer, it browns out and restarts (power off, power
    on: the bootloader runs, uptime starts from zero).  Returns True if the node restarted.
    """
    if duration_us <= hold_up_us:
        return False
    node.power_off()
    node.power_on()
    return True


CallLater = Callable[[int, Callable[[], None]], Timer]


class PowerMonitor:
    """Hold-up capacitance and brown-out of one tendon-powered node, live.

    The emulator calls :meth:`supply_lost` when the tendon contact opens and
    :meth:`supply_restored` when it closes again.  ``hold_up_us`` after the loss the node
    browns out (powered off); it powers on again when the supply returns.  ``call_later``
    must be a timer that survives the node's own resets (the bus fabric's scheduler, e.g.
    ``scheduler.call_later``), not the node's HAL clock, whose timers a reset cancels.
    """

    def __init__(self, node: PoweredNode, call_later: CallLater,
                 hold_up_us: int = HOLD_UP_US) -> None:
        self.node = node
        self.hold_up_us = hold_up_us
        self._call_later = call_later
        self._brownout_timer: Timer | None = None
        #: True while the supply is absent.
        self.supply_lost_now = False
        #: True while the node is browned out (unpowered).
        self.browned_out = False
        #: Brown-outs so far (count).
        self.brownouts = 0

    def supply_lost(self) -> None:
        """The supply disappeared: the node runs on its hold-up capacitance."""
        if self.supply_lost_now:
            return
        self.supply_lost_now = True
        self._brownout_timer = self._call_later(self.hold_up_us, self._brown_out)

    def supply_restored(self) -> None:
        """The supply is back: nothing happened, or a browned-out node boots again."""
        if not self.supply_lost_now:
            return
        self.supply_lost_now = False
        if self._brownout_timer is not None:
            self._brownout_timer.cancel()
            self._brownout_timer = None
        if self.browned_out:
            self.browned_out = False
            self.node.power_on()

    def _brown_out(self) -> None:
        self._brownout_timer = None
        if not self.supply_lost_now:
            return
        self.browned_out = True
        self.brownouts += 1
        self.node.power_off()
