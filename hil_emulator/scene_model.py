"""Scenes around the robot: things in the world the arm and hand can work with.

:data:`SCENES` names what :class:`~hil_emulator.emulator.Emulator` (``scene=``) and
``hil-emulator --scene`` can add to a configuration with the arm:

``none``  the robot alone (the default);
``mug``   a table in front of the arm and a coffee mug standing on it, within reach of the
          hand on the arm's wrist (:func:`add_mug_scene`);
``calibration``  the touch calibration's rig: a table, a board of conical dimples on it, two
          anchor dimples by the base, the probe on the flange, placed off their nominal poses
          by a seeded amount (:mod:`hil_emulator.calibration_scene`).

World frame (m): ``z`` up from the floor, ``x`` forward from the arm's base (the arm's base
frame is the world's raised by :data:`~hil_emulator.arm.model.MOUNT_HEIGHT_M`).

**Contacts.**  The table top has ``contype = conaffinity = TABLE_BITS`` and the mug
``contype = MUG_CONTYPE``, ``conaffinity = MUG_CONAFFINITY``: the mug touches the table, the
floor and the hand (hand geoms: ``contype = 2``), and the hand touches the table, but the
mug does **not** touch the arm's geoms (``contype = 0, conaffinity = 1``): the arm passing
through the mug is this scene's documented simplification, as the hand's fingers passing
through each other is the hand model's.  The hand's back is on the wrist flange, its palmar
face looking away from the arm (:data:`protocol.robot.HAND_ON_FLANGE_QUAT`), so the palm and
the fingers, not the wrist, hold what they grasp.
"""

from __future__ import annotations

import math
from typing import Final, Protocol

import mujoco
import numpy as np

from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.model import PAD_FRICTION

#: The scenes :class:`~hil_emulator.emulator.Emulator` can build.
SCENES: Final = ("none", "mug", "calibration")

#: Table: top surface height above the floor (m), centre of the top (x, y; m), half extents
#: of the top (m) and its thickness (m).
TABLE_TOP_Z_M: Final = 0.68
TABLE_CENTRE_XY_M: Final = (0.67, 0.05)
TABLE_HALF_XY_M: Final = (0.20, 0.25)
TABLE_THICKNESS_M: Final = 0.03
#: Contact bits of the table top (see the module docstring).
TABLE_BITS: Final = 4 | 2

#: Mug: outer radius and height (m; a 350 ml coffee mug: 8 cm across, 10 cm tall), mass
#: (kg, ceramic), where it stands on the table (x, y of its axis; m).
MUG_RADIUS_M: Final = 0.04
MUG_HEIGHT_M: Final = 0.10
MUG_MASS_KG: Final = 0.30
MUG_XY_M: Final = (0.52, 0.025)
#: Contact bits of the mug: touches the table (4), the floor and the hand (1, 2), not the
#: arm (whose geoms have ``contype = 0`` and only ``conaffinity = 1``).
MUG_CONTYPE: Final = 4
MUG_CONAFFINITY: Final = 1 | 2 | 4
#: Glazed ceramic on the finger pads' silicone (sliding, torsional, rolling).
MUG_FRICTION: Final = PAD_FRICTION

#: Body names (the mug's free joint is ``MUG_BODY + "/free"``).
TABLE_BODY: Final = "table"
MUG_BODY: Final = "mug"

_WOOD_RGBA: Final = (0.55, 0.38, 0.22, 1.0)
_MUG_RGBA: Final = (0.92, 0.92, 0.88, 1.0)


def add_table(spec: mujoco.MjSpec) -> mujoco.MjsBody:
    """A table fixed to the world: top :data:`TABLE_TOP_Z_M` above the floor, four legs."""
    cx, cy = TABLE_CENTRE_XY_M
    hx, hy = TABLE_HALF_XY_M
    half_t = TABLE_THICKNESS_M / 2
    table = spec.worldbody.add_body(name=TABLE_BODY, pos=[cx, cy, TABLE_TOP_Z_M - half_t])
    table.add_geom(name=f"{TABLE_BODY}/top", type=mujoco.mjtGeom.mjGEOM_BOX,
                   size=[hx, hy, half_t], rgba=list(_WOOD_RGBA),
                   contype=TABLE_BITS, conaffinity=TABLE_BITS)
    leg_half = (TABLE_TOP_Z_M - TABLE_THICKNESS_M) / 2
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        table.add_geom(name=f"{TABLE_BODY}/leg{i}", type=mujoco.mjtGeom.mjGEOM_BOX,
                       size=[0.02, 0.02, leg_half], rgba=list(_WOOD_RGBA),
                       pos=[sx * (hx - 0.03), sy * (hy - 0.03), -half_t - leg_half],
                       contype=0, conaffinity=0)
    return table


