"""The hand's accelerometers calibrated from poses the robot takes itself (dissertation §4.4).

Each board's chip reads, at rest, ``r = M·u + b`` (counts): ``u`` the upward unit vector in
the board's *nominal* frame (:func:`protocol.robot.accel_mount_rotation` from its segment's
frame), ``b`` the bias (counts) and

    M = ACCEL_COUNTS_PER_G · (I + diag(s)) · (I + C) · Rᵀ

with ``R`` the mounting rotation (the chip's axes in the nominal frame, parametrised by a
rotation vector ``w``), ``s`` the per-axis scale error and ``C`` the cross-axis coupling,
symmetric (its antisymmetric part is a rotation, indistinguishable from ``R``).  Twelve
parameters per board; :meth:`BoardCalibration.correct` undoes them, giving what an ideal
chip on the nominal mounting would read, so every estimator (closed form, EKF, homing) runs
unchanged on corrected readings.

**A finger** (:func:`fit_finger`) is fitted from static poses: each pose's hall-relative
joint angles ``q_h`` (rad, from the motor counts; the true angles are ``q_h + δ`` with ``δ``
the unknown offsets of the halls) and the three boards' averaged readings; the upward
direction in the finger's base frame F0 is one unknown per hand orientation (or known, from
an arm's joint encoders).  All boards' 36 parameters, the 3 offsets and the directions are
fitted together by :func:`scipy.optimize.least_squares` from the nominal mounting (zero
errors), with each parameter also held to its prior (:data:`PRIORS`: the part's datasheet
spread), so a parameter the poses cannot see stays at its nominal value instead of
wandering.  The fit reports, per parameter group, its posterior standard deviation against
its prior (:attr:`FingerFit.observability`): what the poses made observable.

What the poses cannot make observable, whatever their number:

* a board's rotation about the joint axis just before it (f2 about J1, f3 about J2) is
  the same reading as an offset of that joint's halls: with relative halls alone it stays
  at its prior (1° σ) and the estimate of that joint keeps that error.  A sample taken
  resting against a joint's mechanical stop (:attr:`FingerSample.at_stop`) knows that
  joint's angle, hence its offset, and makes the rotation observable;
* with the hand in one orientation the fmcb sees one direction: its 12 parameters give 3
  readings, so it is corrected only at that orientation (its reading is made to agree with
  the direction the phalanges' motion implies); its rotation about J0 is the same as J0's
  offset;
* an axis that never sees gravity (a finger whose J0 is vertical sweeps its phalanges'
  gravity in one plane) has its scale at the prior.

Readings in counts (1 count = 1 mg), angles in rad.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from host.errors import UsageError
from host.estimation.finger_gravity import BOARDS, axis_rotation, segment_rotations
from protocol.robot import ACCEL_COUNTS_PER_G, accel_mount_rotation

#: The calibration section's ``method``.
METHOD: Final = "hand-accelerometers-static-poses-least-squares"
#: Prior standard deviation of each parameter group (the LSM303DLH's datasheet spread and
#: the mounting's): rotation (rad per axis), scale (fraction), cross-axis (fraction), bias
#: (counts), joint offset (rad: a nominal homing is within a few degrees), the up direction
#: (rad per axis, when unknown).
PRIORS: Final = {"rotation": math.radians(1.0), "scale": 0.033, "cross": 0.01,
                 "bias": 20.0, "offset": math.radians(10.0), "up": math.radians(10.0)}
#: How well a joint resting against its stop knows its angle (rad, 1σ): on the emulator
#: within 0.05° after the push; a real build's stops are laser-cut, so their tolerance
#: (to be measured) belongs here.
STOP_SIGMA_RAD: Final = math.radians(0.1)
#: One averaged reading's noise (counts, 1σ): the chip's 1.5 mg over a few samples, its
#: 1 mg steps and a little temperature drift.
READING_SIGMA_COUNTS: Final = 1.0
#: A parameter is called observable when the poses shrink its σ below this fraction of its
#: prior.
OBSERVABLE_FRACTION: Final = 0.3
_GROUPS: Final = ("rotation", "scale", "cross", "bias")
_PER_BOARD: Final = 12


def rotation_vector_matrix(w: Sequence[float] | np.ndarray) -> np.ndarray:
    """The rotation (3×3) by ``|w|`` rad about ``w``."""
    v = np.asarray(w, dtype=float)
    angle = float(np.linalg.norm(v))
    return np.eye(3) if angle == 0.0 else axis_rotation(v / angle, angle)


def _cross(c: np.ndarray) -> np.ndarray:
    xy, xz, yz = c
    return np.array([[0.0, xy, xz], [xy, 0.0, yz], [xz, yz, 0.0]])


def board_matrix(p: np.ndarray) -> np.ndarray:
    """``M`` (counts per g) of a board's 12 parameters ``[w, s, c, b]``."""
    return (ACCEL_COUNTS_PER_G * (np.eye(3) + np.diag(p[3:6])) @ (np.eye(3) + _cross(p[6:9]))
            @ rotation_vector_matrix(p[0:3]).T)


