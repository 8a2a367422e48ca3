"""The finger and palm plant parts against the real firmware conventions and applications.

A FingerPlant drives the MuJoCo finger from the fmcb's motor duties and writes hall states,
currents and the phalange sensors back; these tests check the hall convention against the
firmware's own HallCounter and coupling matrix, close the fmcb's PD loop through physics,
and check the tactile, strain, IMU, repeatability and rest behaviour.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

from firmware_py.fmcb import FmcbApp
from firmware_py.fmcb_control import HallCounter
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_node
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.errors import EmulatorConfigError, PlantError
from hil_emulator.hand.finger_plant import FingerPlant, PalmPlant
from hil_emulator.hand.model import (
    DEFAULT_MOTOR,
    F2_LENGTH,
    F3_LENGTH,
    add_finger,
    add_grasp_object,
    add_hand,
)
from hil_emulator.hand.rig import HandRig
from hil_emulator.hand.sensors import DEFAULT_TACTILE, STRAIN_COUNTS_PER_NM
from hil_emulator.inprocess import BOOT_US
from hil_emulator.plant import Plant, new_spec
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.robot import FINGER_GEAR_RATIOS, motor_to_joint
from protocol.robot import finger_coupling_matrix as coupling_matrix
from protocol.stream import decode_all
from protocol.topology import ADDR_FMCB

S = 1_000_000  # µs
#: Height of the hand above the floor (m): nothing touches the floor.
MOUNT_Z = 0.3


def vhal(mcu: Mcu) -> VirtualHal:
    hal = mcu.hal
    assert isinstance(hal, VirtualHal)
    return hal


class OneFinger:
    """A finger module on a fixed mount, its three boards (no image: they stay in the
    bootloader, so a test owns the motor registers), a plant ticking on the scheduler."""

    def __init__(self, seed: int = 7) -> None:
        self.sched = Scheduler()
        self.fmcb = make_node(self.sched, BoardType.FMCB, installed=False)
        self.f2 = make_node(self.sched, BoardType.F2, installed=False)
        self.f3 = make_node(self.sched, BoardType.F3, installed=False)
        spec = new_spec()
        mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_Z])
        add_finger(spec, mount, "f/")
        self.part = FingerPlant("f/", self.fmcb, self.f2, self.f3, np.random.default_rng(seed))
        self.plant = Plant(spec, [self.part])
        self.plant.attach(self.sched)
        self.motors = vhal(self.fmcb).motors

    def run_ms(self, ms: int) -> None:
        self.sched.run_for(ms * 1000)


def sensor_snapshot(*nodes: Mcu) -> list[dict[str, Any]]:
    return [dict(vhal(n).sensors.values) for n in nodes]


# --- hall convention -----------------------------------------------------------------------
@pytest.mark.parametrize("motor", [0, 1, 2])
def test_positive_duty_counts_up_and_moves_the_joints_as_the_coupling_says(motor: int) -> None:
    rig = OneFinger()
    rig.fmcb.power_on()
    for i, m in enumerate(rig.motors):  # the other two motors hold (shorted windings)
        m.set_enabled(True)
        m.set_duty(1.0 if i == motor else 0.0)
    counters = [HallCounter() for _ in range(3)]
    q_start = rig.part.joint_angles()
    for _ in range(300):  # 0.3 s, halls read at 1 kHz as the fmcb does
        rig.run_ms(1)
        for c, m in zip(counters, rig.motors, strict=True):
            c.update(m.hall_state())
    counts = [c.count for c in counters]
    assert all(c.invalid == 0 for c in counters), "a hall jump the fmcb cannot count"
    # Full duty for 0.3 s: close to the no-load speed (150 rad/s = 859 hall states/s).
    no_load = DEFAULT_MOTOR.no_load_speed_rad_s * 36 / (2 * np.pi) * 0.3
    assert 0.7 * no_load < counts[motor] <= no_load + 2
    assert all(abs(counts[i]) <= 2 for i in range(3) if i != motor)
    # The joints moved as M⁻¹ predicts for this motor alone, and M·Δq matches the counts.
    dq = rig.part.joint_angles() - q_start
    expected = np.linalg.inv(coupling_matrix())[:, motor] * counts[motor]
    assert np.allclose(dq, expected, atol=0.01)
    assert np.allclose(coupling_matrix() @ dq, counts, atol=2.5)
    assert rig.part.motor_currents_a()[motor] > 0


def test_an_unpowered_or_detached_board_gets_no_torque() -> None:
    rig = OneFinger()
    rig.motors[2].set_enabled(True)
    rig.motors[2].set_duty(1.0)  # registers set, but the board is off
    rig.run_ms(100)
    assert np.abs(rig.part.joint_angles()).max() < 1e-3
    assert rig.motors[2].current_ma() == 0
    rig.fmcb.power_on()  # the bootloader halts the motors; set them again
    rig.part.attached = False
    rig.motors[2].set_enabled(True)
    rig.motors[2].set_duty(1.0)
    rig.run_ms(100)
    assert np.abs(rig.part.joint_angles()).max() < 1e-3
    rig.part.attached = True
    rig.run_ms(100)
    assert rig.part.joint_angles()[2] > 0.02


def test_every_tick_drives_the_motors_as_commanded_then_even_when_commands_repeat() -> None:
    """A tick whose commands equal the last one's leaves the actuators as they are (a
    holding finger's fmcb sleeps): whatever changes between ticks (a duty, a bridge, a
    brake, the board's power, the module's attachment) must still reach them."""
    rig = OneFinger()
    rig.fmcb.power_on()
    model, data, motor = rig.plant.model, rig.plant.data, DEFAULT_MOTOR
    rng = np.random.default_rng(3)
    for _ in range(400):
        m = rig.motors[int(rng.integers(3))]
        roll = rng.random()
        if roll < 0.3:
            m.set_duty(float(rng.choice([0.0, -0.0, 0.4, -0.7, 1.0])))
        elif roll < 0.45:
            m.set_enabled(not m.enabled)
        elif roll < 0.55:
            m.set_brake(not m.brake)
        elif roll < 0.6:
            rig.part.attached = not rig.part.attached
        elif roll < 0.62:
            if rig.fmcb.powered:
                rig.fmcb.power_off()
            else:
                rig.fmcb.power_on()
        rig.run_ms(1)  # the other 38 %: nothing changes
        powered = rig.part.attached and rig.fmcb.powered
        for i, (mo, act) in enumerate(zip(rig.motors, rig.part._act, strict=True)):
            drive = powered and mo.enabled and not mo.brake
            duty = mo.duty if drive else 0.0
            assert data.ctrl[act] == duty, i
            coasting = not powered or not (mo.brake or mo.enabled)
            assert model.actuator_biasprm[act, 2] == (-0.0 if coasting
                                                      else -motor.emf_damping_nm_s)
            lo, hi = model.actuator_forcerange[act]
            assert (lo == -motor.torque_limit_nm) == (duty < 0.0)
            assert (hi == motor.torque_limit_nm) == (duty > 0.0)


# --- closed loop through the real fmcb application ----------------------------------------
def send_fmcb(fmcb: Mcu, name: str, fields: dict[str, Any]) -> None:
    vhal(fmcb).uart("pogo").deliver(CATALOGUE[name].request_frame(ADDR_FMCB, fields))


def ask_fmcb(hand: HandRig, fmcb: Mcu, name: str, fields: dict[str, Any]) -> dict[str, Any]:
    pogo = vhal(fmcb).uart("pogo")
    pogo.take_sent()
    send_fmcb(fmcb, name, fields)
    hand.run_for(2_000)
    frames = [f for f in decode_all(b"".join(pogo.take_sent()))
              if f.type == CATALOGUE[name].type_id]
    assert frames, f"no reply to {name}"
    return CATALOGUE[name].parse_reply(frames[-1].payload)


@pytest.fixture(scope="module")
def hand() -> tuple[HandRig, list[FingerPlant], Plant]:
    """A whole hand (13 nodes, four-finger-thumb layout) with finger 0's fmcb booted."""
    hand = HandRig()
    spec = new_spec()
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_Z])
    add_hand(spec, mount)
    rng = np.random.default_rng(3)
    fingers = [FingerPlant(f"hand/finger{k}/", f.fmcb, f.f2, f.f3, rng)
               for k, f in enumerate(hand.fingers)]
    plant = Plant(spec, [*fingers, PalmPlant("hand/", hand.palm, rng)])
    plant.attach(hand.scheduler)
    hand.fingers[0].fmcb.power_on()
    hand.run_for(BOOT_US)  # bootloader window, then the fmcb application
    assert isinstance(hand.fingers[0].fmcb.program, FmcbApp)
    return hand, fingers, plant


