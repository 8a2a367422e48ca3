"""Sensor models of the hand's boards: IMUs, tactile pads, strain gauge, temperatures.

Everything here turns physical quantities from the MuJoCo state into the integer counts the
firmware reads (the plant writes them through the HAL's plant side); noise comes in as arrays
of standard normal draws from the caller's seeded generator, so a run is repeatable.

Conversions (chosen to match the real chips' orders of magnitude; documented, not measured):

- **Accelerometer** (LSM303-like, ±2 g): 1000 counts per g (1 mg/count) of *proper*
  acceleration in the board frame (a board at rest reads +1000 on its upward axis),
  clamped to ±2000.
- **Magnetometer**: MuJoCo's magnetometer sensor, i.e. the model's constant field
  ``option.magnetic`` (default (0, −0.5, 0), taken as gauss: an earth-like field) rotated
  into the board frame, 1100 counts per gauss.
- **Gyro** (palm): 0.01 °/s per count (:data:`GYRO_COUNTS_PER_RAD_S`), clamped to int16.
- **Taxels** (:class:`TactileModel`): each taxel sees the normal forces on its pad weighted
  by a Gaussian of the distance from the taxel centre (σ = 4 mm); the soft layer compresses
  as ``δ = δ_max·f/(f + f_half)`` (δ_max = 1.25 mm, f_half = 1.5 N: 1.5 mm thick unloaded,
  0.25 mm at saturation; the palm uses σ = 7 mm, its taxels being further apart), and the
  photosensor reading *rises* linearly with compression (the white layer comes closer),
  from 2000 counts unloaded to 42000 at 0.25 mm (16-bit ADC, clamped 0..65535).
- **Strain** (f2): :data:`STRAIN_COUNTS_PER_NM` = 2·10⁶ counts per N·m of bending moment
  about F2's flexion axis at the gauge, positive when a palmar load bends the finger
  backwards (a grasp), clamped to the 24-bit signed range.
- **Temperatures**: windings in 0.1 °C (ambient 25 °C = 250); f3 thermistors as a 12-bit
  divider of a 10 kΩ NTC (B = 3950 K) under a 10 kΩ pull-up: 2048 counts at 25 °C, falling
  as the temperature rises.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import mujoco
import numpy as np

from hil_emulator.plant import rint
from protocol.robot import ACCEL_COUNTS_PER_G

#: Standard gravity (m/s²) for the accelerometer scale.
STANDARD_GRAVITY: Final = 9.80665
ACCEL_CLAMP: Final = 2000
#: Magnetometer scale (counts/gauss; the field is the model's ``option.magnetic``).
MAG_COUNTS_PER_GAUSS: Final = 1100.0
#: Gyro counts per rad/s (0.01 °/s per count).
GYRO_COUNTS_PER_RAD_S: Final = 100.0 * 180.0 / math.pi
INT16_MAX: Final = 0x7FFF
#: Strain gauge gain (counts per N·m) and range of its 24-bit signed ADC.
STRAIN_COUNTS_PER_NM: Final = 2.0e6
STRAIN_MAX: Final = (1 << 23) - 1
#: Thermistors: NTC at 25 °C (Ω), its B constant (K), the pull-up (Ω), ADC full scale.
NTC_R25_OHM: Final = 10_000.0
NTC_B_K: Final = 3950.0
NTC_PULLUP_OHM: Final = 10_000.0
THERMISTOR_FULL_SCALE: Final = 4096
KELVIN: Final = 273.15
#: True when this module runs from its source (pure Python), not compiled by mypyc.
_FROM_SOURCE: Final = __file__.endswith(".py")


#: Per IMU channel kind: counts per SI unit (m/s², gauss, rad/s) and the clamp (±counts).
IMU_SCALES: Final = {
    "accel": (ACCEL_COUNTS_PER_G / STANDARD_GRAVITY, ACCEL_CLAMP),
    "mag": (MAG_COUNTS_PER_GAUSS, INT16_MAX),
    "gyro": (GYRO_COUNTS_PER_RAD_S, INT16_MAX),
}


class LinearCounts:
    """``counts = clamp(round(raw·scale + offset + σ·noise), lo, hi)`` per element.

    One instance converts every slowly refreshed channel of a part in one loop, in plain
    Python floats: at a few tens of elements numpy's per-call cost (with the caches cold
    from the firmware) was most of a refresh, and the compiled core runs this loop as C.
    The elements come in *runs* sharing their constants (an IMU's 3-vector, a pad's
    taxels), unpacked once per run.  The same IEEE operations in the same order as numpy's
    ``raw * scale + offset + noise * sigma``, and round-half-even as ``np.rint``: the same
    integers.  Build it with :meth:`imu` and :meth:`taxels` and join with :meth:`join`.
    """

    def __init__(self, runs: list[tuple[int, float, float, float, float, float]]) -> None:
        #: Per run: (length, scale, offset, σ, lo, hi).
        self.runs = runs
        self.size = sum(run[0] for run in runs)
        #: Per element: (scale, offset, σ, lo, hi) (:meth:`_counts_flat`).
        self._constants = [run[1:] for run in runs for _ in range(run[0])]
        #: (first element, step counts) of each 3-vector read in digits of ``step`` counts
        #: (:meth:`imu`); kept through :meth:`join` when it comes first.
        self.stepped: list[tuple[int, int]] = []

    @classmethod
    def imu(cls, channels: list[tuple[str, float]], step: int = 1) -> LinearCounts:
        """Consecutive 3-vectors of ``(kind, noise σ counts)``, kind ``"accel"`` (raw in
        m/s², proper acceleration), ``"mag"`` (gauss) or ``"gyro"`` (rad/s).

        ``step`` (counts, ≥ 1): the accelerometers' output resolution in wire counts.  Above
        1 their runs convert to chip digits of ``step`` counts (scale, σ and clamp divided
        by it) and :meth:`scale_steps` multiplies those digits back into counts: readings
        on a grid of ``step``."""
        runs = []
        for kind, sigma in channels:
            scale, clamp = IMU_SCALES[kind]
            div = float(step) if kind == "accel" else 1.0
            runs.append((3, float(scale) / div, 0.0, float(sigma) / div, -float(clamp) / div,
                         float(clamp) / div))
        out = cls(runs)
        if step > 1:
            out.stepped = [(3 * i, step) for i, (kind, _) in enumerate(channels)
                           if kind == "accel"]
        return out

    def scale_steps(self, counts: list[int]) -> None:
        """Chip digits → counts, in place, for the runs :meth:`imu` made stepped (none:
        nothing to do)."""
        for start, step in self.stepped:
            counts[start] = counts[start] * step
            counts[start + 1] = counts[start + 1] * step
            counts[start + 2] = counts[start + 2] * step

    @classmethod
    def taxels(cls, model: TactileModel, n: int) -> LinearCounts:
        """``n`` taxels whose raw value is the layer's relative compression δ/δ_max (0..1)."""
        return cls([(n, float(model.full_counts - model.unloaded_counts),
                     float(model.unloaded_counts), float(model.noise_counts), 0.0,
                     float(0xFFFF))])

    def join(self, other: LinearCounts) -> LinearCounts:
        """This conversion followed by ``other`` (concatenated elements; runs of equal
        constants merged)."""
        runs = list(self.runs)
        for run in other.runs:
            if runs and runs[-1][1:] == run[1:]:
                runs[-1] = (runs[-1][0] + run[0], *run[1:])
            else:
                runs.append(run)
        out = LinearCounts(runs)
        out.stepped = self.stepped + [(start + self.size, step)
                                      for start, step in other.stepped]
        return out

    def counts(self, raw: list[float], noise: list[float], at: int = 0) -> list[int]:
        """Counts (Python ints) for ``raw`` values and the standard normal draws
        ``noise[at:at + size]``.

        Elements past the end of ``raw`` read a raw value of 0 (unloaded taxels):
        ``0·scale + offset`` is ``offset`` exactly, so only their noise is converted.
        Values are clamped to the integral bounds before rounding (the same integers as
        after; NaN reads as the low bound).
        """
        if _FROM_SOURCE:
            return self._counts_flat(raw, noise, at)
        return self._counts_by_run(raw, noise, at)

    def _counts_by_run(self, raw: list[float], noise: list[float], at: int) -> list[int]:
        """:meth:`counts` a run at a time: the compiled core's loops keep the constants
        unboxed."""
        out: list[int] = []
        n = len(raw)
        k = 0
        # Comprehensions, not loops storing by index: a run's values, then its counts.
        for length, scale, offset, sigma, lo, hi in self.runs:
            end = k + length
            split = n if n < end else end  # raw values up to here, unloaded after
            values = [raw[j] * scale + offset + noise[at + j] * sigma for j in range(k, split)]
            if split < end:
                start = split if split > k else k
                values += [offset + noise[j] * sigma for j in range(at + start, at + end)]
            out += [rint(v) if lo <= v <= hi else _clamped(v, lo, hi) for v in values]
            k = end
        return out

    def _counts_flat(self, raw: list[float], noise: list[float], at: int) -> list[int]:
        """:meth:`counts` in one comprehension over the elements with raw values, then one
        per run of unloaded elements (usually the one run of taxels): from source, a
        comprehension's own cost, paid per run, was most of a refresh.  The same
        operations in the same order as :meth:`_counts_by_run`."""
        size = self.size
        out = [rint(v) if lo <= (v := r * scale + offset + x * sigma) <= hi
               else _clamped(v, lo, hi)
               for r, x, (scale, offset, sigma, lo, hi)
               in zip(raw, noise[at:at + size], self._constants, strict=False)]
        n = len(out)
        if n < size:
            k = 0
            for length, _, offset, sigma, lo, hi in self.runs:
                end = k + length
                if end > n:
                    out += [rint(v) if lo <= (v := offset + x * sigma) <= hi
                            else _clamped(v, lo, hi)
                            for x in noise[at + (n if n > k else k):at + end]]
                k = end
        return out


