"""One fittable physical parameter of a robot profile (:mod:`hil_emulator.profile`).

Its own module so that each part of the robot declares its table of parameters beside what
it knows of them (the arm's in :mod:`hil_emulator.profile`, the hand's in
:mod:`hil_emulator.hand_profile`) and :data:`hil_emulator.profile.PARAMETERS` concatenates
them without an import going round in a circle.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Parameter:
    """One fittable physical parameter: its ``name`` (``arm.J2.stiffness``), ``unit``,
    ``nominal`` value (the emulator's default), the ``low``–``high`` bounds a profile and a
    fit keep it within, and what it is (``doc``).  ``part`` says which part of the robot it
    applies to (:data:`hil_emulator.profile.PARTS`: ``"arm"``, the arm plant's
    :class:`~hil_emulator.arm.actuators.ArmParams`; ``"hand"``,
    :mod:`hil_emulator.hand_profile`); ``field`` and ``index`` where in that part's
    parameters it goes (for the arm: an ``ArmParams`` array of J1..J4 and its element; for
    the hand: its kind and axis), ``element`` which of the part's pieces it is of (the
    hand's finger module or board: ``finger1``, ``finger1.f2``, ``palm``; empty for the
    arm's).  ``scale`` is the fit's unit of it (its unit; 0: the nominal value): a fit moves
    it in shares of it from the nominal, so a parameter whose nominal is 0 (a sensor's
    offset) can be fitted too."""

    name: str
    unit: str
    nominal: float
    low: float
    high: float
    doc: str
    part: str
    field: str
    index: int
    element: str = ""
    scale: float = 0.0

    @property
    def joint(self) -> int:
        """The arm joint (0..3 = J1..J4) of an ``arm`` parameter: its :attr:`index`."""
        return self.index

    @property
    def step(self) -> float:
        """The fit's unit of this parameter (its unit): :attr:`scale`, else the nominal."""
        return self.scale or self.nominal
