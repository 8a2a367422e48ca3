"""A robot profile: the physical parameters of one particular robot, as a versioned file.

Every robot built differs from the drawings: the stiffness of its polyurethane elements, the
friction of each bearing, its steppers' holding torque.  A profile says, for the parameters
it names, what they are on one robot; every parameter it leaves out keeps the emulator's
default (for the bearings: the seeded per-arm draw).  ``Emulator(profile=...)``,
``emu://arm/arm?profile=PATH`` and ``hil-emulator --profile FILE`` load one;
``hil-bench fit`` writes one.

The file is JSON::

    {"format": "hil-emulator robot profile", "version": 1,
     "parameters": {"arm.J2.stiffness": 260.0, "arm.J4.stiffness": 68.8},
     "fit": {...}}

``parameters`` maps names of :data:`PARAMETERS` to values in their units; ``fit`` (optional,
free-form) is what ``hil-bench fit`` records about how the values were found.  An unknown
key, an unknown parameter, a value that is not a finite number or lies outside its bounds is
an :class:`~hil_emulator.errors.EmulatorConfigError` naming it.

The fittable parameters are declared once, a table per part of the robot
(:data:`PART_TABLES`: the arm's :data:`ARM_PARAMETERS`, the hand's
:data:`hil_emulator.hand_profile.HAND_PARAMETERS`) that :data:`PARAMETERS` concatenates
(name, unit, nominal value, bounds, the part and place it applies to); docs/EMULATOR.md
("Robot profiles") lists them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from hil_emulator import hand_profile
from hil_emulator.arm.actuators import ArmParams
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand.finger_plant import FingerParams
from hil_emulator.imperfections import AccelTruth
from hil_emulator.parameter import Parameter

__all__ = ["ARM_PARAMETERS", "FILE_KEYS", "FORMAT", "PARAMETERS", "PARTS", "PART_TABLES",
           "VERSION", "Parameter", "RobotProfile", "as_profile", "load_profile", "parameter"]

#: The ``format`` every profile file carries, and the version this emulator reads.
FORMAT: Final = "hil-emulator robot profile"
VERSION: Final = 1
#: The keys a profile file may have.
FILE_KEYS: Final = ("format", "version", "parameters", "fit")


_DEFAULT = ArmParams()
_STEPPER_JOINTS: Final = ("J1", "J2", "J3", "J4")
#: (suffix, unit, ArmParams field, bounds as multiples of the nominal, what it is).
_ARM_KINDS: Final = (
    ("stiffness", "N·m/rad", "stiffness", (0.3, 3.0),
     "spring stiffness of the joint's series-elastic element (its end stop follows)"),
    ("damping", "N·m·s/rad", "damping", (0.05, 10.0),
     "viscous damping of the joint's series-elastic element"),
    ("bearing_friction", "N·m", "bearing_friction_as_built_nm", (0.05, 20.0),
     "Coulomb friction of the joint's bearings at the joint (replaces the per-arm draw)"),
    ("torque_constant", "N·m/A", "torque_constant_nm_per_a", (0.3, 2.0),
     "the stepper's torque constant at its shaft: holding torque = this × current × reduction"),
)


def _nominal(field_name: str, joint: int) -> float:
    if field_name == "bearing_friction_as_built_nm":  # the draw's median
        return float(_DEFAULT.bearing_friction_nm[joint])
    return float(getattr(_DEFAULT, field_name)[joint])


#: The arm's parameters (part ``"arm"``): per stepper joint J1..J4, each of the kinds above.
ARM_PARAMETERS: Final[tuple[Parameter, ...]] = tuple(
    Parameter(f"arm.{joint}.{suffix}", unit, nominal, nominal * lo, nominal * hi, doc,
              "arm", field_name, j)
    for suffix, unit, field_name, (lo, hi), doc in _ARM_KINDS
    for j, joint in enumerate(_STEPPER_JOINTS)
    for nominal in (_nominal(field_name, j),))

#: The parts of the robot a parameter may apply to, each with its table of parameters.
#: A part's table is declared beside the part; :data:`PARAMETERS` concatenates them.
PART_TABLES: Final[Mapping[str, tuple[Parameter, ...]]] = {
    "arm": ARM_PARAMETERS, "hand": hand_profile.HAND_PARAMETERS}
PARTS: Final = tuple(PART_TABLES)

#: Every fittable parameter, by name: the parts' tables, concatenated.
PARAMETERS: Final[Mapping[str, Parameter]] = {
    p.name: p for table in PART_TABLES.values() for p in table}


def _families() -> str:
    """The parameters' names in short (``arm.J1..J4.stiffness, …``), for messages."""
    seen: dict[str, None] = {}
    for name in PARAMETERS:
        part, kind = name.split(".", 1)[0], name.rsplit(".", 1)[1]
        seen.setdefault(f"{part}.*.{kind}", None)
    return ", ".join(seen)


