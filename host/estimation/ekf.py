"""An extended Kalman filter of one finger's joints from its accelerometers and hall counts.

State (the dissertation, eq. 4.1, plus hall offsets): ``x = [q, q̇, q̈, b]`` (rad, rad/s,
rad/s², rad; J0 J1 J2 each), 12 values; ``b`` is what the hall-derived joint angles read
above the true ones (the homing offsets' error).  Prediction (eq. 4.2): constant
acceleration over ``dt``, ``q ← q + dt·q̇ + dt²/2·q̈``, ``q̇ ← q̇ + dt·q̈``, driven by white
jerk of spectral density :attr:`EkfParams.jerk_psd`; ``b`` a slow random walk
(:attr:`EkfParams.hall_offset_walk`).

Measurements:

- the F2 and F3 accelerometers (g, board axes), predicted by eq. 4.3 as gravity only
  (:func:`host.estimation.finger_gravity.predict_readings`; the dissertation found centripetal and
  tangential terms did not help at these speeds), with the *base* direction ``up_0`` taken
  from the fmcb's accelerometer on F0, low-passed over :attr:`EkfParams.base_tau_s` (the
  role of the calibrated ``R_0^w`` of eq. 4.3, here measured since F0 may move with the arm);
  the Jacobian is taken numerically.  A joint whose axis is vertical simply gets no
  information (its column of the Jacobian vanishes) and its variance grows.  The model
  leaves out the accelerations of motion and the fmcb samples the accelerometers every
  40 ms, so while the joints move their σ grows with the joint speed
  (:attr:`EkfParams.accel_motion_sigma`), and a reading repeated unchanged in the next
  status (the same sample) is not fused twice (:meth:`JointEkf.update_status`).  When the
  motors start or stop, a reading carries a jolt of up to a g or two that no speed-based σ
  foresees (the speed is still zero at the start); a reading whose normalised innovation
  is beyond :attr:`EkfParams.accel_gate` has its σ inflated until it is not (a robust,
  bounded correction), so one such reading cannot drag the joints by tens of degrees.  A
  jolt passes within a sample or two, and while the joints move the readings carry the
  motion's accelerations for as long as it lasts, so they stay gated; but readings that stay
  beyond the gate for longer than :attr:`EkfParams.accel_jolt_s` while the joints rest
  (every joint slower than :attr:`EkfParams.rest_speed_rad_s`) say that the halls, not the
  accelerometers, are wrong (a bad homing, lost hall counts): the offsets' σ is widened by
  :attr:`EkfParams.hall_offset_reset_sigma` (what they were is no longer known) and the
  reading is fused in full, so ``b`` takes up the difference;
- once the finger is homed, the hall counts (homing-relative) turned into joint angles
  through the gears and the tendon coupling (:func:`protocol.robot.motor_to_joint`), a
  linear measurement of ``q + b`` with noise :attr:`EkfParams.hall_sigma_rad`: exact through
  the gears, so the halls carry the motion and the accelerometers, through ``b``, only the
  slow offset.  A status's halls are fused before its accelerometers: the halls pin
  ``q + b``, so the accelerometer update can only move ``q`` against ``b``, and the gate
  above judges the reading against that tight prior.  (Fused the other way round, a jolted
  reading first moved ``q`` by tens of degrees and the halls then put nearly all of that
  into the offsets, which take seconds to walk back.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.estimation.finger_gravity import Vector, predict_readings, to_segment
from protocol.robot import ACCEL_COUNTS_PER_G, motor_to_joint

#: State size: three joints × (angle, velocity, acceleration, hall offset).
STATE_SIZE: Final = 12
#: Where the hall offsets ``b`` sit in the state.
OFFSETS: Final = slice(9, 12)
#: Most relinearisations of one accelerometer update (iterated EKF).
ACCEL_ITERATIONS: Final = 4
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
    angle, velocity and acceleration (rad, rad/s, rad/s²) when no prior is given;
    ``accel_motion_sigma`` how much each accelerometer axis' σ grows per rad/s of the
    fastest joint (g·s/rad: the left-out accelerations of motion and the reading's age);
    ``hall_offset_sigma`` the first σ of the hall offsets (rad: homing is good to about
    0.5°) and ``hall_offset_walk`` their random walk (rad/√s); ``accel_gate`` the
    normalised innovation squared of one accelerometer update (6 axes, χ²: 22.5 is its
    99.9 % point) above which the reading's σ is scaled by √(NIS / gate) (``math.inf``:
    never), for as long as the readings have been beyond it less than ``accel_jolt_s`` (s:
    a jolt of the motors starting or stopping lasts one IMU sample, 40 ms; a disagreement
    that lasts longer while every joint is slower than ``rest_speed_rad_s``, rad/s, is
    believed, and the hall offsets' σ is widened by ``hall_offset_reset_sigma``, rad, to
    take it up).
    """

    jerk_psd: float = 400.0
    accel_sigma_g: float = 0.004
    hall_sigma_rad: float = 0.002
    base_tau_s: float = 0.05
    initial_sigma: tuple[float, float, float] = (1.0, 1.0, 5.0)
    accel_motion_sigma: float = 0.05
    hall_offset_sigma: float = 0.005
    hall_offset_walk: float = 0.001
    accel_gate: float = 22.5
    accel_jolt_s: float = 0.05
    hall_offset_reset_sigma: float = 0.5
    rest_speed_rad_s: float = 0.05


