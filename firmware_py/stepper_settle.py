"""Settling a series-elastic joint after the command watchdog's stop: corrections at the
turns of the link's swing, from the joint encoder alone.

When the watchdog stops a stepper node's move (:mod:`firmware_py.arm_stepper`) the motor
brakes and holds, and the link, carried by the elastic element, swings on about the hold:
lightly damped (damping ratio ~0.1), 1.5 Hz for the outstretched shoulder.  A spring-mass at
a turn of its swing has no velocity; if at that moment the element carries again just the
load's deflection, it has no acceleration either: it is at rest (posicast).  So the node
moves its motor, once the link is about to turn, to the link's turning position plus the
element's static deflection.

Everything comes from the encoder (0.036° counts) without differentiating it sample by
sample, which is far too noisy (one count in 10 ms is 0.06 rad/s):

* a quadratic least-squares fit over the last :data:`SETTLE_WINDOW_TICKS` readings (a
  Savitzky-Golay filter) gives the link's position, velocity and acceleration, at the
  window's end (for the prediction) and at its centre (for the identification);
* the link's own law, ``a = w²·(d − d_s) + b·ḋ`` with ``d`` the node's deflection (motor −
  link) and ``ḋ`` its rate, is fitted by least squares on every tick since the stop: it gives
  the static deflection ``d_s`` the element must carry to hold the link still (the load and
  the route coupling as they are, whatever the move's acceleration left in the deflection
  at the stop) without knowing the link's inertia;
* the turn is predicted kinematically (``t* = −v/a``, ``x* = x − v²/2a``); the correction
  starts when ``t*`` is half the motor's correcting move away, so the move is centred on the
  turn.

Bounded: a correction never moves the motor's goal more than ``max_change`` (counts) from the
watchdog's hold (``max_back`` against the way the motor was going), the static deflection
used is within the deflections seen since the stop,
and at most :data:`SETTLE_CORRECTIONS` corrections are made.  The target is the position the
link itself reaches at its turn plus a deflection it has carried, so it never asks the link
to go anywhere it was not already going.  The numbers are in :mod:`protocol.robot`.
"""

from __future__ import annotations

import math
from collections import deque

from protocol.robot import (
    STEPPER_SETTLE_CORRECTIONS,
    STEPPER_SETTLE_MIN_SWING_COUNTS,
    STEPPER_SETTLE_WINDOW_TICKS,
)

#: Readings in each least-squares fit (1 ms ticks).
SETTLE_WINDOW_TICKS = STEPPER_SETTLE_WINDOW_TICKS
#: Corrections allowed after one watchdog stop.
SETTLE_CORRECTIONS = STEPPER_SETTLE_CORRECTIONS
#: A predicted swing (counts from the element's equilibrium) smaller than this is left alone.
SETTLE_MIN_SWING = STEPPER_SETTLE_MIN_SWING_COUNTS


def _quadratic_weights(times: list[float]) -> tuple[list[float], list[float], list[float]]:
    """Weights giving the least-squares quadratic's value, slope and second derivative at
    time 0 from samples at ``times`` (s)."""
    s = [sum(t ** k for t in times) for k in range(5)]
    m = [[s[0], s[1], s[2]], [s[1], s[2], s[3]], [s[2], s[3], s[4]]]
    inv = _inverse3(m)
    rows = []
    for r in range(3):
        rows.append([inv[r][0] + inv[r][1] * t + inv[r][2] * t * t for t in times])
    value, slope, half_curve = rows
    return value, slope, [2.0 * w for w in half_curve]


def _inverse3(m: list[list[float]]) -> list[list[float]]:
    """The inverse of a 3×3 matrix (raises ZeroDivisionError if singular)."""
    a, b, c = m[0]
    d, e, f = m[1]
    g, h, i = m[2]
    co = [[e * i - f * h, -(d * i - f * g), d * h - e * g],
          [-(b * i - c * h), a * i - c * g, -(a * h - b * g)],
          [b * f - c * e, -(a * f - c * d), a * e - b * d]]
    det = a * co[0][0] + b * co[0][1] + c * co[0][2]
    return [[co[col][row] / det for col in range(3)] for row in range(3)]


def _solve3(m: list[list[float]], rhs: list[float]) -> list[float] | None:
    """``m⁻¹·rhs`` for a 3×3 ``m``, or None when it is (nearly) singular."""
    try:
        inv = _inverse3(m)
    except ZeroDivisionError:
        return None
    return [sum(inv[r][k] * rhs[k] for k in range(3)) for r in range(3)]


_N = SETTLE_WINDOW_TICKS
_DT = 1e-3
_END = _quadratic_weights([(k - (_N - 1)) * _DT for k in range(_N)])
_MID = _quadratic_weights([(k - (_N - 1) / 2.0) * _DT for k in range(_N)])


