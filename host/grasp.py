"""Grasp synergies and named poses as data, and a slewed blend towards them.

A :class:`Synergy` gives every finger's joint targets (rad, J0 J1 J2) as a linear function
of an *amount* 0..1: ``q(a) = start + a·(end − start)``.  Grasps (cylindrical, spherical,
prismatic, pinch) go from an open hand (0) to closed (1); named poses (open, point, relax)
from a relaxed hand (0) to the pose (1).  Targets are given per **role**, not per port,
and :func:`finger_roles` reads the roles from the hand layout (:data:`protocol.robot.HAND_LAYOUTS`):

- ``"opposing"``: a module whose extended direction differs from finger 0's (the thumb of
  ``four-finger-thumb``, the opposed module of ``three-plus-opposed``, the far pair of
  ``two-by-two``);
- ``"index"``: the finger of finger 0's group nearest the first opposing module (the one
  that pinches against it, or points);
- ``"finger"``: the others.

J0 values are *spread* (rad): positive turns a finger away from its group's centre line
(:func:`spread_signs`, from the mounts' positions and J0 axes), so one synergy serves every
layout; a finger on its group's centre line does not spread, one alone in its group takes
J0 as given.

:func:`grasp` blends from the measured pose to the synergy's targets along a straight line
in joint space, rate-limited to ``speed`` rad/s on the largest joint change, timed by the
link's clock (``session.now``/``sleep``), sending intermediate joint targets every
``period`` s.  With ``until_contact`` a finger stops closing (its target becomes its
measured pose) once its taxels rise by :data:`TACTILE_CONTACT_COUNTS` over their values at
the start, or its motors push hard (:data:`CONTACT_EFFORT`) while lagging the blend by
:data:`CONTACT_LAG_RAD`.

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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

import numpy as np

from host.errors import UsageError
from host.hand_state import FingerState
from protocol.robot import (
    DEFAULT_HAND_LAYOUT,
    FINGER_GEAR_RATIOS,
    FINGER_JOINT_STOPS,
    HALL_STATES_PER_RAD,
    HAND_LAYOUTS,
    HandLayout,
    joint_to_motor,
    motor_to_joint,
)
from protocol.topology import FINGERS

if TYPE_CHECKING:
    from host.hand import Hand, MoveResult

Vec3 = tuple[float, float, float]

ROLES: Final = ("finger", "index", "opposing")
KINDS: Final = ("grasp", "pose")
#: Default blend speed (rad/s) of the joint that moves most.
DEFAULT_SPEED_RAD_S: Final = 1.0
#: Period (s) between intermediate targets of a blend (the link's clock).
BLEND_PERIOD_S: Final = 0.02
#: Fastest blend speed taken (rad/s): the widest joint travel (between its stops) in one
#: blend period.  Faster, a blend is a single step, so a larger value is a typo (170 rad/s).
MAX_SPEED_RAD_S: Final = max(hi - lo for lo, hi in FINGER_JOINT_STOPS) / BLEND_PERIOD_S
#: A taxel this many ADC counts above its value at the start of a grasp means contact.
TACTILE_CONTACT_COUNTS: Final = 150
#: A motor effort (1/255 of full PWM) at least this large ...
CONTACT_EFFORT: Final = 150
#: ... while a flexion joint (J1, J2) lags the blend by this much (rad) ...
CONTACT_LAG_RAD: Final = 0.15
#: ... and moves slower than this (rad/s) means contact (blocked, not accelerating).
CONTACT_STALL_RAD_S: Final = 0.1
#: Default squeeze (rad of J1): how far past its pose a squeezed finger's proximal motor is
#: sent; its position error then saturates the fmcb's PD (gain 1/255 of PWM per hall count:
#: 0.3 rad of J1 is 338 counts), so the effort cap sets the force.
SQUEEZE_RAD: Final = 0.3
#: A squeeze sets its targets again at most this many times (:func:`squeeze`): enough for a
#: finger that nothing stops to close J1 across its whole range at :data:`SQUEEZE_RAD` a
#: round and end at its limit with its spread kept; one on an object stops in two or three ...
SQUEEZE_ROUNDS: Final = 12
#: ... until no finger's J1 closed more than this (rad) in a round.
SQUEEZE_SETTLED_RAD: Final = 0.02
#: Two mounts whose extended directions are within this cosine belong to one group.
SAME_DIRECTION_COS: Final = 0.9
#: A finger nearer than this (m) to its group's centre line is on it.
SPREAD_EPS_M: Final = 1e-3


@dataclass(frozen=True)
class Synergy:
    """One grasp or pose: per role, the joint angles (rad; J0 as spread) at amount 0
    (``start``) and at amount 1 (``end``)."""

    name: str
    kind: str
    description: str
    start: Mapping[str, Vec3]
    end: Mapping[str, Vec3]

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise UsageError(f"synergy {self.name}: kind {self.kind!r} is not one of {KINDS}")
        for table in (self.start, self.end):
            if set(table) != set(ROLES):
                raise UsageError(f"synergy {self.name}: give joints for roles {ROLES}")

    def role_joints(self, role: str, amount: float) -> np.ndarray:
        """Joint angles (rad, J0 as spread) of ``role`` at ``amount`` (0..1)."""
        a = np.asarray(self.start[role], dtype=float)
        b = np.asarray(self.end[role], dtype=float)
        return a + float(amount) * (b - a)


_OPEN: Final[Vec3] = (0.0, 0.0, 0.0)
_RELAXED: Final[Vec3] = (0.0, 0.3, 0.3)
_CURLED: Final[Vec3] = (0.0, 1.4, 1.4)


def _same(q: Vec3) -> dict[str, Vec3]:
    return {role: q for role in ROLES}


#: The synergies this library knows, by name.
SYNERGIES: Final[dict[str, Synergy]] = {s.name: s for s in (
    Synergy("cylindrical", "grasp", "wrap every finger round a cylinder (power grasp)",
            _same(_OPEN),
            {"finger": (0.0, 1.35, 1.2), "index": (0.0, 1.35, 1.2),
             "opposing": (0.0, 1.1, 0.9)}),
    Synergy("spherical", "grasp", "fingers spread and curl round a ball",
            {"finger": (0.3, 0.0, 0.0), "index": (0.3, 0.0, 0.0), "opposing": _OPEN},
            {"finger": (0.3, 1.0, 0.9), "index": (0.3, 1.0, 0.9),
             "opposing": (0.0, 0.9, 0.8)}),
    Synergy("prismatic", "grasp", "pads of every finger against the opposing one, "
            "distal joints nearly straight (a long thin object)",
            _same(_OPEN),
            {"finger": (-0.1, 1.2, 0.3), "index": (-0.1, 1.2, 0.3),
             "opposing": (0.0, 1.1, 0.3)}),
    Synergy("pinch", "grasp", "index against the opposing finger, pad to pad; the others "
            "stay open",
            _same(_OPEN),
            {"finger": _OPEN, "index": (0.0, 1.0, 0.4), "opposing": (0.0, 1.0, 0.4)}),
    Synergy("open", "pose", "every joint straight (0: relaxed)", _same(_RELAXED),
            _same(_OPEN)),
    Synergy("relax", "pose", "every finger slightly curled (0: open)", _same(_OPEN),
            _same(_RELAXED)),
    Synergy("point", "pose", "index straight, the others curled (0: relaxed)",
            _same(_RELAXED),
            {"finger": _CURLED, "index": _OPEN, "opposing": (0.0, 1.0, 1.0)}),
)}


def synergy(name: str) -> Synergy:
    """The synergy ``name``; :class:`UsageError` listing the known names otherwise."""
    try:
        return SYNERGIES[name]
    except KeyError:
        raise UsageError(f"unknown grasp {name!r}; choose one of "
                         f"{', '.join(sorted(SYNERGIES))}") from None


def _layout(layout: str | HandLayout) -> HandLayout:
    if isinstance(layout, HandLayout):
        return layout
    try:
        return HAND_LAYOUTS[layout]
    except KeyError:
        raise UsageError(f"unknown hand layout {layout!r}; choose one of "
                         f"{', '.join(HAND_LAYOUTS)}") from None


def _groups(layout: HandLayout) -> list[int]:
    """Group number per finger: modules extending the same way share one; finger 0's is 0."""
    xs = [np.asarray(m.rotation()[:, 0]) for m in layout.mounts]
    group = [-1] * len(xs)
    heads: list[int] = []
    for k, x in enumerate(xs):
        for g, head in enumerate(heads):
            if float(x @ xs[head]) >= SAME_DIRECTION_COS:
                group[k] = g
                break
        else:
            heads.append(k)
            group[k] = len(heads) - 1
    return group


