"""Faults of the arm: external torques, a drifting spring, a missed index pulse, RX-64
overheat and overload, a duplicate servo ID, a sagging supply.

They act through the plant (:meth:`~hil_emulator.arm.plant.ArmPlant.push`,
:meth:`~hil_emulator.arm.plant.ArmPlant.set_stiffness`), the joint encoders' index line
(:class:`~firmware_py.sim.virtual_drives.VirtualEncoder`), the nodes' sensors
(:class:`~hil_emulator.faults.nodes.SensorFault`) and the arm's line
(:meth:`~hil_emulator.lines.rs485_bus.Rs485Bus.attach`: a second node).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import hil_emulator.faults.targets as targets
from firmware_py.sim.virtual_drives import VirtualEncoder
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.faults.base import Fault
from hil_emulator.faults.nodes import SensorFault
from protocol.topology import SERVO_IDS, STEPPER_IDS

if TYPE_CHECKING:
    from hil_emulator.arm.plant import ArmPlant
    from hil_emulator.emulator import Emulator


@dataclass
class ArmPush(Fault):
    """An external torque ``torque_nm`` (N·m, + = positive joint direction) on joint
    ``joint`` (0..6 = J1..J7); beyond a stepper's holding torque it slips and its node
    latches SLIP."""

    name = "arm_push"
    entry_point = "plant force"
    summary = "an external torque on an arm joint (a stepper slips beyond its holding torque)"
    joint: int = 0  #: 0..6 = J1..J7
    torque_nm: float = 5.0  #: N·m

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        _arm_plant(emulator).push(self.joint, self.torque_nm)

    def clear(self, emulator: Emulator) -> None:
        _arm_plant(emulator).push(self.joint, 0.0)


@dataclass
class MissedIndex(Fault):
    """Stepper joint ``joint`` (0..3 = J1..J4) misses its index pulses (dirty code wheel):
    the node never latches the mark while the fault lasts."""

    name = "missed_index"
    entry_point = "node"
    summary = "a stepper joint's encoder index pulse missed"
    joint: int = 0  #: 0..3 = J1..J4

    def __post_init__(self) -> None:
        if not 0 <= self.joint < len(STEPPER_IDS):
            raise ValueError(f"joint {self.joint} is not a stepper joint 0..3")

    def _encoder(self, emulator: Emulator) -> VirtualEncoder:
        return targets.node(emulator, f"arm.{STEPPER_IDS[self.joint]}").hal.encoder()

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        encoder = self._encoder(emulator)
        encoder.index_blind = True
        encoder.missed = 0

    def clear(self, emulator: Emulator) -> None:
        self._encoder(emulator).index_blind = False


@dataclass
class ServoOverheat(Fault):
    """RX-64 ``servo`` (Dynamixel id 5..7) reads ``temperature_c`` °C: beyond its limit it
    sets OVERHEATING and, as its alarm shutdown says, drops torque."""

    name = "servo_overheat"
    entry_point = "node"
    summary = "an RX-64 overheating (alarm shutdown)"
    servo: int = 5  #: Dynamixel id 5..7
    temperature_c: float = 95.0  #: °C
    _sensor: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.servo not in SERVO_IDS:
            raise ValueError(f"servo {self.servo} is not an RX-64 id {SERVO_IDS}")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        self._sensor = SensorFault(node=f"arm.{self.servo}", channel="temperature",
                                   mode="stuck", value=int(round(self.temperature_c * 10)))
        self._sensor.apply(emulator, rng)

    def clear(self, emulator: Emulator) -> None:
        if self._sensor is not None:
            self._sensor.clear(emulator)


@dataclass
class ServoOverload(Fault):
    """RX-64 ``servo`` (id 5..7) reads a load of ``load`` (1/1023 of stall): at or beyond
    its torque limit for long it sets OVERLOAD and drops torque."""

    name = "servo_overload"
    entry_point = "node"
    summary = "an RX-64 overloaded (alarm shutdown)"
    servo: int = 5  #: Dynamixel id 5..7
    load: int = 1023  #: 1/1023 of stall torque
    _sensor: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.servo not in SERVO_IDS:
            raise ValueError(f"servo {self.servo} is not an RX-64 id {SERVO_IDS}")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        self._sensor = SensorFault(node=f"arm.{self.servo}", channel="load", mode="stuck",
                                   value=self.load)
        self._sensor.apply(emulator, rng)

    def clear(self, emulator: Emulator) -> None:
        if self._sensor is not None:
            self._sensor.clear(emulator)


@dataclass
class SupplySag(Fault):
    """The arm's supply sags to ``supply_mv`` (mV) at every node: below a node's minimum it
    reports INPUT_VOLTAGE."""

    name = "supply_sag"
    entry_point = "node"
    summary = "the arm's supply sagging (input voltage alarms)"
    supply_mv: int = 7_000  #: mV at every arm node
    _sensors: list[SensorFault] = field(default_factory=list, init=False, repr=False)

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        self._sensors = [SensorFault(node=f"arm.{i}", channel="supply_mv", mode="stuck",
                                     value=self.supply_mv) for i in (*STEPPER_IDS, *SERVO_IDS)]
        for s in self._sensors:
            s.apply(emulator, rng)

    def clear(self, emulator: Emulator) -> None:
        for s in self._sensors:
            s.clear(emulator)
        self._sensors = []


@dataclass
class SpringDrift(Fault):
    """The polyurethane spring of stepper joint ``joint`` (0..3 = J1..J4) drifts: its
    stiffness moves linearly from nominal to ``final_fraction`` × nominal over ``drift_s``
    and stays there (updated every ``update_us``).  The same load then deflects the coupling
    by ``τ / k``, so the host's torque estimate (nominal stiffness × deflection) drifts by
    ``1 / final_fraction``.  Cleared, the nominal stiffness is back."""

    name = "spring_drift"
    entry_point = "plant force"
    summary = "a series-elastic spring's stiffness drifting over time (arm plant)"
    joint: int = 1  #: 0..3 = J1..J4
    final_fraction: float = 0.5  #: stiffness at the end of the drift / nominal
    drift_s: float = 1.0  #: s from nominal to the final stiffness (linear)
    update_us: int = 10_000  #: µs between stiffness updates
    _nominal: float = field(default=0.0, init=False, repr=False)
    _timer: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.joint < len(STEPPER_IDS):
            raise ValueError(f"joint {self.joint} is not a stepper joint 0..3")
        if not self.final_fraction > 0.0:
            raise ValueError(f"final_fraction {self.final_fraction} must be positive")
        if self.drift_s <= 0.0 or self.update_us <= 0:
            raise ValueError("drift_s and update_us must be positive")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        plant = _arm_plant(emulator)
        self._nominal = float(plant.stiffness[self.joint])
        scheduler = emulator.scheduler
        start_us = scheduler.now_us()

        def drift() -> None:
            done = min(1.0, (scheduler.now_us() - start_us) / (self.drift_s * 1e6))
            fraction = 1.0 + (self.final_fraction - 1.0) * done
            plant.set_stiffness(self.joint, self._nominal * fraction)
            if done >= 1.0 and self._timer is not None:
                self._timer.cancel()

        self._timer = scheduler.call_every(self.update_us, drift)

    def clear(self, emulator: Emulator) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        _arm_plant(emulator).set_stiffness(self.joint, self._nominal)


@dataclass
class DuplicateServoId(Fault):
    """A second RX-64 on the arm's line answers with servo ``servo``'s ID (5..7): a spare
    configured as that servo (its control table copied) plugged into the bus.  Both hear
    every request and reply after the same return delay, so their replies collide on the
    half-duplex line and the host reads garbage or nothing; cleared, the spare is unplugged."""

    name = "duplicate_servo_id"
    entry_point = "node"
    summary = "two RX-64s with the same ID on the arm bus (their replies collide)"
    servo: int = 5  #: Dynamixel id 5..7
    _spare: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.servo not in SERVO_IDS:
            raise ValueError(f"servo {self.servo} is not an RX-64 id {SERVO_IDS}")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        from firmware_py.sim.boards import make_arm_node
        from protocol.image import BoardType

        original = targets.node(emulator, f"arm.{self.servo}")
        assert emulator.arm is not None and original.app is not None
        hal, app = make_arm_node(emulator.scheduler, BoardType.RX64, self.servo)
        original.app.sync_image()
        app.image[:] = original.app.image  # configured exactly as the servo it duplicates
        app.reload_registers()
        app._apply_bus_settings()
        hal.sensors.values.update(original.hal.sensors.values)  # at rest where it was
        uart = hal.uart("bus")
        uart.keep_sent = False
        emulator.arm.bus.attach(uart, f"id{self.servo}-duplicate")
        self._spare = hal

    def clear(self, emulator: Emulator) -> None:
        if self._spare is not None and emulator.arm is not None:
            emulator.arm.bus.detach(self._spare.uart("bus"))
            self._spare.halt(restart_clock=False)
            self._spare = None


def _arm_plant(emulator: Emulator) -> ArmPlant:
    if emulator.arm_plant is None:
        raise EmulatorConfigError("arm faults on the plant need the arm with physics")
    return emulator.arm_plant
