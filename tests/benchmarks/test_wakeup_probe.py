"""The machine's wake-up probe, the baseline of the emulator's real-time lateness."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from benchmarks.wakeup_probe import SLEEP_S, probe
from tools.build_compiled import ROOT


def test_the_probe_counts_its_wake_ups_and_how_late_they_came() -> None:
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    got = probe(0.05)
    assert (os.sched_getscheduler(0), os.sched_getparam(0)) == before  # given back
    assert 0 < int(got["count"]) <= 0.05 / SLEEP_S + 1  # never more wake-ups than sleeps fit
    assert 0.0 <= float(got["p99_ms"]) <= float(got["max_ms"])


def test_the_command_prints_one_json_object() -> None:
    proc = subprocess.run([sys.executable, "-m", "benchmarks.wakeup_probe", "--seconds", "0.05"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120, check=True)
    out = json.loads(proc.stdout)
    assert set(out) == {"count", "p99_ms", "max_ms", "scheduling"}