def finger_roles(layout: str | HandLayout = DEFAULT_HAND_LAYOUT) -> list[str]:
    """Each finger's role (``"finger"``, ``"index"``, ``"opposing"``) in ``layout``."""
    lay = _layout(layout)
    group = _groups(lay)
    roles = ["finger" if g == 0 else "opposing" for g in group]
    opposing = [k for k, g in enumerate(group) if g != 0]
    if opposing:
        first = np.asarray(lay.mounts[opposing[0]].position_m)
        main = [k for k, g in enumerate(group) if g == 0]
        index = min(main, key=lambda k: float(np.linalg.norm(
            np.asarray(lay.mounts[k].position_m) - first)))
        roles[index] = "index"
    return roles


def spread_signs(layout: str | HandLayout = DEFAULT_HAND_LAYOUT) -> list[float]:
    """Per finger, the sign of J0 that turns it away from its group's centre line: +1 or
    −1; 0 for a finger on the line of a group (it does not spread); +1 for a finger alone
    in its group (J0 taken as given)."""
    lay = _layout(layout)
    group = _groups(lay)
    out = []
    for k, mount in enumerate(lay.mounts):
        members = [i for i, g in enumerate(group) if g == group[k]]
        if len(members) == 1:
            out.append(1.0)
            continue
        centre = np.mean([lay.mounts[i].position_m for i in members], axis=0)
        x = mount.rotation()[:, 0]
        offset = np.asarray(mount.position_m) - centre
        offset = offset - x * float(x @ offset)
        tip_motion = np.cross(mount.joint_axes()[0], x)  # where +J0 turns the tip
        side = float(tip_motion @ offset)
        out.append(0.0 if abs(side) < SPREAD_EPS_M else (1.0 if side > 0 else -1.0))
    return out