def _clamped(value: float, lo: float, hi: float) -> int:
    """``value`` outside ``lo..hi`` (or NaN: ``lo``) as the nearer bound's integer."""
    return round(hi) if value > lo else round(lo)


class NormalStream:
    """Standard normal draws of one generator, drawn in blocks and handed out in order.

    ``Generator.standard_normal`` draws each number from the bit stream in turn, so handing
    out a block's numbers in order gives exactly what drawing each request from the
    generator would: the same sensors for the same seed, without a numpy call (and its
    cold-cache cost) per refresh.  The generator must be this stream's alone once it draws.
    """

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self.rng = rng
        self.block = block
        self._buffer: list[float] = []
        self._at = 0

    def take(self, n: int) -> tuple[list[float], int]:
        """The next ``n`` draws: ``buffer[at:at + n]`` of the returned (buffer, at)."""
        at = self._at
        buffer = self._buffer
        if at + n > len(buffer):
            fresh: list[float] = self.rng.standard_normal(max(self.block, n)).tolist()
            buffer = self._buffer = buffer[at:] + fresh
            at = 0
        self._at = at + n
        return buffer, at


class ImuErrors:
    """One board's accelerometer as built, and the magnetometer in the same package.

    The board reads ``a_chip = M·a_nominal + b(T)`` (m/s²) where ``a_nominal`` is the proper
    acceleration in the board's nominal axes (the model's IMU site), ``M = (I + S)(I + C)·Rᵀ``
    folds the mounting rotation ``R`` (chip axes in the nominal frame), the cross-axis
    coupling ``C`` (zero diagonal) and the per-axis scale error ``S`` (diagonal), and
    ``b(T) = b₀ + k·(T − T_ref)`` is the zero-g offset with its temperature coefficient
    ``k`` (m/s² per °C).  The magnetometer turns with the package: ``m_chip = Rᵀ·m``.
    Matrices come precomputed, row-major (9 floats); :meth:`set_temperature` recomputes the
    offset, :meth:`apply` is the per-refresh work (two 3×3 products, plain floats)."""

    def __init__(self, accel_matrix: list[float], bias_m_s2: list[float],
                 bias_tc_m_s2_per_c: list[float], mag_matrix: list[float],
                 reference_c: float) -> None:
        if len(accel_matrix) != 9 or len(mag_matrix) != 9:
            raise ValueError("ImuErrors: the matrices are 9 floats, row-major")
        if len(bias_m_s2) != 3 or len(bias_tc_m_s2_per_c) != 3:
            raise ValueError("ImuErrors: the offsets are 3 floats")
        self.accel_matrix = [float(v) for v in accel_matrix]
        self.mag_matrix = [float(v) for v in mag_matrix]
        self.bias_m_s2 = [float(v) for v in bias_m_s2]
        self.bias_tc = [float(v) for v in bias_tc_m_s2_per_c]
        self.reference_c = float(reference_c)
        #: The offset at the board's present temperature (m/s²).
        self.bias_now = list(self.bias_m_s2)
        self.temperature_c = self.reference_c

    def set_temperature(self, temperature_c: float) -> None:
        """The board is at ``temperature_c`` (°C): its zero-g offset moves with it."""
        dt = temperature_c - self.reference_c
        self.temperature_c = temperature_c
        b, k = self.bias_m_s2, self.bias_tc
        self.bias_now = [b[0] + k[0] * dt, b[1] + k[1] * dt, b[2] + k[2] * dt]

    def apply(self, raw: list[float], accel_at: int, mag_at: int) -> None:
        """Rewrite, in place, the accelerometer 3-vector at ``raw[accel_at:]`` (m/s²) as
        the chip measures it, and the magnetometer's at ``raw[mag_at:]`` (``mag_at`` < 0:
        none)."""
        x, y, z = raw[accel_at], raw[accel_at + 1], raw[accel_at + 2]
        m = self.accel_matrix
        b = self.bias_now
        raw[accel_at] = m[0] * x + m[1] * y + m[2] * z + b[0]
        raw[accel_at + 1] = m[3] * x + m[4] * y + m[5] * z + b[1]
        raw[accel_at + 2] = m[6] * x + m[7] * y + m[8] * z + b[2]
        if mag_at >= 0:
            x, y, z = raw[mag_at], raw[mag_at + 1], raw[mag_at + 2]
            r = self.mag_matrix
            raw[mag_at] = r[0] * x + r[1] * y + r[2] * z
            raw[mag_at + 1] = r[3] * x + r[4] * y + r[5] * z
            raw[mag_at + 2] = r[6] * x + r[7] * y + r[8] * z


