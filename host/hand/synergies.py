"""Grasp synergies and named poses as data, and the pure math of a grasp (no I/O): the
blend towards a synergy, contact, the squeeze target.

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

:func:`blend` gives the joint targets along a straight line in joint space from the measured
pose to a synergy's, rate-limited on the largest joint change; :func:`contact` says why a
finger's status shows contact; :func:`squeeze_target` the targets that press a finger on
what it holds.  :mod:`host.hand.grasp` runs them on a hand.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from host.errors import UsageError
from host.hand.state import FingerState, Vec3
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


def squeeze_target(joints: Sequence[float] | np.ndarray, squeeze: float = SQUEEZE_RAD
                   ) -> Vec3:
    """Joint targets (rad) that squeeze from ``joints`` (rad): the proximal flexion motor
    (motor 1) advanced by ``squeeze`` rad of J1, motors 0 and 2 where they are (J1 target
    ``+squeeze``, J0 target ``−squeeze·g1/g0`` so motor 0 stays, J2 unchanged)."""
    m = list(joint_to_motor([float(q) for q in joints]))
    m[1] += float(squeeze) * FINGER_GEAR_RATIOS[1] * HALL_STATES_PER_RAD
    q = motor_to_joint(m)
    return (float(q[0]), float(q[1]), float(q[2]))