def test_fmcb_pd_loop_reaches_a_joint_target_through_the_physics(
        hand: tuple[HandRig, list[FingerPlant], Plant]) -> None:
    rig, fingers, _ = hand
    fmcb = rig.fingers[0].fmcb
    app = fmcb.program
    assert isinstance(app, FmcbApp)
    imu = ask_fmcb(rig, fmcb, "fmcb.imu", {})
    assert abs(imu["accel"][2] - 1000) < 20 and max(abs(v) for v in imu["accel"][:2]) < 20
    target = [0.15, 0.35, 0.3]
    send_fmcb(fmcb, "fmcb.control", {"mode": 2, "args": {"target": target}})
    # Motor 0 travels ~800 hall counts at ≤ 859 counts/s, then creeps into the deadband
    # (2 counts: the last counts at a few % duty take a while).
    rig.run_for(3_000_000)
    q = fingers[0].joint_angles()
    # The firmware believes it is within its deadband of the target …
    deadband = int(app.params["deadband"])
    assert max(abs(t - p) for t, p in zip(app.hall_target, app.hall_pos, strict=True)) \
        <= deadband + 2
    # … and the physics agrees: the plant's shaft angles are where the halls say.
    true_counts = coupling_matrix() @ q
    assert np.allclose(true_counts, app.hall_pos, atol=1.5)
    assert all(h.invalid == 0 for h in app.hall)
    # Joint error bounded by the deadband mapped through M⁻¹ (worst case ≈ 0.19 rad on J1).
    bound = np.abs(np.linalg.inv(coupling_matrix())) @ np.full(3, deadband + 2)
    assert np.all(np.abs(q - np.array(target)) <= bound)
    assert np.allclose(q, motor_to_joint(app.hall_target), atol=0.12)
    # The distal board's accelerometer sees gravity rotated by J2 + J3 (flexion about −y).
    rig.run_for(20_000)
    pitch = q[1] + q[2]
    accel = np.array(vhal(rig.fingers[0].f3).sensors.values["accel"])
    assert np.allclose(accel, 1000 * np.array([np.sin(pitch), 0.0, np.cos(pitch)]), atol=25)
    # Other fingers (unpowered) did not move.
    assert all(np.abs(f.joint_angles()).max() < 2e-3 for f in fingers[1:])