class PadErrors:
    """Per-taxel offsets (counts) of one board's pads as built, and their drift.

    Each taxel reads its ideal counts plus its own offset, which wanders as a random walk
    (:meth:`drift`, at the plant's thermal period); :meth:`apply` adds the rounded offsets
    to the taxels' counts in place and clamps to the 16-bit ADC."""

    def __init__(self, offsets_counts: list[float], drift_counts_per_sqrt_s: float) -> None:
        self.offsets = [float(v) for v in offsets_counts]
        self.drift_sigma = float(drift_counts_per_sqrt_s)
        self._rounded = [rint(v) for v in self.offsets]

    def drift(self, noise: list[float], at: int, interval_s: float) -> None:
        """Advance the random walk by ``interval_s`` seconds with the standard normal draws
        ``noise[at:at + len(offsets)]``."""
        step = self.drift_sigma * math.sqrt(interval_s)
        self.offsets = [v + step * noise[at + j] for j, v in enumerate(self.offsets)]
        self._rounded = [rint(v) for v in self.offsets]

    def apply(self, counts: list[int], start: int) -> None:
        """Add the offsets to ``counts[start:start + len(offsets)]`` (in place, clamped to
        0..65535)."""
        for j, off in enumerate(self._rounded):
            v = counts[start + j] + off
            counts[start + j] = 0 if v < 0 else 0xFFFF if v > 0xFFFF else v


