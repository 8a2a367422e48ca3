"""``make bench`` keeps running: every benchmark module in quick mode, its figures printed.

Speed is never asserted here (the bench prints it, as ratios and against targets); these
tests check that each module runs to the end, that its results are figures the report can
print, and that the figures users were promised are among them.
"""

from __future__ import annotations

import importlib
import math
import os
import pkgutil
from pathlib import Path

import pytest

import benchmarks
from benchmarks.__main__ import report
from benchmarks.harness import Result, Table

pytestmark = pytest.mark.process_wide("bench_view: rerun serves its web viewer until the process ends")

#: Modules that take more than 30 s in quick mode on a 2-core machine.
SLOW = frozenset({"bench_arm_cycle", "bench_arm_tracking", "bench_backpressure", "bench_emulator",
                  "bench_estimation", "bench_flashing", "bench_hand_cycle", "bench_handbus",
                  "bench_fuzz"})
MODULES = sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__)
                 if m.name.startswith("bench_"))
#: Names (substrings) of the results or table lines each module must print.
PROMISED = {
    "bench_emulator": ["full, with MuJoCo plant", "full, hand up: lateness p99",
                       "full, hand up, 1 CPU hog: lateness p99", "CPU per wall s",
                       "full, default build: CPU per sim s", "full, pure Python: CPU per sim s",
                       "× mj_step", "3 CPU hogs, real-time scheduling",
                       "a bare real-time sleeper's longest stall"],
    "bench_backpressure": ["ping answered after the flood", "emulator memory growth"],
    "bench_arm_tracking": ["100 Hz: flange error RMS", "wire bound: flange error RMS",
                           "wire bound: cycle rate"],
    "bench_estimation": ["static, closed form", "moving, EKF fused with halls", "homing: "],
    "bench_view": ["arm cycles, view off", "arm cycles, view on (10 Hz)"],
    "bench_replay": ["bare mj_step (arm model)", "replay of arm recording",
                     "replay of hand recording", "agrees with its recording",
                     "one replay of the arm excitation", "fit of 1 stiffness(es) from it"],
}


def _children() -> set[int]:
    """Process ids of this process's children (``/proc``)."""
    found: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        text = (task / "children").read_text().split()
        found.update(int(pid) for pid in text)
    return found


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n
                                  for n in MODULES])
def test_each_bench_runs_in_quick_mode_and_prints_its_figures(name: str) -> None:
    before = _children()
    items = importlib.import_module(f"benchmarks.{name}").run(quick=True)
    assert items, f"{name} measured nothing"
    assert _children() <= before, "a benchmark left a process running"
    results = [i for i in items if isinstance(i, Result)]
    tables = [i for i in items if isinstance(i, Table)]
    assert len(results) + len(tables) == len(items)
    lines = report(results)
    assert len(lines) == len(results) + 1
    for r in results:
        assert isinstance(r.rate, float | int), r
        if r.at_most:  # a figure that should stay small is never negative
            assert not r.rate < 0, r
        else:
            assert math.isfinite(r.rate) and r.rate > 0, r
    text = "\n".join(lines + [line for t in tables for line in t.lines])
    for promised in PROMISED.get(name, []):
        assert promised in text, f"{name} no longer prints {promised!r}"


def test_a_figure_that_should_stay_small_is_reported_against_an_upper_bound() -> None:
    met, missed, lost = (Result("g", n, v, "ms", target=1.0, at_most=True)
                         for n, v in (("met", 0.4), ("missed", 1.5), ("lost", math.nan)))
    rate = Result("g", "rate", 5.0, "sim-s", target=4.0)
    lines = report([met, missed, lost, rate])
    assert "met (≤ 1.000)" in lines[1]
    assert "MISSED (≤ 1.000)" in lines[2]
    assert "MISSED" in lines[3]  # nothing measured is not a met target
    assert "sim-s/s" in lines[4] and "met (≥ 4.000)" in lines[4]
