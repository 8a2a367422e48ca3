"""The robot as built (``--sensors realistic``): each imperfection shows where it should, of
the size the part's datasheet gives, drawn from the seed per board; ``ideal`` draws none."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_emulator.arm.plant import POT_UNITS_PER_RAD
from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.finger_plant import FingerPlant
from hil_emulator.hand.model import FingerNames
from hil_emulator.hand.sensors import (
    STANDARD_GRAVITY,
    GaugeErrors,
    LinearCounts,
    PadErrors,
)
from hil_emulator.imperfections import (
    REALISTIC,
    AccelTruth,
    draw_accel,
    part_rng,
    rotation_from_vector,
)
from hil_emulator.inprocess import EmulatorTransport, forget_shared_emulators
from host.errors import UsageError
from protocol.robot import ARM_INDEX_ANGLES, ARM_JOINT_OFFSETS_M

MG = STANDARD_GRAVITY / 1000.0  # m/s² per mg


def _truth(rotation: np.ndarray | None = None, scale: tuple[float, ...] = (0.0, 0.0, 0.0),
           bias_mg: tuple[float, ...] = (0.0, 0.0, 0.0),
           tc: tuple[float, ...] = (0.0, 0.0, 0.0)) -> AccelTruth:
    return AccelTruth(np.eye(3) if rotation is None else rotation, np.array(scale),
                      np.zeros((3, 3)), np.array(bias_mg), np.array(tc), 25.0)


def _chip(truth: AccelTruth, a_mg: tuple[float, float, float]) -> list[float]:
    raw = [v * MG for v in a_mg] + [0.0, 0.0, 0.0]
    truth.errors().apply(raw, 0, 3)
    return [v / MG for v in raw[:3]]


# --------------------------------------------------------------------- one chip, by hand
def test_a_mounting_rotation_reads_as_that_tilt() -> None:
    """A chip turned 3° about its board's x axis sees gravity (board +z up) 3° off its z:
    y reads +1000·sin 3° = 52.3 mg, z 1000·cos 3° = 998.6 mg."""
    rot = rotation_from_vector(np.array([math.radians(3.0), 0.0, 0.0]))
    x, y, z = _chip(_truth(rot), (0.0, 0.0, 1000.0))
    assert x == pytest.approx(0.0, abs=1e-9)
    assert y == pytest.approx(52.336, abs=1e-3)
    assert z == pytest.approx(998.630, abs=1e-3)
    assert _truth(rot).tilt_deg() == pytest.approx(3.0)


def test_offset_scale_and_temperature_by_hand() -> None:
    """1 g on x with +4 % scale and a +15 mg offset reads 1055 mg; 20 °C warmer with
    +0.1 mg/°C, 1057 mg."""
    truth = _truth(scale=(0.04, 0.0, 0.0), bias_mg=(15.0, -7.0, 0.0), tc=(0.1, 0.0, -0.05))
    errors = truth.errors()
    raw = [1000.0 * MG, 0.0, 0.0]
    errors.apply(raw, 0, -1)
    assert [v / MG for v in raw] == pytest.approx([1055.0, -7.0, 0.0])
    errors.set_temperature(45.0)
    raw = [1000.0 * MG, 0.0, 0.0]
    errors.apply(raw, 0, -1)
    assert [v / MG for v in raw] == pytest.approx([1057.0, -7.0, -1.0])


def test_the_magnetometer_turns_with_the_package_only() -> None:
    """Same package: the magnetometer sees the mounting rotation, not the accelerometer's
    offset or scale."""
    rot = rotation_from_vector(np.array([0.0, 0.0, math.radians(90.0)]))
    truth = _truth(rot, scale=(0.1, 0.1, 0.1), bias_mg=(30.0, 30.0, 30.0))
    raw = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0]  # gauss along the board's x
    truth.errors().apply(raw, 0, 3)
    assert raw[3:] == pytest.approx([0.0, -0.5, 0.0], abs=1e-12)


def test_quantisation_reads_on_the_parts_grid() -> None:
    """With a 4-count digit the readings are multiples of 4 within 2 of the value; the
    LSM303DLH's 1 mg digit is the wire's count."""
    counts = LinearCounts.imu([("accel", 0.0), ("mag", 0.0)], step=4)
    raw = [v * MG for v in (10.0, 13.0, -998.6)] + [0.1, 0.2, 0.3]
    out = counts.counts(raw, [0.0] * 6)
    counts.scale_steps(out)
    assert out[:3] == [12, 12, -1000]
    assert out[3:] == [110, 220, 330]  # the magnetometer keeps its own scale
    assert REALISTIC.accel.resolution_mg == 1.0


def test_pad_offsets_and_their_drift() -> None:
    pad = PadErrors([120.4, -80.6, 30.0], drift_counts_per_sqrt_s=2.0)
    counts = [2000, 2000, 65530]
    pad.apply(counts, 0)
    assert counts == [2120, 1919, 65535]  # clamped to the 16-bit ADC
    pad.drift([1.0, -0.5, 0.0], 0, 4.0)  # 2 counts/√s over 4 s: 4 counts per unit draw
    assert pad.offsets == pytest.approx([124.4, -82.6, 30.0])
    gauge = GaugeErrors(1000.0, 50.0)
    gauge.drift(-1.0, 0.01)
    assert gauge.offset == pytest.approx(995.0)


# --------------------------------------------------------------------- the population
def test_drawn_chips_have_the_datasheets_spread() -> None:
    """4000 chips: offset σ 20 mg, scale σ 10 %/3 within ±10 %, offset TC uniform in
    ±0.1 mg/°C, cross-axis σ 1 %, mounting tilts of a few degrees."""
    rng = np.random.default_rng(3)
    chips = [draw_accel(rng) for _ in range(4000)]
    bias = np.array([c.bias_mg for c in chips])
    scale = np.array([c.scale for c in chips])
    tc = np.array([c.tc_mg_per_c for c in chips])
    cross = np.array([c.cross[0, 1] for c in chips])
    tilts = np.array([c.tilt_deg() for c in chips])
    assert bias.std() == pytest.approx(20.0, rel=0.03)
    assert scale.std() == pytest.approx(0.1 / 3, rel=0.05)
    assert np.abs(scale).max() <= 0.1
    assert np.abs(tc).max() <= 0.1
    assert tc.std() == pytest.approx(0.1 / math.sqrt(3), rel=0.05)
    assert cross.std() == pytest.approx(0.01, rel=0.05)
    assert 1.4 < float(np.mean(tilts)) < 1.8  # 1° σ on each of three axes: 1.6° mean
    assert float(tilts.max()) <= 4.0 * math.sqrt(3) + 1e-9


def test_the_part_noise_is_its_density_over_half_the_rate() -> None:
    """218 µg/√Hz over 50 Hz (100 Hz output): 1.54 mg rms."""
    assert REALISTIC.accel.noise_mg() == pytest.approx(1.5415, abs=1e-4)


@given(st.integers(0, 2**32 - 1))
def test_each_part_draws_from_its_own_stream(seed: int) -> None:
    """Same seed, same part: same draws; another part or seed: others."""
    a = draw_accel(part_rng(seed, "finger2"))
    b = draw_accel(part_rng(seed, "finger2"))
    c = draw_accel(part_rng(seed, "finger1"))
    assert np.array_equal(a.bias_mg, b.bias_mg)
    assert not np.array_equal(a.bias_mg, c.bias_mg)


# --------------------------------------------------------------------- on the emulator
def _settled(sensors: str, seed: int = 5) -> Emulator:
    emu = Emulator("loose-finger", seed=seed, sensors=sensors, can="none")
    emu.step(600_000)  # the unpowered finger settles on its stops
    return emu


def _mean_readings(emu: Emulator, board: str, key: str, n: int) -> np.ndarray:
    assert emu.loose is not None
    hal = getattr(emu.loose.finger, board).hal
    rows = []
    for _ in range(n):
        emu.step(10_000)
        values = hal.sensors.values
        if key == "taxels":
            rows.append(tuple(values[f"taxel{j}"] for j in range(len(values))
                              if f"taxel{j}" in values))
        else:
            value = values[key]
            rows.append(value if isinstance(value, tuple) else (value,))
    return np.array(rows, dtype=float)


def _nominal_accel_mg(emu: Emulator, plant: FingerPlant, board: str) -> np.ndarray:
    assert emu.plant is not None
    model, data = emu.plant.model, emu.plant.data
    sensor = model.sensor(FingerNames(plant.prefix).accel_sensor(board))
    adr = int(model.sensor_adr[sensor.id])
    return np.array(data.sensordata[adr:adr + 3]) / MG


@pytest.mark.parametrize("board", ["fmcb", "f2", "f3"])
def test_each_board_reads_what_its_planted_chip_says(board: str) -> None:
    """At rest, the mean of 40 readings is M·a + b of the planted chip (within 0.7 mg),
    and that is several mg from what an ideal chip reads: the errors are there."""
    emu = _settled("realistic")
    plant = emu.finger_plants[0]
    assert emu.planted is not None
    truth = emu.planted.accels[f"finger0.{board}"]
    readings = _mean_readings(emu, board, "accel", 40)
    nominal = _nominal_accel_mg(emu, plant, board)
    expected = truth.matrix() @ nominal + truth.bias_mg
    assert readings.mean(axis=0) == pytest.approx(expected, abs=0.7)
    assert float(np.linalg.norm(expected - nominal)) > 5.0
    assert readings.std(axis=0) == pytest.approx([REALISTIC.accel.noise_mg()] * 3, rel=0.35)


def test_an_ideal_board_reads_the_nominal_acceleration() -> None:
    emu = _settled("ideal")
    assert emu.planted is None and emu.finger_plants[0].errors is None
    readings = _mean_readings(emu, "f2", "accel", 40)
    nominal = _nominal_accel_mg(emu, emu.finger_plants[0], "f2")
    assert readings.mean(axis=0) == pytest.approx(nominal, abs=0.9)


def test_a_warm_motor_board_moves_its_accelerometer_offset() -> None:
    """The fmcb's windings at 65 °C put its board at 25 + 0.5·40 = 45 °C: its chip's
    offset moves by 20 °C × its coefficient."""
    emu = _settled("realistic")
    plant = emu.finger_plants[0]
    assert plant.errors is not None and emu.planted is not None
    truth = emu.planted.accels["finger0.fmcb"]
    plant.thermal.temperature_c = [65.0, 65.0, 65.0]
    plant.thermal.ambient_c, plant.thermal.r_th = 65.0, 0.0  # held there
    emu.step(100_000)
    chip = plant.errors.fmcb
    assert chip.temperature_c == pytest.approx(45.0)
    assert [b / MG for b in chip.bias_now] == pytest.approx(
        list(truth.bias_mg + truth.tc_mg_per_c * 20.0))


def test_taxels_and_gauge_read_their_planted_offsets() -> None:
    """Unloaded, each taxel reads 2000 plus its own offset (±noise), the gauge its offset;
    ideal taxels read 2000."""
    emu = _settled("realistic")
    assert emu.planted is not None
    offsets = emu.planted.pads["finger0.f3"].offsets_counts
    taxels = _mean_readings(emu, "f3", "taxels", 20)
    assert taxels.mean(axis=0) == pytest.approx(2000 + offsets, abs=4.0)
    assert float(np.abs(offsets).max()) > 50.0
    ideal = _mean_readings(_settled("ideal"), "f3", "taxels", 20)
    assert ideal.mean(axis=0) == pytest.approx([2000.0] * len(offsets), abs=2.0)


def test_the_gauge_reads_its_planted_offset() -> None:
    real, ideal = _settled("realistic"), _settled("ideal")
    assert real.planted is not None
    offset = real.planted.gauge_offsets_counts["finger0.f2"]
    assert abs(offset) > 1000.0
    difference = (_mean_readings(real, "f2", "strain", 20).mean()
                  - _mean_readings(ideal, "f2", "strain", 20).mean())
    assert difference == pytest.approx(offset, abs=0.05 * abs(offset) + 200.0)


def test_the_built_arm_is_off_its_drawing_by_a_laser_cut_builds_tolerance() -> None:
    """Each arm body sits at its nominal offset plus the planted one (≤ 1 mm, a few tenths
    on average); the ideal arm exactly at its drawing's."""
    real = Emulator("arm", seed=2, sensors="realistic")
    ideal = Emulator("arm", seed=2, sensors="ideal")
    assert real.planted is not None and real.plant is not None and ideal.plant is not None
    moved = real.planted.geometry_m
    deltas = np.array(list(moved.values()))
    assert np.abs(deltas).max() <= 0.001
    assert 0.0001 < float(np.abs(deltas).mean()) < 0.0005
    forearm = real.plant.model.body("arm/forearm").id
    tube = np.array([0.0, 0.0, -real.planted.arm_tube_errors_m[0]])  # the upper arm's tube
    assert np.array(real.plant.model.body_pos[forearm]) == pytest.approx(
        np.array(ARM_JOINT_OFFSETS_M[3]) + moved["arm/forearm"] + tube, abs=1e-12)
    assert list(ideal.plant.model.body_pos[ideal.plant.model.body("arm/forearm").id]) == \
        list(ARM_JOINT_OFFSETS_M[3])


