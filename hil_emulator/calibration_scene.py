"""The ``calibration`` scene: the rig the arm's touch calibration touches, placed as found.

A table, a board with conical dimples lying on it, two anchor dimples on the arm's mounting
bracket, and the calibration probe on the wrist flange (:data:`protocol.robot.ARM_PROBE_TIP_M`,
its ball :data:`protocol.robot.ARM_PROBE_BALL_RADIUS_M`), all from the figures the host is
told (:mod:`host.arm.calibration_rig`).  What the host is *not* told is drawn from the seed
(:func:`draw_placement`): the board lies off its nominal pose by a few millimetres and a
degree or so, the table's top is a few millimetres off its nominal height, and each anchor
dimple is off the bracket's drawing by a few tenths of a millimetre.  :class:`RigTruth`, the
scene's plant part, keeps what was drawn (ground truth, for tests; never on the wire).

**The dimples.**  A cone cannot be one MuJoCo geom (collisions are between convex shapes), so
each dimple is :data:`FACETS` thin plates whose top faces are tangent planes of the cone:
a hexagonal funnel of :data:`~host.arm.calibration_rig.DIMPLE_SLOPE_RAD` walls and
:data:`~host.arm.calibration_rig.DIMPLE_MOUTH_RADIUS_M` mouth, its apex so deep that the
seated ball's centre is the dimple's point.  The funnel and the probe's ball are nearly
frictionless (:data:`RIG_FRICTION`), so the ball slides to the bottom under a push.

**Contacts.**  Everything here has ``contype = conaffinity =`` :data:`RIG_BITS`, a bit no
other geom uses: only the probe's ball touches the rig; the arm's and the hand's geoms pass
through it (as the ``mug`` scene's arm passes through the mug: a documented simplification).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import mujoco
import numpy as np

import host.arm.calibration_rig as rig
from hil_emulator.arm.model import MOUNT_HEIGHT_M
from hil_emulator.errors import EmulatorConfigError
from host.arm.kinematics import rpy_to_matrix
from protocol.robot import ARM_PROBE_BALL_RADIUS_M, ARM_PROBE_TIP_M

#: The contact bit of the rig and the probe's ball (no other geom has it).
RIG_BITS: Final = 8
#: Sliding, torsional, rolling friction of the funnels and the ball (polished steel, oiled).
RIG_FRICTION: Final = (0.02, 0.005, 0.0001)
#: Plates per dimple.
FACETS: Final = 6
#: The plates' half-thickness (m).
PLATE_HALF_M: Final = 0.0015
#: The placement's spread (1σ, clipped at 3σ): the board's position (m per axis) and
#: orientation (rad per axis), the table top's height (m), each anchor's position (m per axis).
BOARD_SIGMA_M: Final = 0.003
BOARD_SIGMA_RAD: Final = math.radians(1.0)
TABLE_SIGMA_M: Final = 0.003
ANCHOR_SIGMA_M: Final = 0.0003
#: The seed sequence's key of the placement (beside :data:`hil_emulator.imperfections.PART_KEYS`).
PLACEMENT_KEY: Final = 20
#: The probe's mass (kg): a 60 mm steel rod and its ball.
PROBE_MASS_KG: Final = 0.05
#: The world frame is the arm's base frame lowered by the mount height (m).
_BASE_IN_WORLD: Final = np.array([0.0, 0.0, MOUNT_HEIGHT_M])
_STEEL_RGBA: Final = (0.7, 0.7, 0.75, 1.0)
_BOARD_RGBA: Final = (0.3, 0.45, 0.3, 1.0)
_WOOD_RGBA: Final = (0.55, 0.38, 0.22, 1.0)


@dataclass(frozen=True)
class Placement:
    """Where the rig stands (base frame, m): the board's origin and rotation (3×3), the
    table top's height, each anchor dimple's point (2×3)."""

    board_origin_m: np.ndarray
    board_rotation: np.ndarray
    table_top_z_m: float
    anchors_m: np.ndarray

    def dimples_m(self) -> np.ndarray:
        """Every board dimple's point as placed (n×3, m, base frame)."""
        out: np.ndarray = self.board_origin_m + rig.dimple_points() @ self.board_rotation.T
        return out


