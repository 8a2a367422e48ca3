"""The arm plant (hil_emulator.arm.model + arm_plant) driven by the arm's real node firmware.

Stepper nodes (StepperNodeApp, IDs 1-4) and RX-64s (Rx64ServoApp, IDs 5-7) run on one
scheduler with the plant; registers are set with the nodes' own ``set`` (what a host WRITE
ends in), so no bus is involved.  The arm hangs from a mount 1.2 m up (its default start
pose, the kinematic zero).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import pytest

from firmware_py.arm_stepper import StepperNodeApp
from firmware_py.rx64 import Rx64ServoApp
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.arm.model import (
    ARM_JOINTS,
    JOINT_RANGES,
    MOUNT_HEIGHT_M,
    add_arm,
)
from hil_emulator.arm.plant import POT_CENTRE, ArmParams, ArmPlant
from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError, PlantError
from hil_emulator.plant import Plant, new_spec
from protocol.control_tables import StepperFlag
from protocol.image import BoardType
from protocol.robot import (
    ARM_FLANGE_INERTIA_KGM2,
    ARM_FLANGE_MASS_PROPERTIES,
    ARM_LINK_INERTIAS_KGM2,
    ARM_LINK_MASS_PROPERTIES,
    HAND_COM_ON_FLANGE_M,
    HAND_MASS_KG,
    RX64_RANGE_RAD,
    STEPPER_REDUCTIONS,
)

MS = 1_000  # µs
COUNTS_PER_RAD = 10_000 / (2 * np.pi)
CW_BIT = 0x400


@dataclass
class ArmBench:
    """The arm's seven nodes and the plant on one scheduler."""

    scheduler: Scheduler
    plant: Plant
    arm: ArmPlant
    steppers: list[StepperNodeApp]
    servos: list[Rx64ServoApp]
    servo_hals: list[VirtualHal]

    def run_ms(self, ms: int) -> None:
        self.scheduler.run_for(ms * MS)

    def ramp_push(self, joint: int, start: float, end: float, ms: int) -> None:
        """Change the push on ``joint`` linearly over ``ms`` (no step: no overshoot)."""
        for k in range(1, ms + 1):
            self.arm.push(joint, start + (end - start) * k / ms)
            self.run_ms(1)

    def enable_steppers(self, **registers: int) -> None:
        for app in self.steppers:
            for name, value in registers.items():
                app.set(name, value)
            app.set("torque_enable", 1)


def make_bench(seed: int = 0, params: ArmParams | None = None,
               start_pose: Sequence[float] | None = None, lock: Sequence[int] = (),
               hand_kg: float = 0.0) -> ArmBench:
    """Nodes first (as in the emulator), then the model and the plant.  ``lock``: joint
    indices held by equality constraints; ``hand_kg``: a point-ish mass 8 cm below the
    flange standing in for the hand."""
    scheduler = Scheduler()
    stepper_hals: list[VirtualHal] = []
    steppers: list[StepperNodeApp] = []
    for i, reduction in enumerate(STEPPER_REDUCTIONS):
        hal, app = make_arm_node(scheduler, BoardType.ARM_STEPPER, i + 1)
        assert isinstance(app, StepperNodeApp)
        app.set("gear_reduction_x100", round(reduction * 100))
        app.set("watchdog_timeout", 0)  # no host here: the tests set the registers
        stepper_hals.append(hal)
        steppers.append(app)
    servo_hals: list[VirtualHal] = []
    servos: list[Rx64ServoApp] = []
    for i in range(3):
        hal, app = make_arm_node(scheduler, BoardType.RX64, 5 + i)
        assert isinstance(app, Rx64ServoApp)
        servo_hals.append(hal)
        servos.append(app)
    spec = new_spec("arm-test")
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, 1.2])
    flange = add_arm(spec, mount, prefix="arm/", start_pose=start_pose)
    if hand_kg:
        hand = flange.add_body(name="hand", pos=[0.0, 0.0, -0.08])
        hand.mass = hand_kg
        hand.inertia = [0.003, 0.003, 0.002]
        hand.explicitinertial = True
    for j in lock:
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=f"arm/{ARM_JOINTS[j]}")
    arm = ArmPlant("arm/", stepper_hals, servo_hals, np.random.default_rng(seed), params)
    plant = Plant(spec, [arm])
    plant.attach(scheduler)
    return ArmBench(scheduler, plant, arm, steppers, servos, servo_hals)


