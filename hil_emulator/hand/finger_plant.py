"""Plant parts of the hand: one :class:`FingerPlant` per finger module and the :class:`PalmPlant`.

A :class:`FingerPlant` connects a finger module of :mod:`hil_emulator.hand.model` to its
three boards (fmcb, f2, f3):

- **Motors** (every tick).  ``before_step`` reads each fmcb motor's commanded duty, bridge
  enable and brake (the HAL's plant side, :mod:`firmware_py.sim.virtual_hal`, which is all
  the plant touches) and sets the motor actuator's ``data.ctrl`` (the duty, −1..1): *drive*
  (enabled) applies duty·V; *brake* shorts the winding (duty 0, back-EMF damping only);
  *coast* (not enabled, board unpowered, or finger detached) opens the bridge — no current,
  the actuator's back-EMF bias is switched off in ``model.actuator_biasprm``.  The motor
  torque ``k_t·i``, ``i = (duty·V − k_e·ω)/R`` limited to ``I_max`` on the side the bridge
  drives (the sign of the duty; braking current is limited by R alone), is produced by
  MuJoCo's actuator on the motor tendon (see :mod:`hil_emulator.hand.model`), i.e.
  ``τ_joint = M_radᵀ τ_motor``; the limit is the actuator's force range, set per duty sign.
- **Halls and currents** (every tick).  ``after_step`` computes each motor shaft angle
  ``θ_m = M_rad·q`` (rad) and sets the hall state ``HALL_SEQUENCE[⌊θ_m·K + φ⌋ mod 6]``
  (φ a seeded random rotor phase at power-up, in hall states), so positive duty → hall
  count rising, exactly :mod:`protocol.robot`'s convention; the motor current is
  the *signed* winding current in mA (the fmcb never reads it; the palm's supply model can
  sum magnitudes via :meth:`FingerPlant.motor_currents_a`).
- **IMUs, tactile, strain** (every ``sensor_period_ticks`` ticks, default 10 ms, staggered
  per finger by a hash of the prefix): accelerometer + magnetometer of fmcb/f2/f3, taxels
  of f2 (6) and f3 (12), f2's strain gauge.  The firmware samples the phalange IMUs at
  100 Hz and the fmcb's at 25 Hz, autopolls the taxels at 100 Hz and the strain at 1 Hz,
  so a 100 Hz refresh hides nothing the host can observe but sub-10 ms taxel timing.
- **Temperatures** (every ``thermal_period_ticks``, default 50 ms): winding temperatures
  ``temperature0..2`` of the fmcb (0.1 °C) and the f3 thermistors (a slow fingertip
  temperature following ambient + ``tip_coupling`` × the mean winding rise).  f2's
  thermistor channels keep their defaults.

Units and conversions are in :mod:`hil_emulator.hand.sensors`.  Every random draw comes from
the generator passed in, in a fixed order, so equal seeds and commands give equal sensors.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from typing import Final

import mujoco
import numpy as np

from firmware_py.mcu import Mcu
from firmware_py.sim.virtual_drives import VirtualMotor
from firmware_py.sim.virtual_hal import VirtualHal
from firmware_py.sim.virtual_sensors import VirtualSensors
from hil_emulator.errors import EmulatorConfigError, PlantError
from hil_emulator.hand.model import (
    DEFAULT_MOTOR,
    F2_LENGTH,
    F2_PAD_Z,
    F2_TAXELS,
    F3_LENGTH,
    F3_PAD_Z,
    F3_TAXELS,
    GAUGE_POS,
    JOINT_DAMPING,
    PALM_TAXELS,
    FingerNames,
    MotorConstants,
    PalmNames,
    motor_coupling_rad,
)
from hil_emulator.hand.sensors import (
    DEFAULT_TACTILE,
    FingerErrors,
    LinearCounts,
    NormalStream,
    PadContacts,
    PalmErrors,
    TactileModel,
    WindingThermal,
    strain_counts,
    taxel_forces,
    thermistor_counts,
)
from hil_emulator.plant import rint
from protocol.robot import FINGER_GEAR_RATIOS, HALL_SEQUENCE, HALL_STATES_PER_RAD

#: Bridge modes (Final: the compiled core inlines them instead of a lookup per use).
_DRIVE: Final = 0
_BRAKE: Final = 1
_COAST: Final = 2
#: The hall pattern and its scale as this module's own constants (the compiled core reads a
#: Final of a compiled module as C, another module's through its dictionary).
_HALL_SEQUENCE: Final[tuple[int, ...]] = tuple(HALL_SEQUENCE)
_HALL_STATES_PER_RAD: Final[float] = float(HALL_STATES_PER_RAD)
#: Where :meth:`FingerPlant.press` pushes: the pad centre (m, body frame) of each segment.
PRESS_POINTS: Final = {"F2": (F2_LENGTH / 2, 0.0, F2_PAD_Z), "F3": (F3_LENGTH / 2, 0.0, F3_PAD_Z)}


@dataclass(frozen=True)
class FingerParams:
    """Motor constants, sensor rates and noise, thermal model of one finger module.

    Periods in plant ticks (1 ms); noise as standard deviations in counts; thermal
    resistance winding→ambient in K/W, time constants in s.
    """

    motor: MotorConstants = DEFAULT_MOTOR
    tactile: TactileModel = field(default_factory=lambda: DEFAULT_TACTILE)
    sensor_period_ticks: int = 10
    thermal_period_ticks: int = 50
    accel_noise_counts: float = 2.0
    mag_noise_counts: float = 2.0
    strain_noise_counts: float = 30.0
    thermistor_noise_counts: float = 1.0
    ambient_c: float = 25.0
    thermal_resistance_k_per_w: float = 40.0
    thermal_time_constant_s: float = 20.0
    tip_coupling: float = 0.1
    tip_time_constant_s: float = 120.0
    #: The fmcb board's rise over ambient as a fraction of its windings' mean rise (it sits
    #: on the motors' heatsink): the temperature its accelerometer's offset follows.
    board_coupling: float = 0.5
    #: The accelerometers' output resolution in wire counts (1: a digit is 1 mg).
    accel_step_counts: int = 1
    #: Viscous damping of each of the finger's joints J1..J3 (N·m·s/rad, the bearings).
    joint_damping_nm_s_per_rad: float = JOINT_DAMPING

    def __post_init__(self) -> None:
        if self.sensor_period_ticks < 1 or self.thermal_period_ticks < 1:
            raise EmulatorConfigError("sensor periods must be at least one tick")


def _virtual_hal(mcu: Mcu, what: str) -> VirtualHal:
    hal = mcu.hal
    if not isinstance(hal, VirtualHal):
        raise PlantError(f"the {what} board is not on a VirtualHal; the plant cannot drive it")
    return hal


def _block_view(array: np.ndarray, idx: np.ndarray) -> np.ndarray | None:
    """``array[idx]`` as a view if ``idx`` is one consecutive run (else None: gather)."""
    first = int(idx[0])
    if np.array_equal(idx, np.arange(first, first + idx.size)):
        return array[first:first + idx.size]
    return None


def _doubles(array: np.ndarray) -> memoryview[float]:
    """A memoryview of a contiguous float64 view into the MjData/MjModel buffers: it reads
    and writes Python floats exactly, without numpy's per-call cost (a tick's few values)."""
    return array.data.cast("B").cast("d")


def _stagger(prefix: str, period: int) -> int:
    """A deterministic phase (ticks) spreading the parts' slow updates over the period."""
    return zlib.crc32(prefix.encode()) % period


