"""The robot as built, not as drawn: its sensors' imperfections and its geometry's tolerances.

``--sensors realistic`` (the default; ``Emulator(sensors=...)``, ``emu://...?sensors=``)
gives every board sensors as imperfect as the real parts and the robot the link lengths of
a laser-cut build; ``ideal`` keeps the exact sensors and nominal geometry of before (same
draws, same bytes).  Everything here is drawn at construction from the emulator's seed, per
board (each part from its own child of ``SeedSequence(seed)``, keyed by
:data:`PART_KEYS`: the same seed gives finger 2 the same chips in every configuration), and
applied by the plant parts with matrices precomputed here
(:class:`~hil_emulator.hand.sensors.ImuErrors` and its siblings).  What was drawn is the
robot's ground truth, :class:`PlantedTruth` (``EmulatedRobot.planted``), for tests and
calibration to compare estimates with; it never reaches the wire.

The figures, declared once in :data:`REALISTIC` (docs/EMULATOR.md, "Sensors as built",
says where each comes from):

* each accelerometer is an ST **LSM303DLH** (accelerometer and magnetometer in one package;
  datasheet Doc ID 16941, table 3, ±2 g full scale, normal mode): 1 mg/digit, sensitivity
  0.9–1.1 mg/digit (min–max, taken as ±3σ), zero-g offset ±20 mg (typical: ST's terminology
  calls it the population's standard deviation), its change with temperature ±0.1 mg/°C
  (max, drawn uniform), noise density 218 µg/√Hz at 100 Hz output (bandwidth ODR/2: 1.54 mg
  rms); ST gives no cross-axis figure: ±1 % (1σ) as the ADXL345 datasheet's, a comparable
  MEMS part;
* its mounting: a rotation of a few degrees (each axis 1° σ, at most 4°: 1.6° on average) for the chip's
  solder tilt and the board on its laser-cut link (the dissertation's §4.4: "rotations of
  several degrees");
* tactile pads: a per-taxel offset of the photosensor's unloaded reading and its drift;
  the strain gauge: a bridge offset and its drift (representative, no part's datasheet);
* geometry: every joint body's and finger mount's position off by a few tenths of a
  millimetre (0.3 mm σ per axis, at most 1 mm): laser-cut parts and their assembly;
* the arm as assembled (:func:`arm_params`, :func:`lengthen_arm_tubes`): each stepper
  joint's encoder index mark away from the kinematic zero's drawing (0.4° σ: the slotted
  disc clamped on its shaft and the optical flag on its plywood bracket), each RX-64 horn
  turned on its spline (0.5° σ: the spline's play and the horn's alignment mark), and the
  two tubes (upper arm, forearm) 1 mm σ longer or shorter than drawn (cut and seated by
  hand).  None of it is on the wire: the host learns it only by calibration.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import mujoco
import numpy as np

from hil_emulator.arm.actuators import ArmParams
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.finger_plant import FingerParams, PalmParams
from hil_emulator.hand.model import F2_TAXELS, F3_TAXELS, PALM_TAXELS
from hil_emulator.hand.sensors import (
    STANDARD_GRAVITY,
    FingerErrors,
    GaugeErrors,
    ImuErrors,
    NormalStream,
    PadErrors,
    PalmErrors,
)
from protocol.robot import ARM_INDEX_ANGLES

#: The choices of ``--sensors``.
SENSOR_MODES: Final = ("ideal", "realistic")
#: ``--sensors``' default.
DEFAULT_SENSORS: Final = "realistic"
#: Each part's key in the seed sequence's children (``SeedSequence(seed, spawn_key=(k,))``):
#: the palm, finger modules 0..3, then the arm's and the hand's geometry.
PART_KEYS: Final = {"palm": 0, "finger0": 1, "finger1": 2, "finger2": 3, "finger3": 4,
                    "arm geometry": 10, "hand geometry": 11, "serial": 12,
                    "arm assembly": 13, "arm serial": 14}
#: The hand's node uids of ``--sensors ideal`` (the palm's; the fingers' follow it).
IDEAL_UID_BASE: Final = 0x1000
#: The arm's serial number of ``--sensors ideal`` (its stepper nodes' ``arm_serial``).
IDEAL_ARM_SERIAL: Final = 0x0100
#: The arm's bodies whose tube is cut to length by hand (:func:`lengthen_arm_tubes`): the
#: upper arm's (roll bearing → elbow) and the forearm's (forearm roll → wrist pitch).
ARM_TUBE_BODIES: Final = ("arm/forearm", "arm/wrist")
#: The finger boards carrying an accelerometer, in the plant's order.
FINGER_BOARDS: Final = ("fmcb", "f2", "f3")


@dataclass(frozen=True)
class AccelPart:
    """One accelerometer part's datasheet figures (the units in each name)."""

    name: str = "ST LSM303DLH"
    #: Output resolution at ±2 g in normal mode (mg per digit; 12 bits over ±2 g).
    resolution_mg: float = 1.0
    #: Sensitivity tolerance (fraction, ±; the datasheet's min–max, drawn as ±3σ).
    sensitivity_tolerance: float = 0.10
    #: Zero-g offset (mg, 1σ: the datasheet's typical value).
    zero_g_offset_mg: float = 20.0
    #: Zero-g offset change with temperature (mg/°C, ±, the datasheet's max; drawn uniform).
    offset_tc_mg_per_c: float = 0.1
    #: Cross-axis sensitivity (fraction, 1σ).
    cross_axis: float = 0.01
    #: Noise density (µg/√Hz) and output data rate (Hz); the bandwidth is half the rate.
    noise_density_ug_rthz: float = 218.0
    output_rate_hz: float = 100.0
    #: The temperature its offset is given at (°C).
    reference_c: float = 25.0

    def noise_mg(self) -> float:
        """RMS noise of one reading (mg): density × √(ODR/2)."""
        return self.noise_density_ug_rthz * 1e-3 * math.sqrt(self.output_rate_hz / 2.0)


