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

The fit (``hil-bench fit``): an excitation of J2 (and J4 unless ``quick``) recorded on an
arm whose elements are 30 % stiffer and 20 % softer than nominal (a robot profile), then
those stiffnesses fitted from nominal in this process (one worker, so the CPU time is all
this process's).  Its figure is simulated seconds fitted per CPU second, against one replay
of the same recording: the ratio is the number of replays' worth of CPU a fit costs; beside
it the fit's CPU seconds and replays.  Unless ``quick``, also the staged fit of the elbow's
stiffness and holding torque (least squares, then the slip-onset search) from the fit
trial's shorter excitation (:mod:`tools.hil_bench.fit.trial`).  The hand's fit, the same way:
one firm closure of finger 1 recorded on a hand whose f3 accelerometer is turned 2.5° about
its x axis, that angle fitted from 0 (and, unless ``quick``, the other two angles of the same
board, the seed's draw in the robot recorded).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks.bench_emulator import bare_mj_step_cpu
from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.profile import PARAMETERS, RobotProfile
from host.arm.excite import Excitation, excite
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder, record
from host.hand.excite import FingerExcitation, excite_fingers
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from tools.hil_bench.fit.solve import fit
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


def _record_excitation(path: Path, profile: Path, quick: bool) -> list[str]:
    """Record an excitation of an arm whose J2 element is 30 % stiffer (J4's 20 % softer)
    than nominal, its profile written to ``profile``; the parameters to fit."""
    joints, names = ((1,), ["arm.J2.stiffness"]) if quick else (
        (1, 3), ["arm.J2.stiffness", "arm.J4.stiffness"])
    RobotProfile({n: PARAMETERS[n].nominal * f for n, f in zip(
        names, (1.3, 0.8), strict=False)}).write(profile)
    try:
        with Arm.open(f"emu://arm/arm?name=bench-fit&profile={profile}") as arm:
            arm.torque(True)
            with ArmRecorder(arm, path):
                excite(arm, Excitation(joints=joints, chirp_s=0.5 if quick else 1.5,
                                       hold_s=0.2, holds=((0.3, 0.4),)))
    finally:
        forget_shared_emulators()
    return names


def _record_closure(path: Path, profile: Path, quick: bool) -> list[str]:
    """Record one closure of finger 1 on a hand whose f3 accelerometer is turned 2.5° about
    its x axis (the profile written to ``profile``); the parameters to fit."""
    board = "hand.finger1.f3.accel_rotation_"
    RobotProfile({board + "x": 2.5}).write(profile)
    try:
        with Hand.open(f"emu://hand/palm?name=bench-fit-hand&profile={profile}") as hand, \
                HandRecorder(hand, path):
            excite_fingers(hand, FingerExcitation(fingers=(1,), efforts=(255,), unhomed=True,
                                                  closures=((0.0, 0.9, 0.7),),
                                                  timeout_s=1.5))
    finally:
        forget_shared_emulators()
    return [board + "x"] if quick else [board + axis for axis in "xyz"]


def fit_rate(path: Path, names: list[str]) -> tuple[float, float, float, int]:
    """(simulated s fitted per CPU s, one replay's simulated s per CPU s, the fit's CPU s,
    its replays) for the recording at ``path``."""
    recording = load(path)
    emulator = build_emulator(recording)
    try:
        cpu = time.process_time()
        _channels, sim_s = replay_channels(recording, emulator, None,
                                           recorded_exchanges(recording))
        cpu = time.process_time() - cpu
    finally:
        emulator.close()
    result = fit([str(path)], names, workers=1)
    return sim_s / result.cpu_s, sim_s / cpu, result.cpu_s, result.replays


def _fit_results(label: str, what: str, path: Path, names: list[str]) -> list[Result]:
    """The fit's figures for the recording at ``path`` (of the ``label``), ``names`` being
    ``what`` (its results' names)."""
    rate, one, cpu_s, replays = fit_rate(path, names)
    base = f"one replay of the {label}"
    return [
        Result(GROUP, base, one, "sim-s", note="CPU time"),
        Result(GROUP, f"fit of {len(names)} {what} from it", rate, "sim-s", baseline=base,
               note=f"{rate and one / rate:.0f} replays' worth of CPU; one worker"),
        Result(GROUP, f"fit of {len(names)} parameter(s) from the {label}: CPU s per fit",
               cpu_s, "CPU s", at_most=True,
               note=f"{replays} replays; {', '.join(names)}"),
    ]


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
        path, profile = Path(tmp) / "excite.mcap", Path(tmp) / "profile.json"
        names = _record_excitation(path, profile, quick)
        results += _fit_results("arm excitation", "stiffness(es)", path, names)
        if not quick:
            from tools.hil_bench.fit import trial

            elbow = {n: v for n, v in trial.truth().items() if n.startswith("arm.J4.")}
            RobotProfile(elbow).write(profile)
            path = Path(tmp) / "elbow.mcap"
            trial.record(path, profile, trial.SECOND)
            results += _fit_results("elbow probe excitation", "parameters", path, list(elbow))
        path, profile = Path(tmp) / "closure.mcap", Path(tmp) / "hand-profile.json"
        names = _record_closure(path, profile, quick)
        results += _fit_results("hand closure", "accelerometer angle(s)", path, names)
    return results
