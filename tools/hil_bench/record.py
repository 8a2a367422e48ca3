"""What one bench run observed: the record a scenario's assertions are judged on.

:class:`~tools.hil_bench.runner.Bench` fills it while a scenario runs;
:mod:`tools.hil_bench.assertions` reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class RunRecord:
    """What a run observed (times in s from the plan's start)."""

    t0_us: int = 0
    timeline: list[dict[str, Any]] = field(default_factory=list)
    actions: dict[str, dict[str, Any]] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    hand_samples: list[dict[str, Any]] = field(default_factory=list)
    arm_samples: list[dict[str, Any]] = field(default_factory=list)
    truth: list[dict[str, Any]] = field(default_factory=list)
    links: dict[str, dict[str, bytes]] = field(default_factory=dict)
    nodes: dict[str, dict[str, Any]] = field(default_factory=dict)

    def fault_times(self, label: str, action: str = "apply") -> list[float]:
        """When faults labelled ``label`` were applied (or cleared), s."""
        return [e["t_s"] for e in self.timeline if e["label"] == label
                and e["action"] == action]
