"""The virtual HAL's drives: motor bridges, the stepper, the encoder and power switches.

Each part has the firmware's side (:mod:`firmware_py.hal`) and a plant side, which the
emulator's plant (or a test) uses to read what the firmware commands and to drive what the
hardware senses:

* :class:`VirtualMotor`: an H-bridge with hall sensors and current sense; reads the signed
  duty (−1..1), the bridge enable and the brake; drives the hall state (0..7) and the winding
  current (mA);
* :class:`VirtualStepper`: a step-pulse generator whose count integrates the commanded rate
  (microsteps/s) exactly over the scheduler's time; reads the position (microsteps,
  fractional), the rate and the phase current (mA);
* :class:`VirtualEncoder`: a quadrature reader whose count (counts since power-up) the plant
  sets and whose index mark it pulses;
* :class:`VirtualPowerSwitch`: a load switch (state 0 off, 1 low (current-limited), 2 full)
  whose downstream load (mA) the plant sets.

They run in the emulator's 1 kHz tick for every node: each plant-side method is one attribute
read or write (see :mod:`firmware_py.sim.virtual_hal` on reading those attributes directly).
"""

from __future__ import annotations

from collections.abc import Callable

from mypy_extensions import mypyc_attr

from firmware_py import hal
from firmware_py.errors import HalError
from firmware_py.scheduler import Scheduler


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
        now = self.scheduler.now
        self._count0 = self._count0 + self.rate * (now - self._t0) / 1e6
        self._t0 = now
        self.rate = float(steps_per_s)

    def step_count(self) -> int:
        return int(self._count0 + self.rate * (self.scheduler.now - self._t0) / 1e6)

    def set_current(self, milliamps: int) -> None:
        self.current = int(milliamps)

    # --- plant side

    def position_steps(self) -> float:
        """Microsteps emitted so far, exactly (fractional): the rotor's commanded position,
        which :meth:`step_count` truncates.  Positive steps turn the shaft positive."""
        return self._count0 + self.rate * (self.scheduler.now - self._t0) / 1e6

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