@dataclass(frozen=True)
class Imperfections:
    """Every imperfection's size: the one parameter set of ``--sensors realistic``."""

    accel: AccelPart = field(default_factory=AccelPart)
    #: Mounting rotation of each accelerometer (deg, 1σ about each axis; clipped).
    mount_tilt_deg: float = 1.0
    mount_tilt_max_deg: float = 4.0
    #: Taxels: offset of each one's unloaded reading (counts, 1σ) and its drift (counts/√s).
    taxel_offset_counts: float = 150.0
    taxel_drift_counts_per_sqrt_s: float = 2.0
    #: Strain gauge: bridge offset (counts, 1σ; 2·10⁶ counts per N·m) and drift (counts/√s).
    gauge_offset_counts: float = 20_000.0
    gauge_drift_counts_per_sqrt_s: float = 50.0
    #: Geometry: each joint body's and finger mount's position (m, 1σ per axis; clipped).
    geometry_sigma_m: float = 0.0003
    geometry_max_m: float = 0.001
    #: The arm as assembled: each stepper joint's encoder index mark off its drawn angle
    #: (rad, 1σ), each RX-64 horn's turn on its spline (rad, 1σ), each hand-cut tube's
    #: length (m, 1σ); each clipped at 3σ.
    index_sigma_rad: float = math.radians(0.4)
    horn_sigma_rad: float = math.radians(0.5)
    tube_sigma_m: float = 0.001


#: The figures of ``--sensors realistic``.
REALISTIC: Final = Imperfections()


def check_sensors(sensors: str) -> str:
    """``sensors`` if it is one of :data:`SENSOR_MODES`, else :class:`EmulatorConfigError`."""
    if sensors not in SENSOR_MODES:
        raise EmulatorConfigError(f"unknown sensors {sensors!r}; choose one of "
                                  f"{', '.join(SENSOR_MODES)}")
    return sensors