def parameter(name: str) -> Parameter:
    """The parameter ``name``; :class:`EmulatorConfigError` naming the known ones."""
    try:
        return PARAMETERS[name]
    except KeyError:
        raise EmulatorConfigError(
            f"unknown parameter {name!r}; the parameters are {_families()} "
            "(docs/EMULATOR.md, robot profiles)") from None


@dataclass(frozen=True)
class RobotProfile:
    """The parameters of one robot (``values`` by :data:`PARAMETERS` name, in their units);
    ``fit``: how they were found (free-form, written by ``hil-bench fit``); ``source``: the
    file it was read from (empty: made in memory)."""

    values: Mapping[str, float] = field(default_factory=dict)
    fit: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        checked = {}
        for name, value in self.values.items():
            p = parameter(name)
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not math.isfinite(value)):
                raise EmulatorConfigError(f"{name}: {value!r} is not a finite number")
            if not p.low <= value <= p.high:
                raise EmulatorConfigError(f"{name}: {value} {p.unit} is outside its bounds "
                                          f"{p.low:g}..{p.high:g}")
            checked[name] = float(value)
        object.__setattr__(self, "values", checked)

    def part_values(self, part: str) -> dict[str, float]:
        """This profile's values of the parameters of ``part`` (:data:`PARTS`), by name."""
        return {n: v for n, v in self.values.items() if PARAMETERS[n].part == part}

    def arm_params(self, base: ArmParams | None = None) -> ArmParams:
        """``base`` (default: the nominal arm) with this profile's arm parameters."""
        base = base or ArmParams()
        arrays: dict[str, Any] = {}
        for name, value in self.part_values("arm").items():
            p = PARAMETERS[name]
            if p.field not in arrays:
                arrays[p.field] = np.array(getattr(base, p.field), dtype=float)
            arrays[p.field][p.index] = value
        return dataclasses.replace(base, **arrays) if arrays else base

    def finger_params(self, finger: int, base: FingerParams) -> FingerParams:
        """``base`` with this profile's parameters of finger module ``finger``."""
        return hand_profile.finger_params(self.part_values("hand"), finger, base)

    def accel(self, board: str, drawn: AccelTruth) -> AccelTruth:
        """Board ``board``'s accelerometer (``palm``, ``finger1.f2``) as built: ``drawn``
        with this profile's rotation and offset components."""
        return hand_profile.accel_truth(self.part_values("hand"), board, drawn)

    def as_json(self) -> dict[str, Any]:
        """The file's content."""
        out: dict[str, Any] = {"format": FORMAT, "version": VERSION,
                               "parameters": dict(self.values)}
        if self.fit:
            out["fit"] = dict(self.fit)
        return out

    def write(self, path: str | Path) -> None:
        """Write the profile to ``path`` (JSON); :class:`OSError` if it cannot be written."""
        Path(path).write_text(json.dumps(self.as_json(), indent=1) + "\n", encoding="utf-8")


def load_profile(path: str | Path) -> RobotProfile:
    """The profile in file ``path``; :class:`EmulatorConfigError` with a one-line reason
    for a file that cannot be read or is no valid profile."""
    where = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise EmulatorConfigError(f"profile {where}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise EmulatorConfigError(f"profile {where}: not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise EmulatorConfigError(f"profile {where}: not a JSON object")
    unknown = sorted(set(data) - set(FILE_KEYS))
    if unknown:
        raise EmulatorConfigError(f"profile {where}: unknown keys {unknown}; a profile has "
                                  f"{', '.join(FILE_KEYS)}")
    if data.get("format") != FORMAT:
        raise EmulatorConfigError(f"profile {where}: format must be {FORMAT!r}")
    if data.get("version") != VERSION:
        raise EmulatorConfigError(f"profile {where}: version {data.get('version')!r}; this "
                                  f"emulator reads version {VERSION}")
    values = data.get("parameters", {})
    fit = data.get("fit", {})
    if not isinstance(values, dict) or not isinstance(fit, dict):
        raise EmulatorConfigError(f"profile {where}: parameters and fit must be objects")
    try:
        return RobotProfile(values, fit, where)
    except EmulatorConfigError as exc:
        raise EmulatorConfigError(f"profile {where}: {exc}") from None


def as_profile(profile: RobotProfile | str | Path | None) -> RobotProfile | None:
    """``profile`` itself, or the one in that file (:func:`load_profile`), or None."""
    if profile is None or isinstance(profile, RobotProfile):
        return profile
    return load_profile(profile)
