"""An extended Kalman filter of one finger's joints from its accelerometers and hall counts.

State (the dissertation, eq. 4.1): ``x = [q, q̇, q̈]`` (rad, rad/s, rad/s²; J0 J1 J2), 9
values.  Prediction (eq. 4.2): constant acceleration over ``dt``, ``q ← q + dt·q̇ + dt²/2·q̈``,
``q̇ ← q̇ + dt·q̈``, driven by white jerk of spectral density :attr:`EkfParams.jerk_psd`.

Measurements:

- the F2 and F3 accelerometers (g, board axes), predicted by eq. 4.3 as gravity only
  (:func:`host.finger_gravity_model.predict_readings`; the dissertation found centripetal and
  tangential terms did not help at these speeds), with the *base* direction ``up_0`` taken
  from the fmcb's accelerometer on F0, low-passed over :attr:`EkfParams.base_tau_s` (the
  role of the calibrated ``R_0^w`` of eq. 4.3, here measured since F0 may move with the arm);
  the Jacobian is taken numerically.  A joint whose axis is vertical simply gets no
  information (its column of the Jacobian vanishes) and its variance grows;
- once the finger is homed, the hall counts (homing-relative) turned into joint angles
  through the gears and the tendon coupling (:func:`protocol.robot.motor_to_joint`), a
  linear measurement of ``q`` with noise :attr:`EkfParams.hall_sigma_rad`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.finger_gravity_model import Vector, predict_readings, to_segment
from protocol.robot import ACCEL_COUNTS_PER_G, motor_to_joint

#: State size: three joints × (angle, velocity, acceleration).
STATE_SIZE: Final = 9
#: Step of the numerical Jacobian (rad).
JACOBIAN_STEP_RAD: Final = 1e-6


@dataclass(frozen=True)
class EkfParams:
    """Noise model of :class:`JointEkf`.

    ``jerk_psd`` spectral density of the white jerk driving the process ((rad/s³)²·s): how
    briskly the joints may change acceleration; ``accel_sigma_g`` standard deviation of
    each accelerometer axis (g; the emulated LSM303 has 2 mg, a little more covers
    quantisation and the small dynamic terms the model leaves out); ``hall_sigma_rad``
    standard deviation of a joint angle from the hall counts (rad: one hall count is
    1–1.6 mrad at the joint, plus tendon stretch); ``base_tau_s`` time constant of the
    low-pass on the F0 reading (s); ``initial_sigma`` standard deviations of the first
    angle, velocity and acceleration (rad, rad/s, rad/s²) when no prior is given.
    """

    jerk_psd: float = 400.0
    accel_sigma_g: float = 0.004
    hall_sigma_rad: float = 0.003
    base_tau_s: float = 0.05
    initial_sigma: tuple[float, float, float] = (1.0, 1.0, 5.0)


DEFAULT_PARAMS: Final = EkfParams()


def transition(dt: float) -> np.ndarray:
    """``F`` (9×9) of eq. 4.2: constant acceleration over ``dt`` (s)."""
    f1 = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    return np.kron(f1, np.eye(3))


def process_noise(dt: float, jerk_psd: float) -> np.ndarray:
    """``Q`` (9×9): white jerk of density ``jerk_psd`` integrated over ``dt`` (s)."""
    q1 = jerk_psd * np.array([
        [dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
        [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
        [dt ** 3 / 6, dt ** 2 / 2, dt]])
    return np.kron(q1, np.eye(3))


def accel_counts_to_g(counts: Vector) -> np.ndarray:
    """An accelerometer reading in counts (mg) → g."""
    return np.asarray(counts, dtype=float) / ACCEL_COUNTS_PER_G


class JointEkf:
    """The filter for one finger.  :meth:`predict` to a time, then :meth:`update_accels` and
    (homed) :meth:`update_halls`; :attr:`q` the joint angles (rad)."""

    def __init__(self, params: EkfParams = DEFAULT_PARAMS,
                 q0: Vector | None = None,
                 q0_sigma: Vector | float | None = None) -> None:
        self.params = params
        self.x = np.zeros(STATE_SIZE)
        sig = np.repeat(np.asarray(params.initial_sigma, dtype=float), 3)
        if q0 is not None:
            self.x[:3] = np.asarray(q0, dtype=float)
        if q0_sigma is not None:
            sig[:3] = np.broadcast_to(np.asarray(q0_sigma, dtype=float), (3,))
        self.P = np.diag(sig ** 2)
        self.t: float | None = None
        self.up0: np.ndarray | None = None
        self._base_t: float | None = None

    @property
    def q(self) -> np.ndarray:
        """Joint angles (rad)."""
        return self.x[:3].copy()

    @property
    def qd(self) -> np.ndarray:
        """Joint velocities (rad/s)."""
        return self.x[3:6].copy()

    @property
    def q_sigma(self) -> np.ndarray:
        """Standard deviations of the joint angles (rad)."""
        return np.sqrt(np.diag(self.P)[:3])

    def predict(self, t: float) -> None:
        """Advance the state to time ``t`` (s, the caller's clock) by eq. 4.2."""
        if self.t is not None and t > self.t:
            dt = t - self.t
            f = transition(dt)
            self.x = f @ self.x
            self.P = f @ self.P @ f.T + process_noise(dt, self.params.jerk_psd)
        if self.t is None or t > self.t:
            self.t = t

    def _base(self, fmcb_g: np.ndarray, t: float | None) -> np.ndarray:
        up = to_segment("fmcb", fmcb_g)
        up = up / max(float(np.linalg.norm(up)), 1e-9)
        if self.up0 is None or t is None or self._base_t is None:
            self.up0 = up
        else:
            alpha = 1.0 - math.exp(-max(0.0, t - self._base_t) / self.params.base_tau_s)
            mixed = self.up0 + alpha * (up - self.up0)
            self.up0 = mixed / float(np.linalg.norm(mixed))
        self._base_t = t
        return self.up0

    def predicted_accels(self, q: Vector) -> np.ndarray:
        """F2 and F3 readings (6, g) the model expects for ``q`` (rad) and the current base."""
        assert self.up0 is not None
        r = predict_readings(q, self.up0)
        return np.concatenate((r["f2"], r["f3"]))

    def update_accels(self, fmcb: Vector, f2: Vector, f3: Vector,
                      t: float | None = None) -> None:
        """Fuse one reading of each accelerometer (g, board axes) taken at ``t`` (s)."""
        self._base(np.asarray(fmcb, dtype=float), t)
        z = np.concatenate((np.asarray(f2, dtype=float), np.asarray(f3, dtype=float)))
        q = self.x[:3]
        h0 = self.predicted_accels(q)
        jac = np.zeros((6, STATE_SIZE))
        for j in range(3):
            dq = q.copy()
            dq[j] += JACOBIAN_STEP_RAD
            jac[:, j] = (self.predicted_accels(dq) - h0) / JACOBIAN_STEP_RAD
        self._correct(z - h0, jac, np.eye(6) * self.params.accel_sigma_g ** 2)

    def update_halls(self, hall_pos: Vector) -> None:
        """Fuse homing-relative motor positions (hall counts) as joint angles."""
        z = np.array(motor_to_joint([float(v) for v in hall_pos]), dtype=float)
        h = np.zeros((3, STATE_SIZE))
        h[:, :3] = np.eye(3)
        self._correct(z - self.x[:3], h, np.eye(3) * self.params.hall_sigma_rad ** 2)

    def _correct(self, innovation: np.ndarray, h: np.ndarray, r: np.ndarray) -> None:
        s = h @ self.P @ h.T + r
        k = np.linalg.solve(s, h @ self.P).T
        self.x = self.x + k @ innovation
        i_kh = np.eye(STATE_SIZE) - k @ h
        self.P = i_kh @ self.P @ i_kh.T + k @ r @ k.T  # Joseph form: stays symmetric PSD


def fuse_snapshot(hall_pos: Vector, accels: Mapping[str, Vector],
                  params: EkfParams = DEFAULT_PARAMS) -> np.ndarray:
    """Joint angles (rad) fusing one homed finger's hall counts (homing-relative) with one
    reading of its accelerometers (counts): one hall update then one accelerometer update
    of a fresh filter."""
    ekf = JointEkf(params, q0=motor_to_joint([float(v) for v in hall_pos]), q0_sigma=0.2)
    ekf.update_halls(hall_pos)
    ekf.update_accels(accel_counts_to_g(accels["fmcb"]), accel_counts_to_g(accels["f2"]),
                      accel_counts_to_g(accels["f3"]))
    return ekf.q