def _clipped(rng: np.random.Generator, sigma: float, n: int) -> np.ndarray:
    return np.clip(rng.normal(0.0, sigma, n), -3.0 * sigma, 3.0 * sigma)


def draw_placement(seed: int) -> Placement:
    """The rig as placed for ``seed``: the nominal poses moved by drawn amounts."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PLACEMENT_KEY,)))
    origin = np.asarray(rig.BOARD_ORIGIN_M) + _clipped(rng, BOARD_SIGMA_M, 3)
    rotation = rpy_to_matrix(np.asarray(rig.BOARD_RPY) + _clipped(rng, BOARD_SIGMA_RAD, 3))
    table = rig.TABLE_TOP_Z_M + float(_clipped(rng, TABLE_SIGMA_M, 1)[0])
    anchors = np.asarray(rig.ANCHOR_POINTS_M) + _clipped(rng, ANCHOR_SIGMA_M, 6).reshape(2, 3)
    return Placement(origin, rotation, table, anchors)


def _rig_geom(body: mujoco.MjsBody, name: str, gtype: mujoco.mjtGeom, size: list[float],
              rgba: tuple[float, ...], **where: object) -> mujoco.MjsGeom:
    geom = body.add_geom(name=name, type=gtype, size=size, rgba=list(rgba),
                         contype=RIG_BITS, conaffinity=RIG_BITS, friction=list(RIG_FRICTION),
                         condim=3, **where)
    return geom


def _quat_of(rotation: np.ndarray) -> list[float]:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation).ravel())
    return quat.tolist()


def add_dimple(body: mujoco.MjsBody, name: str) -> None:
    """A funnel in ``body`` whose seated probe ball's centre is ``body``'s origin, its axis
    along ``body``'s ``z``."""
    slope = rig.DIMPLE_SLOPE_RAD
    apex = np.array([0.0, 0.0, -ARM_PROBE_BALL_RADIUS_M / math.cos(slope)])
    length = rig.DIMPLE_MOUTH_RADIUS_M / math.cos(slope)
    half_width = rig.DIMPLE_MOUTH_RADIUS_M * math.tan(math.pi / FACETS) * 1.1
    for k in range(FACETS):
        phi = 2.0 * math.pi * k / FACETS
        up = np.array([math.cos(slope) * math.cos(phi), math.cos(slope) * math.sin(phi),
                       math.sin(slope)])
        normal = np.array([-math.sin(slope) * math.cos(phi), -math.sin(slope) * math.sin(phi),
                           math.cos(slope)])
        side = np.cross(normal, up)
        centre = apex + 0.5 * length * up - PLATE_HALF_M * normal
        rotation = np.column_stack((up, side, normal))
        _rig_geom(body, f"{name}/facet{k}", mujoco.mjtGeom.mjGEOM_BOX,
                  [0.5 * length, half_width, PLATE_HALF_M], _STEEL_RGBA,
                  pos=centre.tolist(), quat=_quat_of(rotation))


def _body_at(spec: mujoco.MjSpec, name: str, point_m: np.ndarray,
             rotation: np.ndarray) -> mujoco.MjsBody:
    body: mujoco.MjsBody = spec.worldbody.add_body(
        name=name, pos=(np.asarray(point_m) + _BASE_IN_WORLD).tolist(), quat=_quat_of(rotation))
    return body


