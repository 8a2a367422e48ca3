"""The hand's parameters in a robot profile, and where they go.

Declared once in :data:`HAND_PARAMETERS` (:data:`hil_emulator.profile.PARAMETERS` adds
them to the arm's); docs/EMULATOR.md ("Robot profiles") lists them:

* per finger module ``k`` (0..3): ``hand.finger{k}.motor_friction``, the Coulomb friction of
  each of its three motors at the motor shaft (N·m: gearbox and capstan losses, the model's
  tendon ``frictionloss``), and ``hand.finger{k}.joint_damping``, the viscous damping of each
  of its three joints (N·m·s/rad: the bearings' losses);
* per accelerometer board (``hand.palm``, ``hand.finger{k}.fmcb``, ``.f2``, ``.f3``):
  ``accel_rotation_x|y|z``, the components of the chip's mounting rotation as a rotation
  vector about the board's nominal axes (degrees: the chip's axes are the nominal ones
  turned by it, :func:`hil_emulator.imperfections.rotation_from_vector`), and
  ``accel_bias_x|y|z``, its zero-g offset at the reference temperature along the chip's axes
  (g).  A value replaces that component of the seeded as-built draw
  (:mod:`hil_emulator.imperfections`); the components a profile leaves out keep the draw.
  The sensors' parameters need ``--sensors realistic`` (ideal sensors have none).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Final

import numpy as np
from scipy.spatial.transform import Rotation

from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.finger_plant import FingerParams
from hil_emulator.hand.model import DEFAULT_MOTOR, JOINT_DAMPING
from hil_emulator.imperfections import FINGER_BOARDS, AccelTruth, rotation_from_vector
from hil_emulator.parameter import Parameter
from protocol.topology import FINGERS

#: Every board carrying an accelerometer, by its name in a parameter (``palm``,
#: ``finger1.f2``), as :class:`~hil_emulator.imperfections.PlantedTruth` names them.
ACCEL_BOARDS: Final = ("palm", *(f"finger{k}.{b}" for k in range(FINGERS)
                                 for b in FINGER_BOARDS))
AXES: Final = ("x", "y", "z")
#: (suffix, unit, nominal, low, high, the fit's unit, what it is) of each finger's
#: parameters; ``field`` names the :class:`FingerParams` value it sets.
_FINGER_KINDS: Final = (
    ("motor_friction", "N·m", DEFAULT_MOTOR.friction_nm, 0.1, 5.0,
     "Coulomb friction of each of the finger's three motors at its shaft (gearbox and "
     "capstan losses)"),
    ("joint_damping", "N·m·s/rad", JOINT_DAMPING, 0.1, 10.0,
     "viscous damping of each of the finger's three joints (bearing losses)"),
)
#: (suffix, unit, low, high, the fit's unit, what it is) of each board's; nominal 0 (the
#: draw's median).
_ACCEL_KINDS: Final = (
    ("accel_rotation", "deg", -10.0, 10.0, 10.0,
     "the accelerometer's mounting rotation: its rotation vector's component about the "
     "board's nominal {axis} axis (replaces the draw's)"),
    ("accel_bias", "g", -0.2, 0.2, 0.1,
     "the accelerometer's zero-g offset along its {axis} axis at 25 °C (replaces the "
     "draw's)"),
)

#: The hand's fittable parameters.
HAND_PARAMETERS: Final[tuple[Parameter, ...]] = (
    *(Parameter(f"hand.finger{k}.{suffix}", unit, nominal, nominal * lo, nominal * hi, doc,
                "hand", suffix, -1, f"finger{k}")
      for k in range(FINGERS) for suffix, unit, nominal, lo, hi, doc in _FINGER_KINDS),
    *(Parameter(f"hand.{board}.{suffix}_{axis}", unit, 0.0, lo, hi, doc.format(axis=axis),
                "hand", suffix, i, board, scale)
      for board in ACCEL_BOARDS for suffix, unit, lo, hi, scale, doc in _ACCEL_KINDS
      for i, axis in enumerate(AXES)),
)
_BY_NAME: Final = {p.name: p for p in HAND_PARAMETERS}


def _of(values: Mapping[str, float], part: str, field: str) -> dict[int, float]:
    """The values of finger or board ``part``'s ``field`` parameters in ``values``, by axis
    (-1: none)."""
    out: dict[int, float] = {}
    for name, value in values.items():
        p = _BY_NAME.get(name)
        if p is not None and p.element == part and p.field == field:
            out[p.index] = value
    return out


def sensor_names(values: Mapping[str, float]) -> list[str]:
    """The accelerometer parameters among ``values``' names."""
    return [n for n in values if n in _BY_NAME and _BY_NAME[n].field in
            {kind[0] for kind in _ACCEL_KINDS}]


def finger_params(values: Mapping[str, float], finger: int, base: FingerParams
                  ) -> FingerParams:
    """``base`` with the friction and damping ``values`` give finger module ``finger``."""
    part = f"finger{finger}"
    friction = _of(values, part, "motor_friction")
    damping = _of(values, part, "joint_damping")
    if friction:
        base = dataclasses.replace(base, motor=dataclasses.replace(
            base.motor, friction_nm=friction[-1]))
    if damping:
        base = dataclasses.replace(base, joint_damping_nm_s_per_rad=damping[-1])
    return base


def accel_truth(values: Mapping[str, float], board: str, drawn: AccelTruth) -> AccelTruth:
    """Board ``board``'s accelerometer as built: ``drawn`` with the rotation and offset
    components ``values`` give it."""
    rotation = _of(values, board, "accel_rotation")
    bias = _of(values, board, "accel_bias")
    if not rotation and not bias:
        return drawn
    tilt = np.array(Rotation.from_matrix(drawn.rotation).as_rotvec() if drawn.tilt_rad is None
                    else drawn.tilt_rad, dtype=float)
    for axis, deg in rotation.items():
        tilt[axis] = math.radians(deg)
    offset = np.array(drawn.bias_mg, dtype=float)
    for axis, g in bias.items():
        offset[axis] = 1000.0 * g
    return dataclasses.replace(drawn, rotation=rotation_from_vector(tilt), bias_mg=offset,
                               tilt_rad=tilt)


def check_sensors(values: Mapping[str, float], sensors: str) -> None:
    """:class:`EmulatorConfigError` when ``values`` name a sensor's parameter and the
    robot's ``sensors`` are not as built."""
    named = sensor_names(values)
    if named and sensors != "realistic":
        raise EmulatorConfigError(f"{named[0]}: a sensor's parameter needs --sensors "
                                  f"realistic (the {sensors!r} sensors have no imperfections)")
