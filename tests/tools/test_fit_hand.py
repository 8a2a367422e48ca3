"""``hil-bench fit`` on the hand: a hand recorded with its accelerometers mounted a few
degrees off and offset gives their rotations and offsets back, and the refit emulator
reproduces another recording.  The default test fits one phalange board's rotation from two
short closures; the slow one runs ``handctl excite`` and fits two boards' rotations and
offsets; the long one records a full-robot session (the arm tilting the hand) and fits the
palm's and a motor board's, which closures alone cannot show."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path

import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.profile import RobotProfile
from host.hand.excite import FingerExcitation, excite_fingers
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from tools.hil_bench.cli import main
from tools.hil_bench.fit.cases import HAND_FIT_TOLERANCES
from tools.hil_bench.replay.session import build_emulator, replay
from tools.hil_bench.replay.source import Recorded

#: The default test's robot: finger 1's distal board (f3) turned about its x axis.
TILTED = {"hand.finger1.f3.accel_rotation_x": 2.5}
#: The slow test's: f3 turned about all three axes and offset, f2 turned and offset.
TURNED = {"hand.finger1.f3.accel_rotation_x": 2.0, "hand.finger1.f3.accel_rotation_y": -1.5,
          "hand.finger1.f3.accel_rotation_z": 1.2, "hand.finger1.f3.accel_bias_x": 0.03,
          "hand.finger1.f2.accel_rotation_y": 2.5, "hand.finger1.f2.accel_bias_z": -0.04}
#: The fit's hand tolerances of what a closures' recording has (no palm state in it).
FINGER_TOLERANCES = [(n, v) for n, v in HAND_FIT_TOLERANCES if not n.startswith("state.")]
#: A rotation is recovered within this (deg), an offset within this (g: 1 mg).
ROTATION_DEG, BIAS_G = 0.3, 0.001


def on(profile: str) -> Callable[[Recorded], Emulator]:
    """An emulator factory for :func:`replay`: the recording's emulator with ``profile``
    (empty: the default robot, the seed's draw)."""
    def build(recording: Recorded) -> Emulator:
        return build_emulator(replace(recording, spec=replace(recording.spec, profile=profile)))
    return build


def _record_closures(path: Path, url: str, plan: FingerExcitation) -> None:
    forget_shared_emulators()
    try:
        with Hand.open(url) as hand, HandRecorder(hand, path):
            excite_fingers(hand, plan)
    finally:
        forget_shared_emulators()


def _fit(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code = main(["fit", *args, "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


def _check_recovered(fitted: Mapping[str, float], truth: Mapping[str, float]) -> None:
    for name, value in truth.items():
        limit = ROTATION_DEG if "rotation" in name else BIAS_G
        assert abs(fitted[name] - value) < limit, (name, fitted[name], value)


def _check_refit_replays(second: Path | list[Path], fitted: Path,
                         tolerances: list[tuple[str, float]]) -> None:
    """The refit robot reproduces ``second`` within the fit's ``tolerances``, the default
    not."""
    check = replay(second, tolerances=tolerances, emulator_factory=on(str(fitted)))
    held = [c for c in check.channels.values() if c.tolerance > 0]
    assert held and all(c.within for c in held), [c.name for c in held if not c.within]
    nominal = replay(second, tolerances=tolerances, emulator_factory=on(""))
    assert not all(c.within for c in nominal.channels.values() if c.tolerance > 0)


@pytest.fixture(scope="module")
def closure(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One firm closure of finger 1 on the robot with f3 tilted."""
    here = tmp_path_factory.mktemp("fit-hand")
    profile = here / "tilted.json"
    RobotProfile(TILTED).write(profile)
    path = here / "closure.mcap"
    _record_closures(path, f"emu://hand/palm?seed=3&name=test-fit-hand&profile={profile}",
                     FingerExcitation(fingers=(1,), efforts=(255,), unhomed=True,
                                      closures=((0.0, 0.9, 0.7),), timeout_s=1.5))
    return path


def test_the_default_robot_parts_from_a_turned_board_and_the_fit_turns_it_back(
        closure: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the default robot (the seed's draw) parts from the recording in f3's accelerometer
    nominal = replay(closure, tolerances=FINGER_TOLERANCES, emulator_factory=on(""))
    assert any(".dp_imu[" in name for name in nominal.failing), nominal.failing
    assert not any(".pp_imu[" in name or ".hall_pos[" in name for name in nominal.failing)
    (name, truth), = TILTED.items()
    code, data, _err = _fit(capsys, str(closure), "--params", name, "--workers", "1")
    assert code == 0, data  # the fitted robot replays the closure within the tolerances
    estimate = data["parameters"][name]
    assert abs(estimate["value"] - truth) < ROTATION_DEG, estimate
    assert 0 < estimate["uncertainty"] < ROTATION_DEG
    assert data["rms_after"] < 0.2 * data["rms_before"]
