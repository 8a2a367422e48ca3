"""``hil-bench fit``: an arm recorded with stiffer and softer elastic elements than nominal
gives them back, and the refit emulator reproduces another recording; refusals are one line."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.profile import FORMAT, PARAMETERS, VERSION, load_profile
from host.arm.excite import Excitation, excite
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from tools.hil_bench.cli import main
from tools.hil_bench.fit.cases import FIT_TOLERANCES
from tools.hil_bench.fit.command import text_lines
from tools.hil_bench.fit.solve import FitResult, FittedParameter
from tools.hil_bench.replay.session import build_emulator, replay
from tools.hil_bench.replay.source import Recorded

#: The robot recorded: J2's element 30 % stiffer than nominal, J4's 20 % softer.
TRUE = {"arm.J2.stiffness": PARAMETERS["arm.J2.stiffness"].nominal * 1.3,
        "arm.J4.stiffness": PARAMETERS["arm.J4.stiffness"].nominal * 0.8}


def _record(path: Path, profile: Path, plan: Excitation) -> None:
    forget_shared_emulators()
    try:
        with Arm.open(f"emu://arm/arm?seed=3&name=test-fit&profile={profile}") as arm:
            arm.torque(True)
            with ArmRecorder(arm, path):
                excite(arm, plan)
    finally:
        forget_shared_emulators()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two different excitations of the perturbed arm: J2 and J4 chirped and held (the
    one fitted), and J4 alone with another hold (the one checked)."""
    here = tmp_path_factory.mktemp("fit")
    profile = here / "true.json"
    profile.write_text(json.dumps({"format": FORMAT, "version": VERSION, "parameters": TRUE}))
    first, second = here / "first.mcap", here / "second.mcap"
    _record(first, profile, Excitation(joints=(1, 3), chirp_s=1.5, hold_s=0.3,
                                       holds=((0.3, 0.0), (0.3, 0.4))))
    _record(second, profile, Excitation(joints=(3,), chirp_s=1.0, hold_s=0.3,
                                        holds=((0.2, 0.3),)))
    return first, second


