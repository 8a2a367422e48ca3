"""A tiny benchmark harness: rates measured in the same run, reported as ratios.

Every benchmark module exposes ``run(quick: bool) -> list[Result]``; ``python -m benchmarks``
runs them all and prints a table.  Speed is never asserted by a test: the ratios printed
here are what a reviewer reads.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Result:
    """One measured rate (or, with ``at_most``, a figure that should stay small).

    ``rate`` is in ``unit`` per second; ``baseline`` names another result of the same group
    that this one is compared with; ``target`` is a goal in ``unit``/s (None if none), met
    when ``rate`` ≥ ``target``.  With ``at_most``, ``rate`` is a figure in ``unit`` (a
    lateness in ms, a memory growth in MB, cores) and the target is met when it is ≤
    ``target``.
    """

    group: str
    name: str
    rate: float
    unit: str
    baseline: str | None = None
    target: float | None = None
    note: str = ""
    at_most: bool = False

    @property
    def met(self) -> bool | None:
        """Whether the target is met (None: no target; a NaN figure misses it)."""
        if self.target is None:
            return None
        return self.rate <= self.target if self.at_most else self.rate >= self.target


def best_rate(func: Callable[[], int], repeat: int = 5, min_time: float = 0.2) -> float:
    """Best-of-``repeat`` rate of ``func``, which does some work and returns how many units.

    Each repeat calls ``func`` until at least ``min_time`` seconds (wall clock,
    ``time.perf_counter``) have passed.  Returns units per second.
    """
    best = 0.0
    for _ in range(repeat):
        units = 0
        start = time.perf_counter()
        elapsed = 0.0
        while elapsed < min_time:
            units += func()
            elapsed = time.perf_counter() - start
        best = max(best, units / elapsed)
    return best


@dataclass(frozen=True)
class Table:
    """A table a benchmark prints after the rates (``title`` and its text ``lines``), for
    figures that are not rates (estimation errors, success rates)."""

    title: str
    lines: tuple[str, ...]
