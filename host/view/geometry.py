"""Where the robot's parts are, for drawing it: the arm's and the fingers' skeletons.

Everything comes from :mod:`protocol.robot` and the arm's forward kinematics
(:mod:`host.arm.kinematics`); nothing here declares a robot number.  Units: m, rad.

* :func:`arm_skeleton` — the arm's polyline in its base frame (``z`` up): the base plate,
  each joint's origin J1..J7, the flange; and the flange's pose.
* :func:`hand_skeleton` — the finger modules' polylines in the palm frame (each module's
  back, J0/J1, J2, the fingertip) for their joint angles (J0, J1, J2; rad), all fingers
  at once; :func:`finger_skeleton` — one of them.
* :func:`palm_on_flange` — the palm frame's pose in the arm's base frame, the hand mounted
  as :data:`protocol.robot.HAND_ON_FLANGE_POSITION_M` / ``HAND_ON_FLANGE_QUAT`` say.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from host.arm.kinematics import joint_frames
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


@functools.cache
def _mounts(layout: str) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (n×3×3), positions (n×3, m)) of ``layout``'s finger modules on the palm."""
    mounts = HAND_LAYOUTS[layout].mounts
    return (np.array([m.rotation() for m in mounts]),
            np.array([m.position_m for m in mounts], dtype=float))


def _cross_matrix(axis: Sequence[float]) -> np.ndarray:
    x, y, z = (float(v) for v in axis)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


#: Each finger joint's axis as a cross-product matrix K and K² (Rodrigues' rotation about
#: it by θ: I + sin θ·K + (1 − cos θ)·K²).
_AXIS_K: Final = np.array([_cross_matrix(axis) for axis in FINGER_JOINT_AXES])
_AXIS_K2: Final = _AXIS_K @ _AXIS_K


def hand_skeleton(layout: str, fingers: Sequence[int], q: Sequence[Sequence[float]],
                  palm: Pose = IDENTITY) -> np.ndarray:
    """Points (n×5×3) of the finger modules ``fingers`` (n indices) of hand ``layout`` for
    their joint angles ``q`` (n×3, rad, J0..J2): each module's back, J0 (= the J1 link's
    start), J1, J2, the fingertip; in the frame ``palm`` is given in (the palm frame by
    default).  All fingers in a few array operations."""
    mount_rotations, mount_positions = _mounts(layout)
    index = list(fingers)
    angles = np.asarray(q, dtype=float).reshape(len(index), len(FINGER_JOINT_AXES))
    rotation = palm[1] @ mount_rotations[index]
    position = palm[0] + mount_positions[index] @ palm[1].T
    points = np.empty((len(index), 2 + len(FINGER_LINK_LENGTHS_M), 3))
    points[:, 0] = position - _MODULE_BACK_M * rotation[:, :, 0]
    points[:, 1] = position
    for j, length in enumerate(FINGER_LINK_LENGTHS_M):
        s, c = np.sin(angles[:, j])[:, None, None], np.cos(angles[:, j])[:, None, None]
        rotation = rotation @ (np.eye(3) + s * _AXIS_K[j] + (1.0 - c) * _AXIS_K2[j])
        position = position + length * rotation[:, :, 0]
        points[:, 2 + j] = position
    return points


def finger_skeleton(layout: str, finger: int, q: Sequence[float],
                    palm: Pose = IDENTITY) -> np.ndarray:
    """Points (5×3) of finger ``finger``'s module in hand ``layout`` for joint angles ``q``
    (rad, J0..J2): :func:`hand_skeleton` of one finger."""
    return hand_skeleton(layout, [finger], [q], palm)[0]


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
