"""The arm as a plant part: four series-elastic stepper joints and three RX-64 servos.

:class:`ArmPlant` connects the model of :func:`hil_emulator.arm.model.add_arm` to the arm's
seven nodes' HALs (bus IDs 1–4: :class:`~firmware_py.arm_stepper.StepperNodeApp`, IDs 5–7:
:class:`~firmware_py.rx64.Rx64ServoApp`).  The physics of the actuators is described in
:mod:`hil_emulator.arm.actuators`; here is how it meets the firmware.

Stepper joints J1–J4, every 1 ms tick (:meth:`ArmPlant.before_step`):

* rotor angle at the joint = the stepper's exact position (``position_steps()``, microsteps)
  × ``2π / (200·16·G)`` plus the whole electrical periods it has slipped
  (``G`` = :attr:`ArmParams.reductions`, which must equal the node's
  ``gear_reduction_x100 / 100``); positive steps turn the joint positive;
* capstan angle ``φ`` adds the belt/cable coupling ``C·(q − q_start)``; the linear spring is
  MuJoCo joint stiffness about ``qpos_spring = φ`` (re-set every tick to its mid-tick value,
  evaluated once per 1 ms step), the viscous part MuJoCo joint damping (implicit) plus ``c·φ̇``
  applied; hysteresis, solid-tube and ``−Cᵀτ`` terms are applied forces;
* the stepper's capacity follows its commanded current (``commanded_current_ma()``) and
  step rate (``commanded_rate()``): holding torque at standstill, the pull-out curve while
  stepping (holding / 1.6 up to the corner, falling as corner / rate beyond), the detent
  torque at 0 mA.  Beyond it
  the rotor slips by whole electrical periods (plus a random 0–2 more) until the torque is
  within capacity; :meth:`ArmPlant.slips` counts slip events of an energised motor (slips
  less than :attr:`ArmParams.slip_event_gap_s` apart are one event).  An unpowered rotor
  simply follows the spring (detent torque only); that is not counted.

After the physics (:meth:`ArmPlant.after_step`) each joint encoder's count is the joint
angle since power-up in counts (10 000 per rev, count 0 at the start pose) and the index
pulse fires when the joint crosses its index angle (:attr:`ArmParams.index_angles`, either
direction), at the count of the index angle itself.

The plant touches the nodes only through the HAL's plant side
(:mod:`firmware_py.sim.virtual_hal`).

RX-64 joints J5–J7: with the bridge enabled, torque ``stall·clip(duty − ω/ω₀, ±1)`` (duty from
the firmware, + = counter-clockwise = positive joint angle); sensors ``pot`` (0..1023 over
300°, 512 at joint angle 0 plus the horn's mounting offset :attr:`ArmParams.horn_offsets_rad`,
Gaussian noise :attr:`ArmParams.pot_noise_units`), ``load``
(applied torque in 1/1023 of stall, signed), ``temperature`` (0.1 °C, I²R model),
``supply_mv``; the motor current (mA).

Temperatures (stepper drivers and RX-64s) are refreshed every
:attr:`ArmParams.thermal_every_ticks` ticks (10 ms by default); everything else every tick.
Random draws (each bearing's friction, once at the first bind; pot noise, drawn in blocks
of 1000 ticks; slip overshoot) come from the generator given.

**Error sources** a closed-loop stepper arm really has, and so the arm's repeatability:
joint encoders quantised to 0.036° (the host closes its loop on them); the polyurethane's
hysteresis (the Dahl state remembers which way the coupling last moved); Coulomb friction
and stiction in the joint bearings (:attr:`ArmParams.bearing_friction_nm`, drawn per arm);
stepper slips re-locking a random 0–2 electrical periods on; the RX-64 pots' noise and
compliance margin.

Performance: the per-tick work runs on Python floats joint by joint, not numpy: with 4 + 3
joints numpy's per-call overhead made it several times slower (≈ 220 µs per tick against
≈ 25 µs for both hooks measured alone, ≈ 50 µs interleaved with the seven nodes' firmware).
Interleaved, every numpy call runs with cold caches (microseconds each), so the joints' state
is read and the forces written through memoryviews of the MjData buffers (exact doubles), and
each joint's constants come in one tuple.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Final

import mujoco
import numpy as np

from firmware_py.sim.virtual_drives import VirtualEncoder, VirtualStepper
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.arm.actuators import ArmParams, deflection_at_torque, spring_torque
from hil_emulator.arm.model import ARM_JOINTS, FRICTION_SOLIMP
from hil_emulator.errors import EmulatorConfigError, PlantError
from hil_emulator.plant import TICK_US, rint
from protocol.robot import RX64_POSITION_CENTRE, RX64_UNITS_PER_RAD

__all__ = ["ArmParams", "ArmPlant", "POT_CENTRE", "POT_UNITS_PER_RAD"]

#: RX-64 potentiometer: counts at joint angle 0, and counts per rad (1024 over 300°).
POT_CENTRE: Final = RX64_POSITION_CENTRE
POT_UNITS_PER_RAD: Final = RX64_UNITS_PER_RAD
#: Ticks of potentiometer noise drawn at once.
NOISE_BLOCK_TICKS: Final = 1000
_N_STEPPERS: Final = 4
_N_SERVOS: Final = 3
_STEPPERS: Final = range(_N_STEPPERS)
_SERVOS: Final = range(_N_SERVOS)


def _floats(values: np.ndarray) -> list[float]:
    return [float(v) for v in values]


def _doubles(array: np.ndarray) -> memoryview[float]:
    """A memoryview of a contiguous float64 view into the MjData/MjModel buffers: it reads
    and writes Python floats exactly, without numpy's per-call cost (a tick's few values)."""
    return array.data.cast("B").cast("d")


class _Coupling:
    """One stepper joint's series-elastic coupling in the tick: the stepper's plant side, the
    joint's constants (microstep angle, coupling row of (joint, C), k, c, h, travel, solid
    stiffness, holding torque per mA, detent torque) and state (hysteresis z, deflection,
    torque, Σ I² since the last thermal update).  Attributes of a class, not items of lists:
    the compiled core keeps a class's floats unboxed.

    The tick reads the constants as one tuple, :attr:`constants` (from source, unpacking
    it costs a fifth of reading eleven attributes; compiled, a fixed tuple is unboxed too):
    change them with :meth:`set_stiffness`, which keeps the two alike."""

    def __init__(self, joint: int, stepper: VirtualStepper, microstep: float,
                 row: list[tuple[int, float]], k: float, c: float, h: float, travel: float,
                 k_solid: float, hold_per_ma: float, detent: float) -> None:
        self.joint, self.stepper, self.microstep, self.row = joint, stepper, microstep, row
        self.k, self.c, self.h, self.travel, self.k_solid = k, c, h, travel, k_solid
        self.hold_per_ma, self.detent = hold_per_ma, detent
        self.constants: tuple[int, VirtualStepper, float, list[tuple[int, float]], float,
                              float, float, float, float, float, float] = (
            joint, stepper, microstep, row, k, c, h, travel, k_solid, hold_per_ma, detent)
        self.z = 0.0
        self.deflection = 0.0
        self.torque = 0.0
        self.heat = 0.0

    def set_stiffness(self, k: float, k_solid: float) -> None:
        """New spring and end-stop stiffness (N·m/rad) in the attributes and :attr:`constants`."""
        self.k, self.k_solid = k, k_solid
        self.constants = (self.joint, self.stepper, self.microstep, self.row, k, self.c, self.h,
                          self.travel, k_solid, self.hold_per_ma, self.detent)


class ArmPlant:
    """The arm's joints wired to the HALs of its nodes (a :class:`~hil_emulator.plant.PlantPart`).

    ``stepper_hals``: the HALs of the stepper nodes of J1..J4 (bus IDs 1–4);
    ``servo_hals``: the HALs of the RX-64s of J5..J7 (IDs 5–7); ``prefix`` the one given to
    :func:`~hil_emulator.arm.model.add_arm`.  Joint indices 0..6 mean J1..J7.
    """

    def __init__(self, prefix: str, stepper_hals: Sequence[VirtualHal],
                 servo_hals: Sequence[VirtualHal], rng: np.random.Generator,
                 params: ArmParams | None = None) -> None:
        if len(stepper_hals) != _N_STEPPERS or len(servo_hals) != _N_SERVOS:
            raise EmulatorConfigError(f"the arm needs {_N_STEPPERS} stepper and {_N_SERVOS} "
                                      f"servo HALs, got {len(stepper_hals)} and "
                                      f"{len(servo_hals)}")
        self.prefix = prefix
        self.params = p = params or ArmParams()
        self.rng = rng
        self._steppers = [h.stepper() for h in stepper_hals]
        self._encoders = [h.encoder() for h in stepper_hals]
        self._stepper_sensors = [h.sensors for h in stepper_hals]
        self._motors = [h.motor(0) for h in servo_hals]
        self._servo_sensors = [h.sensors for h in servo_hals]
        # Per-stepper constants (J1..J4) as Python floats for the tick.
        self._k = _floats(p.stiffness)
        self._c = _floats(p.damping)
        self._h = _floats(p.hysteresis)
        self._travel = _floats(p.travel_rad)
        self._k_solid = _floats(p.stiffness * (p.stop_stiffness_factor - 1.0))
        self._microstep = _floats(p.microstep_rad)
        self._period = _floats(p.period_rad)
        self._hold_per_ma = _floats(p.holding_torque_nm(1.0))
        self._detent = _floats(p.detent_torque_at_joint)
        self._index = _floats(p.index_angles)
        self._margin = float(p.holding_margin)
        #: Corner of the pull-out curve in microsteps/s.
        self._corner = float(p.pull_out_corner_full_steps_per_s * p.microstepping)
        self._width = float(p.hysteresis_width_rad)
        c = p.coupling
        self._c_rows = [[(j, float(c[i, j])) for j in _STEPPERS if c[i, j]] for i in _STEPPERS]
        self._c_cols = [[(i, float(c[i, j])) for i in _STEPPERS if c[i, j]] for j in _STEPPERS]
        self._counts_per_rad = p.encoder_counts_per_rev / (2.0 * math.pi)
        #: Per stepper joint: its plant side, the tick's constants and state (_Coupling);
        #: the coupling terms −Cᵀτ as (joint j, capstan i, C[i, j]) in column order.
        self._couplings = [
            _Coupling(i, s, self._microstep[i], self._c_rows[i], self._k[i], self._c[i],
                      self._h[i], self._travel[i], self._k_solid[i], self._hold_per_ma[i],
                      self._detent[i])
            for i, s in enumerate(self._steppers)]
        self._c_terms = [(j, i, cij) for j, column in enumerate(self._c_cols)
                         for i, cij in column]
        self._pot_per_rad = float(POT_UNITS_PER_RAD)
        #: Each servo's pot reading at joint angle 0 (units): the centre plus its horn's
        #: mounting offset (:attr:`ArmParams.horn_offsets_rad`).
        self._pot_centre = [POT_CENTRE + float(off) * self._pot_per_rad
                            for off in p.horn_offsets_rad]
        self._stall = p.rx64_stall_at_supply
        self._emf = p.rx64_emf_damping
        self._inv_noload = 1.0 / p.rx64_no_load_speed_rad_s
        self._amps_per_nm = p.rx64_stall_current_a / self._stall
        self._load_scale = 1023.0 / self._stall
        #: Per servo: its sensors (pot, load) and its motor (current).
        self._servo_rows = [(s, self._servo_sensors[s], self._motors[s]) for s in _SERVOS]
        #: Per encoder (set in bind): joint, encoder, start angle, index angle, index count.
        self._encoder_rows: list[tuple[int, VirtualEncoder, float, float, int]] = []
        # Physical state (set in bind).
        self._q_start = [0.0] * 7
        self._phi_offset = [0.0] * _N_STEPPERS
        self._slip_rad = [0.0] * _N_STEPPERS  # rotor offset from the step count (rad, joint)
        self._slip_dir = [0.0] * _N_STEPPERS  # sign of the last slip
        self._slipping = [False] * _N_STEPPERS  # slid and not yet re-locked
        self._slip_events = [0] * _N_STEPPERS
        self._last_slip_tick = [-(10 ** 9)] * _N_STEPPERS
        self._event_gap_ticks = round(p.slip_event_gap_s * 1e6 / TICK_US)
        self._above_index = [False] * _N_STEPPERS
        self._push = [0.0] * len(ARM_JOINTS)
        self._servo_torque = [0.0] * _N_SERVOS
        self._servo_enabled = [False] * _N_SERVOS
        self._phase_ohm = _floats(p.phase_resistance_ohm)
        self._stepper_rth = _floats(p.stepper_thermal_resistance)
        self._stepper_cap = _floats(p.stepper_thermal_capacity)
        self._stepper_temp = [p.ambient_c] * _N_STEPPERS  # °C
        self._servo_temp = [p.ambient_c] * _N_SERVOS
        self._heat_servo = [0.0] * _N_SERVOS
        self._noise: list[float] = []
        self._noise_at = 0
        self._ticks = 0
        self._bound = False
        #: The payload at the flange (kg, :meth:`set_payload`).
        self.payload_kg = 0.0

    # ------------------------------------------------------------------ binding

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Find the arm's joints; set the couplings' stiffness/damping in ``model``; take the
        present pose as power-up (encoders 0) with every capstan where its spring balances
        gravity (``data.qfrc_bias``: ``data`` must be after ``mj_forward``, as
        :class:`~hil_emulator.plant.Plant` leaves it); write the initial sensor values."""
        p = self.params
        jids = []
        for name in ARM_JOINTS:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, self.prefix + name)
            if jid < 0:
                raise PlantError(f"the model has no joint {self.prefix + name!r}; build it "
                                 f"with arm_model.add_arm(prefix={self.prefix!r})")
            if model.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE:
                raise PlantError(f"joint {self.prefix + name!r} is not a hinge")
            jids.append(jid)
        qadr = model.jnt_qposadr[jids]
        dadr = model.jnt_dofadr[jids]
        if not (np.all(np.diff(qadr) == 1) and np.all(np.diff(dadr) == 1)):
            raise PlantError("the arm's joints are not one contiguous chain in the model")
        self.model, self.data = model, data
        self._flange_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY,
                                              self.prefix + "flange")
        self._flange_site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE,
                                              self.prefix + "flange")
        if self._flange_body < 0 or self._flange_site < 0:
            raise PlantError(f"the model has no flange body and site {self.prefix}flange")
        if not self._bound:
            b = self._flange_body
            self._flange_inertial = (float(model.body_mass[b]), model.body_ipos[b].copy(),
                                     model.body_inertia[b].copy())
        q0, d0 = int(qadr[0]), int(dadr[0])
        self._qpos = data.qpos[q0 : q0 + 7]
        self._qvel = data.qvel[d0 : d0 + 7]
        self._force = data.qfrc_applied[d0 : d0 + 7]
        self._spring_ref = model.qpos_spring[q0 : q0 + _N_STEPPERS]
        self._q_mv, self._qd_mv = _doubles(self._qpos), _doubles(self._qvel)
        self._force_mv, self._spring_mv = _doubles(self._force), _doubles(self._spring_ref)
        self._damping = model.dof_damping[d0 : d0 + 7]
        self._stepper_jids = jids[:_N_STEPPERS]
        model.jnt_stiffness[jids[:4]] = p.stiffness
        model.jnt_stiffness[jids[4:]] = 0.0
        self._damping[:4] = p.damping
        if not self._bound:  # the model's own RX-64 gear damping, before any back-EMF
            self._gear_damping = _floats(self._damping[4:])
        self._damping[4:] = self._gear_damping
        if not self._bound:  # this arm's bearings (seeded), drawn once
            self._bearing_friction = p.bearing_friction_nm * np.exp(
                p.friction_spread * self.rng.standard_normal(_N_STEPPERS))
            measured = p.bearing_friction_as_built_nm
            self._bearing_friction = np.where(np.isnan(measured), self._bearing_friction,
                                              measured)
        model.dof_frictionloss[d0 : d0 + _N_STEPPERS] = self._bearing_friction
        model.dof_solimp[d0 : d0 + _N_STEPPERS] = FRICTION_SOLIMP
        self._servo_enabled = [False] * _N_SERVOS

        q_start = self._qpos.copy()
        self._q_start = _floats(q_start)
        # Capstans where the springs balance gravity (and whatever else presses) at rest:
        # generalised spring forces (I − Cᵀ)·τ = bias.
        bias = data.qfrc_bias[d0 : d0 + _N_STEPPERS]
        torque0 = np.linalg.solve(np.eye(4) - p.coupling.T, bias)
        deflection0 = np.array([deflection_at_torque(p, i, float(torque0[i]), 0.0)
                                for i in _STEPPERS])
        phi0 = q_start[:4] + deflection0
        self._phi_offset = _floats(phi0 - self._rotor_command())
        for coupling, deflection, torque in zip(self._couplings, _floats(deflection0),
                                                _floats(torque0), strict=True):
            coupling.deflection, coupling.torque, coupling.z = deflection, torque, 0.0
        self._spring_ref[:] = phi0
        self._slip_rad = [0.0] * _N_STEPPERS
        self._slipping = [False] * _N_STEPPERS
        self._above_index = [bool(q_start[i] >= self._index[i]) for i in _STEPPERS]
        cpr = self._counts_per_rad
        self._encoder_rows = [
            (i, self._encoders[i], self._q_start[i], self._index[i],
             math.floor((self._index[i] - self._q_start[i]) * cpr + 0.5))
            for i in _STEPPERS]
        for sensors in self._stepper_sensors:
            sensors.set_supply_mv(p.stepper_supply_mv)
        for sensors in self._servo_sensors:
            sensors.set_supply_mv(p.rx64_supply_mv)
        self._bound = True
        self._write_encoders(self._q_start, index=False)
        self._write_servo_sensors(self._q_start)
        self._write_temperatures()

    # ------------------------------------------------------------------ public queries

    def joint_angles(self) -> np.ndarray:
        """Joint angles J1..J7 (rad, model coordinates)."""
        self._check_bound()
        return self._qpos.copy()

    def joint_velocities(self) -> np.ndarray:
        """Joint velocities J1..J7 (rad/s, model coordinates)."""
        self._check_bound()
        return self._qvel.copy()

    def capstan_angles(self) -> np.ndarray:
        """Capstan angles φ of J1..J4 now (rad, joint coordinates)."""
        self._check_bound()
        q = self._qpos.tolist()
        return np.array([self._capstan(i, q) for i in _STEPPERS])

    def deflections(self) -> np.ndarray:
        """Coupling deflections φ − q of J1..J4 now (rad; + = capstan ahead of the joint)."""
        return self.capstan_angles() - self._qpos[:4]

    def coupling_torques(self) -> np.ndarray:
        """Torques the couplings of J1..J4 applied over the last tick (N·m on the joint)."""
        return np.array([coupling.torque for coupling in self._couplings])

    def holding_torques(self) -> np.ndarray:
        """What each stepper resists now before slipping (N·m at the joint)."""
        return np.array([self._capacity(i, float(s.commanded_current_ma()),
                                        float(s.commanded_rate()))
                         for i, s in enumerate(self._steppers)])

    def slips(self) -> np.ndarray:
        """Slip events of each energised stepper J1..J4 since binding."""
        return np.array(self._slip_events, dtype=np.int64)

    def slipped_periods(self) -> np.ndarray:
        """Net electrical periods (4 full steps) each rotor has slipped, powered or not
        (whole numbers once re-locked)."""
        return np.array(self._slip_rad) / np.array(self._period)

    def servo_torques(self) -> np.ndarray:
        """Torques the RX-64s of J5..J7 applied over the last tick (N·m)."""
        return np.array(self._servo_torque)

    def set_payload(self, kg: float) -> None:
        """Experiment: a point mass of ``kg`` (≥ 0) at the flange origin, on top of the
        flange's own mass, from the next tick (the mass the dissertation's payload test added
        until the shoulder slipped).  0 takes it off."""
        self._check_bound()
        mass = float(kg)
        if not math.isfinite(mass) or mass < 0.0:
            raise EmulatorConfigError(f"payload {kg!r} kg is not finite and ≥ 0")
        model, body = self.model, self._flange_body
        base_mass, base_ipos, base_inertia = self._flange_inertial
        total = base_mass + mass
        ipos = base_ipos * (base_mass / total)  # the point mass sits at the body origin
        shift = base_mass * float(base_ipos @ base_ipos) - total * float(ipos @ ipos)
        model.body_mass[body] = total
        model.body_ipos[body] = ipos
        model.body_inertia[body] = base_inertia + max(shift, 0.0) + 1e-9
        self.payload_kg = mass

    def flange_position(self) -> np.ndarray:
        """The flange site's position in the world (m): what an optical tracker sees."""
        self._check_bound()
        return self.data.site_xpos[self._flange_site].copy()

    @property
    def stiffness(self) -> np.ndarray:
        """The couplings' spring stiffness of J1..J4 now (N·m/rad)."""
        return self.params.stiffness.copy()

    def set_stiffness(self, joint: int, stiffness_nm_per_rad: float) -> None:
        """Fault injection: coupling ``joint`` (0..3 = J1..J4) has spring stiffness
        ``stiffness_nm_per_rad`` (N·m/rad, > 0) from the next tick (a polyurethane spring
        ageing or warming): the linear spring, its solid-tube stiffness beyond the travel and
        the slip equilibria all follow; the deflection under the same load is ``τ / k``."""
        if not 0 <= joint < _N_STEPPERS:
            raise EmulatorConfigError(f"joint {joint} is not a stepper joint 0..3")
        k = float(stiffness_nm_per_rad)
        if not math.isfinite(k) or k <= 0.0:
            raise EmulatorConfigError(f"stiffness {stiffness_nm_per_rad!r} N·m/rad is not "
                                      "finite and > 0")
        p = self.params
        values = p.stiffness.copy()
        values[joint] = k
        # A new parameter set (the arrays may be shared with whoever built the params).
        self.params = p = dataclasses.replace(p, stiffness=values)
        self._k[joint] = k
        self._k_solid[joint] = k * (p.stop_stiffness_factor - 1.0)
        self._couplings[joint].set_stiffness(self._k[joint], self._k_solid[joint])
        if self._bound:
            self.model.jnt_stiffness[self._stepper_jids[joint]] = k

    def push(self, joint: int, torque_nm: float) -> None:
        """Fault injection: an external torque (N·m, + = positive joint direction) on joint
        ``joint`` (0..6 = J1..J7) from now until set back to 0."""
        if not 0 <= joint < len(ARM_JOINTS):
            raise EmulatorConfigError(f"joint index {joint} is not 0..{len(ARM_JOINTS) - 1}")
        self._push[joint] = float(torque_nm)

    # ------------------------------------------------------------------ the tick

    def before_step(self, dt_s: float) -> None:
        """Firmware commands → capstan references, coupling and servo forces for ``dt_s``."""
        if not self._bound:
            self._check_bound()
        # Float64 views (typeshed's memoryview.tolist() gives ints; no cast() call per tick).
        q: list[float] = self._q_mv.tolist()  # type: ignore[assignment]
        qd: list[float] = self._qd_mv.tolist()  # type: ignore[assignment]
        q_start = self._q_start
        dq = [q[0] - q_start[0], q[1] - q_start[1], q[2] - q_start[2], q[3] - q_start[3]]
        push = self._push
        phi_offset, slip_rad, slipping = self._phi_offset, self._slip_rad, self._slipping
        margin, corner = self._margin, self._corner
        inv_width = 1.0 / self._width
        half_dt = 0.5 * dt_s
        refs = [0.0] * _N_STEPPERS
        forces = [0.0] * 7
        for coupling in self._couplings:
            (i, stepper, micro, row, k, c, h, travel, k_solid, hold_per_ma,
             detent) = coupling.constants
            # commanded_rate(), commanded_current_ma() and position_steps(), read and
            # computed without the calls (the same operations).
            rate = stepper.rate
            # The commanded current (int mA): every use below (products with floats, its
            # square, comparisons) is exact as it is, as after float() (|I|² < 2⁵³).
            current = stepper.current
            steps = stepper._count0 + rate * (stepper.scheduler.now - stepper._t0) / 1e6
            phi = phi_offset[i] + steps * micro + slip_rad[i]
            phi_rate = rate * micro
            qi, qdi = q[i], qd[i]
            for j, cij in row:
                phi += cij * dq[j]
                phi_rate += cij * qd[j]
            deflection = phi - qi
            z = coupling.z
            change = deflection - coupling.deflection
            if change:  # Dahl hysteresis, exact for a monotone change
                sign = 1.0 if change > 0 else -1.0
                z = sign - (sign - z) * math.exp(-abs(change) * inv_width)
            viscous = c * (phi_rate - qdi)
            solid = 0.0
            if deflection > travel:
                solid = k_solid * (deflection - travel)
            elif deflection < -travel:
                solid = k_solid * (deflection + travel)
            extra = h * z + solid
            torque = k * deflection + extra + viscous
            capacity = hold_per_ma * current
            if rate:
                capacity /= margin  # pull-out torque while stepping: the curve
                speed = rate if rate > 0 else -rate
                if speed > corner:
                    capacity *= corner / speed
            if capacity < detent:
                capacity = detent
            over = torque > capacity or torque < -capacity
            if over or (slipping[i] and current > 0.0):
                if over:
                    deflection, z = self._slip(i, deflection, torque, capacity, z, viscous,
                                               current)
                else:
                    deflection, z = self._relock(i, deflection, capacity, z, viscous)
                extra = h * z + k_solid * _beyond(deflection, travel)
                torque = k * deflection + extra + viscous
                phi = deflection + qi
            coupling.z = z
            coupling.deflection = deflection
            coupling.torque = torque
            coupling.heat += current * current * 1e-6
            # MuJoCo: k·(φ_mid − q) − c·q̇; here the rest (c·φ̇, hysteresis, solid tubes).
            refs[i] = phi + phi_rate * half_dt
            forces[i] = c * phi_rate + extra + push[i]
        couplings = self._couplings
        for j, i, cij in self._c_terms:
            forces[j] = forces[j] - cij * couplings[i].torque  # (not -=: a C subtraction)
        spring = self._spring_mv
        spring[0], spring[1], spring[2], spring[3] = refs

        # RX-64s: stall·clip(duty − ω/ω₀); the back-EMF part −(stall/ω₀)·ω is MuJoCo damping.
        stall, emf, enabled_now = self._stall, self._emf, self._servo_enabled
        inv_noload, amps_per_nm = self._inv_noload, self._amps_per_nm
        servo_torque, heat = self._servo_torque, self._heat_servo
        for s, motor in enumerate(self._motors):
            enabled = motor.enabled  # bridge_enabled() and commanded_duty(), without calls
            omega = qd[4 + s]
            if enabled:
                drive = motor.duty - omega * inv_noload
                drive = stall * (1.0 if drive > 1.0 else -1.0 if drive < -1.0 else drive)
                forces[4 + s] = drive + emf * omega + push[4 + s]
            else:
                drive = 0.0
                forces[4 + s] = push[4 + s]
            if enabled != enabled_now[s]:
                enabled_now[s] = enabled
                self._damping[4 + s] = self._gear_damping[s] + (emf if enabled else 0.0)
            servo_torque[s] = drive
            amps = drive * amps_per_nm
            heat[s] = heat[s] + amps * amps
        force = self._force_mv
        force[0], force[1], force[2], force[3], force[4], force[5], force[6] = forces

    def after_step(self, dt_s: float) -> None:
        """Physics → encoder counts and index pulses, servo sensors, temperatures."""
        if not self._bound:
            self._check_bound()
        self._ticks += 1
        q: list[float] = self._q_mv.tolist()  # type: ignore[assignment]
        # The encoders (as _write_encoders with index pulses), inlined for the tick.
        cpr, above_index = self._counts_per_rad, self._above_index
        for i, encoder, q0, index_q, index_count in self._encoder_rows:
            qi = q[i]
            count = math.floor((qi - q0) * cpr + 0.5)
            above = qi >= index_q
            if above != above_index[i]:
                above_index[i] = above
                encoder.pulse_index(index_count)
            if count != encoder._value:  # else the call would store the same count
                encoder.set_count(count)
        # The servos (as _write_servo_sensors).
        if self._noise_at >= len(self._noise):
            self._draw_pot_noise()
        noise = self._noise
        at = self._noise_at
        self._noise_at = at + _N_SERVOS
        pot_per_rad, scale, amps_per_nm = self._pot_per_rad, self._load_scale, self._amps_per_nm
        servo_torque, centre = self._servo_torque, self._pot_centre
        for s, sensors, motor in self._servo_rows:
            pot = rint(centre[s] + q[4 + s] * pot_per_rad + noise[at + s])
            pot = 0 if pot < 0 else 1023 if pot > 1023 else pot
            # set_pot(pot) without the call when no one watches the channel (it changes
            # every tick; bind checked the board has it): what the setter stores.
            if sensors.channel_watchers:
                sensors.set_pot(pot)
            else:
                sensors.values["pot"] = pot
            torque = servo_torque[s]
            if torque:
                load = rint(torque * scale)
                load = -1023 if load < -1023 else 1023 if load > 1023 else load
                milliamps = rint(abs(torque) * amps_per_nm * 1000.0)
            else:
                load = milliamps = 0
            # Set only when they change (a servo within its margin drives nothing): the
            # setters would store the same values and tell no watcher.
            if load != sensors.values["load"]:
                sensors.set_load(load)
            if milliamps != motor.current:
                motor.set_current_ma(milliamps)
        every = self.params.thermal_every_ticks
        if self._ticks % every == 0:
            self._update_temperatures(every * dt_s)
            self._write_temperatures()

    # ------------------------------------------------------------------ internals

    def _check_bound(self) -> None:
        if not self._bound:
            raise PlantError("ArmPlant used before bind(model, data)")

    def _rotor_command(self) -> np.ndarray:
        """Commanded rotor angles at the joints (rad) from the step generators."""
        return np.array([s.position_steps() * m for s, m in zip(self._steppers, self._microstep,
                                                                 strict=True)])

    def _capstan(self, i: int, q: list[float]) -> float:
        phi = (self._phi_offset[i] + self._steppers[i].position_steps() * self._microstep[i]
               + self._slip_rad[i])
        for j, cij in self._c_rows[i]:
            phi += cij * (q[j] - self._q_start[j])
        return phi

    def _capacity(self, i: int, current_ma: float, rate: float) -> float:
        """Torque stepper ``i`` holds before slipping (N·m at the joint) at ``current_ma``
        stepping at ``rate`` (microsteps/s; 0 = standstill)."""
        holding = self._hold_per_ma[i] * current_ma
        if rate:
            holding /= self._margin
            if abs(rate) > self._corner:
                holding *= self._corner / abs(rate)
        return max(holding, self._detent[i])

    def _slip(self, i: int, deflection: float, torque: float, capacity: float, z: float,
              viscous: float, current: float) -> tuple[float, float]:
        """The rotor of stepper ``i`` slides until the coupling transmits just ``capacity``;
        returns the new deflection and hysteresis state."""
        offset = self._h[i] * z + viscous
        wanted = deflection_at_torque(self.params, i, capacity if torque > 0 else -capacity,
                                      offset)
        change = wanted - deflection
        self._slip_rad[i] += change
        self._slip_dir[i] = 1.0 if change > 0 else -1.0
        self._slipping[i] = True
        if current > 0.0:
            if self._ticks - self._last_slip_tick[i] > self._event_gap_ticks:
                self._slip_events[i] += 1
            self._last_slip_tick[i] = self._ticks
        return wanted, self._hysteresis(z, change)

    def _relock(self, i: int, deflection: float, capacity: float, z: float, viscous: float
                ) -> tuple[float, float]:
        """An energised rotor that has slid settles on an electrical equilibrium (a whole
        number of periods from the step count) within ``capacity``, if there is one: the
        nearest, perhaps a random few periods further in the slip's direction."""
        p = self.params
        period = self._period[i]
        offset = self._h[i] * z + viscous
        slid = self._slip_rad[i]
        periods = slid / period
        nearest = round(periods)
        other = nearest + (1 if periods > nearest else -1)
        for n in (nearest, other):
            if abs(spring_torque(p, i, deflection + n * period - slid) + offset) <= capacity:
                break
        else:
            return deflection, z  # no equilibrium holds yet: keeps sliding
        step = 1 if self._slip_dir[i] > 0 else -1
        for _ in range(int(self.rng.integers(0, p.slip_overshoot_periods + 1))):
            trial = deflection + (n + step) * period - slid
            if abs(spring_torque(p, i, trial) + offset) > capacity:
                break
            n += step
        change = n * period - slid
        self._slip_rad[i] = n * period
        self._slipping[i] = False
        return deflection + change, self._hysteresis(z, change)

    def _hysteresis(self, z: float, change: float) -> float:
        """Dahl state after the deflection changed by ``change`` (rad)."""
        if not change:
            return z
        sign = 1.0 if change > 0 else -1.0
        return sign - (sign - z) * math.exp(-abs(change) / self._width)

    def _write_encoders(self, q: list[float], index: bool) -> None:
        """Counts since power-up; a crossed index mark pulses with the count of the mark
        itself (as the encoder latches it), then the count moves on to the joint's."""
        cpr, q_start = self._counts_per_rad, self._q_start
        for i, encoder in enumerate(self._encoders):
            count = math.floor((q[i] - q_start[i]) * cpr + 0.5)
            above = q[i] >= self._index[i]
            if above != self._above_index[i]:
                self._above_index[i] = above
                if index:
                    encoder.pulse_index(math.floor((self._index[i] - q_start[i]) * cpr + 0.5))
            encoder.set_count(count)

    def _draw_pot_noise(self) -> None:
        """The next :data:`NOISE_BLOCK_TICKS` ticks of potentiometer noise (units)."""
        sigma = self.params.pot_noise_units
        self._noise = (self.rng.standard_normal(_N_SERVOS * NOISE_BLOCK_TICKS) * sigma).tolist()
        self._noise_at = 0

    def _write_servo_sensors(self, q: list[float]) -> None:
        if self._noise_at >= len(self._noise):
            self._draw_pot_noise()
        noise = self._noise
        at = self._noise_at
        self._noise_at = at + _N_SERVOS
        scale = self._load_scale
        for s, sensors in enumerate(self._servo_sensors):
            pot = round(self._pot_centre[s] + q[4 + s] * self._pot_per_rad + noise[at + s])
            sensors.set_pot(0 if pot < 0 else 1023 if pot > 1023 else pot)
            torque = self._servo_torque[s]
            sensors.set_load(max(-1023, min(1023, round(torque * scale))))
            self._motors[s].set_current_ma(round(abs(torque) * self._amps_per_nm * 1000.0))

    def _update_temperatures(self, span_s: float) -> None:
        """First-order I²R thermal models over ``span_s`` seconds (mean I² of the span)."""
        p = self.params
        ambient = p.ambient_c
        per_tick = 1.0 / p.thermal_every_ticks
        temps = self._stepper_temp
        for i in range(_N_STEPPERS):  # two phases at the set current
            power = 2.0 * self._phase_ohm[i] * self._couplings[i].heat * per_tick
            temps[i] = temps[i] + span_s / self._stepper_cap[i] * (
                power - (temps[i] - ambient) / self._stepper_rth[i])
        temps = self._servo_temp
        for s in range(_N_SERVOS):
            power = p.rx64_winding_ohm * self._heat_servo[s] * per_tick
            temps[s] = temps[s] + span_s / p.rx64_thermal_capacity * (
                power - (temps[s] - ambient) / p.rx64_thermal_resistance)
        for coupling in self._couplings:
            coupling.heat = 0.0
        self._heat_servo = [0.0] * _N_SERVOS

    def _write_temperatures(self) -> None:
        stepper_temp, servo_temp = self._stepper_temp, self._servo_temp
        for i, sensors in enumerate(self._stepper_sensors):
            sensors.set_temperature(rint(stepper_temp[i] * 10.0))
        for s, sensors in enumerate(self._servo_sensors):
            sensors.set_temperature(rint(servo_temp[s] * 10.0))


def _beyond(deflection: float, travel: float) -> float:
    """How far ``deflection`` is past the soft travel ``±travel`` (rad; 0 within it)."""
    if deflection > travel:
        return deflection - travel
    if deflection < -travel:
        return deflection + travel
    return 0.0