class GaugeErrors:
    """The strain gauge's bridge offset (counts) as built and its drift (a random walk,
    counts per √s, advanced at the plant's thermal period)."""

    def __init__(self, offset_counts: float, drift_counts_per_sqrt_s: float) -> None:
        self.offset = float(offset_counts)
        self.drift_sigma = float(drift_counts_per_sqrt_s)

    def drift(self, noise: float, interval_s: float) -> None:
        """Advance the random walk by ``interval_s`` seconds with one standard normal draw."""
        self.offset = self.offset + self.drift_sigma * math.sqrt(interval_s) * noise


class FingerErrors:
    """What one finger module's sensors get wrong as built (``--sensors realistic``): each
    board's :class:`ImuErrors`, f2's and f3's :class:`PadErrors`, f2's :class:`GaugeErrors`,
    and the standard normal draws their drifts take (a stream of their own, so the plant's
    noise is the same with them or without)."""

    def __init__(self, fmcb: ImuErrors, f2: ImuErrors, f3: ImuErrors, f2_pad: PadErrors,
                 f3_pad: PadErrors, gauge: GaugeErrors, normals: NormalStream) -> None:
        self.fmcb, self.f2, self.f3 = fmcb, f2, f3
        self.f2_pad, self.f3_pad = f2_pad, f3_pad
        self.gauge = gauge
        self.normals = normals

    def drift(self, interval_s: float) -> None:
        """The pads' and the gauge's offsets wander on by ``interval_s`` seconds."""
        n2, n3 = len(self.f2_pad.offsets), len(self.f3_pad.offsets)
        noise, at = self.normals.take(n2 + n3 + 1)
        self.f2_pad.drift(noise, at, interval_s)
        self.f3_pad.drift(noise, at + n2, interval_s)
        self.gauge.drift(noise[at + n2 + n3], interval_s)