def _fit(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code = main(["fit", *args, "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


@pytest.mark.slow
def test_fit_recovers_the_stiffnesses_and_the_refit_replays_another_recording(
        recordings: tuple[Path, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    first, second = recordings
    out = tmp_path / "fitted.json"
    code, data, err = _fit(capsys, str(first), "--params", *TRUE, "--out", str(out),
                           "--workers", "2")
    assert code == 0, data
    # the default robot disagreed in the joints perturbed, and the fit removed most of it
    channels = data["channels"]
    for joint in ("J2", "J4"):
        assert channels[f"arm.{joint}.cycle_deflection"]["rms_before"] > 2.0
    assert data["rms_after"] < 0.2 * data["rms_before"] and data["removed"] > 0.8
    assert "fit: iteration 1:" in err and "fit: iteration 2:" in err
    fitted = load_profile(out).values
    for name, truth in TRUE.items():
        assert abs(fitted[name] - truth) < 0.10 * truth, (name, fitted[name], truth)
        estimate = data["parameters"][name]
        assert 0 < estimate["uncertainty"] < 0.10 * truth
        assert estimate["value"] == fitted[name]

    def on(profile: str) -> Callable[[Recorded], Emulator]:
        def build(recording: Recorded) -> Emulator:
            return build_emulator(replace(recording,
                                          spec=replace(recording.spec, profile=profile)))
        return build

    # the second recording, another motion: the refit robot reproduces it, the nominal not
    check = replay(second, tolerances=FIT_TOLERANCES, emulator_factory=on(str(out)))
    held = [c for c in check.channels.values() if c.tolerance > 0]
    assert held and all(c.within for c in held), [c.name for c in held if not c.within]
    nominal = replay(second, tolerances=FIT_TOLERANCES, emulator_factory=on(""))
    assert not all(c.within for c in nominal.channels.values() if c.tolerance > 0)


def test_a_parameter_the_recording_does_not_move_stays_nominal_without_an_uncertainty(
        recordings: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    # J1 (the vertical base joint) is neither chirped nor loaded by gravity in the second
    code, data, _err = _fit(capsys, str(recordings[1]), "--params", "arm.J1.stiffness",
                            "--workers", "1")
    estimate = data["parameters"]["arm.J1.stiffness"]
    assert estimate["value"] == estimate["nominal"] and estimate["uncertainty"] is None
    assert data["rms_after"] == data["rms_before"] > 0 and code == 1  # J4 still parts


def test_a_recording_replays_exactly_on_the_profile_it_was_made_with(
        recordings: tuple[Path, Path]) -> None:
    result = replay(recordings[1])
    assert result.recording.spec.profile.endswith("true.json")
    assert result.within, result.failing


def _refused(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    assert main(["fit", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("hil-bench fit: ")
    return err


def test_an_unknown_parameter_is_refused(recordings: tuple[Path, Path],
                                         capsys: pytest.CaptureFixture[str]) -> None:
    err = _refused(capsys, str(recordings[0]), "--params", "arm.J2.stiffnes")
    assert "unknown parameter 'arm.J2.stiffnes'" in err


def test_a_parameter_the_recording_cannot_show_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "hand.mcap"
    forget_shared_emulators()
    try:
        with Hand.open("emu://hand/palm?seed=1&name=test-fit") as hand, \
                HandRecorder(hand, path):
            hand.status()
    finally:
        forget_shared_emulators()
    err = _refused(capsys, str(path), "--params", "arm.J2.stiffness",
                   "--tolerance", "replied=1")
    assert str(path) in err and "no arm" in err


def test_a_file_that_is_no_recording_is_refused(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "not.mcap"
    path.write_bytes(b"not a recording")
    assert str(path) in _refused(capsys, str(path), "--params", "arm.J2.stiffness")


def test_the_text_report_gives_each_estimate_and_the_error_removed() -> None:
    result = FitResult(["a.mcap"], [FittedParameter("arm.J2.stiffness", "N·m/rad", 200.0,
                                                    259.0, 1.5)],
                       rms_before=2.0, rms_after=0.5, channels_before={}, channels_after={},
                       within_after=False, replays=9, iterations=3, cpu_s=12.0, message="ok")
    lines = text_lines(result)
    assert lines[0] == "arm.J2.stiffness = 259 ± 1.5 N·m/rad (nominal 200; least squares)"
    assert "2 before, 0.5 after: 75.0 % removed" in lines[1]
    assert "still parts" in lines[2]


def test_the_text_report_says_a_parameter_is_unobservable_without_a_number() -> None:
    result = FitResult(["a.mcap"], [FittedParameter("arm.J1.torque_constant", "N·m/A", 2.62,
                                                    2.62, float("inf"), observable=False,
                                                    method="slip onset")],
                       rms_before=1.0, rms_after=1.0, channels_before={}, channels_after={},
                       within_after=True, replays=1, iterations=0, cpu_s=1.0, message="")
    line = text_lines(result)[0]
    assert line == ("arm.J1.torque_constant = 2.62 N·m/A (nominal 2.62): unobservable in "
                    "these recordings")
    assert result.as_json()["parameters"]["arm.J1.torque_constant"]["uncertainty"] is None


def test_the_stages_fit_stiffness_then_friction_then_both_then_the_holding_torque() -> None:
    from tools.hil_bench.fit.solve import staged

    names = ["arm.J4.torque_constant", "arm.J2.bearing_friction", "arm.J2.stiffness"]
    assert staged(names) == [["arm.J2.stiffness"], ["arm.J2.bearing_friction"],
                             ["arm.J2.stiffness", "arm.J2.bearing_friction"],
                             ["arm.J4.torque_constant"]]
    assert staged(["arm.J4.stiffness", "arm.J4.torque_constant"]) == [
        ["arm.J4.stiffness"], ["arm.J4.torque_constant"]]
