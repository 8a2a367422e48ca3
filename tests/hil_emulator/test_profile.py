"""Robot profiles: their parameters reach the arm's and the hand's plants; a bad file: one line."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand_profile import ACCEL_BOARDS
from hil_emulator.inprocess import parse_url
from hil_emulator.profile import FORMAT, PARAMETERS, VERSION, RobotProfile, load_profile
from host.errors import UsageError
from tests.hil_emulator.emulator_process import ROOT


def _file(tmp_path: Path, content: object, name: str = "p.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(content), encoding="utf-8")
    return path


def _profile(parameters: dict[str, object], **extra: object) -> dict[str, object]:
    return {"format": FORMAT, "version": VERSION, "parameters": parameters, **extra}


def test_every_parameter_has_its_nominal_within_its_bounds() -> None:
    # the arm's 4 kinds × 4 joints, the hand's 2 per finger and 6 per accelerometer board
    assert len(PARAMETERS) == 16 + 2 * 4 + 6 * len(ACCEL_BOARDS)
    for p in PARAMETERS.values():
        assert p.low < p.nominal < p.high, p.name
        assert p.unit and p.doc and p.step > 0


def test_a_profile_written_reads_back_and_reaches_the_plant(tmp_path: Path) -> None:
    values = {"arm.J2.stiffness": 260.0, "arm.J4.damping": 0.5,
              "arm.J1.bearing_friction": 0.2, "arm.J3.torque_constant": 0.7}
    path = tmp_path / "robot.json"
    RobotProfile(values, {"by": "test"}).write(path)
    assert load_profile(path).values == values
    with Emulator("arm", can="none", profile=str(path)) as emulator:
        plant = emulator.require_arm_plant()
        assert plant.stiffness[1] == 260.0 and plant.stiffness[0] == 160.0
        assert plant.params.damping[3] == 0.5
        assert plant.params.torque_constant_nm_per_a[2] == 0.7
        assert emulator.plant is not None
        d0 = plant.model.jnt_dofadr[plant._stepper_jids[0]]
        assert plant.model.dof_frictionloss[d0] == 0.2  # measured, not the draw
        assert emulator.describe()["profile"] == str(path)


def test_bearings_a_profile_leaves_out_keep_the_seeds_draw() -> None:
    def friction(profile: RobotProfile | None) -> np.ndarray:
        with Emulator("arm", seed=4, can="none", profile=profile) as emulator:
            plant = emulator.require_arm_plant()
            d0 = plant.model.jnt_dofadr[plant._stepper_jids[0]]
            return np.array(plant.model.dof_frictionloss[d0:d0 + 4])

    drawn = friction(None)
    mixed = friction(RobotProfile({"arm.J2.bearing_friction": 0.3}))
    assert mixed[1] == 0.3 and drawn[1] != 0.3
    assert np.array_equal(np.delete(mixed, 1), np.delete(drawn, 1))


@pytest.mark.parametrize(("content", "says"), [
    (_profile({"arm.J9.stiffness": 1.0}), "unknown parameter 'arm.J9.stiffness'"),
    (_profile({"arm.J2.stiffness": "stiff"}), "not a finite number"),
    (_profile({"arm.J2.stiffness": 1e6}), "outside its bounds"),
    (_profile({"hand.finger1.f3.accel_rotation_x": 20.0}), "20.0 deg is outside its bounds"),
    (_profile({"hand.finger4.f3.accel_bias_x": 0.0}), "unknown parameter 'hand.finger4"),
    (_profile({}, colour="red"), "unknown keys ['colour']"),
    ({"format": FORMAT, "version": 99, "parameters": {}}, "version 99"),
    ([1, 2], "not a JSON object"),
])
def test_a_bad_profile_is_one_line_naming_what(tmp_path: Path, content: object,
                                               says: str) -> None:
    path = _file(tmp_path, content)
    with pytest.raises(EmulatorConfigError) as info:
        load_profile(path)
    assert says in str(info.value) and str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_hil_emulator_refuses_a_bad_profile_with_exit_2(tmp_path: Path) -> None:
    path = _file(tmp_path, _profile({"arm.J2.stiffnes": 200.0}))
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config",
                             "arm", "--profile", str(path)], cwd=ROOT, capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    err = result.stderr.strip()
    assert err.startswith("hil-emulator: profile") and "arm.J2.stiffnes" in err
    assert len(err.splitlines()) == 1


def test_an_emu_url_names_its_profile_and_a_bad_one_is_a_usage_error(tmp_path: Path) -> None:
    good = _file(tmp_path, _profile({"arm.J4.stiffness": 70.0}), "good.json")
    spec = parse_url(f"emu://arm/arm?seed=1&ready=0&profile={good}")
    assert spec.profile == str(good)
    assert spec.key() != parse_url("emu://arm/arm?seed=1&ready=0").key()
    with spec.build() as emulator:
        assert emulator.require_arm_plant().stiffness[3] == 70.0
    bad = _file(tmp_path, _profile({"arm.J4.stiffness": -1.0}), "bad.json")
    with pytest.raises(UsageError, match="outside its bounds"):
        parse_url(f"emu://arm/arm?profile={bad}").build()


def _row_name(name: str) -> str:
    """The name of ``name``'s row in the docs' table: the hand's rows stand for every finger
    (``fingerK``) and every board (``BOARD``)."""
    if ".accel_" in name:
        return "hand.BOARD." + name.rsplit(".", 1)[1]
    return re.sub(r"finger\d", "fingerK", name)


def test_the_docs_list_every_parameter_with_its_unit_and_nominal() -> None:
    text = (ROOT / "docs" / "EMULATOR.md").read_text(encoding="utf-8")
    for p in PARAMETERS.values():
        assert f"| `{_row_name(p.name)}` | {p.unit} | {p.nominal:g} |" in text, p.name


def test_a_profile_turns_and_offsets_the_boards_it_names_and_leaves_the_others_drawn(
        ) -> None:
    values = {"hand.finger2.f3.accel_rotation_x": 3.0, "hand.finger2.f3.accel_bias_z": -0.05,
              "hand.palm.accel_rotation_z": -2.0}
    with Emulator("hand", seed=5, can="none") as drawn, \
            Emulator("hand", seed=5, can="none", profile=RobotProfile(values)) as built:
        before, after = drawn.planted, built.planted
        assert before is not None and after is not None
        f3, f3_drawn = after.accels["finger2.f3"], before.accels["finger2.f3"]
        assert f3.tilt_rad is not None and f3_drawn.tilt_rad is not None
        assert np.degrees(f3.tilt_rad[0]) == pytest.approx(3.0)
        assert f3.tilt_rad[1:] == pytest.approx(f3_drawn.tilt_rad[1:])  # the draw's
        assert f3.bias_mg[2] == pytest.approx(-50.0)
        assert f3.bias_mg[:2] == pytest.approx(f3_drawn.bias_mg[:2])
        palm = after.accels["palm"].tilt_rad
        assert palm is not None and np.degrees(palm[2]) == pytest.approx(-2.0)
        for board in ("finger2.f2", "finger0.f3", "finger3.fmcb"):  # not named: as drawn
            assert np.array_equal(after.accels[board].rotation, before.accels[board].rotation)
            assert np.array_equal(after.accels[board].bias_mg, before.accels[board].bias_mg)


def test_a_profile_sets_a_fingers_motor_friction_and_joint_damping() -> None:
    values = {"hand.finger1.motor_friction": 2.0e-3, "hand.finger1.joint_damping": 0.005}
    with Emulator("hand", seed=1, can="none", profile=RobotProfile(values)) as emulator:
        one, other = emulator.finger_plants[1], emulator.finger_plants[2]
        model = one.model
        assert one.params.motor.friction_nm == 2.0e-3
        assert other.params.motor.friction_nm == PARAMETERS[
            "hand.finger2.motor_friction"].nominal
        tendon = model.tendon(one.names.motor(0)).id
        assert model.tendon_frictionloss[tendon] == 2.0e-3
        dofs = model.dof_damping
        assert list(dofs[one._dadr:one._dadr + 3]) == [0.005] * 3
        assert dofs[other._dadr] == PARAMETERS["hand.finger2.joint_damping"].nominal


def test_a_sensors_parameter_on_ideal_sensors_is_one_line() -> None:
    with pytest.raises(EmulatorConfigError, match="needs --sensors realistic"):
        Emulator("hand", sensors="ideal",
                 profile=RobotProfile({"hand.finger0.f2.accel_bias_x": 0.01}))