# ---------------------------------------------------------------------------------- model


def test_model_matches_the_dissertations_arm() -> None:
    spec = new_spec()
    add_arm(spec, spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, 1.2]))
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.body_subtreemass[model.body("arm/base").id] == pytest.approx(11.4)
    assert model.body_subtreemass[model.body("arm/shoulder").id] == pytest.approx(2.0)
    mass_matrix = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, mass_matrix)
    elbow_inertia = mass_matrix[3, 3] - model.dof_armature[3]
    assert elbow_inertia == pytest.approx(0.083, rel=0.03)
    # Shoulder lifted to horizontal: the flange is about 1.0 m from the J2 axis.
    j2_axis = data.xanchor[model.joint("arm/J2").id].copy()
    data.qpos[1] = np.pi / 2
    mujoco.mj_forward(model, data)
    reach = data.site("arm/flange").xpos - j2_axis
    assert reach[0] == pytest.approx(1.0, abs=0.06) and abs(reach[2]) < 1e-9


def test_hanging_arm_clears_the_floor_at_the_recommended_mount() -> None:
    spec = new_spec()
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, MOUNT_HEIGHT_M])
    flange = add_arm(spec, mount)
    flange.add_geom(name="hand", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.04, 0.0, 0.0],
                    fromto=[0.0, 0.0, 0.0, 0.0, 0.0, -0.2])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon == 0
    assert 0.05 < data.site("arm/flange").xpos[2] - 0.24 < 0.15


def test_start_pose_becomes_qpos0_and_is_checked() -> None:
    pose = (0.3, 1.0, 0.2, 1.2, 0.1, 0.3, -0.2)
    spec = new_spec()
    add_arm(spec, spec.worldbody, start_pose=pose)
    assert spec.compile().qpos0 == pytest.approx(pose)
    with pytest.raises(EmulatorConfigError):
        add_arm(new_spec(), new_spec().worldbody, start_pose=(0.0,) * 6)
    with pytest.raises(EmulatorConfigError):
        add_arm(new_spec(), new_spec().worldbody,
                start_pose=(0.0, JOINT_RANGES[1][1] + 0.1, 0, 0, 0, 0, 0))


def test_configuration_errors() -> None:
    with pytest.raises(EmulatorConfigError):
        ArmParams(coupling=np.eye(4))
    with pytest.raises(EmulatorConfigError):
        ArmParams(stiffness=np.ones(3))
    with pytest.raises(EmulatorConfigError):
        ArmPlant("arm/", [], [], np.random.default_rng(0))
    spec = new_spec()
    add_arm(spec, spec.worldbody, prefix="left/")
    stray = ArmPlant("right/", [make_arm_node(Scheduler(), BoardType.ARM_STEPPER, 1)[0]] * 4,
                     [make_arm_node(Scheduler(), BoardType.RX64, 5)[0]] * 3,
                     np.random.default_rng(0))
    with pytest.raises(PlantError):
        Plant(spec, [stray])


# ---------------------------------------------------------------------------------- steppers


def test_arm_holds_still_in_a_loaded_start_pose() -> None:
    """Capstans start where the springs balance gravity: with holding current on, a bent,
    lifted arm stays put and its encoders stay at 0."""
    bench = make_bench(start_pose=(0.3, 1.0, 0.2, 1.2, 0.0, 0.0, 0.0))
    bench.enable_steppers()
    bench.run_ms(600)
    assert [app.get("present_position") for app in bench.steppers] == [0, 0, 0, 0]
    assert bench.arm.slips().tolist() == [0, 0, 0, 0]
    torques = bench.arm.coupling_torques()
    assert torques[1] > 5.0  # J2 really carries the lifted arm
    assert np.all(np.abs(torques) < bench.arm.holding_torques())


def test_elbow_natural_frequency() -> None:
    """Elbow capstan held by its stepper, J1-J3 locked: released from a 2° deflection the
    forearm rings at f0 = sqrt(86 / 0.083) / 2π ≈ 5.1 Hz."""
    bench = make_bench(lock=(0, 1, 2))
    bench.enable_steppers()
    bench.run_ms(50)
    bench.ramp_push(3, 0.0, 3.0, 200)
    bench.run_ms(300)
    settled = bench.arm.joint_angles()[3]
    assert np.degrees(settled) == pytest.approx(3.0 / 86.0 * 180 / np.pi, rel=0.1)
    bench.arm.push(3, 0.0)
    trace = []
    for _ in range(600):
        bench.run_ms(1)
        trace.append(bench.arm.joint_angles()[3])
    x = np.array(trace)
    x -= np.median(x[-200:])
    sign = np.sign(x)
    at = np.flatnonzero(sign[1:] * sign[:-1] < 0)
    crossings = (at + x[at] / (x[at] - x[at + 1])) * 1e-3
    assert len(crossings) >= 5
    frequency = 2.0 / (crossings[4] - crossings[0])  # two full periods
    assert frequency == pytest.approx(5.1, rel=0.1)
    assert bench.arm.slips().tolist() == [0, 0, 0, 0]


