"""The fault injector of one emulator: plans on simulation time, a recorded timeline, and
its replay.  Whoever runs a plan makes one (``FaultInjector(emulator)``): the
``hil-emulator`` command, the HIL bench, a test; the emulator itself knows no faults.

Randomness: occurrence ``k`` of plan entry ``i`` applies its fault with the generator
``default_rng(SeedSequence(seed, spawn_key=(i, k)))`` and jitter is drawn from
``(i, JITTER_KEY)``, where ``seed`` is the emulator's.  So the same seed and the same plan
give the same timeline and the same run, whatever else draws random numbers, and a recorded
timeline replays the same faults with the same draws (:meth:`FaultInjector.replay`).
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Final, Literal

import numpy as np

import hil_emulator.faults.targets as targets
from hil_emulator.errors import FaultPlanError
from hil_emulator.faults.base import Fault, make_fault
from hil_emulator.faults.plan import PlanEntry, Schedule

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

#: Spawn-key slot of a plan entry's jitter draws.
JITTER_KEY: Final = 0x7FFF_FFFF


@dataclass(frozen=True)
class TimelineEvent:
    """A fault applied or cleared at ``t_us`` (simulation µs): plan entry ``entry``, its
    ``occurrence``-th repetition."""

    t_us: int
    action: Literal["apply", "clear"]
    entry: int
    occurrence: int
    fault: str
    label: str
    params: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> TimelineEvent:
        """The event from :meth:`to_dict`'s form."""
        return cls(int(raw["t_us"]), raw["action"], int(raw["entry"]), int(raw["occurrence"]),
                   str(raw["fault"]), str(raw["label"]), dict(raw["params"]))


