"""Bias, scale and mounting misalignment of one accelerometer from static poses.

The dissertation (section 4.4) notes that an accelerometer's axes are off the kinematic
frame by several degrees (chip, solder, board mounting) and that these errors are static,
so they can be calibrated away.  Model of a board at rest, reading ``r`` (counts) when the
upward direction in its segment's frame is the unit vector ``g``::

    r = D · Rᵀ · g + b

with ``D = diag(scale)`` (counts per g on each axis), ``R`` the board's axes in the segment
frame (columns; its deviation from the nominal
:func:`protocol.robot.accel_mount_rotation` is the misalignment) and ``b`` the bias
(counts).  Given ``N ≥ 4`` poses with non-coplanar ``g`` (from the joint angles of the
poses and the base's orientation), :func:`calibrate` solves ``r = A·g + b`` by linear least
squares (12 unknowns), splits ``A`` into scale and rotation (rows of ``A`` are
``scale_i·R[:, i]``; the rotation is the nearest orthonormal one), then refines the nine
physical parameters (bias, scale, rotation) by :func:`scipy.optimize.least_squares`.  A
whole finger, with its relative halls and the priors that keep unobservable parameters at
their nominal values: :mod:`host.estimation.hand_calibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from host.errors import UsageError
from host.estimation.finger_gravity import axis_rotation


@dataclass(frozen=True)
class AccelCalibration:
    """``bias`` (counts, board axes), ``scale`` (counts/g per axis), ``rotation`` (3×3,
    board axes as columns in the segment frame), ``rms_counts`` residual of the fit."""

    bias: np.ndarray
    scale: np.ndarray
    rotation: np.ndarray
    rms_counts: float = 0.0

    def predict(self, up_segment: np.ndarray) -> np.ndarray:
        """Reading(s) (counts) for upward unit vector(s) in the segment frame (…×3)."""
        out: np.ndarray = (np.asarray(up_segment) @ self.rotation) * self.scale + self.bias
        return out

    def to_segment(self, counts: np.ndarray) -> np.ndarray:
        """A reading (counts, …×3) corrected into the segment frame (g)."""
        out: np.ndarray = ((np.asarray(counts, dtype=float) - self.bias) / self.scale
                           ) @ self.rotation.T
        return out

    def misalignment_rad(self, nominal: np.ndarray | None = None) -> float:
        """Angle (rad) of the rotation between the nominal mounting and the fitted one."""
        ref = np.eye(3) if nominal is None else nominal
        rel = ref.T @ self.rotation
        return math.acos(max(-1.0, min(1.0, (float(np.trace(rel)) - 1.0) / 2.0)))


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation matrix closest to ``m`` (Frobenius norm; SVD, determinant +1)."""
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(u @ vt)))])
    out: np.ndarray = u @ d @ vt
    return out


def _residual(params: np.ndarray, rot0: np.ndarray, g: np.ndarray,
              r: np.ndarray) -> np.ndarray:
    rot = rot0 @ _small_rotation(params[6:9])
    pred = (g @ rot) * params[3:6] + params[0:3]
    out: np.ndarray = (pred - r).ravel()
    return out


def _small_rotation(w: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(w))
    if angle == 0.0:
        return np.eye(3)
    return axis_rotation(w / angle, angle)


def calibrate(readings: np.ndarray, up_segment: np.ndarray,
              iterations: int = 10) -> AccelCalibration:
    """Fit bias, scale and mounting rotation to ``readings`` (N×3 counts, board axes) taken
    at rest with the upward direction ``up_segment`` (N×3 unit vectors, segment frame).

    Needs at least 4 poses whose ``up_segment`` do not all lie in one plane
    (:class:`~host.errors.UsageError` otherwise).
    """
    r = np.asarray(readings, dtype=float)
    g = np.asarray(up_segment, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or g.shape != r.shape:
        raise UsageError(f"give N×3 readings and N×3 directions, got {r.shape} and {g.shape}")
    g = g / np.linalg.norm(g, axis=1, keepdims=True)
    design = np.hstack((g, np.ones((len(g), 1))))
    if len(g) < 4 or np.linalg.matrix_rank(design, tol=1e-3) < 4:
        raise UsageError("calibration needs at least 4 static poses whose gravity "
                         "directions are not all in one plane")
    sol, *_ = np.linalg.lstsq(design, r, rcond=None)
    a = sol[:3].T          # r = A g + b
    bias = sol[3]
    scale = np.linalg.norm(a, axis=1)
    rot0 = nearest_rotation((a / scale[:, None]).T)
    params = np.concatenate((bias, scale, np.zeros(3)))
    from scipy.optimize import least_squares  # lazily: a second of start-up
    params = least_squares(_residual, params, args=(rot0, g, r), method="lm",
                           max_nfev=200 * max(1, iterations)).x
    rot = rot0 @ _small_rotation(params[6:9])
    rms = float(np.sqrt(np.mean(_residual(params, rot0, g, r) ** 2)))
    return AccelCalibration(params[0:3].copy(), params[3:6].copy(), rot, rms)