def test_winding_temperature_rises_while_a_motor_stalls_at_the_joint_stop() -> None:
    rig = OneFinger()
    rig.fmcb.power_on()
    rig.run_ms(50)
    values = vhal(rig.fmcb).sensors.values
    before = [values[f"temperature{i}"] for i in range(3)]
    assert before == [250, 250, 250]  # 25 °C ambient in 0.1 °C
    for m in rig.motors:  # motors 1 and 2 enabled at duty 0: shorted windings resist
        m.set_enabled(True)
    rig.motors[0].set_duty(1.0)  # J1 runs into its 1.6 rad stop in ≈ 1.9 s, then stalls
    rig.run_ms(6000)
    assert rig.part.joint_angles()[0] == pytest.approx(1.6, abs=0.02)
    assert rig.part.motor_currents_a()[0] == pytest.approx(DEFAULT_MOTOR.current_limit_a)
    # Motor 0 pulls its tendon with its torque at the current limit, geared to the capstan.
    assert rig.part.capstan_torques_nm()[0] == pytest.approx(
        FINGER_GEAR_RATIOS[0] * DEFAULT_MOTOR.torque_limit_nm, rel=0.01)
    assert rig.part.tendon_load_nm() == pytest.approx(
        float(np.max(np.abs(rig.part.capstan_torques_nm()))))
    after = [values[f"temperature{i}"] for i in range(3)]
    assert isinstance(after[0], int) and after[0] >= 252
    # Motors 1 and 2 brake the creep motor 0 forces on J2/J3 through the coupling: they
    # carry current and warm too, never cool below ambient.
    assert all(isinstance(t, int) and t >= 250 for t in after)
    tip = [vhal(rig.f3).sensors.values[f"thermistor{k}"] for k in range(4)]
    assert all(isinstance(v, int) and abs(v - 2048) <= 5 for v in tip)