class FaultInjector:
    """Applies faults to ``emulator`` on its clock and records every apply and clear."""

    def __init__(self, emulator: Emulator) -> None:
        self.emulator = emulator
        self.seed = emulator.seed
        self.entries: list[PlanEntry] = []
        self.timeline: list[TimelineEvent] = []
        self._active: dict[int, int] = {}  # entry → occurrence applied and not cleared
        #: Called with each event as it happens (the control channel, reports).
        self.observers: list[Callable[[TimelineEvent], None]] = []

    # ------------------------------------------------------------------ planning
    def load(self, plan: Iterable[PlanEntry]) -> list[int]:
        """Schedule every entry of ``plan`` from now; returns their entry ids."""
        return [self._add(entry) for entry in plan]

    def inject(self, fault: Fault | str, params: dict[str, Any] | None = None, *,
               at_s: float = 0.0, duration_s: float | None = None,
               schedule: Schedule | None = None, label: str | None = None) -> int:
        """Schedule ``fault`` (an instance, or a name with ``params``) ``at_s`` from now
        (0: at once), cleared after ``duration_s`` if given; returns its entry id for
        :meth:`clear`."""
        if isinstance(fault, str):
            fault = make_fault(fault, params)
        schedule = schedule or Schedule(at_s=at_s, duration_s=duration_s)
        schedule.check("inject")
        return self._add(PlanEntry(fault, schedule, label or fault.name))

    def clear(self, entry: int) -> None:
        """Clear entry ``entry`` now if it is applied (idempotent)."""
        if not 0 <= entry < len(self.entries):
            raise FaultPlanError(f"no fault entry {entry}")
        if entry in self._active:
            self._clear(entry, self._active[entry])

    def clear_all(self) -> None:
        """Clear every applied fault now."""
        for entry in sorted(self._active):
            self.clear(entry)

    @property
    def active(self) -> list[int]:
        """Entry ids applied and not yet cleared."""
        return sorted(self._active)

    # ------------------------------------------------------------------ replay
    def replay(self, events: Sequence[TimelineEvent | dict[str, Any]]) -> None:
        """Schedule a recorded timeline on this (fresh) emulator: every apply and clear at
        its recorded simulation time, with the recorded parameters and the same draws."""
        for raw in events:
            event = raw if isinstance(raw, TimelineEvent) else TimelineEvent.from_dict(raw)
            while len(self.entries) <= event.entry:
                self.entries.append(None)  # type: ignore[arg-type]  # filled below
            if self.entries[event.entry] is None:
                fault = make_fault(event.fault, event.params, f"timeline entry {event.entry}")
                self.entries[event.entry] = PlanEntry(fault, Schedule(), event.label)
            action = self._apply if event.action == "apply" else self._clear
            self._at(event.t_us, functools.partial(action, event.entry, event.occurrence))

    # ------------------------------------------------------------------ record
    def timeline_dicts(self) -> list[dict[str, Any]]:
        """The timeline as plain data (JSON)."""
        return [e.to_dict() for e in self.timeline]

    def timeline_digest(self) -> str:
        """SHA-256 of the timeline's canonical JSON: equal for equal timelines."""
        text = json.dumps(self.timeline_dicts(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    # ------------------------------------------------------------------ internals
    def _rng(self, entry: int, occurrence: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence(self.seed,
                                                            spawn_key=(entry, occurrence)))

    def _at(self, t_us: int, action: Callable[[], None]) -> None:
        scheduler = self.emulator.scheduler
        if t_us <= scheduler.now_us():
            action()
        else:
            scheduler.call_at(t_us, action)

    def _add(self, entry: PlanEntry) -> int:
        index = len(self.entries)
        self.entries.append(entry)
        s = entry.schedule
        if s.after_flash_bytes is not None:
            assert s.flash_node is not None
            self._arm_flash_trigger(index, s.flash_node, s.after_flash_bytes)
            return index
        now = self.emulator.scheduler.now_us()
        jitter = self._rng(index, JITTER_KEY)
        for k in range(s.count):
            start_s = s.at_s + k * (s.every_s or 0.0)
            if s.jitter_s:
                start_s += float(jitter.uniform(0.0, s.jitter_s))
            self._at(now + round(start_s * 1e6), functools.partial(self._occur, index, k))
        return index

    def _occur(self, index: int, occurrence: int) -> None:
        """Occurrence ``occurrence`` of entry ``index`` starts now (and is cleared later)."""
        entry = self.entries[index]
        self._apply(index, occurrence)
        duration = entry.schedule.duration_s
        if duration is not None and not entry.fault.instantaneous:
            self.emulator.scheduler.call_later(round(duration * 1e6),
                                               lambda: self._clear(index, occurrence))

    def _apply(self, index: int, occurrence: int) -> None:
        entry = self.entries[index]
        if index in self._active:  # a repetition while still applied: clear it first
            self._clear(index, self._active[index])
        entry.fault.apply(self.emulator, self._rng(index, occurrence))
        if not entry.fault.instantaneous:
            self._active[index] = occurrence
        self._record("apply", index, occurrence)

    def _clear(self, index: int, occurrence: int) -> None:
        if self._active.get(index) != occurrence:
            return
        del self._active[index]
        self.entries[index].fault.clear(self.emulator)
        self._record("clear", index, occurrence)

    def _record(self, action: Literal["apply", "clear"], index: int, occurrence: int) -> None:
        entry = self.entries[index]
        event = TimelineEvent(self.emulator.scheduler.now_us(), action, index, occurrence,
                              entry.fault.name, entry.label, entry.fault.params())
        self.timeline.append(event)
        for observer in list(self.observers):
            observer(event)

    def _arm_flash_trigger(self, index: int, node_name: str, threshold: int) -> None:
        """Apply entry ``index`` once ``node_name`` has started writing ``threshold`` bytes
        of flash: one page write after the count reaches it, in the middle of that write."""
        flash = targets.node(self.emulator, node_name).hal.flash
        original = type(flash).write_page
        written = 0

        def write_page(page: int, data: bytes, done: Callable[[bool], None]) -> None:
            nonlocal written
            original(flash, page, data, done)
            written += len(data)
            if written >= threshold and "write_page" in vars(flash):
                del flash.write_page  # the trigger fires once
                self.emulator.scheduler.call_later(max(1, flash.page_write_us // 2),
                                                   lambda: self._occur(index, 0))

        flash.write_page = write_page  # type: ignore[method-assign]
