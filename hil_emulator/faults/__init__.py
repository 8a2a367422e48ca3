"""The emulator's fault registry, in one place (after dm_control's ``composer/variation``).

Each fault is one class (:class:`~hil_emulator.faults.base.Fault`) with typed parameters, a
seeded ``apply(emulator, rng)`` and ``clear(emulator)``, naming the entry point it acts
through; declaring it registers it in :data:`FAULTS`.  Plans schedule faults on simulation
time (:mod:`~hil_emulator.faults.plan`), an injector that whoever runs the plan makes
(``FaultInjector(emulator)``) applies them and records a replayable timeline
(:mod:`~hil_emulator.faults.injector`), and the control channel lets another process inject
into a running emulator (:mod:`~hil_emulator.faults.control`).  The emulator imports nothing
from here: faults act on it from above.

Modules by entry point: :mod:`.line` (bus line models), :mod:`.contact` (pogo pins, tendon
supply, node power), :mod:`.host_link` (the host's serial ports), :mod:`.nodes` (hang, reset,
sensors), :mod:`.arm` (plant forces, index, servo alarms, supply), :mod:`.flashing`.
"""

from __future__ import annotations

from hil_emulator.faults import arm, contact, flashing, host_link, line, nodes  # noqa: F401  (registration)
from hil_emulator.faults.base import ENTRY_POINTS, FAULTS, NOT_YET_IMPLEMENTED, Fault, make_fault
from hil_emulator.faults.injector import FaultInjector, TimelineEvent
from hil_emulator.faults.plan import PlanEntry, Schedule, load_plan, parse_plan

__all__ = ["ENTRY_POINTS", "FAULTS", "NOT_YET_IMPLEMENTED", "Fault", "FaultInjector",
           "PlanEntry", "Schedule", "TimelineEvent", "catalogue", "load_plan", "make_fault",
           "parse_plan"]


def catalogue() -> list[dict[str, object]]:
    """Every fault of the catalogue: name, entry point, summary, parameters (name, type,
    default), and ``implemented`` (False for :data:`NOT_YET_IMPLEMENTED`)."""
    out: list[dict[str, object]] = []
    for name in sorted(FAULTS):
        cls = FAULTS[name]
        out.append({"name": name, "entry_point": cls.entry_point, "summary": cls.summary,
                    "instantaneous": cls.instantaneous, "implemented": True,
                    "parameters": [{"name": p, "type": t, "default": d}
                                   for p, t, d in cls.parameters()]})
    for name, what in sorted(NOT_YET_IMPLEMENTED.items()):
        out.append({"name": name, "entry_point": None, "summary": what, "implemented": False,
                    "instantaneous": False, "parameters": []})
    return out