def add_mug(spec: mujoco.MjSpec, xy: tuple[float, float] = MUG_XY_M,
            z: float = TABLE_TOP_Z_M) -> mujoco.MjsBody:
    """A free coffee mug standing upright with its base at height ``z`` (m) and its axis at
    ``xy`` (m, world): a cylinder (the contact shape) of :data:`MUG_RADIUS_M` and
    :data:`MUG_HEIGHT_M`, :data:`MUG_MASS_KG` in all, and a handle on the side away from
    the hand (visual only; its mass counts)."""
    body = spec.worldbody.add_body(name=MUG_BODY,
                                   pos=[xy[0], xy[1], z + MUG_HEIGHT_M / 2 + 0.0005])
    body.add_freejoint(name=f"{MUG_BODY}/free")
    handle_mass = 0.03
    body.add_geom(name=f"{MUG_BODY}/body", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=[MUG_RADIUS_M, MUG_HEIGHT_M / 2, 0.0], mass=MUG_MASS_KG - handle_mass,
                  rgba=list(_MUG_RGBA), contype=MUG_CONTYPE, conaffinity=MUG_CONAFFINITY,
                  friction=list(MUG_FRICTION), condim=4)
    # The handle: a C of three capsules, turned towards −x −y (the arm's side, away from
    # the palm and the fingers' bases).
    reach, span = 0.025, 0.03
    c, s = math.cos(-0.75 * math.pi), math.sin(-0.75 * math.pi)

    def turned(x: float, zz: float) -> list[float]:
        return [c * x, s * x, zz]

    r0 = MUG_RADIUS_M - 0.004
    for name, a, b in (("top", (r0, span), (r0 + reach, span)),
                       ("side", (r0 + reach, span), (r0 + reach, -span)),
                       ("bottom", (r0 + reach, -span), (r0, -span))):
        g = body.add_geom(name=f"{MUG_BODY}/handle_{name}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                          size=[0.006, 0.0, 0.0], mass=handle_mass / 3, rgba=list(_MUG_RGBA),
                          contype=0, conaffinity=0)
        g.fromto = turned(*a) + turned(*b)
    return body


def add_mug_scene(spec: mujoco.MjSpec) -> None:
    """The table and the mug on it (:func:`add_table`, :func:`add_mug`).  MuJoCo's
    multi-point convex collision (on unless ``mjDSBL_MULTICCD``) stands the mug's flat base
    on several contacts, so it does not rock on one."""
    add_table(spec)
    add_mug(spec)


class MugTracker:
    """A plant part that watches the mug (ground truth, for demos and tests): where it
    started, where it is, the highest it has been (m, world) and how far its axis leans
    from vertical (rad).  It applies no force."""

    #: The tracked object's name (its body's).
    name: Final = MUG_BODY

    def __init__(self) -> None:
        self.start = np.zeros(3)
        self.highest_z = 0.0
        self._data: mujoco.MjData | None = None
        self._id = -1

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._data = data
        self._id = model.body(MUG_BODY).id
        self.start = data.xpos[self._id].copy()
        self.highest_z = float(self.start[2])

    def before_step(self, dt_s: float) -> None:
        pass

    def after_step(self, dt_s: float) -> None:
        assert self._data is not None
        z = float(self._data.xpos[self._id][2])
        if z > self.highest_z:
            self.highest_z = z

    @property
    def position(self) -> np.ndarray:
        """The mug's centre now (m, world)."""
        assert self._data is not None
        return self._data.xpos[self._id].copy()

    @property
    def tilt_rad(self) -> float:
        """Angle between the mug's axis and the vertical now (rad)."""
        assert self._data is not None
        axis_z = float(self._data.xmat[self._id][8])
        return math.acos(max(-1.0, min(1.0, axis_z)))

    def summary(self) -> dict[str, float]:
        """Start and present height, highest lift above the start (m), tilt (rad)."""
        now = self.position
        return {"start_z_m": float(self.start[2]), "z_m": float(now[2]),
                "lift_m": float(now[2] - self.start[2]),
                "highest_lift_m": self.highest_z - float(self.start[2]),
                "moved_xy_m": float(np.linalg.norm(now[:2] - self.start[:2])),
                "tilt_rad": self.tilt_rad}


class SceneObject(Protocol):
    """A scene's plant part that watches its objects (ground truth): a ``name`` and a
    ``summary()`` of numbers."""

    @property
    def name(self) -> str: ...

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None: ...

    def before_step(self, dt_s: float) -> None: ...

    def after_step(self, dt_s: float) -> None: ...

    def summary(self) -> dict[str, float]: ...


def add_scene(spec: mujoco.MjSpec, scene: str, seed: int = 0) -> list[SceneObject]:
    """Add scene ``scene`` (:data:`SCENES`) to ``spec``, its placement drawn from ``seed``
    where it has one; returns its plant parts (the trackers of its objects)."""
    if scene not in SCENES:
        raise EmulatorConfigError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if scene == "mug":
        add_mug_scene(spec)
        return [MugTracker()]
    if scene == "calibration":
        from hil_emulator.calibration_scene import add_calibration_scene
        return [add_calibration_scene(spec, seed)]
    return []