def add_probe(spec: mujoco.MjSpec, flange_body: str = "arm/flange") -> None:
    """The calibration probe on the flange: a rod (no contacts) and its ball (the rig's bit)."""
    flange = spec.body(flange_body)
    if flange is None:
        raise EmulatorConfigError("the calibration scene needs the arm's flange for its probe")
    tip = list(ARM_PROBE_TIP_M)
    rod = flange.add_geom(name="probe/rod", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                          size=[0.003, 0.0, 0.0], rgba=list(_STEEL_RGBA), contype=0,
                          conaffinity=0, mass=PROBE_MASS_KG * 0.8)
    rod.fromto = [0.0, 0.0, 0.0, tip[0], tip[1], tip[2] * 0.9]
    _rig_geom(flange, "probe/ball", mujoco.mjtGeom.mjGEOM_SPHERE, [ARM_PROBE_BALL_RADIUS_M],
              _STEEL_RGBA, pos=tip, mass=PROBE_MASS_KG * 0.2)
    flange.add_site(name="probe/tip", pos=tip, size=[0.002, 0.0, 0.0])


def add_calibration_scene(spec: mujoco.MjSpec, seed: int) -> RigTruth:
    """The rig (table, board, anchors) placed for ``seed`` and the probe on the flange; the
    scene's plant part, which keeps the placement."""
    placed = draw_placement(seed)
    add_probe(spec)
    cx, cy = rig.TABLE_TOUCH_CENTRE_XY_M
    half_t = 0.015
    table = _body_at(spec, "calibration/table",
                     np.array([cx, cy, placed.table_top_z_m - half_t]), np.eye(3))
    _rig_geom(table, "calibration/table/top", mujoco.mjtGeom.mjGEOM_BOX,
              [rig.TABLE_TOUCH_HALF_M + 0.02, rig.TABLE_TOUCH_HALF_M + 0.15, half_t],
              _WOOD_RGBA)
    board = _body_at(spec, "calibration/board", placed.board_origin_m, placed.board_rotation)
    rows, cols = rig.DIMPLE_GRID
    pitch = rig.DIMPLE_PITCH_M
    plate = board.add_geom(name="calibration/board/plate", type=mujoco.mjtGeom.mjGEOM_BOX,
                           size=[rows * pitch / 2, cols * pitch / 2, 0.002],
                           pos=[(rows - 1) * pitch / 2, (cols - 1) * pitch / 2, -0.012],
                           rgba=list(_BOARD_RGBA), contype=0, conaffinity=0)
    del plate
    for i, point in enumerate(rig.dimple_points()):
        holder = board.add_body(name=f"calibration/dimple{i}", pos=point.tolist())
        add_dimple(holder, f"calibration/dimple{i}")
    for i, point in enumerate(placed.anchors_m):
        anchor = _body_at(spec, f"calibration/anchor{i}", point, np.eye(3))
        add_dimple(anchor, f"calibration/anchor{i}")
    return RigTruth(placed)


class RigTruth:
    """The calibration scene's plant part: the rig as placed (:class:`Placement`, ground
    truth) and the probe's tip now (m, the arm's base frame).  It applies no force."""

    #: The part's name (:meth:`hil_emulator.robot.EmulatedRobot.scene_stats`).
    name: Final = "calibration"

    def __init__(self, placement: Placement) -> None:
        self.placement = placement
        self._data: mujoco.MjData | None = None
        self._tip = -1

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._data = data
        self._tip = model.site("probe/tip").id

    def before_step(self, dt_s: float) -> None:
        pass

    def after_step(self, dt_s: float) -> None:
        pass

    @property
    def tip_m(self) -> np.ndarray:
        """The probe ball's centre now (m, base frame): the optical tracker's truth."""
        assert self._data is not None
        out: np.ndarray = self._data.site_xpos[self._tip] - _BASE_IN_WORLD
        return out

    def summary(self) -> dict[str, float]:
        """The placement's offsets from nominal (m) and the probe's tip now (m, base frame)."""
        off = self.placement.board_origin_m - np.asarray(rig.BOARD_ORIGIN_M)
        tip = self.tip_m
        return {"board_dx_m": float(off[0]), "board_dy_m": float(off[1]),
                "board_dz_m": float(off[2]),
                "table_dz_m": self.placement.table_top_z_m - rig.TABLE_TOP_Z_M,
                "tip_x_m": float(tip[0]), "tip_y_m": float(tip[1]), "tip_z_m": float(tip[2])}