def part_rng(seed: int, part: str) -> np.random.Generator:
    """The generator of ``part``'s imperfections (:data:`PART_KEYS`) for ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PART_KEYS[part],)))


def hand_uid_base(seed: int, sensors: str) -> int:
    """The palm's uid (its boards' numbering base, a multiple of 0x1000): ``ideal`` keeps
    :data:`IDEAL_UID_BASE`; ``realistic`` draws it from the seed, so robots of different
    seeds, whose parts differ, have different serial numbers (a calibration file is named
    by it) as two real hands do."""
    if sensors != "realistic":
        return IDEAL_UID_BASE
    return int(part_rng(seed, "serial").integers(2, 0x80000)) << 12


def arm_serial(seed: int, sensors: str) -> int:
    """The arm's serial number (16 bits, never :data:`~protocol.control_tables.ARM_SERIAL_UNSET`),
    programmed into its stepper nodes' ``arm_serial``: ``ideal`` keeps
    :data:`IDEAL_ARM_SERIAL`; ``realistic`` draws it from the seed, so arms of different
    seeds (whose assembly errors differ) have different serials, as two built arms do."""
    if sensors != "realistic":
        return IDEAL_ARM_SERIAL
    return int(part_rng(seed, "arm serial").integers(1, 0x10000))


def rotation_from_vector(v: np.ndarray) -> np.ndarray:
    """The rotation (3×3) by ``|v|`` rad about ``v`` (Rodrigues)."""
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    out: np.ndarray = np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)
    return out


@dataclass(frozen=True)
class AccelTruth:
    """One accelerometer as built: ``a_chip = (I + diag(scale))(I + cross)·rotationᵀ·a +
    bias + tc·(T − T_ref)``.  ``rotation``: the chip's axes (columns) in the board's nominal
    frame; ``scale`` (fraction per axis); ``cross`` (3×3, zero diagonal); ``bias_mg`` (mg)
    and ``tc_mg_per_c`` (mg/°C) per axis; ``reference_c`` (°C); ``tilt_rad``: ``rotation``
    as a rotation vector (rad, :func:`rotation_from_vector`; None: not kept)."""

    rotation: np.ndarray
    scale: np.ndarray
    cross: np.ndarray
    bias_mg: np.ndarray
    tc_mg_per_c: np.ndarray
    reference_c: float
    tilt_rad: np.ndarray | None = None

    def matrix(self) -> np.ndarray:
        """``M`` (3×3): nominal-frame acceleration → what the chip's axes read (no offset)."""
        out: np.ndarray = ((np.eye(3) + np.diag(self.scale)) @ (np.eye(3) + self.cross)
                           @ self.rotation.T)
        return out

    def tilt_deg(self) -> float:
        """The mounting rotation's angle (deg)."""
        return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(self.rotation) - 1) / 2))))

    def errors(self) -> ImuErrors:
        """The plant's per-refresh form (SI units, row-major)."""
        mg = STANDARD_GRAVITY / 1000.0
        return ImuErrors(self.matrix().ravel().tolist(), (self.bias_mg * mg).tolist(),
                         (self.tc_mg_per_c * mg).tolist(), self.rotation.T.ravel().tolist(),
                         self.reference_c)


def draw_accel(rng: np.random.Generator, p: Imperfections = REALISTIC) -> AccelTruth:
    """One accelerometer and its mounting, drawn from ``rng`` in a fixed order."""
    a = p.accel
    tilt = np.clip(rng.normal(0.0, math.radians(p.mount_tilt_deg), 3),
                   -math.radians(p.mount_tilt_max_deg), math.radians(p.mount_tilt_max_deg))
    scale = np.clip(rng.normal(0.0, a.sensitivity_tolerance / 3.0, 3),
                    -a.sensitivity_tolerance, a.sensitivity_tolerance)
    cross = rng.normal(0.0, a.cross_axis, (3, 3))
    np.fill_diagonal(cross, 0.0)
    bias = rng.normal(0.0, a.zero_g_offset_mg, 3)
    tc = rng.uniform(-a.offset_tc_mg_per_c, a.offset_tc_mg_per_c, 3)
    return AccelTruth(rotation_from_vector(tilt), scale, cross, bias, tc, a.reference_c, tilt)