class _Winding:
    """One finger motor in the plant: its HAL plant side, its row of ``M_rad`` and hall phase
    (hall states), and the tick's state: bridge mode, duty sign (the current limit set),
    duty, winding current (A) and Σ I² (A²) since the last thermal update.  Attributes of a
    class, not items of lists: the compiled core keeps a class's floats unboxed.  The tick
    reads the constants as one tuple, :attr:`constants` (from source, unpacking it costs
    less than five attribute reads; compiled, a fixed tuple is unboxed too)."""

    def __init__(self, hal: VirtualMotor, a0: float, a1: float, a2: float,
                 phase: float) -> None:
        self.hal = hal
        self.a0, self.a1, self.a2 = a0, a1, a2
        self.phase = phase
        #: ``(a0, a1, a2, phase, hal)``, fixed.
        self.constants: tuple[float, float, float, float, VirtualMotor] = (a0, a1, a2, phase,
                                                                             hal)
        self.act = -1  # its actuator in the model (bind)
        self.mode = _COAST
        self.sign = 0
        self.duty = 0.0
        # The commands the tick's state was set from (before_step), None: not yet.
        self.commanded: float | None = None
        self.enabled = False
        self.brake = False
        self.current = 0.0
        self.i2_sum = 0.0


class FingerPlant:
    """One finger module's physics ↔ its fmcb, f2 and f3 (a :class:`~hil_emulator.plant.PlantPart`).

    ``prefix`` is the module's name prefix in the model (``"hand/finger0/"``). ``attached``
    False (set by the emulator on a break-away) leaves the motors coasting whatever the
    fmcb commands; the module stays where it is on the palm in the model.
    """

    def __init__(self, prefix: str, fmcb: Mcu, f2: Mcu, f3: Mcu, rng: np.random.Generator,
                 params: FingerParams | None = None, errors: FingerErrors | None = None
                 ) -> None:
        self.prefix = prefix
        #: The sensors' imperfections as built (None: ideal sensors).
        self.errors = errors
        self.names = FingerNames(prefix)
        self.params = params or FingerParams()
        self.fmcb, self.f2, self.f3 = fmcb, f2, f3
        self.rng = rng
        self.attached = True
        motors: list[VirtualMotor] = _virtual_hal(fmcb, "fmcb").motors[:3]
        if len(motors) != 3:
            raise PlantError("an fmcb drives three motors")
        self._fmcb_sensors: VirtualSensors = _virtual_hal(fmcb, "fmcb").sensors
        self._f2_sensors: VirtualSensors = _virtual_hal(f2, "f2").sensors
        self._f3_sensors: VirtualSensors = _virtual_hal(f3, "f3").sensors
        #: Rotor phase at power-up (hall states, 0..6): where the hall pattern starts.
        self.hall_phase = [float(v) for v in rng.uniform(0.0, 6.0, 3)]
        self._m_rad = motor_coupling_rad()
        #: Per motor: its plant side, constants and state of the tick.
        self._windings = [_Winding(m, float(row[0]), float(row[1]), float(row[2]), phase)
                          for m, row, phase in zip(motors, self._m_rad, self.hall_phase,
                                                   strict=True)]
        self._i2_ticks = 0
        self._presses: dict[str, float] = {}
        self._press_dirty = False
        p = self.params
        # Countdowns (ticks) to the next slow updates, staggered per finger.
        self._sensor_countdown = 1 + _stagger(prefix, p.sensor_period_ticks)
        self._thermal_countdown = 1 + _stagger(prefix, p.thermal_period_ticks)
        motor = p.motor
        self._electrical = (motor.supply_v, motor.ke_v_s_per_rad, motor.resistance_ohm,
                            motor.current_limit_a)
        self._torque_limit = motor.torque_limit_nm
        #: A force bound never reached (4 × the unlimited stall torque): "no limit".
        self._torque_open = 4.0 * motor.gain_nm_per_duty
        self.thermal = WindingThermal(3, p.ambient_c, p.thermal_resistance_k_per_w,
                                      p.thermal_time_constant_s)
        self.tip_temperature_c = p.ambient_c
        self._f2_taxels_xy = np.array(F2_TAXELS)
        self._f3_taxels_xy = np.array(F3_TAXELS)
        n2, n3 = len(F2_TAXELS), len(F3_TAXELS)
        #: One conversion for all slow channels: fmcb accel, mag, f2 accel, mag, f3 accel,
        #: mag (the order of the IMU sensors in bind), then f2 and f3 taxels.
        self._counts = LinearCounts.imu(
            [("accel", p.accel_noise_counts), ("mag", p.mag_noise_counts)] * 3,
            step=p.accel_step_counts).join(LinearCounts.taxels(p.tactile, n2 + n3))
        self._n_f2 = n2
        self._zeros_f2, self._zeros_f3 = np.zeros(n2), np.zeros(n3)
        #: Every random number after the hall phases, in the order they were drawn one
        #: refresh at a time (the slow sensors' size + 1, the thermistors' 4).
        self._normals = NormalStream(rng)

    # --- binding ----------------------------------------------------------------------------
    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Resolve the module's names; write :attr:`params`' motor constants into ``model``.

        Raises :class:`PlantError` if the model integrates with explicit Euler or RK4: the
        motors' back-EMF damping (time constant ≈ 0.16 ms) diverges there even at 0.5 ms steps.
        """
        if model.opt.integrator not in (mujoco.mjtIntegrator.mjINT_IMPLICIT,
                                        mujoco.mjtIntegrator.mjINT_IMPLICITFAST):
            raise PlantError("the finger motors need the implicit or implicitfast integrator "
                             "(hand_model.add_hand sets implicitfast)")
        self.model, self.data = model, data
        names = self.names
        try:
            joints = [model.joint(names.joint(j)).id for j in range(3)]
            self._act = [model.actuator(names.motor(i)).id for i in range(3)]
            tendons = [model.tendon(names.motor(i)).id for i in range(3)]
            self._body = {s: model.body(names.body(s)).id for s in ("F0", "F1", "F2", "F3")}
            self._gauge_site = model.site(names.gauge_site).id
            pads = [model.geom(names.pad(s)).id for s in ("F2", "F3")]
            imu_sensors = [model.sensor(name).id for b in ("fmcb", "f2", "f3")
                           for name in (names.accel_sensor(b), names.mag_sensor(b))]
        except KeyError as exc:
            raise PlantError(f"finger {self.prefix!r} is not in the model: {exc}") from exc
        qadr = [int(model.jnt_qposadr[j]) for j in joints]
        dadr = [int(model.jnt_dofadr[j]) for j in joints]
        if qadr != list(range(qadr[0], qadr[0] + 3)) or dadr != list(range(dadr[0], dadr[0] + 3)):
            raise PlantError(f"finger {self.prefix!r}: joints J1..J3 are not consecutive")
        self._qadr, self._dadr = qadr[0], dadr[0]
        model.dof_damping[dadr[0]:dadr[0] + 3] = self.params.joint_damping_nm_s_per_rad
        # Views into the MjData buffers (fixed for the data's lifetime): no slicing per tick.
        self._qpos = data.qpos[qadr[0]:qadr[0] + 3]
        self._qvel = data.qvel[dadr[0]:dadr[0] + 3]
        self._ctrl = _doubles(data.ctrl)
        self._q_mv, self._w_mv = _doubles(self._qpos), _doubles(self._qvel)
        self._imu_idx = np.concatenate(
            [np.arange(model.sensor_adr[s], model.sensor_adr[s] + 3) for s in imu_sensors])
        view = _block_view(data.sensordata, self._imu_idx)
        self._imu_mv = None if view is None else _doubles(view)
        motor = self.params.motor
        for a, t in zip(self._act, tendons, strict=True):
            model.actuator_gainprm[a, 0] = motor.gain_nm_per_duty
            model.actuator_biasprm[a, :3] = (0.0, 0.0, 0.0)
            model.tendon_armature[t] = motor.rotor_inertia_kg_m2
            model.tendon_frictionloss[t] = motor.friction_nm
        self._powered: bool | None = None  # before_step sets every winding anew
        for i, winding in enumerate(self._windings):
            winding.act = self._act[i]
            winding.mode = _COAST
            self._set_drive_sign(i, 0)
        self._pads = PadContacts(model, data, pads)
        self._f3_root = int(model.body_rootid[self._body["F3"]])
        # Row views of what the strain gauge reads (fixed buffers, as _qpos).
        self._gauge_rows = (_doubles(data.cfrc_int[self._body["F3"]]),
                            _doubles(data.subtree_com[self._f3_root]),
                            _doubles(data.site_xpos[self._gauge_site]),
                            _doubles(data.site_xmat[self._gauge_site]))
        self._write_temperatures()
        self._update_sensors()

    # --- per tick ---------------------------------------------------------------------------
    def before_step(self, dt_s: float) -> None:
        """Motor commands → actuator controls (duty) and bridge state; press forces."""
        powered = self.attached and self.fmcb.powered
        if powered == self._powered:
            # The commands of the last tick (a holding finger's fmcb sleeps): the modes,
            # limits and controls set then stand (nothing else writes them).  ``!=`` on the
            # duty, not ``is`` (compiled, the attribute is a C double): ±0.0 read alike,
            # and drive alike (0·gain plus a bias that is never −0.0).
            for winding in self._windings:
                motor = winding.hal
                if (motor.duty != winding.commanded or motor.enabled != winding.enabled
                        or motor.brake != winding.brake):
                    break
            else:
                if self._press_dirty or self._presses:
                    self._apply_presses()
                return
        self._powered = powered
        ctrl = self._ctrl
        for i, winding in enumerate(self._windings):
            # What drive_command() returns, read without the call (twelve motors a tick).
            motor = winding.hal
            winding.commanded, winding.enabled, winding.brake = (motor.duty, motor.enabled,
                                                                 motor.brake)
            if not powered:
                mode = _COAST
            elif motor.brake:
                mode = _BRAKE
            elif motor.enabled:
                mode = _DRIVE
            else:
                mode = _COAST
            if mode != winding.mode:
                self._set_mode(i, mode)
            duty = motor.duty if mode == _DRIVE else 0.0
            sign = (duty > 0.0) - (duty < 0.0)
            if sign != winding.sign:
                self._set_drive_sign(i, sign)
            winding.duty = duty
            # Written every tick: one store costs less than telling whether it changed.
            ctrl[winding.act] = duty
        if self._press_dirty or self._presses:
            self._apply_presses()

    def _set_drive_sign(self, i: int, sign: int) -> None:
        """Current limit on the side the bridge drives (``sign`` of the duty) only.

        The L6229's chopper limits the current it *sources*; braking (regenerative or
        shorted-winding) current through the low-side switches is bounded by R alone.
        """
        lim, open_ = self._torque_limit, self._torque_open
        self.model.actuator_forcerange[self._act[i]] = (-lim if sign < 0 else -open_,
                                                        lim if sign > 0 else open_)
        self._windings[i].sign = sign

    def _set_mode(self, i: int, mode: int) -> None:
        damping = 0.0 if mode == _COAST else self.params.motor.emf_damping_nm_s
        self.model.actuator_biasprm[self._act[i], 2] = -damping
        self._windings[i].mode = mode

    def after_step(self, dt_s: float) -> None:
        """Halls and currents every tick; IMUs, taxels, strain and temperatures when due."""
        # Float64 views (typeshed's memoryview.tolist() gives ints; no cast() call per tick).
        q: list[float] = self._q_mv.tolist()  # type: ignore[assignment]
        w: list[float] = self._w_mv.tolist()  # type: ignore[assignment]
        q0, q1, q2 = q
        w0, w1, w2 = w
        v, ke, r, lim = self._electrical
        k_hall, sequence = _HALL_STATES_PER_RAD, _HALL_SEQUENCE
        for winding in self._windings:
            a0, a1, a2, phase, motor = winding.constants
            # math.floor and rint called by name: the compiled core makes them C calls.
            hall = sequence[math.floor((a0 * q0 + a1 * q1 + a2 * q2) * k_hall + phase) % 6]
            if winding.mode == _COAST:
                current = 0.0
            else:
                duty = winding.duty
                current = (duty * v - ke * (a0 * w0 + a1 * w1 + a2 * w2)) / r
                if duty > 0.0 and current > lim:
                    current = lim
                elif duty < 0.0 and current < -lim:
                    current = -lim
            winding.current = current
            winding.i2_sum += current * current
            milliamps = rint(current * 1000.0)
            # Written only when it changes (a holding finger's never do): the call would
            # store the same values and raise no interrupt.
            if hall != motor._hall or milliamps != motor.current:
                motor.set_hall_and_current(hall, milliamps)
        self._i2_ticks += 1
        self._sensor_countdown -= 1
        if self._sensor_countdown <= 0:
            self._sensor_countdown = self.params.sensor_period_ticks
            self._update_sensors()
        self._thermal_countdown -= 1
        if self._thermal_countdown <= 0:
            self._thermal_countdown = self.params.thermal_period_ticks
            self._update_thermal(self._i2_ticks * dt_s)

    # --- fault / test injection -------------------------------------------------------------
    def press(self, segment: str, force_n: float) -> None:
        """Push the pad of ``"F2"`` or ``"F3"`` with ``force_n`` newtons until changed (0 = release).

        The force acts at the pad centre along the pad's inward normal (−z of the segment),
        through ``data.xfrc_applied`` of that body (rewritten every tick, as the body moves),
        and the tactile model and strain gauge see it as a contact load at the pad centre.
        """
        if segment not in PRESS_POINTS:
            raise EmulatorConfigError(f"press: segment {segment!r} is not 'F2' or 'F3'")
        force = float(force_n)
        if not math.isfinite(force) or force < 0.0:
            raise EmulatorConfigError(f"press: force {force_n!r} N is not finite and ≥ 0")
        if force == 0.0:
            self._presses.pop(segment, None)
        else:
            self._presses[segment] = force
        self._press_dirty = True

    def _apply_presses(self) -> None:
        """Rewrite ``xfrc_applied`` of F2/F3: the press force and its moment about the CoM."""
        data = self.data
        for segment in ("F2", "F3"):
            body = self._body[segment]
            force = self._presses.get(segment, 0.0)
            if force == 0.0:
                data.xfrc_applied[body] = 0.0
                continue
            r = data.xmat[body].tolist()
            px, py, pz = PRESS_POINTS[segment]
            bx, by, bz = data.xpos[body].tolist()
            cx, cy, cz = data.xipos[body].tolist()
            # Lever from the CoM to the pad centre (world), force along the body's −z.
            lx = bx + r[0] * px + r[1] * py + r[2] * pz - cx
            ly = by + r[3] * px + r[4] * py + r[5] * pz - cy
            lz = bz + r[6] * px + r[7] * py + r[8] * pz - cz
            fx, fy, fz = -force * r[2], -force * r[5], -force * r[8]
            data.xfrc_applied[body] = (fx, fy, fz, ly * fz - lz * fy, lz * fx - lx * fz,
                                       lx * fy - ly * fx)
        self._press_dirty = False

    # --- state for tests and the emulator ----------------------------------------------------
    def joint_angles(self) -> np.ndarray:
        """Joint angles J1, J2, J3 (rad), a copy."""
        return np.array(self._qpos)

    def joint_velocities(self) -> np.ndarray:
        """Joint velocities J1, J2, J3 (rad/s), a copy."""
        return np.array(self._qvel)

    def motor_angles(self) -> np.ndarray:
        """Motor shaft angles (rad) from the model's zero pose: ``M_rad·q``."""
        return np.asarray(self._m_rad @ self.joint_angles())

    def motor_currents_a(self) -> np.ndarray:
        """Signed winding currents of the last tick (A); 0 while coasting."""
        return np.array([winding.current for winding in self._windings])

    def capstan_torques_nm(self) -> np.ndarray:
        """Each motor's pull on its tendon as the torque at its capstan (N·m, signed): the
        motor torque of the last step (the actuator's force on its motor tendon, MuJoCo's
        ``actuator_force``) times its gear ratio (:data:`protocol.robot.FINGER_GEAR_RATIOS`).
        A tendon's tension is this over its capstan's radius, which the model does not
        have; 0 while the motors coast (a slack finger)."""
        force = self.data.actuator_force
        return np.array([g * float(force[a]) for g, a in zip(FINGER_GEAR_RATIOS, self._act,
                                                              strict=True)])

    def tendon_load_nm(self) -> float:
        """The most loaded tendon's capstan torque (N·m, ≥ 0; :meth:`capstan_torques_nm`):
        what flexes and strains the tendons, and so their contacts."""
        force = self.data.actuator_force
        return max(abs(g * float(force[a])) for g, a in zip(FINGER_GEAR_RATIOS, self._act,
                                                             strict=True))

    def winding_temperatures_c(self) -> np.ndarray:
        """Winding temperatures (°C) of motors 0..2."""
        return np.array(self.thermal.temperature_c)

    # --- slow sensors -----------------------------------------------------------------------
    def _update_sensors(self) -> None:
        """IMUs (accel, mag) of the three boards, f2/f3 taxels, f2 strain.

        Plain Python floats, no numpy call unless a pad is loaded: this runs every 10 ms per
        finger, with the caches cold from the firmware, where each numpy call costs
        microseconds.
        """
        p = self.params
        mv = self._imu_mv
        raw: list[float] = (mv.tolist() if mv is not None  # type: ignore[assignment]
                            else self.data.sensordata[self._imu_idx].tolist())
        loads = self._pads.collect()
        if self._presses:
            for k, segment in enumerate(("F2", "F3")):
                force = self._presses.get(segment)
                if force is not None:
                    x, y, _ = PRESS_POINTS[segment]
                    extra = np.array([[x, y, force]])
                    old = loads[k]
                    loads[k] = extra if old is None else np.vstack((old, extra))
        if loads[0] is not None or loads[1] is not None:  # else the taxels read 0
            tactile = p.tactile
            f2 = taxel_forces(loads[0], self._f2_taxels_xy, tactile.spread_m)
            f3 = taxel_forces(loads[1], self._f3_taxels_xy, tactile.spread_m)
            raw += tactile.compression(np.concatenate(
                (self._zeros_f2 if f2 is None else f2,
                 self._zeros_f3 if f3 is None else f3))).tolist()
        errors = self.errors
        if errors is not None:  # the chips as built, before their noise and rounding
            errors.fmcb.apply(raw, 0, 3)
            errors.f2.apply(raw, 6, 9)
            errors.f3.apply(raw, 12, 15)
        size = self._counts.size
        noise, at = self._normals.take(size + 1)  # the last one: the strain gauge's
        counts = self._counts.counts(raw, noise, at)
        self._counts.scale_steps(counts)
        n2 = self._n_f2
        strain_noise = p.strain_noise_counts * noise[at + size]
        if errors is not None:
            errors.f2_pad.apply(counts, 18)
            errors.f3_pad.apply(counts, 18 + n2)
            strain_noise += errors.gauge.offset
        fmcb_in, f2_in, f3_in = self._fmcb_sensors, self._f2_sensors, self._f3_sensors
        fmcb_in.set_accel(counts[0], counts[1], counts[2])
        fmcb_in.set_mag(counts[3], counts[4], counts[5])
        f2_in.set_accel(counts[6], counts[7], counts[8])
        f2_in.set_mag(counts[9], counts[10], counts[11])
        f3_in.set_accel(counts[12], counts[13], counts[14])
        f3_in.set_mag(counts[15], counts[16], counts[17])
        f2_in.set_taxels(counts[18:18 + n2])
        f3_in.set_taxels(counts[18 + n2:])
        moment = self.gauge_moment_nm(loads[0])
        f2_in.set_strain(strain_counts(moment, strain_noise))

    def gauge_moment_nm(self, f2_loads: np.ndarray | None = None) -> float:
        """Bending moment at the F2 gauge about F2's flexion axis (N·m), + for palmar loads.

        From the wrench F2 transmits to the F3 subtree (``data.cfrc_int``, valid after a step
        because the accelerometers make MuJoCo run ``mj_rnePostConstraint``) taken about the
        gauge, plus the normal loads on F2's pad beyond the gauge (``f2_loads`` rows x, y, N).
        Small-vector arithmetic is plain Python: numpy's per-call cost dominates at n = 3.
        """
        cfrc, com, site_pos, site_mat = self._gauge_rows
        wrench: list[float] = cfrc.tolist()  # type: ignore[assignment]
        centre: list[float] = com.tolist()  # type: ignore[assignment]
        gauge: list[float] = site_pos.tolist()  # type: ignore[assignment]
        rot: list[float] = site_mat.tolist()  # type: ignore[assignment]
        tx, ty, tz, fx, fy, fz = wrench
        cx, cy, cz = centre
        gx, gy, gz = gauge
        rx, ry, rz = cx - gx, cy - gy, cz - gz
        # torque about the gauge = τ_c + (c − g) × f; its component along F2's y axis.
        mx = tx + ry * fz - rz * fy
        my = ty + rz * fx - rx * fz
        mz = tz + rx * fy - ry * fx
        moment: float = -(mx * rot[1] + my * rot[4] + mz * rot[7])
        if f2_loads is not None:
            lever = np.maximum(f2_loads[:, 0] - GAUGE_POS[0], 0.0)
            moment += float(f2_loads[:, 2] @ lever)
        return moment

    def _update_thermal(self, interval_s: float) -> None:
        p = self.params
        scale = p.motor.resistance_ohm / max(1, self._i2_ticks)
        temps = self.thermal.update([w.i2_sum * scale for w in self._windings], interval_s)
        for winding in self._windings:
            winding.i2_sum = 0.0
        self._i2_ticks = 0
        rise = sum(temps) / len(temps) - p.ambient_c
        target = p.ambient_c + p.tip_coupling * rise
        decay = math.exp(-interval_s / p.tip_time_constant_s)
        self.tip_temperature_c = target + (self.tip_temperature_c - target) * decay
        errors = self.errors
        if errors is not None:
            errors.fmcb.set_temperature(self.board_temperature_c())
            errors.f2.set_temperature(self.tip_temperature_c)
            errors.f3.set_temperature(self.tip_temperature_c)
            errors.drift(interval_s)
        self._write_temperatures()

    def board_temperature_c(self) -> float:
        """The fmcb board's temperature (°C): ambient plus :attr:`FingerParams.board_coupling`
        × its windings' mean rise.  The phalange boards are at the fingertip's
        (:attr:`tip_temperature_c`)."""
        p = self.params
        temps = self.thermal.temperature_c
        return p.ambient_c + p.board_coupling * (sum(temps) / len(temps) - p.ambient_c)

    def _write_temperatures(self) -> None:
        self._fmcb_sensors.set_temperatures([round(t * 10.0) for t in self.thermal.temperature_c])
        noise, at = self._normals.take(4)
        sigma = self.params.thermistor_noise_counts
        ideal = thermistor_counts(self.tip_temperature_c)
        self._f3_sensors.set_thermistors(
            [max(0, min(0xFFFF, round(ideal + sigma * n))) for n in noise[at:at + 4]])