def test_stepper_node_moves_its_joint_to_the_goal() -> None:
    bench = make_bench()
    bench.enable_steppers()
    pan = bench.steppers[0]
    pan.set("goal_position", 1500)  # 54°: J1 has no gravity load in any pose
    bench.run_ms(300)
    assert StepperFlag.MOVING & pan.get("status_flags")
    bench.run_ms(900)
    assert not StepperFlag.MOVING & pan.get("status_flags")
    assert abs(pan.get("present_position") - 1500) <= 4
    assert bench.arm.joint_angles()[0] == pytest.approx(1500 / COUNTS_PER_RAD, abs=5e-4)
    # The elbow too, sagging by its gravity torque over its stiffness (the node is open-loop
    # on the motor side, as on the arm).
    elbow = bench.steppers[3]
    elbow.set("goal_position", 1500)
    bench.run_ms(1200)
    sag = bench.plant.data.qfrc_bias[3] / 86.0 * COUNTS_PER_RAD
    assert sag > 10
    assert elbow.get("present_position") == pytest.approx(1500 - sag, abs=6)


def test_index_pulse_latches_in_the_firmware() -> None:
    params = ArmParams()
    bench = make_bench(params=params)
    bench.enable_steppers()
    elbow = bench.steppers[3]
    elbow.set("goal_position", 400)  # through the index at 0.08 rad = 127 counts
    bench.run_ms(600)
    assert elbow.get("index_seen") == 1
    assert StepperFlag.INDEX_SEEN & elbow.get("status_flags")
    expected = params.index_angles[3] * COUNTS_PER_RAD
    assert abs(elbow.get("index_encoder_count") - expected) <= 1.5
    assert bench.steppers[2].get("index_seen") == 0  # J3 did not move to its index


def test_push_reads_as_deflection_proportional_to_torque() -> None:
    bench = make_bench()
    bench.enable_steppers()
    elbow = bench.steppers[3]
    readings: list[int] = []
    for torque in (1.5, 3.0):
        bench.ramp_push(3, 0.0, torque, 200)
        bench.run_ms(300)
        readings.append(elbow.get("deflection"))
        expected = -torque / 86.0 * COUNTS_PER_RAD  # motor held, joint pushed ahead
        assert readings[-1] == pytest.approx(expected, rel=0.1)
        assert bench.arm.deflections()[3] == pytest.approx(-torque / 86.0, rel=0.1)
        bench.ramp_push(3, torque, 0.0, 100)
        bench.run_ms(200)
    assert readings[1] / readings[0] == pytest.approx(2.0, rel=0.1)
    assert not StepperFlag.SLIP & elbow.get("status_flags")


def test_stepper_slips_beyond_its_holding_torque() -> None:
    """Holding current = run current (as the dissertation's controllers ran): the elbow holds
    1.3× its maximum moving torque, slips beyond 1.6× and the node latches SLIP."""
    params = ArmParams()
    bench = make_bench(params=params)
    # (the elbow's electrical period is 154 counts, its coupling deflects 113 counts at
    # 1.3× the moving maximum: a one-period slip is seen with a threshold between them)
    bench.enable_steppers(holding_current=800, deflection_limit=5000, slip_threshold=130)
    bench.run_ms(20)
    elbow = bench.steppers[3]
    moving_max = float(params.max_moving_torque_nm(800)[3])
    assert bench.arm.holding_torques()[3] == pytest.approx(1.6 * moving_max)
    bench.ramp_push(3, 0.0, 1.3 * moving_max, 300)
    bench.run_ms(200)
    assert bench.arm.slips()[3] == 0
    assert not StepperFlag.SLIP & elbow.get("status_flags")
    bench.ramp_push(3, 1.3 * moving_max, 1.8 * moving_max, 100)
    bench.run_ms(100)
    assert bench.arm.slips()[3] == 1
    assert abs(bench.arm.coupling_torques()[3]) <= 1.6 * moving_max + 1e-6
    bench.arm.push(3, 0.0)
    bench.run_ms(300)
    assert StepperFlag.SLIP & elbow.get("status_flags")
    slipped = bench.arm.slipped_periods()[3]
    assert slipped >= 1 and slipped == pytest.approx(round(slipped))  # re-locked
    # The step count no longer matches: the node's deflection is off by the slip (and by
    # the capstan shift the J2/J3 reaction caused through C).
    lost = slipped * params.period_rad[3] * COUNTS_PER_RAD
    shift = params.coupling[3] @ bench.arm.joint_angles()[:4] * COUNTS_PER_RAD
    true_deflection = bench.arm.deflections()[3] * COUNTS_PER_RAD
    assert elbow.get("deflection") == pytest.approx(true_deflection - lost - shift, abs=2)


