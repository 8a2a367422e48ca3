"""The stepper node's settling after a watchdog stop (:mod:`firmware_py.stepper_settle`):
on a single spring-mass it stops the swing at the first turn; whatever the encoder says,
no correction leaves its bound."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.stepper_settle import SETTLE_CORRECTIONS, SwingSettler

DT = 1e-3
ACCEL = 20_000.0  # counts/s² (the correcting move's)
SPEED = 2_300.0  # counts/s
MAX_CHANGE = 83.0  # counts: room for the whole first correction of these swings


def swing(settle: bool, omega: float = 2 * math.pi * 1.5, zeta: float = 0.05,
          v0: float = 400.0, d_s: float = 60.0, seconds: float = 1.2,
          d_s_error: float = 5.0, model: float | None = None) -> list[float]:
    """A link (counts) on a spring from a motor held at 0 + ``d_s`` (its static deflection),
    passing its equilibrium at ``v0`` counts/s when the motor stops (what a watchdog stop
    leaves); the motor follows the settler's goals with a trapezoidal profile.  Returns the
    link's speed (counts/s) every tick."""
    x, v = 0.0, v0
    motor, motor_v = d_s, 0.0
    settler = SwingSettler(motor, d_s + d_s_error, MAX_CHANGE, ACCEL, SPEED, model=model)
    goal = motor
    speeds = []
    for _ in range(int(seconds / DT)):
        a = omega * omega * (motor - d_s - x) - 2.0 * zeta * omega * v
        v += a * DT
        x += v * DT
        speeds.append(v)
        if settle:
            target = settler.feed(round(x), motor, motor_v)
            if target is not None:
                goal = target
        error = goal - motor
        wanted = math.copysign(min(SPEED, math.sqrt(2.0 * ACCEL * abs(error))), error)
        motor_v += max(-ACCEL * DT, min(ACCEL * DT, wanted - motor_v))
        if abs(error) < 0.05 and abs(motor_v) <= ACCEL * DT:
            motor_v, motor = 0.0, goal
        motor += motor_v * DT
    return speeds


def test_a_single_spring_mass_is_at_rest_after_its_first_turn():
    """1.5 Hz, damping ratio 0.05, 400 counts/s (0.25 rad/s) through the equilibrium when the
    motor stops: the first turn comes a quarter period (0.17 s) later.  From 0.35 s on the
    link moves at under 2 % of that speed when the deflection at the stop was the static
    one, under 10 % when it was 5 counts off (the move's acceleration in it); the bare hold
    still swings at over 50 %."""
    after = int(0.35 / DT)
    held = max(abs(v) for v in swing(False)[after:])
    assert held > 0.5 * 400.0
    assert max(abs(v) for v in swing(True, d_s_error=0.0)[after:]) < 0.02 * 400.0
    assert max(abs(v) for v in swing(True)[after:]) < 0.10 * 400.0


def test_the_hosts_model_of_the_rest_deflection_is_used_within_the_swing():
    """The deflection at the stop 15 counts off (a move's acceleration in it): the link still
    moves at over 10 % of its speed after the first turn on the identification alone, under
    2 % with the host's ``rest_deflection`` right; a model the swing never went through is clamped to what it did
    (the identification's own bound), so it moves nothing further than it could."""
    after = int(0.35 / DT)
    assert max(abs(v) for v in swing(True, d_s_error=15.0)[after:]) > 0.10 * 400.0
    assert max(abs(v) for v in swing(True, d_s_error=15.0, model=60.0)[after:]) < 0.02 * 400.0
    settler = SwingSettler(100.0, 40.0, MAX_CHANGE, ACCEL, SPEED, model=500.0)
    assert settler.static_deflection() == 40.0


@settings(max_examples=150, deadline=None)
@given(hold=st.floats(-5e4, 5e4), deflection=st.floats(-300, 300),
       amplitude=st.floats(0.0, 3_000.0), hz=st.floats(0.2, 25.0),
       phase=st.floats(0.0, 2 * math.pi), drift=st.floats(-2_000.0, 2_000.0),
       noise=st.lists(st.integers(-3, 3), min_size=1, max_size=50),
       motor_wander=st.floats(-500.0, 500.0), travel=st.sampled_from([-1.0, 0.0, 1.0]),
       max_back=st.floats(0.0, 100.0),
       model=st.none() | st.floats(-2_000.0, 2_000.0))
def test_no_correction_leaves_its_bound(hold, deflection, amplitude, hz, phase, drift, noise,
                                        motor_wander, travel, max_back, model):
    """Any swing (up to 3000 counts, 0.2-25 Hz, drifting, jittering by a few counts) and a
    motor anywhere, the host's model of the rest deflection anything or nothing: every goal the settler gives is within ``max_change`` of the hold, and
    within ``max_back`` of it against the way the motor was going, finite, and there are at
    most SETTLE_CORRECTIONS of them."""
    settler = SwingSettler(hold, deflection, MAX_CHANGE, ACCEL, SPEED, travel, max_back, model)
    centre = hold - deflection
    targets = []
    for k in range(1500):
        t = k * DT
        link = centre + amplitude * math.sin(2 * math.pi * hz * t + phase) + drift * t
        motor = hold + motor_wander * math.sin(3.0 * t)
        target = settler.feed(round(link) + noise[k % len(noise)], motor, 0.0)
        if target is not None:
            targets.append(target)
    assert len(targets) <= SETTLE_CORRECTIONS
    for target in targets:
        assert math.isfinite(target)
        assert abs(target - hold) <= MAX_CHANGE + 1e-9
        assert (target - hold) * travel >= -max_back - 1e-9


def test_a_link_at_rest_is_left_alone():
    """A link that does not swing (jitter of one count at rest): no correction at all."""
    settler = SwingSettler(100.0, 40.0, MAX_CHANGE, ACCEL, SPEED)
    for k in range(2000):
        assert settler.feed(60 + (k // 7) % 2, 100.0, 0.0) is None
