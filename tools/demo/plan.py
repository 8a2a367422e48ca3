"""The plan of ``make demo`` (:mod:`tools.demo`): where the mug stands, where the palm goes,
the wrist tilts for homing, the grasp, the lift and what counts as success; and the flange
pose that puts the palm at the mug.

Units: m, rad, rad/s, s, mA.  Positions are in the arm's base frame (the world's, raised by
the arm's mount height).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from hil_emulator.arm.model import MOUNT_HEIGHT_M
from hil_emulator.scene_model import MUG_XY_M, TABLE_TOP_Z_M
from host.arm.kinematics import matrix_to_rpy
from protocol.robot import (
    HAND_ON_FLANGE_POSITION_M,
    STEPPER_DEFAULT_CURRENT_MA,
    hand_on_flange_rotation,
)

#: Version of the demo firmware images flashed to the finger MCUs.
FW_VERSION: Final = "1.1.0"
#: Run and holding current of the arm's steppers during the demo (mA): the nodes' power-up
#: value, written again so the demo does not depend on what ran before it.
STEPPER_CURRENT_MA: Final = STEPPER_DEFAULT_CURRENT_MA
#: Where the mug stands (m, base frame: the world's raised by the arm's mount height): its
#: axis's x, y on the table top (the mug scene's placement).
MUG_BASE_M: Final = (MUG_XY_M[0], MUG_XY_M[1], TABLE_TOP_Z_M - MOUNT_HEIGHT_M)
#: The palm's axes at the mug (base frame; rows: palm x, y, z): the palm upright (its width,
#: x, pointing down), the fingers along +y, the palmar face towards +x, the mug, so the hand
#: comes from the arm's side.
PALM_AXES_AT_MUG: Final = ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
#: Where the mug's axis runs in the palm frame at the grasp (m; palm y, z): 36 mm towards the
#: fingers' edge, so the closing fingers' pads (the prismatic grasp: proximal joints at
#: 1.2 rad, distal nearly straight) press on the mug's side, the thumb from the other side;
#: 5 mm off the palmar face.  (The fingers, 103 mm long, cannot wrap the far side of a mug
#: 80 mm across: the cylindrical grasp's curled distal links poke it away from the palm
#: before any pad touches it.)
MUG_AXIS_IN_PALM_M: Final = (0.036, 0.0575)
#: Height of the palm's centre above the table top at the grasp (m; the mug is 0.10 m tall).
#: The open hand's lowest finger (its distal link) then clears the table top by about 10 mm
#: on the way in; at 60 mm it dragged on the table, the controller pushed J3 against it and
#: its node latched STALLED in about one real-time run in four.
GRASP_HEIGHT_M: Final = 0.07
#: Pre-grasp: the palm this far back from the grasp along its normal (m).
APPROACH_M: Final = 0.08
#: Ready pose: the palm this far back from the grasp (m, along its normal) and up (m), in
#: front of the table's edge.
READY_BACK_M: Final = 0.15
READY_UP_M: Final = 0.12
#: Joint angles (rad, J1..J7) the grasp's inverse kinematics starts from, which pick its arm
#: configuration: the upper arm rolled (J3) so the elbow bends sideways and the forearm hangs
#: steeply, the wrist turning the palm upright (see :mod:`tools.demo`, **Torque**).
GRASP_SEED_Q: Final = (0.95, 0.81, -2.31, 1.4, 0.73, 0.64, 1.05)
#: Tries at homing a finger that is still swaying after the wrist's tilt, and the rest (s,
#: simulated) before each retry.
HOMING_ATTEMPTS: Final = 3
HOMING_RETRY_S: Final = 1.0
#: Speed of the fastest joint in the joint-space moves, and left in the nodes' speed
#: registers for the Cartesian moves' controller (rad/s).
JOINT_SPEED_RAD_S: Final = 0.5
#: Joint speed of the Cartesian moves near the mug (rad/s, fastest joint): slow, so the
#: elastic arm tracks its path within a few millimetres.
NEAR_SPEED_RAD_S: Final = 0.2
#: How far the mug is lifted (m), how long it is held up (s).
LIFT_M: Final = 0.10
HOLD_S: Final = 2.0
#: The put-down feels for the table instead of going back to the grasp's height: the mug
#: may have slid down in the grip while it hung (seen: 15 mm; 20 mm fails the demo,
#: :data:`tools.demo.watch.SLIP_M`) or sit higher in it than when grasped, and on a robot
#: as built the flange's height is known to a millimetre or so; pushed a centimetre into the
#: table, the arm winds up its elastic elements until a node latches OVERLOAD.  So the
#: flange goes to :data:`SET_DOWN_FROM_M` (m) above the grasp's height, then down at
#: :data:`SET_DOWN_SPEED_RAD_S` (rad/s, fastest joint: about 3 cm/s) towards
#: :data:`SET_DOWN_PRESS_M` (m) below it (the grasp's height itself: where the mug stood),
#: until the stepper joints' torques (N·m, from their
#: elastic deflections) have changed by :data:`SET_DOWN_LOAD_NM` in all (the table taking
#: the mug's 0.3 kg is about 1.3 N·m at the shoulder alone, less where the grip gives),
#: and holds there :data:`SET_DOWN_HOLD_S` (s) before the hand opens.
SET_DOWN_FROM_M: Final = 0.03
SET_DOWN_PRESS_M: Final = 0.0
SET_DOWN_SPEED_RAD_S: Final = 0.06
SET_DOWN_LOAD_NM: Final = 1.0
SET_DOWN_HOLD_S: Final = 0.5
#: Success: the mug rose at least this much (m) and ends within SET_DOWN_M of its start
#: height, upright within SET_DOWN_TILT_RAD.
MIN_LIFT_M: Final = 0.05
SET_DOWN_M: Final = 0.01
SET_DOWN_TILT_RAD: Final = 0.3
#: The opposing finger's (the thumb's) joints (rad) while the hand comes to the mug and
#: leaves it: bent back, away from the fingers, so it passes beside the mug (it stands up
#: from the palm 32 mm from the centre, inside the mug's reach when straight).
THUMB_CLEAR_Q: Final = (0.0, -0.6, -0.4)
#: Grasp: synergy, amount, closing speed (rad/s), motor effort (1/255 of full PWM).
GRASP_SYNERGY: Final = "prismatic"
GRASP_AMOUNT: Final = 1.0
GRASP_SPEED_RAD_S: Final = 1.0
GRASP_EFFORT: Final = 255
#: Squeeze (rad of J1): how far past the contact each finger's proximal motor is sent
#: (:func:`host.hand.grasp.squeeze`), so its effort cap, not a position, sets the grip force.
SQUEEZE_RAD: Final = 0.3


@dataclass(frozen=True)
class FlangePose:
    """A flange target: position (m, base frame) and orientation (rad, roll pitch yaw)."""

    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


def flange_pose(back_m: float = 0.0, up_m: float = 0.0) -> FlangePose:
    """The flange pose that puts the palm at the grasp (:data:`PALM_AXES_AT_MUG`,
    :data:`MUG_AXIS_IN_PALM_M`, :data:`GRASP_HEIGHT_M`), moved ``back_m`` (m) back along the
    palm's normal and ``up_m`` (m) up: the palm's pose through the hand's mounting on the
    flange (:data:`protocol.robot.HAND_ON_FLANGE_POSITION_M`)."""
    palm = np.array(PALM_AXES_AT_MUG, dtype=float).T  # columns: the palm's axes
    mug = np.array(MUG_BASE_M, dtype=float)
    y, z = MUG_AXIS_IN_PALM_M
    centre = mug - palm[:, 1] * y - palm[:, 2] * (z + back_m)
    centre[2] = mug[2] + GRASP_HEIGHT_M + up_m
    flange = palm @ hand_on_flange_rotation().T
    xyz = centre - flange @ np.array(HAND_ON_FLANGE_POSITION_M)
    r, p, w = matrix_to_rpy(flange)
    return FlangePose((float(xyz[0]), float(xyz[1]), float(xyz[2])), (r, p, w))

#: The sensors the demo's robot has unless ``--sensors`` says otherwise: the robot as built
#: (the emulator's default).  Uncalibrated, its grasp held the mug loosely (it slid down in
#: the hand about 3.5 mm/s from the lift on: seed 0, 2.7 cm by the put-down, a failure); the
#: demo calibrates the hand's accelerometers before homing it (:mod:`tools.demo.script`).
DEMO_SENSORS: Final = "realistic"