def synergy_targets(name: str, amount: float,
                    layout: str | HandLayout = DEFAULT_HAND_LAYOUT) -> dict[int, Vec3]:
    """Joint targets (rad) of every finger for synergy ``name`` at ``amount`` (0..1)."""
    s = synergy(name)
    a = float(amount)
    if not 0.0 <= a <= 1.0:
        raise UsageError(f"grasp amount {amount}: give a value in 0..1")
    roles, signs = finger_roles(layout), spread_signs(layout)
    out: dict[int, Vec3] = {}
    for k in range(FINGERS):
        q = s.role_joints(roles[k], a)
        out[k] = (float(q[0]) * signs[k], float(q[1]), float(q[2]))
    return out


# ============================================================================ the blend


def blend(start: Sequence[float] | np.ndarray, end: Sequence[float] | np.ndarray, speed: float,
          elapsed: float) -> np.ndarray:
    """The blend's joint targets (rad) ``elapsed`` s after it started from ``start`` towards
    ``end``: a straight line, the largest joint change moving at ``speed`` rad/s."""
    a = np.asarray(start, dtype=float)
    b = np.asarray(end, dtype=float)
    span = float(np.max(np.abs(b - a))) if a.size else 0.0
    if span <= 0.0:
        return b.copy()
    frac = min(1.0, max(0.0, elapsed) * speed / span)
    return a + frac * (b - a)


def contact(state: FingerState, baseline: FingerState,
            commanded: Sequence[float] | np.ndarray,
            previous: FingerState | None = None, dt: float = BLEND_PERIOD_S) -> str | None:
    """Why ``state`` shows contact (a text), or None: taxels above their ``baseline`` by
    :data:`TACTILE_CONTACT_COUNTS`, or a motor at :data:`CONTACT_EFFORT` while a flexion
    joint lags ``commanded`` (rad) by :data:`CONTACT_LAG_RAD` and has moved slower than
    :data:`CONTACT_STALL_RAD_S` since ``previous`` (read ``dt`` s earlier)."""
    for pad, values in state.tactile.items():
        base = baseline.tactile.get(pad, [])
        rises = [v - b for v, b in zip(values, base, strict=False)]
        if rises and max(rises) >= TACTILE_CONTACT_COUNTS:
            return f"{pad} taxels +{max(rises)} counts"
    if previous is None or dt <= 0:
        return None
    q = np.asarray(state.joints, dtype=float)
    lag = np.asarray(commanded, dtype=float) - q
    speed = np.abs(q - np.asarray(previous.joints, dtype=float)) / dt
    push = max(abs(e) for e in state.effort)
    for j in (1, 2):
        if lag[j] >= CONTACT_LAG_RAD and speed[j] < CONTACT_STALL_RAD_S \
                and push >= CONTACT_EFFORT:
            return f"J{j} blocked {lag[j]:.2f} rad short at effort {push}"
    return None


@dataclass
class GraspResult:
    """How a grasp ended: the ``targets`` (rad) per finger, ``contacts`` (finger → why it
    stopped closing), the final settle (:class:`~host.hand.MoveResult`), ``elapsed_s`` on
    the link's clock."""

    name: str
    amount: float
    targets: dict[int, Vec3]
    contacts: dict[int, str] = field(default_factory=dict)
    move: MoveResult | None = None
    elapsed_s: float = 0.0


def squeeze_target(joints: Sequence[float] | np.ndarray, squeeze: float = SQUEEZE_RAD
                   ) -> Vec3:
    """Joint targets (rad) that squeeze from ``joints`` (rad): the proximal flexion motor
    (motor 1) advanced by ``squeeze`` rad of J1, motors 0 and 2 where they are (J1 target
    ``+squeeze``, J0 target ``−squeeze·g1/g0`` so motor 0 stays, J2 unchanged)."""
    m = list(joint_to_motor([float(q) for q in joints]))
    m[1] += float(squeeze) * FINGER_GEAR_RATIOS[1] * HALL_STATES_PER_RAD
    q = motor_to_joint(m)
    return (float(q[0]), float(q[1]), float(q[2]))


def squeeze(hand: Hand, fingers: Sequence[int] | None = None, amount: float = SQUEEZE_RAD,
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


def grasp(hand: Hand, name: str, amount: float, *, speed: float = DEFAULT_SPEED_RAD_S,
          fingers: Sequence[int] | None = None, until_contact: bool = False,
          effort: Sequence[int] | int | None = None, timeout: float = 3.0,
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
        hand._require_homed(chosen)
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