def test_unpowered_steppers_let_the_arm_fall_without_counting_slips() -> None:
    bench = make_bench(start_pose=(0.0, 0.8, 0.0, 0.8, 0.0, 0.0, 0.0))
    bench.run_ms(1500)  # torque off at power-up: only detent torque
    angles = bench.arm.joint_angles()
    assert angles[1] < 0.3 and angles[3] < 0.3
    assert bench.arm.slips().tolist() == [0, 0, 0, 0]
    assert np.all(np.abs(bench.arm.slipped_periods()[[1, 3]]) > 10)
    fallen = round((angles[1] - 0.8) * COUNTS_PER_RAD)
    assert abs(bench.steppers[1].get("present_position") - fallen) <= 1


def test_coupling_matrix_moves_the_distal_capstans() -> None:
    """Lifting J2 with J3/J4 holding turns the J3/J4 joints by C·Δq2 (versus C = 0)."""
    finals = []
    for coupling in (None, np.zeros((4, 4))):
        params = ArmParams() if coupling is None else ArmParams(coupling=coupling)
        bench = make_bench(params=params)
        # The nodes know nothing of C: let them tolerate the J3/J4 shift; lift gently.
        bench.enable_steppers(deflection_limit=1000, slip_threshold=1000)
        bench.steppers[1].set("acceleration_limit", 5000)
        bench.steppers[1].set("goal_position", 1000)
        bench.run_ms(1200)
        finals.append(bench.arm.joint_angles())
    lift = finals[0][1]
    assert lift == pytest.approx(1000 / COUNTS_PER_RAD, rel=0.1)
    c = ArmParams().coupling
    difference = finals[0] - finals[1]
    assert difference[2] == pytest.approx(c[2, 1] * lift, rel=0.15)
    assert difference[3] == pytest.approx(c[3, 1] * lift, rel=0.15)


# ---------------------------------------------------------------------------------- RX-64


def test_rx64_reaches_goal_and_reports_its_load() -> None:
    bench = make_bench(hand_kg=1.0)
    wrist = bench.servos[1]  # J6, wrist pitch
    assert wrist.get("present_position") == POT_CENTRE
    wrist.set("torque_enable", 1)
    bench.run_ms(10)
    wrist.set("goal_position", 620)  # +31.6°: the hand tips forward, gravity pulls back
    bench.run_ms(800)
    assert abs(wrist.get("present_position") - 620) <= 6
    angle = bench.arm.joint_angles()[5]
    assert angle == pytest.approx((620 - POT_CENTRE) / 1024 * RX64_RANGE_RAD, abs=0.03)
    load = wrist.get("present_load")
    assert not load & CW_BIT and 40 < load < 400  # counter-clockwise, against gravity
    gravity = bench.plant.data.qfrc_bias[5]
    # within the gear train's Coulomb friction (0.3 N·m) of gravity
    assert bench.arm.servo_torques()[1] == pytest.approx(gravity, abs=0.3)
    assert bench.servos[0].get("present_load") == 0  # torque off: nothing applied
    assert wrist.get("present_voltage") == 180 and wrist.get("present_temperature") == 25


def test_rx64_stalled_heats_and_overloads() -> None:
    """A servo blocked by an obstacle (its joint locked) and driven far from its goal: load
    at the limit, winding heating, OVERLOAD latched after 200 ms, output shut down."""
    bench = make_bench(lock=(6,))
    yaw = bench.servos[2]
    yaw.set("torque_enable", 1)
    yaw.set("goal_position", 800)
    bench.run_ms(100)
    assert yaw.get("present_load") == 1023 and bench.arm.servo_torques()[2] > 6.0
    bench.run_ms(300)
    assert yaw.get("torque_limit") == 0  # alarm shutdown
    assert yaw.alarms
    assert bench.arm.servo_torques()[2] == 0.0
    temperature = bench.servo_hals[2].sensors.values["temperature"]
    assert isinstance(temperature, int) and temperature > 250


