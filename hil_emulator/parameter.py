"""One fittable physical parameter of a robot profile (:mod:`hil_emulator.profile`).

Its own module so that each part of the robot declares its parameters beside what it knows
of them (the arm's in :mod:`hil_emulator.profile`, the hand's in
:mod:`hil_emulator.hand_profile`) and :data:`hil_emulator.profile.PARAMETERS` concatenates
them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Parameter:
    """One fittable physical parameter: its ``name`` (``arm.J2.stiffness``), ``unit``,
    ``nominal`` value (the emulator's default), the ``low``–``high`` bounds a profile and a
    fit keep it within, and what it is (``doc``).  ``field`` and ``joint`` say where it goes
    (for the arm: a field of :class:`~hil_emulator.arm.actuators.ArmParams`, an array of
    J1..J4; for the hand: its kind and axis, :mod:`hil_emulator.hand_profile`); ``part``
    is the hand's board or finger it belongs to (empty for the arm's).  ``scale`` is the fit's
    unit of it (its unit; 0: the nominal value): a fit moves it in shares of ``scale`` from
    the nominal, so a parameter whose nominal is 0 (a sensor's offset) can be fitted too."""

    name: str
    unit: str
    nominal: float
    low: float
    high: float
    doc: str
    field: str
    joint: int
    part: str = ""
    scale: float = 0.0

    @property
    def step(self) -> float:
        """The fit's unit of this parameter (its unit): :attr:`scale`, else the nominal."""
        return self.scale or self.nominal