@dataclass(frozen=True)
class BoardCalibration:
    """One accelerometer's fit: ``rotation_vector`` (rad), ``scale`` (fraction per axis),
    ``cross`` (xy, xz, yz; fraction), ``bias`` (counts), each group's posterior σ
    (``sigma``: group → 3 values, same units) and whether the poses made it observable."""

    rotation_vector: np.ndarray
    scale: np.ndarray
    cross: np.ndarray
    bias: np.ndarray
    sigma: dict[str, list[float]] = field(default_factory=dict)

    @classmethod
    def nominal(cls) -> BoardCalibration:
        z = np.zeros(3)
        return cls(z, z, z, z)

    def params(self) -> np.ndarray:
        return np.concatenate((self.rotation_vector, self.scale, self.cross, self.bias))

    def matrix(self) -> np.ndarray:
        """``M`` (counts per g): nominal-frame upward unit vector → chip counts."""
        return board_matrix(self.params())

    def rotation(self) -> np.ndarray:
        """The mounting rotation ``R`` (the chip's axes as columns in the nominal frame)."""
        return rotation_vector_matrix(self.rotation_vector)

    def correct(self, counts: Sequence[float] | np.ndarray) -> np.ndarray:
        """A reading (counts, the chip's axes) as an ideal chip on the nominal mounting
        would give it (counts, 1000 per g)."""
        r = np.asarray(counts, dtype=float) - self.bias
        out: np.ndarray = ACCEL_COUNTS_PER_G * np.linalg.solve(self.matrix(), r)
        return out

    def to_json(self) -> dict[str, Any]:
        return {"rotation_vector_rad": self.rotation_vector.tolist(),
                "scale": self.scale.tolist(), "cross": self.cross.tolist(),
                "bias_counts": self.bias.tolist(),
                "tilt_deg": math.degrees(float(np.linalg.norm(self.rotation_vector))),
                "sigma": self.sigma}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> BoardCalibration:
        def vec(key: str) -> np.ndarray:
            try:
                v = np.asarray(data[key], dtype=float)
            except (TypeError, ValueError):
                raise UsageError(f"calibration value {key!r} is not 3 finite numbers") from None
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise UsageError(f"calibration value {key!r} is not 3 finite numbers")
            return v

        try:
            return cls(vec("rotation_vector_rad"), vec("scale"), vec("cross"),
                       vec("bias_counts"), dict(data.get("sigma", {})))
        except (KeyError, TypeError, AttributeError) as exc:
            raise UsageError(f"a board's calibration lacks {exc}") from None


@dataclass(frozen=True)
class FingerSample:
    """One static pose of a finger: hall-relative joint angles ``q_hall`` (rad), the
    boards' averaged readings (counts, ``"fmcb"``, ``"f2"``, ``"f3"``) and which hand
    orientation it was taken in (``group``, 0 for a hand that never turns)."""

    q_hall: tuple[float, float, float]
    readings: Mapping[str, Sequence[float]]
    group: int = 0
    #: Taken resting against a mechanical stop: (joint, the stop's angle, rad); the joint's
    #: true angle is then known, which fixes its hall offset.
    at_stop: tuple[int, float] | None = None


@dataclass
class FingerFit:
    """A finger's fit: each board's :class:`BoardCalibration`, the hall offsets ``offsets``
    (rad; true joint angles = hall-relative + offsets), each orientation's upward direction
    in F0 (``up``), the residual (counts RMS over every reading), the poses used and, per
    board and group, the posterior σ as a fraction of the prior (``observability``)."""

    boards: dict[str, BoardCalibration]
    offsets: np.ndarray
    up: dict[int, np.ndarray]
    rms_counts: float
    poses: int
    observability: dict[str, dict[str, list[float]]]

    def unobservable(self) -> list[str]:
        """``"f2.rotation[y]"`` … : the parameters the poses left near their priors."""
        out = []
        for board, groups in self.observability.items():
            for group, fractions in groups.items():
                out += [f"{board}.{group}[{'xyz'[k] if group != 'cross' else ('xy', 'xz', 'yz')[k]}]"
                        for k, f in enumerate(fractions) if f > OBSERVABLE_FRACTION]
        return out


