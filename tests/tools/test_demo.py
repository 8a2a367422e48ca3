"""``make demo`` end to end, in process: the mug is lifted (the physics' ground truth), the
report and the recordings are written, and a failure is one line, never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.inprocess import EmulatorTransport, forget_shared_emulators
from hil_emulator.profile import RobotProfile
from hil_emulator.scene_model import (
    MUG_HEIGHT_M,
    MUG_MASS_KG,
    MUG_RADIUS_M,
    TABLE_TOP_Z_M,
    MugTracker,
)
from host.arm.facade import Arm
from tests.tools.mcap_check import check_recording
from tools.demo import command
from tools.demo import script as demo
from tools.demo.watch import SLIP_M


def test_the_mug_scene_stands_a_real_mug_on_the_table_within_reach() -> None:
    emu = Emulator("full", can="none", scene="mug")
    assert emu.plant is not None
    model = emu.plant.model
    mug = model.body("mug").id
    assert model.body_subtreemass[mug] == pytest.approx(MUG_MASS_KG)
    assert 0.035 <= MUG_RADIUS_M <= 0.045 and 0.08 <= MUG_HEIGHT_M <= 0.12
    emu.step(500_000)
    tracker = emu.scene_parts[0]
    assert isinstance(tracker, MugTracker)
    summary = emu.scene_stats()["mug"]
    # Standing still on the table top, upright.
    assert tracker.position[2] - MUG_HEIGHT_M / 2 == pytest.approx(TABLE_TOP_Z_M, abs=0.002)
    assert abs(summary["lift_m"]) < 0.002 and summary["tilt_rad"] < 0.01
    assert emu.describe()["scene"] == "mug"
    with pytest.raises(EmulatorConfigError, match="unknown scene"):
        Emulator("arm", physics=False, scene="teapot")
    with pytest.raises(EmulatorConfigError, match="in front of the arm"):
        Emulator("hand", physics=False, scene="mug")


def test_judge_needs_a_lift_and_a_set_down() -> None:
    ok, text = demo.judge({"highest_lift_m": 0.09, "lift_m": 0.001, "tilt_rad": 0.02})
    assert ok and "9.0 cm" in text
    ok, text = demo.judge({"highest_lift_m": 0.03, "lift_m": 0.0, "tilt_rad": 0.0})
    assert not ok and text.startswith("lift:")
    ok, text = demo.judge({"highest_lift_m": 0.09, "lift_m": -0.05, "tilt_rad": 1.5})
    assert not ok and text.startswith("put down:")


def test_a_failure_is_one_line_and_exit_1(monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str],
                                          tmp_path: Path) -> None:
    def broken(out: Path, seed: int, view_port: int | None = None,
               sensors: str | None = None, profile: Path | None = None,
               arm_calibration: str | None = None) -> tuple[bool, str]:
        raise demo.DemoFailed("grasp", "no finger felt the mug")

    monkeypatch.setattr(demo, "run_inprocess", broken)
    assert command.main(["--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1] == "demo: FAILED (grasp: no finger felt the mug)"
    assert "Traceback" not in out


def test_the_demo_with_a_profile_has_its_robot_in_the_plant(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    profile = tmp_path / "robot.json"
    RobotProfile({"arm.J2.stiffness": 260.0, "arm.J4.torque_constant": 0.7}).write(profile)
    seen: list[tuple[Path | None, float, float]] = []

    def opened(out: Path, seed: int, view_port: int | None = None,
               sensors: str | None = None, profile: Path | None = None,
               arm_calibration: str | None = None) -> tuple[bool, str]:
        # what run_inprocess opens, without the demo's motions
        forget_shared_emulators()
        try:
            with Arm.open(demo.demo_url(seed, sensors, profile).format("arm")) as arm:
                transport = arm.transport
                assert isinstance(transport, EmulatorTransport)
                params = transport.emulator.require_arm_plant().params
                seen.append((profile, float(params.stiffness[1]),
                             float(params.torque_constant_nm_per_a[3])))
        finally:
            forget_shared_emulators()
        return True, "opened"

    monkeypatch.setattr(demo, "run_inprocess", opened)
    assert command.main(["--out", str(tmp_path), "--profile", str(profile),
                         "--sensors", "ideal"]) == 0
    assert seen == [(profile, 260.0, 0.7)]


def test_the_demo_refuses_a_profile_that_is_no_profile_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "hil-emulator robot profile", "version": 1, '
                   '"parameters": {"arm.J9.stiffness": 1}}')
    with pytest.raises(SystemExit) as exit_info:
        command.main(["--out", str(tmp_path), "--profile", str(bad)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "arm.J9.stiffness" in err[-1] and str(bad) in err[-1]


def test_the_demo_refuses_an_arm_calibration_that_is_not_there_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nothing.json"
    with pytest.raises(SystemExit) as exit_info:
        command.main(["--out", str(tmp_path / "out"), "--arm-calibration", str(missing)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert str(missing) in err[-1] and "no such file" in err[-1]
    assert not (tmp_path / "out").exists()  # refused before anything started


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_demo_lifts_the_mug_and_writes_report_and_recordings(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    forget_shared_emulators()
    try:
        status = command.main(["--out", str(tmp_path)])
    finally:
        forget_shared_emulators()
    out = capsys.readouterr().out
    assert "Traceback" not in out
    assert status == 0, out
    last = out.strip().splitlines()[-1]
    assert last.startswith("demo: OK (mug lifted "), last
    for step in ("emulator:", "firmware:", "homing:", "reach:", "grasp:", "lift:",
                 "put down:", "park:"):
        assert f"] {step}" in out
    # The robot as built: its hand calibrated before homing, the fit written and used.
    assert out.count("accelerometers calibrated") == 4
    written = json.loads((tmp_path / "calibration.json").read_text())
    assert written["format"] == "lowcost-calibration"
    assert len(written["sections"]["hand"]["boards"]) == 12
    # No arm calibration in the test's own calibration directory: the CAD model, said.
    assert "arm: arm calibration: none (the CAD model's kinematics)" in out
    report = (tmp_path / "report.md").read_text()
    result = json.loads(report.split("```json", 1)[1].split("```", 1)[0])
    # Ground truth from the physics: lifted at least 5 cm, set down upright.
    assert result["mug"]["highest_lift_m"] >= demo.MIN_LIFT_M
    assert abs(result["mug"]["lift_m"]) <= demo.SET_DOWN_M
    assert result["flashed_nodes"] == 12 and result["contacts"]
    assert result["arm_calibration"]["path"] is None
    assert result["arm_calibration"]["warnings"]  # the missing file is a warning
    for png in ("arm_joints.png", "hand.png", "mug_height.png"):
        assert (tmp_path / png).stat().st_size > 1000
        assert f"]({png})" in report
    for name, topic in (("hand.mcap", "/hand/frames/rx"), ("arm.mcap", "/arm/state")):
        with open(tmp_path / name, "rb") as stream:
            topics = {channel.topic for _, channel, _ in make_reader(stream).iter_messages()}
        assert topic in topics
    # What a viewer reads: valid files, schemas with units, the wall clock; the whole
    # session (from the firmware step, about 65 s simulated), the hand's state at 10 Hz
    # while the arm moves and every finger reading of the hand's own moves.
    hand, arm = check_recording(tmp_path / "hand.mcap"), check_recording(tmp_path / "arm.mcap")
    assert hand["/hand/state"] >= 300 and hand["/hand/fingers"] >= 300
    assert arm["/arm/state"] >= 3000
    # The log agrees with the tactile plot: every finger holds the mug, none slipped
    assert "closed without contact" not in out
    assert set(result["holding"]) == {"0", "1", "2", "3"}
    assert all(text.startswith("contact:") for text in result["holding"].values())
    assert result["slip_m"] < SLIP_M


def test_fastest_fall_finds_the_hands_drop() -> None:
    samples = [(t / 100, 0.0, 1.0 - (0.2 * (t - 50) / 30 if 50 <= t <= 80 else
                                     (0.2 if t > 80 else 0.0)), 0.0) for t in range(200)]
    fall, at = demo.fastest_fall(samples, 0.3)
    assert fall == pytest.approx(0.2, abs=0.01) and at == pytest.approx(0.5)
    assert demo.fastest_fall([], 0.3) == (0.0, 0.0)


class _Body:
    """A rigid body's pose, as MuJoCo's data arrays give it (position, row-major rotation)."""

    def __init__(self) -> None:
        self.xpos = np.zeros((2, 3))
        self.xmat = np.tile(np.eye(3).ravel(), (2, 1))


def test_the_mug_moving_in_the_hand_while_off_the_table_is_a_slip() -> None:
    from types import SimpleNamespace

    from tools.demo.watch import SLIP_M, MugInHand

    data = _Body()
    mug = SimpleNamespace(start=np.array([0.0, 0.0, 0.05]), position=np.array([0.0, 0.0, 0.05]))
    watch = MugInHand(mug, data, palm_id=1)
    data.xpos[1] = [0.0, 0.03, 0.05]
    watch.sample(0.0)  # on the table: no hold yet
    for k, (palm_z, mug_z) in enumerate([(0.10, 0.10), (0.15, 0.15), (0.09, 0.09)]):
        data.xpos[1][2], mug.position[2] = palm_z, mug_z  # the hand and the mug together
        watch.sample(1.0 + k)
    assert watch.slip_m == pytest.approx(0.0)  # the hand fell 6 cm: no slip
    data.xpos[1][2], mug.position[2] = 0.12, 0.09  # the hand rose, the mug stayed
    watch.sample(5.0)
    assert watch.slip_m == pytest.approx(0.03) and watch.slip_m > SLIP_M
    assert watch.slip_t == 5.0


def test_what_a_finger_felt_is_its_taxels_rise_since_the_baseline() -> None:
    from host.hand.state import FingerState
    from tools.demo.watch import felt

    base = FingerState(0, tactile={"proximal": [100] * 6, "distal": [100] * 12})
    pressed = FingerState(0, tactile={"proximal": [100, 400, 100, 100, 90, 100],
                                      "distal": [150] * 12})
    light = FingerState(1, tactile={"proximal": [120] * 6, "distal": [100] * 12})
    text = felt({0: pressed, 1: light}, {0: base, 1: FingerState(1, tactile=base.tactile)})
    assert text == {0: "contact: taxels +900 counts in all (+300 the most)",
                    1: "no contact (taxels +20 counts at most)"}
