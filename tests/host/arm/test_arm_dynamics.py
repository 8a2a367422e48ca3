"""The host's linear model of the arm (host/arm/dynamics.py): its mass matrix is the
emulator's, from protocol.robot's masses and inertias alone."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hil_emulator.emulator import Emulator
from host.arm.dynamics import gravity_stiffness, mass_matrix
from host.arm.gravity import holding_torques

POSES = [(0.0, 1.5, 0.0, 1.5, 0.0, 0.2, 0.0), (0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0),
         (0.3, 0.9, 0.2, 1.0, 0.1, 0.1, 0.1), (-1.0, 2.2, -0.8, 0.3, 1.0, -0.5, 0.4)]


@pytest.fixture(scope="module", params=["arm", "full"])
def model(request: pytest.FixtureRequest) -> tuple[mujoco.MjModel, mujoco.MjData, int, int,
                                                   bool]:
    # The drawing's geometry (ideal): the host's model is of the drawing, and the built
    # robot's bodies sit a few tenths of a millimetre off it.
    plant = Emulator(request.param, seed=0, can="none", sensors="ideal").arm_plant
    assert plant is not None
    m = plant.model
    joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "arm/J1")
    return (m, mujoco.MjData(m), int(m.jnt_qposadr[joint]), int(m.jnt_dofadr[joint]),
            request.param == "full")


@pytest.mark.parametrize("pose", POSES)
def test_the_mass_matrix_is_the_emulators(model, pose):
    """J1..J4 with the wrist held, the hubs included: the MuJoCo model's within 0.005 kg·m²
    (the hand taken as a point mass: its own inertia); symmetric, positive definite."""
    m, data, qadr, dadr, hand = model
    data.qpos[qadr:qadr + 7] = pose
    mujoco.mj_forward(m, data)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, data, full)
    theirs = full[dadr:dadr + 4, dadr:dadr + 4]
    ours = mass_matrix(np.array(pose), hand=hand)
    assert np.abs(ours - theirs).max() < (0.005 if hand else 1e-6)
    assert np.allclose(ours, ours.T) and np.all(np.linalg.eigvalsh(ours) > 0)


def test_gravity_stiffness_is_the_holding_torques_slope():
    q = np.array(POSES[2])
    g = gravity_stiffness(q, hand=True)
    for j in range(4):
        step = np.zeros(7)
        step[j] = 1e-3
        change = holding_torques(q + step, True)[:4] - holding_torques(q - step, True)[:4]
        assert g[:, j] == pytest.approx(change / 2e-3, rel=1e-3, abs=1e-3)
