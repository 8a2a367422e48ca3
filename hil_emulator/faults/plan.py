"""Fault plans: which faults, when, on simulation time; read from TOML or built in code.

A plan is a list of :class:`PlanEntry` (a fault and its :class:`Schedule`).  In a file::

    [[faults]]
    fault = "break_away"          # a name from `hil-bench list-faults`
    params = { finger = 2 }       # the fault's parameters
    at_s = 0.5                    # first start, s after the plan is loaded
    duration_s = 1.0              # cleared after this long (absent: stays until cleared)
    every_s = 2.0                 # repeated with this period …
    count = 3                     # … this many times (default 1)
    jitter_s = 0.1                # each start later by a uniform draw in [0, jitter_s]
    after_flash_bytes = 8192      # trigger instead of at_s: once node `flash_node` has
    flash_node = "finger1.fmcb"   #   started writing this many bytes of flash
    label = "pop finger 2"        # the name in the timeline and the reports

Every key is checked; a mistake raises :class:`~hil_emulator.errors.FaultPlanError` naming
it (``faults[1].duration_s``).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from hil_emulator.errors import FaultPlanError
from hil_emulator.faults.base import Fault, make_fault

#: The keys of one plan entry.
ENTRY_KEYS: Final = ("fault", "params", "at_s", "duration_s", "every_s", "count", "jitter_s",
                     "after_flash_bytes", "flash_node", "label")


@dataclass(frozen=True)
class Schedule:
    """When a fault acts, on simulation time (s, from the moment the plan is loaded).

    ``at_s`` first start; ``duration_s`` until it is cleared (None: until cleared by hand;
    ignored by instantaneous faults); ``every_s`` and ``count`` repetition; ``jitter_s`` a
    uniform delay of each start drawn from the run's seed; ``after_flash_bytes`` with
    ``flash_node``: a trigger instead of a time (once that node has started writing that
    many bytes of flash, the fault starts then, in the middle of the write)."""

    at_s: float = 0.0
    duration_s: float | None = None
    every_s: float | None = None
    count: int = 1
    jitter_s: float = 0.0
    after_flash_bytes: int | None = None
    flash_node: str | None = None

    def check(self, where: str) -> None:
        """Raise :class:`FaultPlanError` (naming the key under ``where``) if inconsistent."""
        if self.at_s < 0:
            raise FaultPlanError(f"{where}.at_s: {self.at_s} is before the plan starts")
        if self.duration_s is not None and self.duration_s <= 0:
            raise FaultPlanError(f"{where}.duration_s: {self.duration_s} must be positive")
        if self.count < 1:
            raise FaultPlanError(f"{where}.count: {self.count} must be at least 1")
        if self.count > 1 and (self.every_s is None or self.every_s <= 0):
            raise FaultPlanError(f"{where}.every_s: a repeated fault needs a positive period")
        if (self.every_s is not None and self.duration_s is not None
                and self.duration_s + self.jitter_s >= self.every_s):
            raise FaultPlanError(f"{where}.duration_s: {self.duration_s} s (+ jitter) does "
                                 f"not end before the next repetition ({self.every_s} s)")
        if self.jitter_s < 0:
            raise FaultPlanError(f"{where}.jitter_s: {self.jitter_s} must be >= 0")
        if (self.after_flash_bytes is None) != (self.flash_node is None):
            raise FaultPlanError(f"{where}.after_flash_bytes: give it with flash_node "
                                 "(the node whose flash writes are counted)")
        if self.after_flash_bytes is not None and self.after_flash_bytes < 0:
            raise FaultPlanError(f"{where}.after_flash_bytes: must be >= 0")


@dataclass
class PlanEntry:
    """One fault of a plan, when it acts, and its name in the timeline."""

    fault: Fault
    schedule: Schedule
    label: str

    def to_dict(self) -> dict[str, Any]:
        """The entry as a plan file holds it."""
        out: dict[str, Any] = {"fault": self.fault.name, "params": self.fault.params(),
                               "label": self.label}
        for key, value in vars(self.schedule).items():
            if value is not None and value != getattr(Schedule, key, None):
                out[key] = value
        return out


def _number(where: str, value: Any, kind: type) -> Any:
    if isinstance(value, bool) or not isinstance(value, int | float) or (
            kind is int and not isinstance(value, int)):
        raise FaultPlanError(f"{where}: {value!r} is not {'an integer' if kind is int else 'a number'}")
    return kind(value)


def parse_entry(raw: Any, where: str) -> PlanEntry:
    """One plan entry from its table ``raw`` (errors name keys under ``where``)."""
    if not isinstance(raw, dict):
        raise FaultPlanError(f"{where}: a fault entry is a table, got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(ENTRY_KEYS))
    if unknown:
        raise FaultPlanError(f"{where}.{unknown[0]}: unknown key; an entry has "
                             f"{', '.join(ENTRY_KEYS)}")
    if "fault" not in raw:
        raise FaultPlanError(f"{where}.fault: missing (the fault's name)")
    if not isinstance(raw["fault"], str):
        raise FaultPlanError(f"{where}.fault: {raw['fault']!r} is not a name")
    params = raw.get("params", {})
    if not isinstance(params, dict):
        raise FaultPlanError(f"{where}.params: a table of parameters, got {params!r}")
    fault = make_fault(raw["fault"], params, where)
    numbers: dict[str, Any] = {}
    for key, kind in (("at_s", float), ("duration_s", float), ("every_s", float),
                      ("jitter_s", float), ("count", int), ("after_flash_bytes", int)):
        if key in raw:
            numbers[key] = _number(f"{where}.{key}", raw[key], kind)
    flash_node = raw.get("flash_node")
    if flash_node is not None and not isinstance(flash_node, str):
        raise FaultPlanError(f"{where}.flash_node: {flash_node!r} is not a node name")
    schedule = Schedule(flash_node=flash_node, **numbers)
    schedule.check(where)
    label = raw.get("label", fault.name)
    if not isinstance(label, str):
        raise FaultPlanError(f"{where}.label: {label!r} is not text")
    return PlanEntry(fault, schedule, label)


def parse_plan(raw: Any, where: str = "faults") -> list[PlanEntry]:
    """A plan from the list of tables under ``faults`` (errors name ``faults[i].key``)."""
    if not isinstance(raw, list):
        raise FaultPlanError(f"{where}: a list of fault tables ([[{where}]]), got {raw!r}")
    return [parse_entry(item, f"{where}[{i}]") for i, item in enumerate(raw)]


def load_plan(path: str | Path) -> list[PlanEntry]:
    """The plan in TOML file ``path`` (its ``[[faults]]`` tables)."""
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except OSError as exc:
        raise FaultPlanError(f"{path}: cannot read the fault plan: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FaultPlanError(f"{path}: not valid TOML: {exc}") from exc
    unknown = sorted(set(raw) - {"faults"})
    if unknown:
        raise FaultPlanError(f"{path}: unknown key {unknown[0]!r}; a plan file has [[faults]]")
    try:
        return parse_plan(raw.get("faults", []))
    except FaultPlanError as exc:
        raise FaultPlanError(f"{path}: {exc}") from exc
