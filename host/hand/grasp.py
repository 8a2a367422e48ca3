"""Grasping with the hand: a slewed blend towards a synergy, stopping at contact, then a
squeeze (the procedure; the synergies and the pure math are :mod:`host.hand.synergies`).

:func:`grasp` blends from the measured pose to the synergy's targets along a straight line
in joint space, rate-limited to ``speed`` rad/s on the largest joint change, timed by the
link's clock (``session.now``/``sleep``), sending intermediate joint targets every
``period`` s.  With ``until_contact`` a finger stops closing (its target becomes its
measured pose) once its taxels rise by :data:`~host.hand.synergies.TACTILE_CONTACT_COUNTS` over their values at
the start, or its motors push hard (:data:`~host.hand.synergies.CONTACT_EFFORT`) while lagging the blend by
:data:`~host.hand.synergies.CONTACT_LAG_RAD`.

A finger stopped at a contact, or closed onto an object to its target, presses with no
force: its fmcb stops pushing once its motors are within their deadband.  :func:`squeeze`
(``grasp(..., squeeze=rad)``) sets each finger's target past where it is by advancing its
proximal flexion motor (motor 1, which turns J1 only) while the other two motors keep their
positions, so the blocked motor pushes with its effort cap for as long as the target stands
(the hold): the cap, not a position, sets the squeeze force.  Advancing J1 in joint space
instead would also advance motor 0, which turns J0 with J1 (the tendon differential,
:func:`protocol.robot.joint_to_motor`): with J1 blocked by the object it would swing the
finger sideways, off the object.  Holding motor 0 instead turns J0 back by g1/g0 of what J1
still closes before the object stops it, so the squeeze sets its targets again from the
measured J1 and the J0 it started from until J1 stops closing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Final

import numpy as np

from host.errors import UsageError
from host.hand.interface import MovingHand
from host.hand.state import FingerState, GraspResult, Vec3
from host.hand.synergies import (
    BLEND_PERIOD_S,
    CONTACT_EFFORT,
    CONTACT_LAG_RAD,
    CONTACT_STALL_RAD_S,
    DEFAULT_SPEED_RAD_S,
    KINDS,
    MAX_SPEED_RAD_S,
    ROLES,
    SAME_DIRECTION_COS,
    SPREAD_EPS_M,
    SQUEEZE_RAD,
    SYNERGIES,
    TACTILE_CONTACT_COUNTS,
    Synergy,
    blend,
    contact,
    finger_roles,
    spread_signs,
    squeeze_target,
    synergy,
    synergy_targets,
)
from protocol.robot import HandLayout
from protocol.topology import FINGERS

#: A squeeze sets its targets again at most this many times (:func:`squeeze`): enough for a
#: finger that nothing stops to close J1 across its whole range at :data:`SQUEEZE_RAD` a
#: round and end at its limit with its spread kept; one on an object stops in two or three ...
SQUEEZE_ROUNDS: Final = 12
#: ... until no finger's J1 closed more than this (rad) in a round.
SQUEEZE_SETTLED_RAD: Final = 0.02
#: How long (s) a grasp waits at the end for the fingers to settle.
GRASP_TIMEOUT_S: Final = 3.0


def squeeze(hand: MovingHand, fingers: Sequence[int] | None = None, amount: float = SQUEEZE_RAD,
            *, effort: Sequence[int] | int | None = None, timeout: float = 1.0,
            rounds: int = SQUEEZE_ROUNDS,
            on_states: Callable[[float, Mapping[int, FingerState]], None] | None = None
            ) -> dict[int, Vec3]:
    """Press ``fingers`` (default: all four) on what they hold: each finger's target becomes
    :func:`squeeze_target` of its pose (``amount`` rad of J1 past it), with the motor effort
    cap ``effort`` (1/255 of full PWM) setting the force (less than ``amount`` where J1's
    upper limit is nearer); waits up to ``timeout`` s for the
    fingers to stall on the object.  Holding motor 0 turns J0 back by g1/g0 of whatever J1
    still closes before the object stops it, so up to ``rounds`` times the targets are set
    again from the measured J1, J2 and the J0 before the squeeze, until no J1 closed more
    than :data:`SQUEEZE_SETTLED_RAD` in a round.  The targets stand until the next command,
    so the squeeze lasts through a hold.  Returns the targets (rad) per finger."""
    if amount < 0:
        raise UsageError(f"squeeze {amount} rad: give a non-negative amount")
    chosen = list(range(FINGERS)) if fingers is None else sorted(set(fingers))
    states = hand.finger_states(chosen)
    if on_states is not None:
        on_states(hand.session.now(), states)
    spread = {k: float(states[k].joints[0]) for k in chosen}
    targets: dict[int, Vec3] = {}
    for _ in range(max(1, rounds)):
        targets = {}
        for k in chosen:
            q1 = float(states[k].joints[1])
            # J1's target stays inside its upper limit (rounding: a µrad inside).
            room = max(0.0, min(amount, hand.limits.upper[k][1] - 1e-6 - q1))
            targets[k] = hand.limits.apply(k, squeeze_target(
                (spread[k], q1, float(states[k].joints[2])), room))
        hand.send([hand.fingers[k].make_command(targets[k], effort=effort) for k in chosen],
                  unhomed=True)
        hand.wait_settled(chosen, timeout)
        before, states = states, hand.finger_states(chosen)
        if on_states is not None:
            on_states(hand.session.now(), states)
        if all(abs(states[k].joints[1] - before[k].joints[1]) < SQUEEZE_SETTLED_RAD
               for k in chosen):
            break
    return targets


def grasp(hand: MovingHand, name: str, amount: float, *, speed: float = DEFAULT_SPEED_RAD_S,
          fingers: Sequence[int] | None = None, until_contact: bool = False,
          effort: Sequence[int] | int | None = None, timeout: float = GRASP_TIMEOUT_S,
          squeeze_rad: float = 0.0,
          unhomed: bool = False, layout: str | HandLayout | None = None,
          period: float = BLEND_PERIOD_S,
          on_states: Callable[[float, Mapping[int, FingerState]], None] | None = None
          ) -> GraspResult:
    """Blend ``fingers`` (default: all four) from their measured pose to synergy ``name`` at
    ``amount`` (0..1) at ``speed`` rad/s, then wait up to ``timeout`` s for them to settle.
    Refused for fingers not homed unless ``unhomed``; targets pass the hand's joint limits
    before anything moves.  ``on_states(t, states)`` is told every reading of the fingers'
    status the grasp makes (the link's clock, s; finger → :class:`FingerState`).
    ``squeeze_rad`` > 0: once settled, :func:`squeeze` the fingers by that much (rad of J1)
    with ``effort``; ``targets`` then holds the squeeze's targets."""
    if not 0 < speed <= MAX_SPEED_RAD_S:  # NaN too
        raise UsageError(f"speed {speed} rad/s: give a speed > 0 and <= {MAX_SPEED_RAD_S:g}")
    chosen = list(range(FINGERS)) if fingers is None else sorted(set(fingers))
    if any(not 0 <= k < FINGERS for k in chosen):
        raise UsageError(f"fingers {chosen}: a hand has fingers 0..{FINGERS - 1}")
    all_targets = synergy_targets(name, amount, layout or hand.layout)
    targets = {k: hand.limits.apply(k, all_targets[k]) for k in chosen}
    if not unhomed:
        hand.require_homed(chosen)
    session = hand.session
    baseline = hand.finger_states(chosen)
    if on_states is not None:
        on_states(session.now(), baseline)
    start = {k: np.asarray(baseline[k].joints) for k in chosen}
    t0 = session.now()
    result = GraspResult(name, float(amount), dict(targets))
    active = list(chosen)
    previous: dict[int, FingerState] = {}
    last_read = t0
    while active:
        elapsed = session.now() - t0
        now_targets = {k: blend(start[k], targets[k], speed, elapsed) for k in active}
        hand.send([hand.fingers[k].make_command(tuple(now_targets[k]), effort=effort)
                   for k in active], unhomed=True)
        done = all(np.allclose(now_targets[k], targets[k]) for k in active)
        if until_contact:
            session.sleep(period)
            states = hand.finger_states(active)
            now = session.now()
            if on_states is not None:
                on_states(now, states)
            for k in list(active):
                why = contact(states[k], baseline[k], now_targets[k], previous.get(k),
                              now - last_read)
                if why is not None:
                    result.contacts[k] = why
                    held = hand.limits.apply(k, states[k].joints)
                    hand.send([hand.fingers[k].make_command(held, effort=effort)],
                              unhomed=True)
                    active.remove(k)
            previous, last_read = states, now
        elif not done:
            session.sleep(period)
        if done:
            break
    result.move = hand.wait_settled(chosen, timeout)
    if squeeze_rad > 0:
        result.targets.update(squeeze(hand, chosen, squeeze_rad, effort=effort,
                                      on_states=on_states))
    result.elapsed_s = session.now() - t0
    return result


#: The procedure, and (declared in :mod:`host.hand.synergies`) the synergies and the pure
#: math, importable from here as before the split.
__all__ = [
    "GRASP_TIMEOUT_S", "SQUEEZE_ROUNDS", "SQUEEZE_SETTLED_RAD", "grasp", "squeeze",
    "GraspResult", "Vec3", "BLEND_PERIOD_S", "CONTACT_EFFORT", "CONTACT_LAG_RAD",
    "CONTACT_STALL_RAD_S", "DEFAULT_SPEED_RAD_S", "KINDS", "MAX_SPEED_RAD_S", "ROLES", "SAME_DIRECTION_COS", "SPREAD_EPS_M",
    "SQUEEZE_RAD", "SYNERGIES", "TACTILE_CONTACT_COUNTS", "Synergy", "blend", "contact",
    "finger_roles", "spread_signs", "squeeze_target", "synergy", "synergy_targets",
]