def _tangent_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def _segment_up(q: np.ndarray, up_f0: np.ndarray) -> dict[str, np.ndarray]:
    return {b: accel_mount_rotation(b).T @ (rot.T @ up_f0)
            for b, rot in segment_rotations(q).items()}


def fit_finger(samples: Sequence[FingerSample], *, offsets_guess: Sequence[float],
               up_guess: Mapping[int, Sequence[float]],
               up_known: Mapping[int, Sequence[float]] | None = None,
               boards: Sequence[str] = BOARDS) -> FingerFit:
    """Fit ``boards``' accelerometers and the hall offsets of one finger to ``samples``.

    ``offsets_guess`` (rad): the offsets a nominal homing gives (the fit's start and the
    centre of their prior); ``up_guess``: per orientation group, the upward direction in F0
    to start from (the fmcb's nominal reading); ``up_known``: groups whose direction is
    known (an arm's encoders) and is not fitted.  Needs 6 poses or more."""
    if len(samples) < 6:
        raise UsageError(f"a finger's calibration needs at least 6 poses, got {len(samples)}")
    known = {g: np.asarray(v, float) / np.linalg.norm(v) for g, v in (up_known or {}).items()}
    groups = sorted({s.group for s in samples})
    free = [g for g in groups if g not in known]
    base_up = {g: np.asarray(up_guess[g], float) / np.linalg.norm(up_guess[g]) for g in free}
    bases = {g: _tangent_basis(base_up[g]) for g in free}
    nb = len(boards)
    off0 = np.asarray(offsets_guess, dtype=float)
    q_h = np.array([s.q_hall for s in samples], dtype=float)
    readings = np.array([[s.readings[b] for b in boards] for s in samples], dtype=float)
    sample_group = [s.group for s in samples]
    stops = [(i, s.at_stop[0], s.at_stop[1]) for i, s in enumerate(samples)
             if s.at_stop is not None]
    prior_sigma = np.concatenate(
        [np.repeat([PRIORS[g] for g in _GROUPS], 3)] * nb
        + [np.full(3, PRIORS["offset"]), np.full(2 * len(free), PRIORS["up"])])
    n_params = prior_sigma.size

    def ups(x: np.ndarray) -> dict[int, np.ndarray]:
        out = dict(known)
        for k, g in enumerate(free):
            a, b = x[nb * _PER_BOARD + 3 + 2 * k: nb * _PER_BOARD + 5 + 2 * k]
            e1, e2 = bases[g]
            out[g] = rotation_vector_matrix(a * e1 + b * e2) @ base_up[g]
        return out

    def residual(x: np.ndarray) -> np.ndarray:
        mats = [board_matrix(x[k * _PER_BOARD:(k + 1) * _PER_BOARD]) for k in range(nb)]
        bias = [x[k * _PER_BOARD + 9:(k + 1) * _PER_BOARD] for k in range(nb)]
        offsets = x[nb * _PER_BOARD: nb * _PER_BOARD + 3] + off0
        up = ups(x)
        res = np.empty((len(samples), nb, 3))
        for i in range(len(samples)):
            seg = _segment_up(q_h[i] + offsets, up[sample_group[i]])
            for k, board in enumerate(boards):
                res[i, k] = mats[k] @ seg[board] + bias[k] - readings[i, k]
        at_stops = [(q_h[i, j] + offsets[j] - angle) / STOP_SIGMA_RAD for i, j, angle in stops]
        return np.concatenate((res.ravel() / READING_SIGMA_COUNTS, at_stops, x / prior_sigma))

    from scipy.optimize import least_squares  # lazily: a second of start-up
    sol = least_squares(residual, np.zeros(n_params), method="trf", x_scale=prior_sigma)
    x = sol.x
    jac = np.asarray(sol.jac)
    try:
        cov = np.linalg.inv(jac.T @ jac)
        sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sigma = prior_sigma.copy()
    data_res = residual(x)[: len(samples) * nb * 3] * READING_SIGMA_COUNTS
    fitted: dict[str, BoardCalibration] = {}
    observability: dict[str, dict[str, list[float]]] = {}
    for k, board in enumerate(boards):
        p = x[k * _PER_BOARD:(k + 1) * _PER_BOARD]
        s = sigma[k * _PER_BOARD:(k + 1) * _PER_BOARD]
        ps = prior_sigma[k * _PER_BOARD:(k + 1) * _PER_BOARD]
        groups_sigma = {g: [float(v) for v in s[3 * j:3 * j + 3]] for j, g in enumerate(_GROUPS)}
        fitted[board] = BoardCalibration(p[0:3].copy(), p[3:6].copy(), p[6:9].copy(),
                                         p[9:12].copy(), groups_sigma)
        observability[board] = {g: [round(float(v), 3) for v in (s / ps)[3 * j:3 * j + 3]]
                                for j, g in enumerate(_GROUPS)}
    return FingerFit(fitted, x[nb * _PER_BOARD: nb * _PER_BOARD + 3] + off0, ups(x),
                     float(np.sqrt(np.mean(data_res ** 2))), len(samples), observability)


