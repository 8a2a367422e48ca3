"""``make demo`` end to end, in process: the mug is lifted (the physics' ground truth), the
report and the recordings are written, and a failure is one line, never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.scene_model import MUG_HEIGHT_M, MUG_MASS_KG, MUG_RADIUS_M, TABLE_TOP_Z_M
from tools import demo


def test_the_mug_scene_stands_a_real_mug_on_the_table_within_reach() -> None:
    emu = Emulator("full", can="none", scene="mug")
    assert emu.plant is not None
    model = emu.plant.model
    mug = model.body("mug").id
    assert model.body_subtreemass[mug] == pytest.approx(MUG_MASS_KG)
    assert 0.035 <= MUG_RADIUS_M <= 0.045 and 0.08 <= MUG_HEIGHT_M <= 0.12
    emu.step(500_000)
    tracker = emu.scene_parts[0]
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
    def broken(out: Path, seed: int) -> tuple[bool, str]:
        raise demo.DemoFailed("grasp", "no finger felt the mug")

    monkeypatch.setattr(demo, "run_inprocess", broken)
    assert demo.main(["--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1] == "demo: FAILED (grasp: no finger felt the mug)"
    assert "Traceback" not in out


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_demo_lifts_the_mug_and_writes_report_and_recordings(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    forget_shared_emulators()
    try:
        status = demo.main(["--out", str(tmp_path)])
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
    report = (tmp_path / "report.md").read_text()
    result = json.loads(report.split("```json", 1)[1].split("```", 1)[0])
    # Ground truth from the physics: lifted at least 5 cm, set down upright.
    assert result["mug"]["highest_lift_m"] >= demo.MIN_LIFT_M
    assert abs(result["mug"]["lift_m"]) <= demo.SET_DOWN_M
    assert result["flashed_nodes"] == 12 and result["contacts"]
    for png in ("arm_joints.png", "hand.png", "mug_height.png"):
        assert (tmp_path / png).stat().st_size > 1000
        assert f"]({png})" in report
    for name, topic in (("hand.mcap", "/hand/frames/rx"), ("arm.mcap", "/arm/state")):
        with open(tmp_path / name, "rb") as stream:
            topics = {channel.topic for _, channel, _ in make_reader(stream).iter_messages()}
        assert topic in topics