#: The palm's taxels are further apart (11 × 20 mm) than the fingers' (≈ 9 mm): a wider
#: spread of each load so a contact between taxels still registers.
PALM_TACTILE: Final = TactileModel(spread_m=0.007)


@dataclass(frozen=True)
class PalmParams:
    """Palm sensor rates (ticks), noise (counts), and fixed readings."""

    tactile: TactileModel = field(default_factory=lambda: PALM_TACTILE)
    sensor_period_ticks: int = 10
    accel_noise_counts: float = 2.0
    gyro_noise_counts: float = 5.0
    mag_noise_counts: float = 2.0
    temperature_decic: int = 250
    supply_mv: int = 24000
    #: The accelerometer's output resolution in wire counts (1: a digit is 1 mg).
    accel_step_counts: int = 1


class PalmPlant:
    """The palm board's sensors (a :class:`~hil_emulator.plant.PlantPart` with no dofs).

    Every ``sensor_period_ticks`` (default 10 ms, staggered): ``accel`` (1 mg/count),
    ``gyro`` (0.01 °/s per count, board = palm frame), ``mag`` and ``taxel0..31`` from the
    palm pad's contacts (:data:`~hil_emulator.hand.model.PALM_TAXELS` order).  ``bind``
    writes ``temperature0..6`` (ambient, 0.1 °C) and ``supply_mv`` once.
    """

    def __init__(self, prefix: str, palm: Mcu, rng: np.random.Generator,
                 params: PalmParams | None = None, errors: PalmErrors | None = None) -> None:
        self.prefix = prefix
        #: The sensors' imperfections as built (None: ideal sensors).
        self.errors = errors
        self.names = PalmNames(prefix)
        self.params = params or PalmParams()
        self.palm = palm
        self.rng = rng
        self._sensors: VirtualSensors = _virtual_hal(palm, "palm").sensors
        self._taxels_xy = np.array(PALM_TAXELS)
        self._sensor_countdown = 1 + _stagger(prefix + "palm", self.params.sensor_period_ticks)
        p = self.params
        self._counts = LinearCounts.imu(
            [("accel", p.accel_noise_counts), ("gyro", p.gyro_noise_counts),
             ("mag", p.mag_noise_counts)], step=p.accel_step_counts
        ).join(LinearCounts.taxels(p.tactile, len(PALM_TAXELS)))
        self._normals = NormalStream(rng)

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Resolve the palm's names; write the constant channels; take a first sample."""
        self.model, self.data = model, data
        names = self.names
        try:
            imu_sensors = [model.sensor(name).id for name in
                           (names.accel_sensor, names.gyro_sensor, names.mag_sensor)]
            pad = model.geom(names.pad).id
        except KeyError as exc:
            raise PlantError(f"palm {self.prefix!r} is not in the model: {exc}") from exc
        self._imu_idx = np.concatenate(
            [np.arange(model.sensor_adr[s], model.sensor_adr[s] + 3) for s in imu_sensors])
        view = _block_view(data.sensordata, self._imu_idx)
        self._imu_mv = None if view is None else _doubles(view)
        self._pads = PadContacts(model, data, [pad])
        self._sensors.set_temperatures([self.params.temperature_decic] * 7)
        self._sensors.set_supply_mv(self.params.supply_mv)
        self._update_sensors()

    def before_step(self, dt_s: float) -> None:
        """Nothing to command: the palm has no actuators."""

    def after_step(self, dt_s: float) -> None:
        """IMU and taxels when due."""
        self._sensor_countdown -= 1
        if self._sensor_countdown <= 0:
            self._sensor_countdown = self.params.sensor_period_ticks
            self._update_sensors()

    def _update_sensors(self) -> None:
        """As the fingers': plain floats, no numpy call unless the pad is loaded."""
        p = self.params
        mv = self._imu_mv
        raw: list[float] = (mv.tolist() if mv is not None  # type: ignore[assignment]
                            else self.data.sensordata[self._imu_idx].tolist())
        forces = taxel_forces(self._pads.collect()[0], self._taxels_xy, p.tactile.spread_m)
        if forces is not None:  # else the taxels read 0
            raw += p.tactile.compression(forces).tolist()
        errors = self.errors
        if errors is not None:  # accel at 0, gyro at 3 (another part), mag at 6
            errors.imu.apply(raw, 0, 6)
        noise, at = self._normals.take(self._counts.size)
        counts = self._counts.counts(raw, noise, at)
        self._counts.scale_steps(counts)
        if errors is not None:
            errors.pad.apply(counts, 9)
        sensors = self._sensors
        sensors.set_accel(counts[0], counts[1], counts[2])
        sensors.set_gyro(counts[3], counts[4], counts[5])
        sensors.set_mag(counts[6], counts[7], counts[8])
        sensors.set_taxels(counts[9:])