#: What a robot profile makes of a board's drawn accelerometer (the board's name, the draw).
AccelAdjust = Callable[[str, AccelTruth], AccelTruth]


def _as_drawn(_board: str, drawn: AccelTruth) -> AccelTruth:
    return drawn


@dataclass(frozen=True)
class PadTruth:
    """One board's taxel offsets (counts) as built, before any drift."""

    offsets_counts: np.ndarray


@dataclass
class PlantedTruth:
    """What ``--sensors realistic`` drew for one robot: the ground truth of its parts.

    ``accels`` by board (``"palm"``, ``"finger{k}.fmcb"``, ``"finger{k}.f2"``, ``"finger{k}.f3"``);
    ``pads`` by board (``"palm"``, ``"finger{k}.f2"``, ``"finger{k}.f3"``); ``gauge_offsets_counts``
    by board (``"finger{k}.f2"``); ``geometry_m``: each moved body's name in the model and how far
    it moved from its nominal position (m, its parent's frame).  The drifting offsets' present
    values are the plant parts' (``FingerPlant.errors``)."""

    accels: dict[str, AccelTruth] = field(default_factory=dict)
    pads: dict[str, PadTruth] = field(default_factory=dict)
    gauge_offsets_counts: dict[str, float] = field(default_factory=dict)
    geometry_m: dict[str, np.ndarray] = field(default_factory=dict)
    #: The arm as assembled (zeros: not drawn): J1..J4's index marks' angles less their
    #: drawn ones (rad; the plant's index sits at ``ARM_INDEX_ANGLES + this``, so the homed
    #: host reads ``q − this``), J5..J7's horn offsets (rad; the host reads ``q + this``),
    #: and the upper-arm and forearm tubes' length errors (m, :data:`ARM_TUBE_BODIES`' order).
    arm_index_offsets_rad: np.ndarray = field(default_factory=lambda: np.zeros(4))
    arm_horn_offsets_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))
    arm_tube_errors_m: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def arm_reading_offsets_rad(self) -> np.ndarray:
        """What the homed host reads less the true joint angle (rad, J1..J7): ``−index``
        for the steppers, ``+horn`` for the servos."""
        return np.concatenate((-self.arm_index_offsets_rad, self.arm_horn_offsets_rad))


def _pad(rng: np.random.Generator, n: int, p: Imperfections) -> PadTruth:
    return PadTruth(rng.normal(0.0, p.taxel_offset_counts, n))


def finger_errors(seed: int, finger: int, truth: PlantedTruth,
                  p: Imperfections = REALISTIC, adjust: AccelAdjust = _as_drawn
                  ) -> FingerErrors:
    """Finger module ``finger``'s sensor errors for ``seed``, recorded in ``truth``;
    ``adjust`` turns each board's drawn accelerometer into the one built (a robot profile's
    values, :func:`hil_emulator.hand_profile.accel_truth`) after every draw."""
    rng = part_rng(seed, f"finger{finger}")
    name = f"finger{finger}"
    drawn = [draw_accel(rng, p) for _ in FINGER_BOARDS]
    f2_pad, f3_pad = _pad(rng, len(F2_TAXELS), p), _pad(rng, len(F3_TAXELS), p)
    gauge = float(rng.normal(0.0, p.gauge_offset_counts))
    accels = [adjust(f"{name}.{board}", a) for board, a in zip(FINGER_BOARDS, drawn,
                                                                 strict=True)]
    for board, accel in zip(FINGER_BOARDS, accels, strict=True):
        truth.accels[f"{name}.{board}"] = accel
    truth.pads[f"{name}.f2"], truth.pads[f"{name}.f3"] = f2_pad, f3_pad
    truth.gauge_offsets_counts[f"{name}.f2"] = gauge
    drift = p.taxel_drift_counts_per_sqrt_s
    return FingerErrors(accels[0].errors(), accels[1].errors(), accels[2].errors(),
                        PadErrors(f2_pad.offsets_counts.tolist(), drift),
                        PadErrors(f3_pad.offsets_counts.tolist(), drift),
                        GaugeErrors(gauge, p.gauge_drift_counts_per_sqrt_s),
                        NormalStream(rng))


