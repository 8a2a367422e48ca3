"""The procedural hand model: layouts, names, kinematics, motor tendons and constants."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.model import (
    DEFAULT_LAYOUT,
    DEFAULT_MOTOR,
    JOINT_RANGES,
    LAYOUTS,
    FingerNames,
    HandLayout,
    add_grasp_object,
    add_hand,
    motor_coupling_rad,
)
from hil_emulator.plant import new_spec
from protocol.robot import HALL_STATES_PER_RAD
from protocol.robot import finger_coupling_matrix as coupling_matrix


def compiled(layout: str = DEFAULT_LAYOUT, degree: bool = True) -> mujoco.MjModel:
    spec = new_spec()
    spec.compiler.degree = degree
    mount = spec.worldbody.add_body(name="mount", pos=[0.0, 0.0, 0.3])
    add_hand(spec, mount, layout)
    return spec.compile()


def rotation(quat: tuple[float, float, float, float]) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.array(quat))
    return mat.reshape(3, 3)


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_compiles_with_four_complete_finger_modules(layout: str) -> None:
    model = compiled(layout)
    assert model.nu == 12 and model.ntendon == 12  # three motors per module
    assert model.nq == 12  # three hinges per module, the palm welded
    for k in range(4):
        names = FingerNames(f"hand/finger{k}/")
        for segment in ("F0", "F1", "F2", "F3"):
            model.body(names.body(segment))
        for board in ("fmcb", "f2", "f3"):
            model.sensor(names.accel_sensor(board))
            model.sensor(names.mag_sensor(board))
        model.geom(names.pad("F2"))
        model.geom(names.pad("F3"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    tips = [data.xpos[model.body(f"hand/finger{k}/F3").id] for k in range(4)]
    distances = [np.linalg.norm(a - b) for i, a in enumerate(tips) for b in tips[i + 1:]]
    assert min(distances) > 0.02  # four distinct fingertips


def test_finger_and_thumb_mounts_of_the_default_layout() -> None:
    mounts = LAYOUTS["four-finger-thumb"].mounts
    for pos, quat in mounts[:3]:  # fingers along the palm's +y, pads on the palmar side
        rot = rotation(quat)
        assert np.allclose(rot[:, 0], (0, 1, 0), atol=1e-9)
        assert np.allclose(rot[:, 2], (0, 0, 1), atol=1e-9)
        assert pos[1] == pytest.approx(0.05)
    thumb = rotation(mounts[3][1])
    assert np.allclose(thumb[:, 0], (0, 0, 1), atol=1e-9)  # stands out of the palmar face
    assert thumb[1, 2] > 0.9  # its pads face the fingers: opposable
    for _, quat in mounts:
        assert np.allclose(rotation(quat) @ rotation(quat).T, np.eye(3), atol=1e-9)


def test_motor_tendons_are_the_firmware_coupling_in_radians() -> None:
    model = compiled()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, 3)
    qadr = model.jnt_qposadr[model.joint("hand/finger2/J1").id]
    data.qpos[qadr:qadr + 3] = q
    mujoco.mj_forward(model, data)
    lengths = [data.ten_length[model.tendon(f"hand/finger2/motor{i}").id] for i in range(3)]
    assert np.allclose(lengths, coupling_matrix() @ q / HALL_STATES_PER_RAD)
    assert np.allclose(motor_coupling_rad() * HALL_STATES_PER_RAD, coupling_matrix())
    tendon = model.tendon("hand/finger2/motor0").id
    assert model.tendon_armature[tendon] == pytest.approx(DEFAULT_MOTOR.rotor_inertia_kg_m2)


@pytest.mark.parametrize("degree", [True, False])
def test_joint_ranges_are_radians_whatever_the_compiler_angle_unit(degree: bool) -> None:
    model = compiled(degree=degree)
    for j in range(3):
        jid = model.joint(f"hand/finger0/J{j + 1}").id
        assert np.allclose(model.jnt_range[jid], JOINT_RANGES[j])


def test_motor_speed_stays_countable_by_the_fmcb() -> None:
    # The fmcb's HallCounter accepts one state per 1 ms read: the no-load speed must stay
    # under one hall state per millisecond (174.5 rad/s).
    states_per_ms = DEFAULT_MOTOR.no_load_speed_rad_s * HALL_STATES_PER_RAD / 1000
    assert states_per_ms < 0.9
    assert DEFAULT_MOTOR.torque_limit_nm == pytest.approx(
        DEFAULT_MOTOR.ke_v_s_per_rad * DEFAULT_MOTOR.current_limit_a)


def test_bad_layouts_and_objects_are_refused() -> None:
    spec = new_spec()
    with pytest.raises(EmulatorConfigError):
        add_hand(spec, spec.worldbody, "six-fingers")
    with pytest.raises(EmulatorConfigError):
        HandLayout("three", LAYOUTS[DEFAULT_LAYOUT].mounts[:3])
    mount = spec.worldbody.add_body(name="mount")
    with pytest.raises(EmulatorConfigError):
        add_grasp_object(spec, mount)
    with pytest.raises(EmulatorConfigError):
        add_grasp_object(spec, spec.worldbody, size=(0.0, 0.02))
    body = add_grasp_object(spec, spec.worldbody, name="can", pos=(0.0, 0.0, 0.5))
    model = spec.compile()
    assert model.body("can").id == model.body(body.name).id
    assert model.jnt_type[model.body_jntadr[model.body("can").id]] == mujoco.mjtJoint.mjJNT_FREE
    assert math.isclose(model.body_mass[model.body("can").id], 0.08)
