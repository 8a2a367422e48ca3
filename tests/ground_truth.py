"""Ground truth of a robot opened on an in-process emulator (``emu://``): the emulator behind
a host ``Hand`` or ``Arm``, and the plant's joint angles a test holds the host's view to."""

from __future__ import annotations

import numpy as np

from hil_emulator.arm.plant import ArmPlant
from hil_emulator.arm.rig import ArmRig
from hil_emulator.emulator import Emulator
from hil_emulator.hand.rig import HandRig
from hil_emulator.imperfections import PlantedTruth
from hil_emulator.inprocess import EmulatorTransport
from host.arm.facade import Arm
from host.hand.facade import Hand


def emulator_of(robot: Hand | Arm) -> Emulator:
    """The emulator ``robot`` talks to (it was opened on ``emu://``)."""
    transport = robot.session.transport if isinstance(robot, Hand) else robot.transport
    if not isinstance(transport, EmulatorTransport):
        raise TypeError(f"{transport!r} is not an in-process emulator (emu://)")
    return transport.emulator


def arm_rig_of(emulator: Emulator) -> ArmRig:
    """The arm's nodes on ``emulator`` (its configuration has an arm)."""
    assert emulator.arm is not None, "this emulator has no arm"
    return emulator.arm


def hand_rig_of(emulator: Emulator) -> HandRig:
    """The hand's nodes on ``emulator`` (its configuration has a hand)."""
    assert emulator.hand is not None, "this emulator has no hand"
    return emulator.hand


def arm_plant_of(emulator: Emulator) -> ArmPlant:
    """The arm's MuJoCo plant on ``emulator`` (built with physics)."""
    assert emulator.arm_plant is not None, "the arm's emulator runs without physics"
    return emulator.arm_plant


def finger_joints(hand: Hand) -> np.ndarray:
    """Every finger plant's joint angles (rad), one row per finger (J0, J1, J2)."""
    emulator = emulator_of(hand)
    return np.array([plant.joint_angles() for plant in emulator.finger_plants])


def arm_joints(arm: Arm) -> np.ndarray:
    """The arm plant's seven joint angles (rad)."""
    return np.array(arm_plant_of(emulator_of(arm)).joint_angles())


def arm_velocities(arm: Arm) -> np.ndarray:
    """The arm plant's seven joint velocities (rad/s)."""
    return np.array(arm_plant_of(emulator_of(arm)).joint_velocities())


def planted_of(robot: Hand | Arm) -> PlantedTruth:
    """What the emulator behind ``robot`` drew for its sensors and geometry (it was opened
    with ``sensors=realistic``, the default)."""
    planted = emulator_of(robot).planted
    assert planted is not None, "this emulator's sensors are ideal"
    return planted