class PalmErrors:
    """What the palm board's sensors get wrong as built: its accelerometer (and the
    magnetometer with it; the gyro is another part, left ideal) and its pad's offsets."""

    def __init__(self, imu: ImuErrors, pad: PadErrors) -> None:
        self.imu = imu
        self.pad = pad


def strain_counts(moment_nm: float, noise: float) -> int:
    """Strain ADC counts for a bending moment (N·m), clamped to the 24-bit signed range."""
    counts = round(moment_nm * STRAIN_COUNTS_PER_NM + noise)
    low = -STRAIN_MAX - 1
    return low if counts < low else STRAIN_MAX if counts > STRAIN_MAX else counts


def thermistor_counts(temperature_c: float) -> float:
    """Ideal ADC reading (counts, not rounded) of the f3 NTC divider at ``temperature_c``."""
    t_k = temperature_c + KELVIN
    r_ntc = NTC_R25_OHM * math.exp(NTC_B_K * (1.0 / t_k - 1.0 / (25.0 + KELVIN)))
    return THERMISTOR_FULL_SCALE * r_ntc / (r_ntc + NTC_PULLUP_OHM)


@dataclass(frozen=True)
class TactileModel:
    """Force → soft-layer thickness → ADC counts for one kind of taxel (see module doc)."""

    unloaded_thickness_mm: float = 1.5
    loaded_thickness_mm: float = 0.25
    half_force_n: float = 1.5
    spread_m: float = 0.004
    unloaded_counts: int = 2000
    full_counts: int = 42000
    noise_counts: float = 3.0

    @property
    def max_deflection_mm(self) -> float:
        return self.unloaded_thickness_mm - self.loaded_thickness_mm

    def thickness_mm(self, force_n: np.ndarray) -> np.ndarray:
        """Soft-layer thickness (mm) over each taxel under its share of normal force (N)."""
        out: np.ndarray = (self.unloaded_thickness_mm
                           - self.max_deflection_mm * self.compression(force_n))
        return out

    def compression(self, force_n: np.ndarray) -> np.ndarray:
        """Relative compression δ/δ_max (0..1) of the layer over taxels loaded with ``force_n``."""
        f = np.maximum(force_n, 0.0)
        out: np.ndarray = f / (f + self.half_force_n)
        return out

    def ideal_counts(self, force_n: np.ndarray) -> np.ndarray:
        """Noise-free ADC counts (float) for per-taxel forces (N)."""
        span = self.full_counts - self.unloaded_counts
        out: np.ndarray = self.unloaded_counts + span * self.compression(force_n)
        return out


DEFAULT_TACTILE: Final = TactileModel()