def test_the_same_finger_has_the_same_chips_in_every_configuration() -> None:
    full = Emulator("hand", seed=9, physics=True, can="none")
    loose = Emulator("loose-finger", seed=9, can="none")
    assert full.planted is not None and loose.planted is not None
    for board in ("fmcb", "f2", "f3"):
        assert np.array_equal(full.planted.accels[f"finger0.{board}"].bias_mg,
                              loose.planted.accels[f"finger0.{board}"].bias_mg)
    assert not np.array_equal(full.planted.accels["finger0.f2"].bias_mg,
                              full.planted.accels["finger1.f2"].bias_mg)


def test_sensors_is_checked_and_reaches_emu_urls() -> None:
    with pytest.raises(EmulatorConfigError, match="unknown sensors"):
        Emulator("arm", sensors="perfect", physics=False)
    forget_shared_emulators()
    try:
        ideal = EmulatorTransport.from_url("emu://arm/arm?sensors=ideal&physics=0")
        real = EmulatorTransport.from_url("emu://arm/arm?physics=0")
        assert ideal.emulator.sensors == "ideal" and real.emulator.sensors == "realistic"
        assert ideal.emulator is not real.emulator
        with pytest.raises(UsageError, match="unknown sensors"):
            EmulatorTransport.from_url("emu://arm/arm?sensors=perfect&physics=0")
    finally:
        forget_shared_emulators()



