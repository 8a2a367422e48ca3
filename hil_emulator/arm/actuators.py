"""The arm's actuators as numbers and formulas: series-elastic stepper joints and RX-64 servos.

:class:`ArmParams` holds every constant of :class:`~hil_emulator.arm.plant.ArmPlant`; the
functions here are pieces of its physics (all torques at the *joint*, N·m; angles rad;
index ``i`` = J1..J4 for the stepper joints).

**Series-elastic coupling** (dissertation §5.4).  Stepper → belt + cable circuit (reduction
``G``) → capstan → two pre-compressed polyurethane tubes → output link.  The capstan angle is

    φ = θ_rotor / G + C · (q_prox − q_start) + φ_start

with ``C`` the constant belt/cable coupling matrix (:attr:`ArmParams.coupling`, zero diagonal:
all belt routes turn about the shoulder-lift axis, so J2 shifts the J3 and J4 capstans, and
the elbow cables twist about the upper-arm roll axis, so J3 shifts the J4 capstan).  The
tubes give, with deflection ``δ = φ − q``,

    τ = k·δ + c·(φ̇ − q̇) + h·z + k·(s − 1)·(δ − clip(δ, ±travel))

— linear stiffness ``k``, viscous damping ``c``, a Dahl hysteresis state ``z`` ∈ [−1, 1]
(the loop of the dissertation's figure 5.6: ``z`` moves exponentially towards
``sign(δ̇)`` over :attr:`ArmParams.hysteresis_width_rad` of deflection) of height ``h``, and
tubes compressed solid beyond ``±travel`` (±4°), stiffness ``s·k`` there.  By virtual work the
cable circuit also loads the joints it is routed around: generalised force ``−Cᵀ·τ``.

**Stepper torque capacity** (a torque–speed curve).  Holding torque at the joint
``k_T · I · G`` (``k_T`` N·m/A at the motor, ``I`` the commanded current) at standstill;
while stepping at ``f`` full steps/s the pull-out torque is

    T_po(f) = k_T · I · G / holding_margin · min(1, f_c / f)

— the maximum moving torque (holding / 1.6: the dissertation's controllers held ~60 % more
than the maximum moving torque) up to the corner ``f_c``, then falling as ``f_c / f``
(constant power); with no current only the detent torque ``G·T_detent`` resists.  A coupling
torque beyond the capacity makes the rotor slip: it slides, transmitting just its capacity
(:func:`deflection_at_torque`), until the torque is back under it, and then re-locks to an
electrical equilibrium, a whole number of electrical periods (4 full steps) from where the
step count puts it — possibly a random few periods further on, as a rotor slowing down does.
The step count then no longer matches the motor.

**RX-64** (directly coupled, 200:1 inside): ``τ = stall · clip(duty − ω/ω₀, ±1)`` with the
stall torque scaled by supply voltage; the back-EMF term ``stall/ω₀`` is realised as MuJoCo
joint damping (implicit) while the bridge is enabled.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np

from hil_emulator.errors import EmulatorConfigError
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    ARM_INDEX_ANGLES,
    ARM_ROUTE_COUPLING,
    SERIES_ELASTIC_SOLID_STIFFNESS_FACTOR,
    SERIES_ELASTIC_STIFFNESS_NM_PER_RAD,
    SERIES_ELASTIC_TRAVEL_RAD,
    STEPPER_FULL_STEPS_PER_REV,
    STEPPER_HOLDING_MARGIN,
    STEPPER_MICROSTEPPING,
    STEPPER_PULL_OUT_CORNER_FULL_STEPS_PER_S,
    STEPPER_REDUCTIONS,
    STEPPER_TORQUE_CONSTANT_NM_PER_A,
    series_elastic_deflection,
    series_elastic_torque,
)

#: Electrical period of a two-phase hybrid stepper: 4 full steps.
FULL_STEPS_PER_ELECTRICAL_PERIOD: Final = 4


def _vec(values: tuple[float, ...]) -> np.ndarray:
    return np.array(values, dtype=float)


#: Couplings of the belt/cable circuits (rows: capstan J1..J4; columns: joint J1..J4), rad of
#: capstan per rad of joint: :data:`protocol.robot.ARM_ROUTE_COUPLING`.
DEFAULT_COUPLING: Final = ARM_ROUTE_COUPLING


@dataclass
class ArmParams:
    """Constants of the arm plant (joint side unless named otherwise; arrays are J1..J4).

    Defaults: :data:`protocol.robot.STEPPER_TORQUE_CONSTANT_NM_PER_A` (NEMA-34 on J1/J2,
    NEMA-23 on J3/J4).  At the firmware's default run and holding current (2000 mA) the
    maximum moving torques are 19.7, 32.75, 14.0, 14.0 N·m and the holding torques 1.6×
    that (31.4, 52.4, 22.4, 22.4 N·m); J2 outstretched carries 10.15 N·m of arm and 0.18 of
    the elbow's torque through the routes, so 2.0 kg at the flange is what it can move
    slowly (§5.6).
    """

    #: Coupling stiffness (N·m/rad), :data:`protocol.robot.SERIES_ELASTIC_STIFFNESS_NM_PER_RAD`.
    stiffness: np.ndarray = field(
        default_factory=lambda: _vec(SERIES_ELASTIC_STIFFNESS_NM_PER_RAD))
    #: Viscous damping of the polyurethane (N·m·s/rad): damping ratio ~0.1 for J2
    #: outstretched, ~0.04 for the elbow, more for the lighter J1/J3 loads.
    damping: np.ndarray = field(default_factory=lambda: _vec((0.8, 4.0, 0.25, 0.2)))
    #: Hysteresis torque (N·m): half the height of the loading/unloading loop.
    hysteresis: np.ndarray = field(default_factory=lambda: _vec((0.3, 0.4, 0.15, 0.1)))
    #: Deflection over which the hysteresis state turns round (rad).  Its slope for small
    #: oscillations, ``h / width``, adds to ``k``: 0.1 / 0.015 = 6.7 N·m/rad for the elbow
    #: (86 N·m/rad), so the elbow rings at 5.1–5.3 Hz from small to large amplitudes, the
    #: dissertation's ``sqrt(k/I)/2π`` with the quasi-static loop's ``k`` (figure 5.6);
    #: 0.003 made small oscillations 40 % stiffer (5.9 Hz).
    hysteresis_width_rad: float = 0.015
    #: Soft travel of the tubes each way (rad), and the stiffness factor beyond it.
    travel_rad: np.ndarray = field(default_factory=lambda: np.full(4, SERIES_ELASTIC_TRAVEL_RAD))
    stop_stiffness_factor: float = SERIES_ELASTIC_SOLID_STIFFNESS_FACTOR
    #: Belt/cable coupling matrix C (4×4, zero diagonal): see DEFAULT_COUPLING.
    coupling: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_COUPLING))
    #: Reductions (motor revs per joint rev); must equal the nodes' gear_reduction_x100/100.
    reductions: np.ndarray = field(default_factory=lambda: _vec(STEPPER_REDUCTIONS))
    #: Stepper torque constants at the motor shaft (N·m/A): holding torque = k_T · current.
    torque_constant_nm_per_a: np.ndarray = field(
        default_factory=lambda: _vec(STEPPER_TORQUE_CONSTANT_NM_PER_A))
    #: Detent (unpowered cogging) torque at the motor shaft (N·m).
    detent_torque_nm: np.ndarray = field(default_factory=lambda: _vec((0.15, 0.15, 0.05, 0.05)))
    #: Holding torque over maximum moving (pull-out) torque at the same current.
    holding_margin: float = STEPPER_HOLDING_MARGIN
    #: Corner of the pull-out curve (full steps/s): constant torque below, ``∝ 1/f`` above.
    pull_out_corner_full_steps_per_s: float = STEPPER_PULL_OUT_CORNER_FULL_STEPS_PER_S
    #: Motor full steps per rev and the drivers' microstepping (the nodes' EEPROM values).
    full_steps_per_rev: int = STEPPER_FULL_STEPS_PER_REV
    microstepping: int = STEPPER_MICROSTEPPING
    #: Coulomb friction (stiction) of the joint bearings of J1..J4 at the joint (N·m): the
    #: capstan hub's bearings and cable pulleys; each plant draws its own from
    #: ``friction_spread`` (relative, 1 σ, log-normal) with its seed, as arms differ.
    bearing_friction_nm: np.ndarray = field(default_factory=lambda: _vec((0.05, 0.1, 0.05,
                                                                          0.05)))
    friction_spread: float = 0.25
    #: The bearings' friction of one arm as measured (N·m, J1..J4; NaN: drawn as above), as a
    #: robot profile gives it (:mod:`hil_emulator.profile`).
    bearing_friction_as_built_nm: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))
    #: On re-locking after a slip the rotor settles 0..this many electrical periods further on
    #: in the slip's direction (random, as long as the coupling stays within capacity).
    slip_overshoot_periods: int = 2
    #: Slips of one motor less than this apart (s) are one slip event.
    slip_event_gap_s: float = 0.2
    #: Joint encoders: counts per joint revolution (0.036°), and the joint angle (rad, in the
    #: model's joint coordinates) of each index mark (:data:`protocol.robot.ARM_INDEX_ANGLES`):
    #: a few degrees from the default start pose (0): +3.4°, +4.0°, −2.9°, +4.6°.
    encoder_counts_per_rev: int = ARM_ENCODER_COUNTS_PER_REV
    index_angles: np.ndarray = field(default_factory=lambda: _vec(ARM_INDEX_ANGLES))
    #: Stepper windings: phase resistance (Ω); driver/winding thermal resistance (K/W) and
    #: capacity (J/K), for the ``temperature`` sensor (0.1 °C); supply (mV).
    phase_resistance_ohm: np.ndarray = field(default_factory=lambda: _vec((1.4, 1.4, 1.8, 1.8)))
    stepper_thermal_resistance: np.ndarray = field(
        default_factory=lambda: _vec((1.5, 1.5, 2.5, 2.5)))
    stepper_thermal_capacity: np.ndarray = field(
        default_factory=lambda: _vec((900.0, 900.0, 450.0, 450.0)))
    stepper_supply_mv: int = 24_000
    #: RX-64 at ``rx64_rated_supply_mv``: stall torque (N·m), no-load speed (rad/s; 0.157 s
    #: per 60°), stall current (A); supply actually applied (mV).
    rx64_stall_torque_nm: float = 6.4
    rx64_no_load_speed_rad_s: float = 6.7
    rx64_stall_current_a: float = 4.8
    rx64_rated_supply_mv: int = 18_000
    rx64_supply_mv: int = 18_000
    #: RX-64 thermal model (K/W, J/K) and potentiometer noise (position units, 1 σ).
    rx64_thermal_resistance: float = 6.0
    rx64_thermal_capacity: float = 25.0
    pot_noise_units: float = 0.3
    #: J5..J7: how far (rad) each servo's horn sits turned on its output spline from where
    #: the kinematic zero has it: the pot reads 512 at joint angle ``−offset``, so the host,
    #: taking 512 as 0, reads ``q + offset`` (0: as drawn; ``--sensors realistic`` draws them).
    horn_offsets_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Ambient temperature (°C) and the thermal models' update interval (ticks).
    ambient_c: float = 25.0
    thermal_every_ticks: int = 10

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping", "hysteresis", "travel_rad", "reductions",
                     "bearing_friction_nm",
                     "torque_constant_nm_per_a", "detent_torque_nm", "index_angles",
                     "phase_resistance_ohm", "stepper_thermal_resistance",
                     "stepper_thermal_capacity"):
            value = np.array(getattr(self, name), dtype=float).reshape(-1)
            if value.shape != (4,) or not np.isfinite(value).all():
                raise EmulatorConfigError(f"ArmParams.{name} needs 4 finite values, got "
                                          f"{getattr(self, name)!r}")
            setattr(self, name, value)
        built = np.array(self.bearing_friction_as_built_nm, dtype=float).reshape(-1)
        if built.shape != (4,) or (built[~np.isnan(built)] < 0).any():
            raise EmulatorConfigError("ArmParams.bearing_friction_as_built_nm needs 4 values "
                                      ">= 0 or NaN")
        self.bearing_friction_as_built_nm = built
        coupling = np.array(self.coupling, dtype=float)
        if coupling.shape != (4, 4) or not np.isfinite(coupling).all():
            raise EmulatorConfigError("ArmParams.coupling must be a finite 4×4 matrix")
        if np.any(np.diag(coupling) != 0.0):
            raise EmulatorConfigError("ArmParams.coupling must have a zero diagonal (the "
                                      "direct drive is the reduction)")
        self.coupling = coupling
        positive = ("stiffness", "travel_rad", "reductions", "stepper_thermal_resistance",
                    "stepper_thermal_capacity")
        for name in positive:
            if np.any(getattr(self, name) <= 0):
                raise EmulatorConfigError(f"ArmParams.{name} must be positive")
        if min(self.hysteresis_width_rad, self.stop_stiffness_factor, self.holding_margin,
               self.pull_out_corner_full_steps_per_s,
               self.rx64_stall_torque_nm, self.rx64_no_load_speed_rad_s,
               self.rx64_stall_current_a, self.rx64_thermal_capacity,
               self.rx64_thermal_resistance) <= 0 or self.thermal_every_ticks < 1:
            raise EmulatorConfigError("ArmParams: widths, factors, RX-64 constants and the "
                                      "thermal interval must be positive")

    # ------------------------------------------------------------------ derived (J1..J4)

    @property
    def microstep_rad(self) -> np.ndarray:
        """Joint angle of one microstep (rad)."""
        return 2.0 * np.pi / (self.full_steps_per_rev * self.microstepping * self.reductions)

    @property
    def period_rad(self) -> np.ndarray:
        """Joint angle of one electrical period, 4 full steps (rad): the slip quantum."""
        return (2.0 * np.pi * FULL_STEPS_PER_ELECTRICAL_PERIOD
                / (self.full_steps_per_rev * self.reductions))

    def holding_torque_nm(self, current_ma: np.ndarray | float) -> np.ndarray:
        """Static holding torque at the joint (N·m) for the commanded current (mA)."""
        return self.torque_constant_nm_per_a * self.reductions * np.asarray(current_ma) / 1000.0

    def max_moving_torque_nm(self, current_ma: np.ndarray | float) -> np.ndarray:
        """Pull-out torque while stepping slowly (below the corner) at the joint (N·m) for
        the current (mA)."""
        return self.holding_torque_nm(current_ma) / self.holding_margin

    def pull_out_torque_nm(self, current_ma: np.ndarray | float,
                           microsteps_per_s: np.ndarray | float) -> np.ndarray:
        """Pull-out torque at the joint (N·m) stepping at ``microsteps_per_s`` (either sign;
        0 = standstill: the holding torque)."""
        full = np.abs(np.asarray(microsteps_per_s, dtype=float)) / self.microstepping
        corner = self.pull_out_corner_full_steps_per_s
        fraction = np.where(full > corner, corner / np.maximum(full, 1e-12), 1.0)
        moving = self.max_moving_torque_nm(current_ma) * fraction
        return np.where(full == 0.0, self.holding_torque_nm(current_ma), moving)

    @property
    def detent_torque_at_joint(self) -> np.ndarray:
        """What an unpowered motor resists with, at the joint (N·m)."""
        return self.detent_torque_nm * self.reductions

    # ------------------------------------------------------------------ RX-64

    @property
    def rx64_stall_at_supply(self) -> float:
        """RX-64 stall torque at the applied supply (N·m)."""
        return self.rx64_stall_torque_nm * self.rx64_supply_mv / self.rx64_rated_supply_mv

    @property
    def rx64_emf_damping(self) -> float:
        """Back-EMF damping of an enabled RX-64 at its output (N·m·s/rad)."""
        return self.rx64_stall_torque_nm / self.rx64_no_load_speed_rad_s

    @property
    def rx64_winding_ohm(self) -> float:
        """RX-64 motor resistance (Ω) from rated supply over stall current."""
        return self.rx64_rated_supply_mv / 1000.0 / self.rx64_stall_current_a


def spring_torque(params: ArmParams, i: int, deflection: float) -> float:
    """Spring and solid-tube torque of coupling ``i`` at ``deflection`` (N·m; rad)."""
    return series_elastic_torque(deflection, float(params.stiffness[i]),
                                 float(params.travel_rad[i]), params.stop_stiffness_factor)


def deflection_at_torque(params: ArmParams, i: int, torque: float, offset: float) -> float:
    """The deflection (rad) at which coupling ``i``'s spring and solid-tube terms give
    ``torque − offset`` (N·m; ``offset`` = hysteresis + viscous parts): the inverse of
    :func:`spring_torque`."""
    return series_elastic_deflection(torque - offset, float(params.stiffness[i]),
                                     float(params.travel_rad[i]), params.stop_stiffness_factor)