class SwingSettler:
    """Watches one joint's link after a watchdog stop and says when and where to move the
    motor (joint counts, the motor's frame) to bring it to rest.

    ``hold`` is the watchdog's hold goal, ``deflection`` the node's deflection (motor −
    link, counts) when it fired, ``max_change`` the most a correction may move the goal from
    ``hold`` (counts; against ``travel``, the sign of the motor's velocity when the watchdog
    fired, at most ``max_back``), ``accel`` and ``speed`` the correcting move's profile
    (counts/s², counts/s)."""

    def __init__(self, hold: float, deflection: float, max_change: float, accel: float,
                 speed: float, travel: float = 0.0, max_back: float | None = None,
                 model: float | None = None) -> None:
        self.hold = hold
        #: the host's static deflection (counts), if it gave one
        self.model = model
        # the goal's range: ``max_change`` either way, only ``max_back`` against ``travel``
        back = max_change if max_back is None or travel == 0.0 else min(max_change, max_back)
        self.low = hold - (back if travel > 0.0 else max_change)
        self.high = hold + (back if travel < 0.0 else max_change)
        self.goal = hold
        self.fallback_deflection = deflection
        self.max_change = max_change
        self.accel = accel
        self.speed = speed
        self.left = SETTLE_CORRECTIONS
        self._links: deque[float] = deque(maxlen=_N)
        self._motors: deque[float] = deque(maxlen=_N)
        self._rates: deque[float] = deque(maxlen=_N)
        # least squares of a = p0·d + p1·ḋ + p2: the sums of the normal equations
        self._m = [[0.0] * 3 for _ in range(3)]
        self._r = [0.0] * 3
        self._samples = 0
        self._d_low = self._d_high = deflection
        self._quiet = 0  # ticks before another correction may start
        self.last_deflection = deflection  # the static deflection last used (counts)

    @property
    def done(self) -> bool:
        """No correction left and none under way."""
        return not self.left and not self._quiet

    def static_deflection(self) -> float:
        """The deflection (counts) that holds the link still: the host's model once it lies
        within the deflections seen since the stop (the swing goes about it), else as
        identified so far (the deflection at the stop while too few readings say
        otherwise), within those seen."""
        model = self.model
        if model is not None:
            return min(self._d_high, max(self._d_low, model))
        if self._samples >= _N:
            p = _solve3(self._m, self._r)
            if p is not None and p[0] > 0.0:  # a = w²·(d − d_s) + b·ḋ: w² = p0 > 0
                d_s = -p[2] / p[0]
                return min(self._d_high, max(self._d_low, d_s))
        return self.fallback_deflection

    def feed(self, link: int, motor: float, motor_rate: float) -> float | None:
        """One tick's readings: the encoder (counts), the motor's position (counts, motor
        frame) and its commanded velocity (counts/s).  Returns a new goal to move the motor
        to now, or None."""
        links, motors, rates = self._links, self._motors, self._rates
        links.append(float(link))
        motors.append(motor)
        rates.append(motor_rate)
        if len(links) < _N:
            return None
        x_mid = v_mid = a_mid = 0.0
        x_end = v_end = a_end = 0.0
        mv, ms, ma = _MID
        ev, es, ea = _END
        for k, x in enumerate(links):
            x_mid += mv[k] * x
            v_mid += ms[k] * x
            a_mid += ma[k] * x
            x_end += ev[k] * x
            v_end += es[k] * x
            a_end += ea[k] * x
        centre = _N // 2
        d = motors[centre] - x_mid
        if d < self._d_low:
            self._d_low = d
        if d > self._d_high:
            self._d_high = d
        row = (d, rates[centre] - v_mid, 1.0)
        m, r = self._m, self._r
        for i in range(3):
            r[i] += row[i] * a_mid
            mi = m[i]
            for j in range(3):
                mi[j] += row[i] * row[j]
        self._samples += 1
        if self._quiet:
            self._quiet -= 1
            return None
        if not self.left or v_end * a_end >= 0.0:
            return None  # no turn ahead
        turn_in = -v_end / a_end  # s
        turn_at = x_end - v_end * v_end / (2.0 * a_end)
        d_s = self.static_deflection()
        if abs(turn_at - (self.goal - d_s)) < SETTLE_MIN_SWING:
            return None  # swinging too little to matter
        target = turn_at + d_s
        change = target - motor
        duration = self._move_duration(abs(change))
        if turn_in > duration / 2.0 + _DT:
            return None
        target = min(self.high, max(self.low, target))
        self.goal = target
        self.left -= 1
        self.last_deflection = d_s
        self._quiet = int(duration / _DT) + _N // 2
        return target

    def _move_duration(self, distance: float) -> float:
        """Time (s) of a rest-to-rest move over ``distance`` counts at the correcting
        profile."""
        accel, speed = self.accel, self.speed
        if distance * accel <= speed * speed:
            return 2.0 * math.sqrt(distance / accel)
        return distance / speed + speed / accel