# --- tactile and strain ----------------------------------------------------------------------
def test_f3_taxels_rise_monotonically_with_the_pressing_force() -> None:
    rig = OneFinger()
    tactile = DEFAULT_TACTILE
    rig.run_ms(20)
    values = vhal(rig.f3).sensors.values
    unloaded = np.array([values[f"taxel{k}"] for k in range(12)])
    assert np.all(np.abs(unloaded - tactile.unloaded_counts) <= 5 * tactile.noise_counts)
    means = []
    for force in (0.25, 0.5, 1.0, 2.0):
        rig.part.press("F3", force)
        samples = []
        for _ in range(10):
            rig.run_ms(5)
            samples.append([values[f"taxel{k}"] for k in range(12)])
        means.append(np.mean(samples, axis=0))
    means_arr = np.array([unloaded, *means])
    assert np.all(np.diff(means_arr, axis=0) > 0), "every taxel rises with the force"
    centre = means_arr[-1].argmax()
    assert centre in (4, 7)  # the taxels under the pad centre (middle column) rise most
    assert means_arr[-1][centre] - tactile.unloaded_counts > 10_000
    # F2 is not touched.
    f2 = np.array([vhal(rig.f2).sensors.values[f"taxel{k}"] for k in range(6)])
    assert np.all(np.abs(f2 - tactile.unloaded_counts) <= 5 * tactile.noise_counts)
    rig.part.press("F3", 0.0)
    rig.run_ms(20)
    released = np.array([values[f"taxel{k}"] for k in range(12)])
    assert np.all(np.abs(released - tactile.unloaded_counts) <= 5 * tactile.noise_counts)


def test_strain_follows_the_bending_moment_at_the_gauge() -> None:
    rig = OneFinger()
    for m in rig.motors:  # hold the joints with shorted windings
        m.set_brake(True)
    rig.fmcb.power_on()
    for m in rig.motors:
        m.set_brake(True)
    rig.run_ms(50)
    f2 = vhal(rig.f2).sensors.values
    rest = f2["strain"]
    assert isinstance(rest, int) and rest > 0  # F3's weight already bends F2 palmwards-up
    rig.part.press("F3", 1.0)
    rig.run_ms(50)
    loaded = f2["strain"]
    assert isinstance(loaded, int)
    lever = F2_LENGTH / 2 + F3_LENGTH / 2  # gauge at F2's middle, press at F3's pad centre
    assert loaded - rest == pytest.approx(STRAIN_COUNTS_PER_NM * lever, rel=0.05)
    rig.part.press("F2", 1.0)  # at the gauge itself: no extra moment
    rig.run_ms(50)
    both = f2["strain"]
    assert isinstance(both, int) and abs(both - loaded) < 0.05 * (loaded - rest)
    with pytest.raises(EmulatorConfigError):
        rig.part.press("F1", 1.0)
    with pytest.raises(EmulatorConfigError):
        rig.part.press("F3", -1.0)


def test_an_explicit_integrator_is_refused() -> None:
    sched = Scheduler()
    fmcb, f2, f3 = (make_node(sched, board, installed=False)
                    for board in (BoardType.FMCB, BoardType.F2, BoardType.F3))
    spec = new_spec()
    add_finger(spec, spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_Z]), "f/")
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER  # overridden after add_finger
    with pytest.raises(PlantError, match="integrator"):
        Plant(spec, [FingerPlant("f/", fmcb, f2, f3, np.random.default_rng(0))])
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    with pytest.raises(PlantError, match="not in the model"):
        Plant(spec, [FingerPlant("g/", fmcb, f2, f3, np.random.default_rng(0))])


# --- repeatability -----------------------------------------------------------------------------
def _scripted_run(seed: int) -> tuple[list[dict[str, Any]], list[int]]:
    rig = OneFinger(seed)
    rig.fmcb.power_on()
    rig.motors[1].set_enabled(True)
    rig.motors[1].set_duty(0.6)
    rig.part.press("F3", 0.7)
    rig.run_ms(137)
    return sensor_snapshot(rig.fmcb, rig.f2, rig.f3), [m.hall for m in rig.motors]


