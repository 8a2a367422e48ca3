"""``hil-bench replay``'s speed: simulated seconds replayed per CPU second, against bare
``mj_step`` of the same model measured in the same run.

A recording of the arm cycling at 100 Hz (``armctl record``'s loop) and one of the hand's
state read at 50 Hz are made on the in-process emulator; each is then replayed against a
fresh emulator of its configuration (:func:`tools.hil_bench.replay.session.replay_channels`:
driving, pairing, comparing).  The figures are CPU time of this process
(``time.process_time``), not wall time, and leave out building and bringing up the emulator.
The baseline is ``mj_step`` alone on that emulator's model from its present state
(:func:`benchmarks.bench_emulator.bare_mj_step_cpu`), so the ratio says how many times
slower than the bare physics a replay runs.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks.bench_emulator import bare_mj_step_cpu
from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.arm.recording import record
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from tools.hil_bench.replay.session import build_emulator, recorded_exchanges, replay_channels
from tools.hil_bench.replay.source import load

GROUP = "replay"


def _record_arm(path: Path, seconds: float) -> None:
    try:
        with Arm.open("emu://arm/arm?name=bench-replay") as arm:
            record(arm, path, seconds=seconds)
    finally:
        forget_shared_emulators()


def _record_hand(path: Path, seconds: float) -> None:
    try:
        with Hand.open("emu://hand/palm?name=bench-replay") as hand, \
                HandRecorder(hand, path) as recorder:
            recorder.record(seconds, 50.0)
    finally:
        forget_shared_emulators()


def replay_rate(path: Path) -> tuple[float, float, bool]:
    """(simulated s per CPU s of the replay, bare mj_step's simulated s per CPU s, whether
    the replay agreed) for the recording at ``path``."""
    recording = load(path)
    recorded = recorded_exchanges(recording)
    emulator = build_emulator(recording)
    try:
        cpu = time.process_time()
        channels, sim_s = replay_channels(recording, emulator, None, recorded)
        cpu = time.process_time() - cpu
        bare = bare_mj_step_cpu(emulator, min(sim_s, 1.0))
    finally:
        emulator.close()
    return sim_s / cpu, 1.0 / bare, all(c.within for c in channels.values())


def run(quick: bool) -> list[Result]:
    results: list[Result] = []
    with tempfile.TemporaryDirectory() as tmp:
        for what, make, seconds in (("arm", _record_arm, 1.0 if quick else 4.0),
                                    ("hand", _record_hand, 0.5 if quick else 2.0)):
            path = Path(tmp) / f"{what}.mcap"
            make(path, seconds)
            rate, bare, agreed = replay_rate(path)
            base = f"bare mj_step ({what} model)"
            results += [
                Result(GROUP, base, bare, "sim-s", note="CPU time of mj_step alone"),
                Result(GROUP, f"replay of {what} recording", rate, "sim-s", baseline=base,
                       note=f"{seconds:g} s recorded; CPU time; "
                            f"{'agrees' if agreed else 'DISAGREES'} with its recording"),
            ]
    return results