def fit_board(readings: np.ndarray, up_nominal: np.ndarray) -> BoardCalibration:
    """One board's 12 parameters from static readings (N×3 counts) with known upward
    directions in its nominal frame (N×3 unit vectors: the palm on an arm, from the arm's
    encoders), by :func:`scipy.optimize.least_squares` from the nominal mounting, each
    parameter held to its prior (:data:`PRIORS`)."""
    r = np.asarray(readings, dtype=float)
    u = np.asarray(up_nominal, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or u.shape != r.shape or len(r) < 1:
        raise UsageError(f"give N×3 readings and N×3 directions, got {r.shape} and {u.shape}")
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    prior_sigma = np.repeat([PRIORS[g] for g in _GROUPS], 3)

    def residual(x: np.ndarray) -> np.ndarray:
        pred = u @ board_matrix(x).T + x[9:12]
        return np.concatenate(((pred - r).ravel() / READING_SIGMA_COUNTS, x / prior_sigma))

    from scipy.optimize import least_squares  # lazily: a second of start-up
    sol = least_squares(residual, np.zeros(12), method="trf", x_scale=prior_sigma)
    jac = np.asarray(sol.jac)
    sigma = np.sqrt(np.clip(np.diag(np.linalg.pinv(jac.T @ jac)), 0.0, None))
    x = sol.x
    return BoardCalibration(x[0:3].copy(), x[3:6].copy(), x[6:9].copy(), x[9:12].copy(),
                            {g: [float(v) for v in sigma[3 * j:3 * j + 3]]
                             for j, g in enumerate(_GROUPS)})


#: Board names in the file: ``"palm"``, ``"finger{k}.{board}"``.
def board_key(finger: int, board: str) -> str:
    """The calibration file's key of finger ``finger``'s ``board``."""
    return f"finger{finger}.{board}"


@dataclass
class HandCalibration:
    """The hand section of a calibration file, ready to correct readings: each calibrated
    board (:func:`board_key`, ``"palm"``) and where it came from (``source``, for the one
    line a program prints)."""

    boards: dict[str, BoardCalibration] = field(default_factory=dict)
    source: str = "none"

    def correct(self, finger: int, readings: Mapping[str, Any]) -> dict[str, Any]:
        """A finger's readings (counts by board, as :func:`host.hand.homing.accels_from_status`
        gives them) corrected where a board is calibrated; others (and missing readings)
        pass unchanged."""
        out: dict[str, Any] = dict(readings)
        for board, value in readings.items():
            cal = self.boards.get(board_key(finger, board))
            if cal is not None and value is not None and any(float(v) != 0.0 for v in value):
                out[board] = [float(v) for v in cal.correct(value)]
        return out

    def to_section(self, *, fits: Mapping[int, FingerFit] | None = None,
                   firmware: str | None = None) -> dict[str, Any]:
        """The file's ``hand`` section (``method``, ``boards``, per finger ``fits``: the
        residual, poses used, offsets and what the poses left unobservable)."""
        section: dict[str, Any] = {
            "method": METHOD,
            "model": "r = 1000*(I+diag(scale))*(I+C(cross))*R(rotation_vector)^T*u + bias",
            "boards": {k: v.to_json() for k, v in sorted(self.boards.items())},
        }
        if firmware is not None:
            section["firmware"] = firmware
        if fits:
            section["fits"] = {str(f): {"rms_counts": fit.rms_counts, "poses": fit.poses,
                                        "offsets_rad": fit.offsets.tolist(),
                                        "unobservable": fit.unobservable()}
                               for f, fit in sorted(fits.items())}
        return section

    @classmethod
    def from_section(cls, section: Mapping[str, Any], source: str) -> HandCalibration:
        """Read a file's ``hand`` section (:class:`UsageError` for a malformed one)."""
        boards = section.get("boards")
        if section.get("method") != METHOD or not isinstance(boards, dict):
            raise UsageError(f"{source}: the hand section is not of method {METHOD!r} "
                             "with boards")
        out = {}
        for k, v in boards.items():
            try:
                out[str(k)] = BoardCalibration.from_json(v)
            except UsageError as exc:
                raise UsageError(f"{source}: board {k}: {exc}") from None
        return cls(out, source)