class PadContacts:
    """Normal contact forces on a set of pad geoms, located in each pad body's frame.

    ``pad_geoms[k]`` is the geom id of pad ``k``; :meth:`collect` scans ``data.contact`` for
    contacts that involve a pad and calls :func:`mujoco.mj_contactForce` for those only.
    Plain Python over the contact list: a hand has tens of contacts at most, where numpy's
    per-call overhead would cost more than the loop.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData,
                 pad_geoms: list[int]) -> None:
        self.model = model
        self.data = data
        self.pad_of_geom = {int(g): k for k, g in enumerate(pad_geoms)}
        self.pad_bodies = [int(model.geom_bodyid[g]) for g in pad_geoms]
        self._wrench = np.zeros(6)

    def collect(self) -> list[np.ndarray | None]:
        """Per pad: an (n, 3) array of x, y (m, pad body frame) and normal force (N) of its
        contacts, or None when nothing touches it."""
        data = self.data
        found: list[np.ndarray | None] = [None] * len(self.pad_bodies)
        if data.ncon == 0:
            return found
        contacts = data.contact
        pad_of = self.pad_of_geom
        per_pad: dict[int, list[tuple[float, float, float]]] = {}
        positions: list[list[float]] | None = None
        for i, (g1, g2) in enumerate(contacts.geom.tolist()):
            pad = pad_of.get(g1)
            if pad is None:
                pad = pad_of.get(g2)
                if pad is None:
                    continue
            mujoco.mj_contactForce(self.model, data, i, self._wrench)
            force = float(self._wrench[0])
            if force <= 0.0:
                continue
            body = self.pad_bodies[pad]
            if positions is None:
                positions = contacts.pos.tolist()
            px, py, pz = positions[i]
            bx, by, bz = data.xpos[body].tolist()
            r = data.xmat[body].tolist()
            dx, dy, dz = px - bx, py - by, pz - bz
            # Rᵀ·d: the contact point in the body frame (x, y only).
            local_x = r[0] * dx + r[3] * dy + r[6] * dz
            local_y = r[1] * dx + r[4] * dy + r[7] * dz
            per_pad.setdefault(pad, []).append((local_x, local_y, force))
        for pad, rows in per_pad.items():
            found[pad] = np.array(rows)
        return found


def taxel_forces(loads: np.ndarray | None, taxels_xy: np.ndarray,
                 spread_m: float) -> np.ndarray | None:
    """Force (N) each taxel sees: Σ loads' normal forces × Gaussian(distance, ``spread_m``).

    ``loads`` is (n, 3): x, y (m, pad body frame), normal force (N), or None (no load:
    returns None); ``taxels_xy`` is (k, 2).
    """
    if loads is None or loads.shape[0] == 0:
        return None
    dx = np.subtract.outer(loads[:, 0], taxels_xy[:, 0])
    dy = np.subtract.outer(loads[:, 1], taxels_xy[:, 1])
    weights = np.exp((dx * dx + dy * dy) * (-0.5 / spread_m ** 2))
    out: np.ndarray = loads[:, 2] @ weights
    return out


class WindingThermal:
    """First-order winding temperatures (°C) of ``n`` motors heated by I²R.

    ``dT/dt = (T_ambient + R_th·P − T) / τ``, integrated exactly over each update with the
    mean power of the interval.  Plain Python lists: n is 3 and numpy's call overhead
    would dominate.
    """

    def __init__(self, n: int, ambient_c: float, thermal_resistance_k_per_w: float,
                 time_constant_s: float) -> None:
        self.ambient_c = ambient_c
        self.r_th = thermal_resistance_k_per_w
        self.tau_s = time_constant_s
        self.temperature_c = [float(ambient_c)] * n

    def update(self, mean_power_w: list[float], dt_s: float) -> list[float]:
        """Advance ``dt_s`` seconds at ``mean_power_w`` (W per motor); returns the temps (°C)."""
        decay = math.exp(-dt_s / self.tau_s)
        temps = []
        for t, power in zip(self.temperature_c, mean_power_w, strict=True):
            target = self.ambient_c + self.r_th * power
            temps.append(target + (t - target) * decay)
        self.temperature_c = temps
        return temps