DEFAULT_PARAMS: Final = EkfParams()


def transition(dt: float) -> np.ndarray:
    """``F`` (12×12) of eq. 4.2: constant acceleration over ``dt`` (s); offsets held."""
    f1 = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    f = np.eye(STATE_SIZE)
    f[:9, :9] = np.kron(f1, np.eye(3))
    return f


def process_noise(dt: float, jerk_psd: float, offset_walk: float = 0.0) -> np.ndarray:
    """``Q`` (12×12): white jerk of density ``jerk_psd`` integrated over ``dt`` (s), and the
    hall offsets' random walk (``offset_walk`` rad/√s)."""
    q1 = jerk_psd * np.array([
        [dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
        [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
        [dt ** 3 / 6, dt ** 2 / 2, dt]])
    q = np.zeros((STATE_SIZE, STATE_SIZE))
    q[:9, :9] = np.kron(q1, np.eye(3))
    q[OFFSETS, OFFSETS] = np.eye(3) * offset_walk ** 2 * dt
    return q


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
        sig = np.concatenate((np.repeat(np.asarray(params.initial_sigma, dtype=float), 3),
                              np.full(3, params.hall_offset_sigma)))
        if q0 is not None:
            self.x[:3] = np.asarray(q0, dtype=float)
        if q0_sigma is not None:
            sig[:3] = np.broadcast_to(np.asarray(q0_sigma, dtype=float), (3,))
        self.P = np.diag(sig ** 2)
        self.t: float | None = None
        self.up0: np.ndarray | None = None
        self._base_t: float | None = None
        self._last_accels: tuple[float, ...] | None = None
        #: Normalised innovation squared of the last accelerometer update (before any
        #: inflation; dimensionless, 6 degrees of freedom).
        self.last_accel_nis = 0.0
        self._beyond_gate_since: float | None = None

    @property
    def q(self) -> np.ndarray:
        """Joint angles (rad)."""
        return self.x[:3].copy()

    @property
    def qd(self) -> np.ndarray:
        """Joint velocities (rad/s)."""
        return self.x[3:6].copy()

    @property
    def hall_offsets(self) -> np.ndarray:
        """What the hall-derived joint angles read above the true ones (rad)."""
        return self.x[OFFSETS].copy()

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
            self.P = f @ self.P @ f.T + process_noise(dt, self.params.jerk_psd,
                                                      self.params.hall_offset_walk)
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
        speed = float(np.max(np.abs(self.x[3:6])))
        sigma = self.params.accel_sigma_g + self.params.accel_motion_sigma * speed
        r = np.eye(6) * sigma ** 2
        # Robust gate: a reading far outside what the prior allows carries accelerations of
        # motion (a start or stop); inflating its σ bounds how far it moves the state.
        h0, jac = self._accel_jacobian(self.x[:3])
        nu = z - h0
        self.last_accel_nis = float(nu @ np.linalg.solve(jac @ self.P @ jac.T + r, nu))
        if self.last_accel_nis <= self.params.accel_gate:
            self._beyond_gate_since = None
        else:
            if self._beyond_gate_since is None or t is None or speed > self.params.rest_speed_rad_s:
                self._beyond_gate_since = t  # a disagreement counts from when the joints rest
            since = self._beyond_gate_since
            if since is None or t is None or t - since < self.params.accel_jolt_s:
                r = r * (self.last_accel_nis / self.params.accel_gate)
            else:  # no jolt lasts this long: the halls are off, their offsets unknown again
                self._widen_offsets(self.params.hall_offset_reset_sigma)
                self._beyond_gate_since = None
        # Iterated EKF: relinearise at the corrected angles, so a first reading far from the
        # prior (σ of a rad) does not leave a linearisation error for the offsets to absorb.
        x_prior = self.x.copy()
        xi = x_prior.copy()
        for _ in range(ACCEL_ITERATIONS):
            h0, jac = self._accel_jacobian(xi[:3])
            s_ = jac @ self.P @ jac.T + r
            k = np.linalg.solve(s_, jac @ self.P).T
            step = x_prior + k @ (z - h0 - jac @ (x_prior - xi))
            converged = float(np.max(np.abs(step[:3] - xi[:3]))) < 1e-6
            xi = step
            if converged:
                break
        self.x = xi
        i_kh = np.eye(STATE_SIZE) - k @ jac
        self.P = i_kh @ self.P @ i_kh.T + k @ r @ k.T

    def _widen_offsets(self, sigma: float) -> None:
        """Make the hall offsets ``b`` and the angles ``q`` uncertain by ``sigma`` (rad) in
        opposite directions: ``q + b``, what the halls read, stays as known as it was."""
        q_b = np.zeros((STATE_SIZE, 3))
        q_b[:3] = np.eye(3)
        q_b[OFFSETS] = -np.eye(3)
        self.P = self.P + sigma ** 2 * (q_b @ q_b.T)

    def _accel_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h0 = self.predicted_accels(q)
        jac = np.zeros((6, STATE_SIZE))
        for j in range(3):
            dq = q.copy()
            dq[j] += JACOBIAN_STEP_RAD
            jac[:, j] = (self.predicted_accels(dq) - h0) / JACOBIAN_STEP_RAD
        return h0, jac

    def update_halls(self, hall_pos: Vector) -> None:
        """Fuse homing-relative motor positions (hall counts) as joint angles ``q + b``."""
        z = np.array(motor_to_joint([float(v) for v in hall_pos]), dtype=float)
        h = np.zeros((3, STATE_SIZE))
        h[:, :3] = np.eye(3)
        h[:, OFFSETS] = np.eye(3)
        self._correct(z - self.x[:3] - self.x[OFFSETS], h,
                      np.eye(3) * self.params.hall_sigma_rad ** 2)

    def update_status(self, t: float, accels: Mapping[str, Vector],
                      hall_pos: Vector | None = None) -> None:
        """One finger status read at ``t`` (s): predict to ``t``, fuse, for a homed finger,
        ``hall_pos`` (hall counts, homing-relative), then its accelerometers (counts, mg;
        skipped when the reading repeats the last one: the fmcb samples them every 40 ms, a
        status may carry the same sample again).  Halls first: see the module's note."""
        self.predict(t)
        if hall_pos is not None:
            self.update_halls(hall_pos)
        key = tuple(float(v) for b in ("fmcb", "f2", "f3") for v in accels[b])
        if key != self._last_accels:
            self._last_accels = key
            self.update_accels(accel_counts_to_g(accels["fmcb"]), accel_counts_to_g(accels["f2"]),
                               accel_counts_to_g(accels["f3"]), t)

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
