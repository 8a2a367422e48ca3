"""The arm's kinematic calibration: joint zero offsets and link geometry from touches.

After the dissertation's §4.4 (eqs. 4.15–4.18), for an arm whose joints carry encoders
(eq. 4.20's case: the encoders are the reference for the joint angles).  The end effector
(the flange point, :data:`protocol.robot.ARM_FLANGE_OFFSET_M`, or a tool tip given as the
flange offset) is touched to points of known spacing on a board placed in several poses, and
to a table many times; with ``q`` the host's joint readings (rad) and ``FK(q; θ)`` the flange
position of geometry ``θ`` (:class:`ArmGeometry`, m, base frame), least squares finds

    θ* = argmin  Σ_boards Σ_{i<j} (|FK(q_i) − FK(q_j)| − d_ij)² / σ²          (g1, eq. 4.16–4.17)
               + Σ_table dist(FK(q_k), P(θ))² / σ²                          (g2, eq. 4.18)
               + Σ_p ((θ_p − θ_p,CAD) / s_p)²                                 (the CAD prior)

with ``d_ij`` the known distance between the touched points, ``P(θ)`` the plane fitted to
the table touches (the smallest singular vector of their centred positions), ``σ`` the
touch's repeatability (:data:`TOUCH_SIGMA_M`) and ``s_p`` each parameter's CAD tolerance
(:data:`PRIOR_SIGMA_RAD`, :data:`PRIOR_SIGMA_M`).  It starts from the CAD model
(:meth:`ArmGeometry.nominal`), as §4.4 advises; scipy's trust-region least squares does the
rest.

**What it estimates** (:data:`PARAMETERS`): the zero offsets of J2..J6 (rad, added to the
readings), each joint body's offset J2..J7 in its parent's frame (m, 3 each) and the flange
offset (m, 3), except what no touch can see:

* the *gauge*: distances and planarity do not change when the whole arm is moved, and the
  board's and the table's poses are unknown, so the base's yaw about J1 and its position are
  free: J1's zero offset, J1's body offset and J2's offset along J1's axis (:data:`GAUGE`)
  are held at the CAD values.  An error there is a rigid motion of everything the arm
  touches (compare with a true geometry after :meth:`ArmGeometry.with_gauge_of`).  Anchor
  touches, of points drawn in the base frame (:attr:`CalibrationData.anchor_points_m`: a
  dimple or two on the base plate), make J1's zero and body offset (:data:`ANCHORED`) seen;
  residual ``FK(q) − p``;
* what another parameter does exactly (:data:`SUMMED`): J3's and J4's offsets along the
  upper arm (J3's axis) appear only as their sum (J3's is held, J4's estimated), likewise
  J5's and J6's along the forearm; J7's zero turns the flange *point* about J7's axis, the
  same as moving the flange offset in ``y`` and ``z``, so the flange offset takes it (a tool's
  orientation would need J7's zero; touches give none).  Offsets that add along a parallel or the same axis further on (J2's
  and J3's ``y`` along J2's axis, J4's and J5's ``y``, J6's and J7's ``y``, J7's and the
  flange's ``x``) are estimated together: the prior splits their sum, which is what the
  flange's position depends on (``tests/host/arm/test_arm_calibration.py`` checks this list
  against the Jacobian's null space).

What it does not model: joint axes tilted from their drawing, link compliance, the encoders'
quantisation; they stay in the residual.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from scipy.optimize import least_squares

from protocol.robot import ARM_FLANGE_OFFSET_M, ARM_JOINT_AXES, ARM_JOINT_OFFSETS_M

#: Repeatability of one touch (m, 1σ): the tool tip seated in a dimple or on the table.
TOUCH_SIGMA_M: Final = 0.0003
#: The CAD model's tolerances, the prior's widths: a joint's zero (rad) and a body's offset
#: (m, per axis).
PRIOR_SIGMA_RAD: Final = math.radians(2.0)
PRIOR_SIGMA_M: Final = 0.003
#: The joints J1..J7 (names as in :data:`protocol.robot.ARM_JOINT_NAMES`).
_N: Final = len(ARM_JOINT_AXES)
_AXES: Final = np.array(ARM_JOINT_AXES, dtype=float)

#: The gauge (held at the CAD values, :meth:`ArmGeometry.with_gauge_of`): J1's zero, J1's
#: body offset, J2's offset along J1's axis.
GAUGE: Final = (("zero", 0), ("offset", 0, 0), ("offset", 0, 1), ("offset", 0, 2),
                ("offset", 1, 2))
#: Held at the CAD values because another parameter does exactly what they do: J3's and J4's,
#: J5's and J6's offsets along J3's and J5's axes only add (the later one is estimated); J7's
#: zero turns the flange point about J7's axis, which is the same as moving the flange offset.
SUMMED: Final = (("offset", 2, 2), ("offset", 4, 2), ("zero", 6))
#: Estimated as well when the data has anchor touches (points drawn in the base frame, e.g.
#: dimples on the base plate): J1's zero and J1's body offset.  J2's offset along J1's axis
#: stays held: it only adds to J1's.
ANCHORED: Final = (("zero", 0), ("offset", 0, 0), ("offset", 0, 1), ("offset", 0, 2))
#: What the solver estimates, in the parameter vector's order: ``("zero", joint)`` (rad,
#: joint 0..6 = J1..J7), ``("offset", joint, axis)`` (m, axis 0..2 = x, y, z of the joint
#: body's offset in its parent's frame), ``("flange", axis)`` (m).
PARAMETERS: Final[tuple[tuple[object, ...], ...]] = tuple(
    p for p in (*(("zero", j) for j in range(_N)),
                *(("offset", j, a) for j in range(_N) for a in range(3)),
                *(("flange", a) for a in range(3)))
    if p not in GAUGE and p not in SUMMED)


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

    def vector(self, parameters: Sequence[tuple[object, ...]] = PARAMETERS) -> np.ndarray:
        """The values of ``parameters`` (default :data:`PARAMETERS`; rad and m)."""
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
                    parameters: Sequence[tuple[object, ...]] = PARAMETERS) -> ArmGeometry:
        """A copy with ``parameters`` (default :data:`PARAMETERS`) set to ``values``."""
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
        """A copy with ``other``'s :data:`GAUGE` values (J1's zero and body offset, J2's offset
        along J1's axis): a rigid motion of the whole arm, which no touch can see.  Comparing
        a calibrated geometry with the true one so removes exactly the gauge."""
        zero = self.zero_offsets_rad.copy()
        offsets = self.joint_offsets_m.copy()
        zero[0] = other.zero_offsets_rad[0]
        offsets[0] = other.joint_offsets_m[0]
        offsets[1, 2] = other.joint_offsets_m[1, 2]
        return ArmGeometry(zero, offsets, self.flange_offset_m.copy())

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


@dataclass(frozen=True)
class BoardTouches:
    """One placement of the board: the host's joint readings at each touch (n×7, rad) and the
    touched dimples' positions on the board (n×2 or n×3, m, the board's own frame)."""

    joints: np.ndarray
    points_m: np.ndarray


@dataclass(frozen=True)
class CalibrationData:
    """What the arm gathered: the board's placements, the table touches' readings (m×7,
    rad) and, if any, anchor touches: readings (k×7, rad) at points drawn in the base frame
    (``anchor_points_m``, k×3, m), which make the gauge's J1 zero and base position seen."""

    boards: tuple[BoardTouches, ...]
    table_joints: np.ndarray
    anchor_joints: np.ndarray = field(default_factory=lambda: np.zeros((0, _N)))
    anchor_points_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def parameters(self) -> tuple[tuple[object, ...], ...]:
        """What these touches can tell: :data:`PARAMETERS`, and :data:`ANCHORED` with
        anchors."""
        return (*ANCHORED, *PARAMETERS) if len(self.anchor_joints) else PARAMETERS


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate` found: the ``geometry``; the rms of the board's distance
    residuals and of the table touches' distances from their plane (m), before (the start)
    and after; the solver's ``evaluations`` and ``success``."""

    geometry: ArmGeometry
    board_rms_m: tuple[float, float]
    table_rms_m: tuple[float, float]
    evaluations: int
    success: bool


def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(n, k=1)
    return i, j


def plane_distances(points: np.ndarray) -> np.ndarray:
    """Signed distances (m) of ``points`` (n×3) from the plane fitted to them (least squares:
    the normal is the smallest singular vector of the centred points)."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    out: np.ndarray = centred @ normal
    return out


def board_residuals(geometry: ArmGeometry, boards: Sequence[BoardTouches]) -> np.ndarray:
    """``|FK(q_i) − FK(q_j)| − d_ij`` (m) over every pair of touches of each placement."""
    out = []
    for board in boards:
        tips = geometry.tips(board.joints)
        i, j = _pairs(len(tips))
        pts = np.asarray(board.points_m, dtype=float)
        known = np.linalg.norm(pts[i] - pts[j], axis=1)
        out.append(np.linalg.norm(tips[i] - tips[j], axis=1) - known)
    return np.concatenate(out) if out else np.zeros(0)


def _residuals(values: np.ndarray, start: ArmGeometry, prior: np.ndarray,
               data: CalibrationData) -> np.ndarray:
    parameters = data.parameters()
    geometry = start.with_vector(values, parameters)
    parts = [board_residuals(geometry, data.boards) / TOUCH_SIGMA_M]
    if len(data.table_joints) >= 4:
        parts.append(plane_distances(geometry.tips(data.table_joints)) / TOUCH_SIGMA_M)
    if len(data.anchor_joints):
        parts.append((geometry.tips(data.anchor_joints) - data.anchor_points_m).ravel()
                     / TOUCH_SIGMA_M)
    parts.append((values - prior) / _prior_widths(parameters))
    return np.concatenate(parts)


def _prior_widths(parameters: Sequence[tuple[object, ...]]) -> np.ndarray:
    return np.array([PRIOR_SIGMA_RAD if p[0] == "zero" else PRIOR_SIGMA_M
                     for p in parameters])


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else 0.0


def calibrate(data: CalibrationData, start: ArmGeometry | None = None) -> CalibrationResult:
    """The geometry that best explains ``data`` (see the module docs), from ``start``
    (default the CAD model, which is also the prior's centre)."""
    if not data.boards or sum(len(b.joints) for b in data.boards) < 3:
        raise ValueError("calibration needs at least one board placement with 3 touches")
    start = start or ArmGeometry.nominal()
    parameters = data.parameters()
    prior = ArmGeometry.nominal().vector(parameters)
    x0 = start.vector(parameters)
    fit = least_squares(_residuals, x0, args=(start, prior, data), method="trf",
                        x_scale=_prior_widths(parameters), xtol=1e-10, ftol=1e-10)
    geometry = start.with_vector(fit.x, parameters)

    def table(g: ArmGeometry) -> float:
        if len(data.table_joints) < 4:
            return 0.0
        return _rms(plane_distances(g.tips(data.table_joints)))

    return CalibrationResult(
        geometry,
        (_rms(board_residuals(start, data.boards)), _rms(board_residuals(geometry, data.boards))),
        (table(start), table(geometry)), int(fit.nfev), bool(fit.success))


#: The calibration file's section for the arm (``host.estimation.calibration_file``).
ARM_SECTION: Final = "arm"
#: Its ``method``: how the section was made.
METHOD: Final = "touches (board distances, table planarity; §4.4) by least squares"


def arm_section(result: CalibrationResult) -> dict[str, object]:
    """The calibration file's ``"arm"`` section for ``result`` (JSON values: the geometry
    in rad and m, the residuals' rms before and after in m, the estimated parameters)."""
    return {"method": METHOD, "geometry": result.geometry.as_dict(),
            "board_rms_m": list(result.board_rms_m), "table_rms_m": list(result.table_rms_m),
            "estimated": [list(p) for p in PARAMETERS]}


def geometry_of_section(section: dict[str, object]) -> ArmGeometry:
    """The geometry an ``"arm"`` section holds; :class:`ValueError` (one line) if it holds
    none or a malformed one."""
    geometry = section.get("geometry")
    if not isinstance(geometry, dict):
        raise ValueError("the calibration's arm section has no geometry")
    try:
        return ArmGeometry.from_dict(geometry)
    except (KeyError, TypeError) as exc:
        raise ValueError(f"the calibration's arm section has a malformed geometry ({exc})"
                         ) from exc
