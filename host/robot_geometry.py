"""Where the robot's parts are, for drawing it: the arm's and the fingers' skeletons.

Everything comes from :mod:`protocol.robot` and the arm's forward kinematics
(:mod:`host.arm_kinematics`); nothing here declares a robot number.  Units: m, rad.

* :func:`arm_skeleton` — the arm's polyline in its base frame (``z`` up): the base plate,
  each joint's origin J1..J7, the flange; and the flange's pose.
* :func:`finger_skeleton` — one finger module's polyline in the palm frame (the module's
  back, J0/J1, J2, the fingertip) for its joint angles (J0, J1, J2; rad).
* :func:`palm_on_flange` — the palm frame's pose in the arm's base frame, the hand mounted
  as :data:`protocol.robot.HAND_ON_FLANGE_POSITION_M` / ``HAND_ON_FLANGE_QUAT`` say.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from host.arm_kinematics import axis_rotation, joint_frames
from protocol.robot import (
    FINGER_JOINT_AXES,
    FINGER_LINK_LENGTHS_M,
    HAND_LAYOUTS,
    HAND_ON_FLANGE_POSITION_M,
    PALM_HALF_EXTENTS_M,
    hand_on_flange_rotation,
)

#: A pose: (position (3,), rotation (3×3)).
Pose = tuple[np.ndarray, np.ndarray]
#: The identity pose (a hand seen on its own: the palm frame is the world).
IDENTITY: Final[Pose] = (np.zeros(3), np.eye(3))
#: How far behind J0 the finger module's motor block reaches (m, along the module's −x):
#: drawn as the polyline's first segment.
_MODULE_BACK_M: Final = 2 * FINGER_LINK_LENGTHS_M[0]


def arm_skeleton(q: Sequence[float]) -> tuple[np.ndarray, Pose]:
    """(points (9×3): the base, J1..J7's origins, the flange; the flange's pose) for the
    arm's joint angles ``q`` (rad, 7), in the base frame."""
    origins, _axes, tip, rotation = joint_frames(q)
    points = np.vstack((np.zeros((1, 3)), origins, tip[None, :]))
    return points, (tip, rotation)


def palm_on_flange(flange: Pose) -> Pose:
    """The palm frame's pose in the base frame for the flange's ``flange`` pose."""
    position, rotation = flange
    return (position + rotation @ np.asarray(HAND_ON_FLANGE_POSITION_M),
            rotation @ hand_on_flange_rotation())


def finger_skeleton(layout: str, finger: int, q: Sequence[float],
                    palm: Pose = IDENTITY) -> np.ndarray:
    """Points (5×3) of finger ``finger``'s module in hand ``layout`` for joint angles ``q``
    (rad, J0..J2): the module's back, J0 (= the J1 link's start), J1, J2, the fingertip;
    in the frame ``palm`` is given in (the palm frame by default)."""
    mount = HAND_LAYOUTS[layout].mounts[finger]
    rotation = palm[1] @ mount.rotation()
    position = palm[0] + palm[1] @ np.asarray(mount.position_m, dtype=float)
    points = [position + rotation @ np.array([-_MODULE_BACK_M, 0.0, 0.0]), position]
    for axis, angle, length in zip(FINGER_JOINT_AXES, q, FINGER_LINK_LENGTHS_M, strict=True):
        rotation = rotation @ axis_rotation(axis, float(angle))
        position = position + rotation @ np.array([length, 0.0, 0.0])
        points.append(position)
    return np.array(points)


def palm_outline(palm: Pose = IDENTITY) -> np.ndarray:
    """The palm's palmar-face rectangle (5×3, closed) in the frame ``palm`` is given in."""
    hx, hy, hz = PALM_HALF_EXTENTS_M
    corners = np.array([[-hx, -hy, hz], [hx, -hy, hz], [hx, hy, hz], [-hx, hy, hz],
                        [-hx, -hy, hz]])
    return palm[0] + corners @ palm[1].T


def quaternion_xyzw(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """A rotation matrix's unit quaternion as (x, y, z, w)."""
    m = np.asarray(rotation, dtype=float)
    w = math.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + m[0, 0] - m[1, 1] - m[2, 2])) / 2.0,
                      m[2, 1] - m[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - m[0, 0] + m[1, 1] - m[2, 2])) / 2.0,
                      m[0, 2] - m[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - m[0, 0] - m[1, 1] + m[2, 2])) / 2.0,
                      m[1, 0] - m[0, 1])
    return x, y, z, w
