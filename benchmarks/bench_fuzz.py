"""hil-fuzz against the emulator in process (fast mode: no MuJoCo plant, simulation clock).

* **Examples per second**: a standard fmcb campaign (a fresh loose-finger emulator brought
  up per example, 12 steps, every oracle after each step) on the project's firmware.
* **Planted defect**: the test-only fmcb whose ``fmcb.param_set`` with index 0xFFFF hangs
  (tests/tools/fuzz_planted.py, registered here as the tests do); the median over seeds of
  the examples and seconds until the first failing example (before shrinking), with the
  campaign focused on ``fmcb.param_*`` as the test runs it, reported as finds per second
  (1 / median).  The campaign stops at the first failing example (no shrinking: the test
  covers the shrinking).
"""

from __future__ import annotations

import statistics

from benchmarks.harness import Result
from firmware_py.sim import boards
from tools.fuzz.campaign import run_campaign

GROUP = "fuzz"


def run(quick: bool = False) -> list[Result]:
    examples = 10 if quick else 60
    clean = run_campaign("fmcb", examples=examples, seed=11, steps=12)
    rate = clean.examples / clean.seconds
    results = [Result(GROUP, "fmcb campaign (emulator, fast)", rate, "ex",
                      note=f"{clean.steps_sent / clean.seconds:.0f} steps/s, "
                           f"{'FOUND ' + clean.reproducer.failure if clean.reproducer else 'clean'}")]
    seeds = range(1 if quick else 3)
    saved = boards.APP_PROGRAMS["fmcb"]
    from tests.tools.fuzz_planted import PROGRAM

    boards.APP_PROGRAMS["fmcb"] = PROGRAM
    try:
        times, counts, missed = [], [], 0
        for seed in seeds:
            r = run_campaign("fmcb", examples=400, seed=seed, steps=10,
                             messages=["fmcb.param_*"], shrink=False)
            if r.first_failure_s is None:
                missed += 1
                continue
            times.append(r.first_failure_s)
            counts.append(r.examples_to_failure or 0)
    finally:
        boards.APP_PROGRAMS["fmcb"] = saved
    if times:
        median_s = statistics.median(times)
        results.append(Result(
            GROUP, "planted hang found", 1.0 / median_s, "finds",
            note=f"median {median_s:.1f} s, {statistics.median(counts):.0f} examples over "
                 f"{len(times)} seeds ({missed} missed in 400)"))
    return results


if __name__ == "__main__":
    for result in run(quick=True):
        print(result)
