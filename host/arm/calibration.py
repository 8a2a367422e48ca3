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
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np

from host.arm.geometry import ArmGeometry
from host.errors import CalibrationError, CalibrationFileError
from host.estimation.calibration_file import default_path, find
from protocol.robot import ARM_JOINT_AXES

#: Repeatability of one touch (m, 1σ): the tool tip seated in a dimple or on the table.
TOUCH_SIGMA_M: Final = 0.0003
#: The CAD model's tolerances, the prior's widths: a joint's zero (rad) and a body's offset
#: (m, per axis).
PRIOR_SIGMA_RAD: Final = math.radians(2.0)
PRIOR_SIGMA_M: Final = 0.003
#: The joints J1..J7 (names as in :data:`protocol.robot.ARM_JOINT_NAMES`).
_N: Final = len(ARM_JOINT_AXES)

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
    #: The touching point in the flange's frame (m; zeros: the flange point itself; the
    #: probe's ball, :data:`protocol.robot.ARM_PROBE_TIP_M`, for ``armctl calibrate``).
    tool_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def parameters(self) -> tuple[tuple[object, ...], ...]:
        """What these touches can tell: :data:`PARAMETERS`, and :data:`ANCHORED` with
        anchors."""
        return (*ANCHORED, *PARAMETERS) if len(self.anchor_joints) else PARAMETERS


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate` found: the ``geometry`` (of the flange: a tool's tip taken
    off again); the rms of the board's distance residuals and of the table touches'
    distances from their plane (m), before (the start) and after; the solver's
    ``evaluations`` and ``success``; the ``parameters`` it estimated."""

    geometry: ArmGeometry
    board_rms_m: tuple[float, float]
    table_rms_m: tuple[float, float]
    evaluations: int
    success: bool
    parameters: tuple[tuple[object, ...], ...] = PARAMETERS


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
    (default the CAD model, which is also the prior's centre; both of the flange, the
    touches' ``tool_m`` added for the fit: a tool's error is so fitted as the flange's)."""
    if not data.boards or sum(len(b.joints) for b in data.boards) < 3:
        raise ValueError("calibration needs at least one board placement with 3 touches")
    from scipy.optimize import least_squares  # here: armctl starts without scipy

    tool = np.asarray(data.tool_m, dtype=float)
    start = (start or ArmGeometry.nominal()).with_tool(tool)
    parameters = data.parameters()
    prior = ArmGeometry.nominal().with_tool(tool).vector(parameters)
    x0 = start.vector(parameters)
    fit = least_squares(_residuals, x0, args=(start, prior, data), method="trf",
                        x_scale=_prior_widths(parameters), xtol=1e-10, ftol=1e-10)
    geometry = start.with_vector(fit.x, parameters)

    def table(g: ArmGeometry) -> float:
        if len(data.table_joints) < 4:
            return 0.0
        return _rms(plane_distances(g.tips(data.table_joints)))

    return CalibrationResult(
        geometry.with_tool(-tool),
        (_rms(board_residuals(start, data.boards)), _rms(board_residuals(geometry, data.boards))),
        (table(start), table(geometry)), int(fit.nfev), bool(fit.success), parameters)


#: A fit whose touches still disagree by more than this (rms of the board distances or of
#: the table planarity, m) did not find the arm the touches saw: a touch seated in the wrong
#: dimple or on a dimple's wall.  Five times the touches' own scatter (TOUCH_SIGMA_M) and
#: half fig. 4.4's calibrated error.
ACCEPT_RMS_M: Final = 0.0015
#: A fitted parameter further than this many prior widths from the CAD model is not a
#: laser-cut build's error but a fit gone astray.
ACCEPT_PRIOR_WIDTHS: Final = 5.0


def check(result: CalibrationResult) -> None:
    """:class:`~host.errors.CalibrationError` when ``result`` is not fit to be written or used
    (its touches still disagree, or it moved a parameter implausibly far from the CAD
    model): a bad arm calibration would send every Cartesian move astray."""
    worst = max(result.board_rms_m[1], result.table_rms_m[1])
    if worst > ACCEPT_RMS_M:
        raise CalibrationError(
            f"the touches still disagree by {worst * 1000:.2f} mm rms after the fit (board "
            f"distances {result.board_rms_m[1] * 1000:.2f}, table "
            f"{result.table_rms_m[1] * 1000:.2f} mm; at most {ACCEPT_RMS_M * 1000:.1f}): a "
            f"touch seated wrong; nothing written")
    nominal = ArmGeometry.nominal().vector(result.parameters)
    moved = np.abs(result.geometry.vector(result.parameters) - nominal)
    widths = _prior_widths(result.parameters)
    far = int(np.argmax(moved / widths))
    if moved[far] > ACCEPT_PRIOR_WIDTHS * widths[far]:
        raise CalibrationError(
            f"the fit moved {result.parameters[far]} {moved[far] / widths[far]:.0f} prior widths "
            f"from the CAD model (at most {ACCEPT_PRIOR_WIDTHS:.0f}): not a build's error; "
            f"nothing written")


#: The calibration file's section for the arm (``host.estimation.calibration_file``).
ARM_SECTION: Final = "arm"
#: Its ``method``: how the section was made.
METHOD: Final = "touches (board distances, table planarity; §4.4) by least squares"
#: ``--calibration none``: no file, no warning.
NO_CALIBRATION: Final = "none"
#: What the arm uses without its calibration, and how to make one (the warnings' words).
_FALLBACK: Final = ("the CAD model", "run 'armctl calibrate'")


def arm_section(result: CalibrationResult, *, firmware: int | None = None,
                touches: dict[str, int] | None = None) -> dict[str, object]:
    """The calibration file's ``"arm"`` section for ``result`` (JSON values: the geometry
    in rad and m, the residuals' rms before and after in m, the estimated parameters; the
    stepper nodes' ``firmware`` version and how many ``touches`` of each kind, if given)."""
    out: dict[str, object] = {
        "method": METHOD, "geometry": result.geometry.as_dict(),
        "board_rms_m": list(result.board_rms_m), "table_rms_m": list(result.table_rms_m),
        "estimated": [list(p) for p in result.parameters]}
    if firmware is not None:
        out["firmware"] = str(firmware)
    if touches is not None:
        out["touches"] = dict(touches)
    return out


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


@dataclass
class ArmCalibrationChoice:
    """Which kinematics a program uses: ``geometry`` (None: the CAD model), the ``path`` it
    came from, the ``warnings`` its user must see (one line each), when it was made."""

    geometry: ArmGeometry | None
    path: Path | None
    warnings: list[str] = field(default_factory=list)
    created_utc: str | None = None

    def summary(self) -> str:
        """The one line a program prints: which kinematics its Cartesian moves use."""
        if self.geometry is None:
            return "arm calibration: none (the CAD model's kinematics)"
        return f"arm calibration: {self.path} (arm, made {self.created_utc})"

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: the file (None), when it was made, the warnings."""
        return {"path": None if self.geometry is None or self.path is None else str(self.path),
                "created_utc": self.created_utc, "warnings": list(self.warnings)}


def choose_calibration(robot_serial: str | None, choice: str | os.PathLike[str] | None = None,
                       firmware: int | None = None) -> ArmCalibrationChoice:
    """The arm calibration to use for the arm ``robot_serial`` (None: an arm whose nodes hold
    no serial: a file only if ``choice`` names one): ``choice`` None (the file at
    :func:`~host.estimation.calibration_file.default_path`), ``"none"`` (the CAD model, asked
    for: no warning) or a file's path.  Missing, another robot's, an older format, one
    without an ``"arm"`` section, or made on older stepper firmware than ``firmware``: a
    warning (another robot's file is not used; the CAD model is).  A file that is not one,
    or whose arm section is malformed, raises :class:`~host.errors.CalibrationFileError`."""
    if choice is not None and str(choice) == NO_CALIBRATION:
        return ArmCalibrationChoice(None, None)
    if robot_serial is None:
        return ArmCalibrationChoice(None, None if choice is None else Path(choice), [
            "the arm's nodes hold no serial number (arm_serial 0): no calibration file is "
            "its; Cartesian moves use the CAD model"])
    path = default_path(robot_serial) if choice is None else Path(choice)
    found, warnings = find(robot_serial, path, section=ARM_SECTION,
                           firmware=None if firmware is None else str(firmware),
                           fallback=_FALLBACK)
    section = None if found is None else found.section(ARM_SECTION)
    if found is None or section is None:
        return ArmCalibrationChoice(None, path, warnings)
    try:
        geometry = geometry_of_section(section)
    except ValueError as exc:
        raise CalibrationFileError(f"{path}: {exc}", path=path) from None
    return ArmCalibrationChoice(geometry, path, warnings, str(section.get("created_utc")))