def test_the_assembled_arm_has_its_index_marks_horns_and_tubes_off_the_drawing() -> None:
    """The built arm's plant has each index mark at the drawing's angle plus the planted
    offset, each horn's pot reading off 512 at joint angle 0 by the planted offset, and its
    tubes longer or shorter by theirs (0.4°, 0.5°, 1 mm σ); the ideal arm has none of it."""
    real = Emulator("arm", seed=2, sensors="realistic")
    ideal = Emulator("arm", seed=2, sensors="ideal")
    assert real.planted is not None and real.arm_plant is not None
    assert ideal.arm_plant is not None and ideal.plant is not None and real.plant is not None
    assert real.arm is not None
    planted = real.planted
    index, horn, tubes = (planted.arm_index_offsets_rad, planted.arm_horn_offsets_rad,
                          planted.arm_tube_errors_m)
    assert real.arm_plant.params.index_angles == pytest.approx(np.array(ARM_INDEX_ANGLES) + index)
    assert list(ideal.arm_plant.params.index_angles) == list(ARM_INDEX_ANGLES)
    assert list(ideal.arm_plant.params.horn_offsets_rad) == [0.0, 0.0, 0.0]
    assert float(np.abs(index).max()) > math.radians(0.1)
    assert float(np.abs(index).max()) <= 3 * REALISTIC.index_sigma_rad
    assert float(np.abs(horn).max()) > math.radians(0.1)
    assert float(np.abs(tubes).max()) > 0.0002
    real.step(20_000)
    ideal.step(20_000)
    pots = np.array([real.arm_plant.joint_angles()[4:]]) * POT_UNITS_PER_RAD + 512
    read = np.array([hal.sensors.values["pot"] for hal in real.arm.servo_hals])
    assert read - pots[0] == pytest.approx(horn * POT_UNITS_PER_RAD, abs=1.5)
    wrist = real.plant.model.body("arm/wrist").id
    drawn = ideal.plant.model.body_pos[ideal.plant.model.body("arm/wrist").id][2]
    assert real.plant.model.body_pos[wrist][2] - drawn == pytest.approx(
        -tubes[1] + planted.geometry_m["arm/wrist"][2], abs=1e-12)
    assert planted.arm_reading_offsets_rad() == pytest.approx(np.concatenate((-index, horn)))