def test_push_backdrives_an_rx64_beyond_its_stall_torque() -> None:
    bench = make_bench()
    wrist = bench.servos[1]
    wrist.set("torque_enable", 1)
    bench.run_ms(20)
    bench.arm.push(5, 4.0)  # within the 6.4 N·m stall torque: the servo holds
    bench.run_ms(300)
    assert abs(wrist.get("present_position") - POT_CENTRE) <= 25
    bench.arm.push(5, 8.0)
    bench.run_ms(100)
    assert wrist.get("present_position") > POT_CENTRE + 100
    load = wrist.get("present_load")
    assert load & CW_BIT and load & 0x3FF == 1023  # full torque, clockwise, losing


def _scenario(seed: int) -> np.ndarray:
    bench = make_bench(seed=seed, hand_kg=0.5)
    bench.enable_steppers()
    for servo, goal in zip(bench.servos, (560, 600, 470), strict=True):
        servo.set("torque_enable", 1)
        servo.set("goal_position", goal)
    bench.steppers[1].set("goal_position", 600)
    bench.steppers[3].set("goal_position", 900)
    trace = []
    for _ in range(40):
        bench.run_ms(10)
        trace.append(bench.arm.joint_angles())
    bench.arm.push(0, 5.0)
    bench.run_ms(100)
    trace.append(bench.arm.joint_angles())
    return np.array(trace)


def test_seeded_runs_repeat_exactly() -> None:
    first, again, other = _scenario(11), _scenario(11), _scenario(12)
    assert np.array_equal(first, again)
    assert not np.array_equal(first, other)  # pot noise differs
    assert np.abs(first - other).max() < 0.05


#: The arm's bodies moved by J1..J7, and the flange (:data:`ARM_LINK_MASS_PROPERTIES`).
_MOVING_BODIES = ("link1", "shoulder", "upper_arm", "forearm", "forearm_roll", "wrist",
                  "wrist_yaw")


@pytest.mark.parametrize("config", ["arm", "full"])
def test_mass_properties_the_host_uses_are_the_models(config: str) -> None:
    """protocol.robot's per-body masses, centres of mass and inertias (the host's gravity
    model and mass matrix) equal
    the MuJoCo model's, and with the hand mounted its mass and centre of mass on the flange
    (fingers extended) too: the two cannot drift apart.  On the drawing (``ideal``): the
    built robot's bodies sit a laser-cut build's tenths of a millimetre off it."""
    model = Emulator(config, seed=0, can="none",  # type: ignore[union-attr]
                     sensors="ideal").arm_plant.model

    def body(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    declared = (*ARM_LINK_MASS_PROPERTIES, ARM_FLANGE_MASS_PROPERTIES)
    inertias = (*ARM_LINK_INERTIAS_KGM2, ARM_FLANGE_INERTIA_KGM2)
    for name, (mass, com), inertia in zip((*_MOVING_BODIES, "flange"), declared, inertias,
                                          strict=True):
        b = body(f"arm/{name}")
        assert model.body_mass[b] == pytest.approx(mass, abs=1e-9), name
        assert model.body_ipos[b] == pytest.approx(com, abs=1e-9), name
        assert model.body_inertia[b] == pytest.approx(inertia, rel=1e-8), name
    flange = body("arm/flange")
    hand = [b for b in range(model.nbody) if model.body_rootid[b] == model.body_rootid[flange]
            and b != flange and _descends_from(model, b, flange)]
    assert bool(hand) == (config == "full")
    if hand:
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        mass = float(sum(model.body_mass[b] for b in hand))
        com = sum(model.body_mass[b] * data.xipos[b] for b in hand) / mass
        rot = data.xmat[flange].reshape(3, 3)
        assert mass == pytest.approx(HAND_MASS_KG, abs=1e-6)
        assert rot.T @ (com - data.xpos[flange]) == pytest.approx(HAND_COM_ON_FLANGE_M,
                                                                  abs=1e-4)


def _descends_from(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body:
        body = int(model.body_parentid[body])
        if body == ancestor:
            return True
    return False
