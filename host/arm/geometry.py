"""The arm's kinematic parameters as one value: :class:`ArmGeometry`.

The CAD model (:meth:`ArmGeometry.nominal`) is :mod:`protocol.robot`'s drawing; a calibrated
one (:mod:`host.arm.calibration`, stored in the calibration file's ``"arm"`` section) adds
each joint's zero offset and the built arm's body offsets.  :mod:`host.arm.kinematics` takes
one (``geometry=``) wherever it computes a pose; None there is the CAD model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from protocol.robot import ARM_FLANGE_OFFSET_M, ARM_JOINT_AXES, ARM_JOINT_OFFSETS_M

#: The joints J1..J7.
_N: Final = len(ARM_JOINT_AXES)
_AXES: Final = np.array(ARM_JOINT_AXES, dtype=float)
#: The parameter names :meth:`ArmGeometry.vector` takes: ``("zero", joint)`` (rad),
#: ``("offset", joint, axis)`` (m), ``("flange", axis)`` (m).
Parameter = tuple[object, ...]


def _rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (n×3×3) by ``angles`` (rad, n) about unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    out: np.ndarray = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    return out


@dataclass(frozen=True)
class ArmGeometry:
    """The arm's kinematic parameters: ``zero_offsets_rad`` (7, added to the host's joint
    readings to give the kinematic angles), ``joint_offsets_m`` (7×3: each joint body's
    origin in its parent's frame at the kinematic zero) and ``flange_offset_m`` (3, in the
    J7 body's frame).  The nominal (CAD) model is :data:`protocol.robot`'s."""

    zero_offsets_rad: np.ndarray = field(default_factory=lambda: np.zeros(_N))
    joint_offsets_m: np.ndarray = field(
        default_factory=lambda: np.array(ARM_JOINT_OFFSETS_M, dtype=float))
    flange_offset_m: np.ndarray = field(
        default_factory=lambda: np.array(ARM_FLANGE_OFFSET_M, dtype=float))

    @classmethod
    def nominal(cls) -> ArmGeometry:
        """The CAD model: no zero offsets, the drawing's offsets."""
        return cls()

    def tips(self, joints: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
        """The flange position (n×3, m, base frame) for each row of host joint readings
        ``joints`` (n×7, rad)."""
        q = np.atleast_2d(np.asarray(joints, dtype=float)) + self.zero_offsets_rad
        if q.shape[1] != _N:
            raise ValueError(f"need {_N} joint angles per row, got {q.shape[1]}")
        rot = np.broadcast_to(np.eye(3), (len(q), 3, 3))
        pos = np.zeros((len(q), 3))
        for i in range(_N):
            pos = pos + rot @ self.joint_offsets_m[i]
            rot = rot @ _rotations(_AXES[i], q[:, i])
        out: np.ndarray = pos + rot @ self.flange_offset_m
        return out

    def vector(self, parameters: Sequence[Parameter]) -> np.ndarray:
        """The values of ``parameters`` (rad and m; see :data:`Parameter`)."""
        out = []
        for p in parameters:
            if p[0] == "zero":
                out.append(self.zero_offsets_rad[int(p[1])])  # type: ignore[call-overload]
            elif p[0] == "offset":
                out.append(self.joint_offsets_m[int(p[1]), int(p[2])])  # type: ignore[call-overload]
            else:
                out.append(self.flange_offset_m[int(p[1])])  # type: ignore[call-overload]
        return np.array(out, dtype=float)

    def with_vector(self, values: np.ndarray,
                    parameters: Sequence[Parameter]) -> ArmGeometry:
        """A copy with ``parameters`` (see :data:`Parameter`) set to ``values``."""
        zero = self.zero_offsets_rad.copy()
        offsets = self.joint_offsets_m.copy()
        flange = self.flange_offset_m.copy()
        for p, v in zip(parameters, values, strict=True):
            if p[0] == "zero":
                zero[int(p[1])] = v  # type: ignore[call-overload]
            elif p[0] == "offset":
                offsets[int(p[1]), int(p[2])] = v  # type: ignore[call-overload]
            else:
                flange[int(p[1])] = v  # type: ignore[call-overload]
        return ArmGeometry(zero, offsets, flange)

    def with_gauge_of(self, other: ArmGeometry) -> ArmGeometry:
        """A copy with ``other``'s :data:`~host.arm.calibration.GAUGE` values (J1's zero and body offset, J2's offset
        along J1's axis): a rigid motion of the whole arm, which no touch can see.  Comparing
        a calibrated geometry with the true one so removes exactly the gauge."""
        zero = self.zero_offsets_rad.copy()
        offsets = self.joint_offsets_m.copy()
        zero[0] = other.zero_offsets_rad[0]
        offsets[0] = other.joint_offsets_m[0]
        offsets[1, 2] = other.joint_offsets_m[1, 2]
        return ArmGeometry(zero, offsets, self.flange_offset_m.copy())

    def with_tool(self, tool_m: Sequence[float] | np.ndarray) -> ArmGeometry:
        """A copy whose flange point is moved by ``tool_m`` (m, the flange's frame): the tip
        of a tool on the flange (e.g. :data:`protocol.robot.ARM_PROBE_TIP_M`); a negative
        ``tool_m`` takes it off again."""
        return ArmGeometry(self.zero_offsets_rad.copy(), self.joint_offsets_m.copy(),
                           self.flange_offset_m + np.asarray(tool_m, dtype=float))

    def is_nominal(self) -> bool:
        """True if this is the CAD model exactly."""
        cad = ArmGeometry.nominal()
        return bool(np.array_equal(self.zero_offsets_rad, cad.zero_offsets_rad)
                    and np.array_equal(self.joint_offsets_m, cad.joint_offsets_m)
                    and np.array_equal(self.flange_offset_m, cad.flange_offset_m))

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (rad, m)."""
        return {"zero_offsets_rad": self.zero_offsets_rad.tolist(),
                "joint_offsets_m": self.joint_offsets_m.tolist(),
                "flange_offset_m": self.flange_offset_m.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> ArmGeometry:
        """The inverse of :meth:`as_dict`; :class:`ValueError` if a shape is wrong."""
        zero = np.asarray(data["zero_offsets_rad"], dtype=float)
        offsets = np.asarray(data["joint_offsets_m"], dtype=float)
        flange = np.asarray(data["flange_offset_m"], dtype=float)
        if zero.shape != (_N,) or offsets.shape != (_N, 3) or flange.shape != (3,):
            raise ValueError("an arm geometry needs 7 zero offsets, 7×3 joint offsets and a "
                             "3-vector flange offset")
        if not (np.isfinite(zero).all() and np.isfinite(offsets).all()
                and np.isfinite(flange).all()):
            raise ValueError("an arm geometry's values must be finite")
        return cls(zero, offsets, flange)


