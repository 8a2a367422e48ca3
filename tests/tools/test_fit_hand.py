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
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder
from host.hand.excite import FingerExcitation, excite_fingers
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from tools.cli import handctl
from tools.hil_bench.cli import main
from tools.hil_bench.fit.cases import FIT_TOLERANCES, HAND_FIT_TOLERANCES
from tools.hil_bench.replay.session import build_emulator, replay
from tools.hil_bench.replay.source import Recorded

#: The default test's robot: finger 1's distal board (f3) turned about its x axis.
TILTED = {"hand.finger1.f3.accel_rotation_x": 2.5}
#: The slow test's: f3 turned about all three axes and offset, f2 turned and offset.
TURNED = {"hand.finger1.f3.accel_rotation_x": 2.0, "hand.finger1.f3.accel_rotation_y": -1.5,
          "hand.finger1.f3.accel_rotation_z": 1.2, "hand.finger1.f3.accel_bias_x": 0.03,
          "hand.finger1.f2.accel_rotation_y": 2.5, "hand.finger1.f2.accel_bias_z": -0.04}
#: The fit's hand tolerances of what a closures' recording has (no palm state in it).
FINGER_TOLERANCES = [(n, v) for n, v in HAND_FIT_TOLERANCES if not n.startswith("accel")]
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


def _handctl_excite(path: Path, url: str, efforts: str) -> None:
    forget_shared_emulators()
    try:
        assert handctl.main(["--port", url, "excite", str(path), "--fingers", "1",
                             "--efforts", efforts, "--unhomed"]) == 0
    finally:
        forget_shared_emulators()


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_handctl_excite_gives_back_two_boards_rotations_and_offsets(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "turned.json"
    RobotProfile(TURNED).write(profile)
    url = f"emu://hand/palm?seed=3&name=test-fit-hand-excite&profile={profile}"
    first, second = tmp_path / "firm.mcap", tmp_path / "light.mcap"
    _handctl_excite(first, url, "255")
    _handctl_excite(second, url, "150")  # another recording: the light closures
    capsys.readouterr()
    nominal = replay(first, tolerances=FINGER_TOLERANCES, emulator_factory=on(""))
    failing = {name.rsplit(".", 1)[1].partition("[")[0] for name in nominal.failing}
    assert failing == {"pp_imu", "dp_imu"}, nominal.failing  # f2's and f3's, named
    out = tmp_path / "fitted.json"
    code, data, err = _fit(capsys, str(first), "--params", *TURNED, "--out", str(out),
                           "--workers", "2")
    assert code == 0, data
    assert data["removed"] > 0.9 and "fit: iteration 2:" in err
    _check_recovered(RobotProfile(json.loads(out.read_text())["parameters"]).values, TURNED)
    _check_refit_replays(second, out, FINGER_TOLERANCES)


#: The long test's robot: the palm's accelerometer turned about all three axes and offset.
PALM = {"hand.palm.accel_rotation_x": 1.5, "hand.palm.accel_rotation_y": -2.0,
        "hand.palm.accel_rotation_z": 2.5, "hand.palm.accel_bias_x": -0.02,
        "hand.palm.accel_bias_y": 0.03, "hand.palm.accel_bias_z": 0.015}
#: The wrist's turns (J5, J6, J7 from where the arm starts, rad) of a full-robot session,
#: each held while the host reads the hand.
WRIST_TURNS = ((0.0, 0.0, 0.0), (0.0, 0.6, 0.0), (0.0, 0.6, 0.8), (0.7, -0.5, 0.0),
               (-0.7, 0.0, -0.8), (0.0, -0.6, 0.5))


def _record_session(arm_path: Path, hand_path: Path, query: str,
                    turns: tuple[tuple[float, float, float], ...]) -> None:
    """One full-robot session, a recorder per link: the wrist turned to each of ``turns``,
    the hand's status and the palm's state read three times at each."""
    forget_shared_emulators()
    try:
        with Arm.open(f"emu://full/arm?{query}") as arm, \
                Hand.open(f"emu://full/palm?{query}") as hand, \
                ArmRecorder(arm, arm_path), HandRecorder(hand, hand_path):
            arm.torque(True)
            start = list(arm.state().joints)
            for turn in turns:
                target = start[:4] + [s + t for s, t in zip(start[4:], turn, strict=True)]
                _state, arrived = arm.move(target, speed=1.0)
                assert arrived
                for _ in range(3):
                    hand.status()
                    hand.session.request("palm.state")
    finally:
        forget_shared_emulators()


@pytest.mark.long
@pytest.mark.timeout(3600)
def test_a_full_robot_session_gives_back_the_palms_rotation_about_every_axis(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "palm.json"
    RobotProfile(PALM).write(profile)
    query = f"seed=3&name=test-fit-robot&profile={profile}"
    arm_path, hand_path = tmp_path / "arm.mcap", tmp_path / "hand.mcap"
    _record_session(arm_path, hand_path, query, WRIST_TURNS)
    check_arm, check_hand = tmp_path / "arm-2.mcap", tmp_path / "hand-2.mcap"
    _record_session(check_arm, check_hand, query, ((0.0, 0.0, 0.0), (0.4, 0.4, -0.6),
                                                   (-0.5, -0.3, 0.7)))
    session = [arm_path, hand_path]
    tolerances = [*FIT_TOLERANCES, *HAND_FIT_TOLERANCES]
    nominal = replay(session, tolerances=tolerances, emulator_factory=on(""))
    assert any(".accel[" in name for name in nominal.failing), nominal.failing
    out = tmp_path / "fitted.json"
    code, data, _err = _fit(capsys, f"{arm_path}+{hand_path}", "--params", *PALM,
                            "--out", str(out), "--workers", "2")
    assert code == 0, data
    _check_recovered(RobotProfile(json.loads(out.read_text())["parameters"]).values, PALM)
    _check_refit_replays([check_arm, check_hand], out, tolerances)


def test_a_sensors_parameter_of_a_recording_with_ideal_sensors_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "ideal.mcap"
    forget_shared_emulators()
    try:
        with Hand.open("emu://hand/palm?seed=1&sensors=ideal&name=test-fit-hand-ideal") as hand, \
                HandRecorder(hand, path):
            hand.status()
    finally:
        forget_shared_emulators()
    assert main(["fit", str(path), "--params", "hand.finger1.f2.accel_bias_x"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err
    assert "'ideal' sensors" in err and "hand.finger1.f2.accel_bias_x" in err
    # one session's files joined by +: these two are one link twice, refused as replay does
    assert main(["fit", f"{path}+{path}", "--params", "hand.finger1.motor_friction"]) == 2
    assert "repeats the hand link" in capsys.readouterr().err
