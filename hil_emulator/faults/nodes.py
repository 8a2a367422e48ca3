"""Faults of a node: hang, reset, reset storm, a sensor stuck, noisy, biased or misaligned.

They act through the node's HAL (:class:`~firmware_py.sim.virtual_hal.VirtualHal`: ``halt``,
``reset``, its sensors) and never through a branch in the firmware.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

import hil_emulator.faults.targets as targets
from firmware_py.sim.virtual_sensors import VirtualSensors
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.faults.base import Fault

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

SensorValue = int | tuple[int, ...]


@dataclass
class NodeHang(Fault):
    """Node ``node`` hangs: its program stops (timers, receivers, motors off) with no
    watchdog to save it; cleared, it is reset and boots again."""

    name = "node_hang"
    entry_point = "node"
    summary = "a node's program hangs (no watchdog); cleared by a reset"
    node: str = "finger0.fmcb"  #: palm, finger<k>.fmcb|f2|f3, arm.<id>

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        targets.node(emulator, self.node).hal.halt(restart_clock=False)

    def clear(self, emulator: Emulator) -> None:
        targets.node(emulator, self.node).reset()


@dataclass
class NodeReset(Fault):
    """Node ``node`` resets once (brown-out detector, watchdog): a hand node restarts in its
    bootloader, an arm node reboots its application."""

    name = "node_reset"
    entry_point = "node"
    summary = "a node resets once"
    instantaneous = True
    node: str = "finger0.fmcb"  #: palm, finger<k>.fmcb|f2|f3, arm.<id>

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        targets.node(emulator, self.node).reset()


@dataclass
class ResetStorm(Fault):
    """Node ``node`` resets ``resets`` times, ``period_us`` apart (± ``jitter_us`` drawn
    from the seed), starting now."""

    name = "reset_storm"
    entry_point = "node"
    summary = "a node resetting again and again"
    instantaneous = True
    node: str = "finger0.fmcb"  #: palm, finger<k>.fmcb|f2|f3, arm.<id>
    resets: int = 5  #: how many
    period_us: int = 20_000  #: µs between resets
    jitter_us: int = 0  #: up to this much later each (µs)

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        ref = targets.node(emulator, self.node)
        for k in range(self.resets):
            extra = int(rng.integers(0, self.jitter_us + 1)) if self.jitter_us else 0
            emulator.scheduler.call_later(k * self.period_us + extra, ref.reset)


@dataclass
class SensorFault(Fault):
    """Channel ``channel`` of node ``node`` reads wrong: ``stuck`` at ``value``, ``noisy``
    (Gaussian, ``sigma`` counts, drawn per read), ``biased`` by ``bias`` counts, or
    ``misaligned``: a three-axis channel (``accel``, ``gyro``, ``mag``) mounted rotated by
    ``angle_deg`` about ``axis`` (``x``, ``y``, ``z`` or components ``"1,1,0"``, in the
    sensor's frame), so it reads ``R · v`` (rounded to counts) for the true vector ``v``."""

    name = "sensor_fault"
    entry_point = "node"
    summary = "a sensor channel stuck, noisy, biased or misaligned (a rotated mounting)"
    node: str = "finger0.f2"  #: palm, finger<k>.fmcb|f2|f3, arm.<id>
    channel: str = "strain"  #: the HAL's channel name (strain, accel, pot, temperature …)
    mode: Literal["stuck", "noisy", "biased", "misaligned"] = "stuck"
    value: int = 0  #: stuck: the value read (counts)
    sigma: float = 10.0  #: noisy: standard deviation (counts)
    bias: int = 100  #: biased: added (counts)
    angle_deg: float = 10.0  #: misaligned: rotation of the mounting (degrees, right-handed)
    axis: str = "z"  #: misaligned: the rotation axis (x, y, z or "ax,ay,az")
    _key: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self._rotation = rotation_matrix(self.axis, self.angle_deg)

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        sensors = targets.node(emulator, self.node).hal.sensors
        true = sensors.read(self.channel)  # the board must have it
        if self.mode == "misaligned" and not (isinstance(true, tuple) and len(true) == 3):
            raise EmulatorConfigError(f"sensor_fault: channel {self.channel!r} of "
                                      f"{self.node} is not a three-axis vector; a "
                                      "misaligned mounting rotates one")
        rotation = self._rotation

        def shift(value: SensorValue, by: Callable[[], int]) -> SensorValue:
            if isinstance(value, tuple):
                return tuple(v + by() for v in value)
            return value + by()

        def fault(value: SensorValue) -> SensorValue:
            if self.mode == "stuck":
                return tuple(self.value for _ in value) if isinstance(value, tuple) \
                    else self.value
            if self.mode == "biased":
                return shift(value, lambda: self.bias)
            if self.mode == "misaligned":
                assert isinstance(value, tuple)
                x, y, z = value
                return tuple(int(round(r[0] * x + r[1] * y + r[2] * z)) for r in rotation)
            return shift(value, lambda: int(round(rng.normal(0.0, self.sigma))))

        sensors.announce_change(self.channel)  # a program reading it late reads it as it was
        sensors.faults[self.channel] = fault

    def clear(self, emulator: Emulator) -> None:
        sensors: VirtualSensors = targets.node(emulator, self.node).hal.sensors
        if self.channel in sensors.faults:
            sensors.announce_change(self.channel)
            del sensors.faults[self.channel]


def rotation_matrix(axis: str, angle_deg: float) -> tuple[tuple[float, float, float], ...]:
    """The rotation by ``angle_deg`` (degrees, right-handed) about ``axis`` — ``x``, ``y``,
    ``z`` or comma-separated components ``"ax,ay,az"`` (normalised) — as three rows
    (Rodrigues' formula).  Raises :class:`ValueError` for an axis it cannot read."""
    named = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
    try:
        parts = named.get(axis.strip().lower()) or tuple(float(a) for a in axis.split(","))
    except ValueError:
        parts = ()
    norm = math.sqrt(sum(a * a for a in parts)) if len(parts) == 3 else 0.0
    if not (math.isfinite(norm) and norm > 0.0 and math.isfinite(angle_deg)):
        raise ValueError(f"axis {axis!r} is not x, y, z or three components 'ax,ay,az' "
                         f"(not all 0), or angle {angle_deg!r} is not finite")
    ux, uy, uz = (a / norm for a in parts)
    theta = math.radians(angle_deg)
    c, s, t = math.cos(theta), math.sin(theta), 1.0 - math.cos(theta)
    return ((c + ux * ux * t, ux * uy * t - uz * s, ux * uz * t + uy * s),
            (uy * ux * t + uz * s, c + uy * uy * t, uy * uz * t - ux * s),
            (uz * ux * t - uy * s, uz * uy * t + ux * s, c + uz * uz * t))