def palm_errors(seed: int, truth: PlantedTruth, p: Imperfections = REALISTIC,
                adjust: AccelAdjust = _as_drawn) -> PalmErrors:
    """The palm board's sensor errors for ``seed``, recorded in ``truth`` (``adjust`` as
    :func:`finger_errors`')."""
    rng = part_rng(seed, "palm")
    drawn = draw_accel(rng, p)
    pad = _pad(rng, len(PALM_TAXELS), p)
    accel = adjust("palm", drawn)
    truth.accels["palm"], truth.pads["palm"] = accel, pad
    return PalmErrors(accel.errors(), PadErrors(pad.offsets_counts.tolist(), 0.0))


def finger_params(p: Imperfections = REALISTIC) -> FingerParams:
    """A finger module's plant parameters with the part's noise and resolution."""
    return FingerParams(accel_noise_counts=p.accel.noise_mg(),
                        accel_step_counts=round(p.accel.resolution_mg))


def palm_params(p: Imperfections = REALISTIC) -> PalmParams:
    """The palm's plant parameters with the part's noise and resolution."""
    return PalmParams(accel_noise_counts=p.accel.noise_mg(),
                      accel_step_counts=round(p.accel.resolution_mg))


def perturb_bodies(spec: mujoco.MjSpec, names: list[str], rng: np.random.Generator,
                   truth: PlantedTruth, p: Imperfections = REALISTIC) -> None:
    """Move each body of ``names`` in ``spec`` (before it compiles) from its nominal
    position by a drawn offset (:attr:`Imperfections.geometry_sigma_m` per axis), in order;
    recorded in ``truth.geometry_m``."""
    for name in names:
        body = spec.body(name)
        if body is None:
            raise EmulatorConfigError(f"no body {name!r} to place as built")
        delta = np.clip(rng.normal(0.0, p.geometry_sigma_m, 3), -p.geometry_max_m,
                        p.geometry_max_m)
        body.pos = np.asarray(body.pos, dtype=float) + delta
        truth.geometry_m[name] = delta


def _clipped(rng: np.random.Generator, sigma: float, n: int) -> np.ndarray:
    return np.clip(rng.normal(0.0, sigma, n), -3.0 * sigma, 3.0 * sigma)


def draw_arm_assembly(seed: int, truth: PlantedTruth, p: Imperfections = REALISTIC) -> None:
    """Draw the arm's assembly errors for ``seed`` (index marks, horns, tubes, in that order)
    into ``truth``."""
    rng = part_rng(seed, "arm assembly")
    truth.arm_index_offsets_rad = _clipped(rng, p.index_sigma_rad, 4)
    truth.arm_horn_offsets_rad = _clipped(rng, p.horn_sigma_rad, 3)
    truth.arm_tube_errors_m = _clipped(rng, p.tube_sigma_m, len(ARM_TUBE_BODIES))


def arm_params(truth: PlantedTruth) -> ArmParams:
    """The arm plant's parameters as assembled (``truth``'s index marks and horns)."""
    return ArmParams(index_angles=np.array(ARM_INDEX_ANGLES) + truth.arm_index_offsets_rad,
                     horn_offsets_rad=(float(truth.arm_horn_offsets_rad[0]),
                                       float(truth.arm_horn_offsets_rad[1]),
                                       float(truth.arm_horn_offsets_rad[2])))


def lengthen_arm_tubes(spec: mujoco.MjSpec, truth: PlantedTruth) -> None:
    """Move each of :data:`ARM_TUBE_BODIES` along its link (the parent's ``−z``) by its tube's
    length error in ``truth`` (a longer tube puts the joint further down the link)."""
    for name, error in zip(ARM_TUBE_BODIES, truth.arm_tube_errors_m, strict=True):
        body = spec.body(name)
        if body is None:
            raise EmulatorConfigError(f"no body {name!r} to place as built")
        body.pos = np.asarray(body.pos, dtype=float) + np.array([0.0, 0.0, -float(error)])