def test_equal_seeds_and_commands_give_identical_sensors() -> None:
    first, second, other = _scripted_run(11), _scripted_run(11), _scripted_run(12)
    assert first == second
    assert first[0] != other[0] or first[1] != other[1]  # noise really comes from the seed


# --- rest ---------------------------------------------------------------------------------------
def test_whole_hand_at_rest_stays_finite_and_still_and_the_palm_feels_an_object() -> None:
    hand = HandRig()
    spec = new_spec()
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_Z])
    add_hand(spec, mount)
    # A small capsule dropped from 1 cm onto the palm, clear of the thumb.
    add_grasp_object(spec, spec.worldbody, pos=(-0.005, 0.02, MOUNT_Z + 0.04),
                     size=(0.012, 0.03), mass_kg=0.08)
    rng = np.random.default_rng(5)
    fingers = [FingerPlant(f"hand/finger{k}/", f.fmcb, f.f2, f.f3, rng)
               for k, f in enumerate(hand.fingers)]
    plant = Plant(spec, [*fingers, PalmPlant("hand/", hand.palm, rng)])
    q0 = [f.joint_angles() for f in fingers]
    for _ in range(2000):
        plant.tick()
    assert np.isfinite(plant.data.qpos).all() and np.isfinite(plant.data.qvel).all()
    for f, q in zip(fingers, q0, strict=True):
        assert np.abs(f.joint_angles() - q).max() < 1e-3
        assert np.abs(f.joint_velocities()).max() < 1e-3
    obj = plant.model.body("object").id
    assert np.abs(plant.data.cvel[obj]).max() < 1e-2  # the object has settled
    palm = vhal(hand.palm).sensors.values
    taxels = np.array([palm[f"taxel{k}"] for k in range(32)])
    assert taxels.max() > DEFAULT_TACTILE.unloaded_counts + 500  # something lies on the palm
    assert np.median(taxels) < DEFAULT_TACTILE.unloaded_counts + 100  # but not everywhere
    accel = palm["accel"]
    assert isinstance(accel, tuple) and abs(accel[2] - 1000) < 20
    assert isinstance(palm["gyro"], tuple) and max(abs(v) for v in palm["gyro"]) < 50
    assert palm["supply_mv"] == 24000 and palm["temperature0"] == 250
    assert plant.model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST


# --- grasp ----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_four_fmcbs_close_on_an_object_and_hold_it_upside_down() -> None:
    hand = HandRig()
    spec = new_spec()
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_Z])
    add_hand(spec, mount)
    add_grasp_object(spec, spec.worldbody, pos=(0.0, 0.012, MOUNT_Z + 0.036),
                     size=(0.02, 0.03), mass_kg=0.1)
    rng = np.random.default_rng(9)
    fingers = [FingerPlant(f"hand/finger{k}/", f.fmcb, f.f2, f.f3, rng)
               for k, f in enumerate(hand.fingers)]
    plant = Plant(spec, [*fingers, PalmPlant("hand/", hand.palm, rng)])
    plant.attach(hand.scheduler)
    for f in hand.fingers:
        f.fmcb.power_on()
    hand.run_for(BOOT_US)
    for k, f in enumerate(hand.fingers):
        target = [0.0, 1.5, 1.5] if k < 3 else [0.0, 1.2, 1.0]  # fingers curl, thumb opposes
        send_fmcb(f.fmcb, "fmcb.control", {"mode": 2, "args": {"target": target}})
    hand.run_for(4_000_000)
    obj = plant.model.body("object").id
    held_at = plant.data.xpos[obj].copy()
    thumb_tip = [vhal(hand.fingers[3].f3).sensors.values[f"taxel{k}"] for k in range(12)]
    assert max(int(v) for v in thumb_tip if isinstance(v, int)) > 10_000  # the thumb presses
    plant.model.opt.gravity[:] = (0.0, 0.0, 9.81)  # turn the world upside down
    hand.run_for(1_000_000)
    assert np.linalg.norm(plant.data.xpos[obj] - held_at) < 0.01  # still in the hand
    assert all(h.invalid == 0 for f in hand.fingers if isinstance(f.fmcb.program, FmcbApp)
               for h in f.fmcb.program.hall)
