"""Forward model of a finger's accelerometers: what each reads at rest for joint angles ``q``.

The dissertation's eq. 4.3: an accelerometer on segment ``i`` reads the gravity direction
("up", proper acceleration) rotated into its frame through the joints between it and the
base, ``z_i = R_αi^i · R_i^{i−1}(q) ⋯ R_1^0(q) · up_0``.  Here the base is the finger
module's F0 frame (its fmcb accelerometer measures ``up_0`` directly), the joint rotations
are about :data:`protocol.robot.FINGER_JOINT_AXES` and the board mountings are
:func:`protocol.robot.accel_mount_rotation`.  Units: joint angles in rad, readings in g.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

from protocol.robot import FINGER_JOINT_AXES, accel_mount_rotation

#: A 3-vector (or a vector of joint angles) as a sequence or a numpy array.
Vector = Sequence[float] | np.ndarray
#: The accelerometer boards of a finger, base first.
BOARDS: Final = ("fmcb", "f2", "f3")
#: Joints between F0 and each board's segment (F0: none, F2: J0 J1, F3: J0 J1 J2).
JOINTS_BEFORE: Final = {"fmcb": 0, "f2": 2, "f3": 3}


def axis_rotation(axis: Vector, angle: float) -> np.ndarray:
    """Rotation matrix (3×3) turning by ``angle`` (rad) counter-clockwise about ``axis``."""
    u = np.asarray(axis, dtype=float)
    u = u / np.linalg.norm(u)
    c, s = np.cos(angle), np.sin(angle)
    ux = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    out: np.ndarray = c * np.eye(3) + s * ux + (1.0 - c) * np.outer(u, u)
    return out


def segment_rotations(q: Vector) -> dict[str, np.ndarray]:
    """Orientation (3×3, columns = the segment's axes in F0) of F0, F2 and F3 for ``q`` (rad)."""
    r1 = axis_rotation(FINGER_JOINT_AXES[0], float(q[0]))
    r2 = r1 @ axis_rotation(FINGER_JOINT_AXES[1], float(q[1]))
    r3 = r2 @ axis_rotation(FINGER_JOINT_AXES[2], float(q[2]))
    return {"fmcb": np.eye(3), "f2": r2, "f3": r3}


def predict_readings(q: Vector, up_f0: Vector) -> dict[str, np.ndarray]:
    """Each board's reading (g, its own axes) at rest for joint angles ``q`` (rad) when the
    upward direction in the F0 *segment* frame is ``up_f0`` (the unit vector, g)."""
    up = np.asarray(up_f0, dtype=float)
    out = {}
    for board, rot in segment_rotations(q).items():
        out[board] = accel_mount_rotation(board).T @ (rot.T @ up)
    return out


def to_segment(board: str, reading: Vector) -> np.ndarray:
    """A board's reading expressed in its segment's frame (same unit)."""
    out: np.ndarray = accel_mount_rotation(board) @ np.asarray(reading, dtype=float)
    return out
