"""handctl and the calibration file: which one a command uses, the warnings, a bad file,
and ``calibrate`` writing the file the next command loads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from host.estimation import calibration_file as cf
from host.estimation.hand_calibration import BoardCalibration, HandCalibration, board_key
from host.hand.facade import Hand
from tools.cli.handctl import main

URL = "emu://hand/palm?name=calibration-tests"


@pytest.fixture(scope="module")
def serial() -> str:
    with Hand.open(URL) as hand:
        return hand.serial()


def _a_calibration(firmware: str = "1.0.0") -> dict:
    """A hand section tilting finger 3's f2 (made on ``firmware``; the emulator runs 1.0.0)."""
    tilted = BoardCalibration(np.array([0.0, 0.0, 0.01]), np.zeros(3), np.zeros(3),
                              np.array([5.0, -3.0, 2.0]))
    return HandCalibration({board_key(3, "f2"): tilted}).to_section(firmware=firmware)


def test_the_serial_is_the_palms_uid_and_differs_between_seeds(serial: str) -> None:
    with Hand.open("emu://hand/palm?seed=2&name=calibration-tests-2") as other:
        assert other.serial() != serial
    assert len(serial) == 8 and int(serial, 16) > 0


def test_status_without_a_file_warns_in_one_line(serial: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "--json", "status"]) == 0
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if "no calibration file" in line]
    assert len(warnings) == 1 and serial in warnings[0]
    assert "calibration: none" in err[-1]


def test_status_uses_this_robots_file_and_says_so(serial: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    path = cf.default_path(serial)
    cf.save_section(path, serial, "hand", _a_calibration())
    assert main(["--port", URL, "--json", "status"]) == 0
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [f"calibration: {path} (hand, 1 boards, made "
                                                 f"{cf.load(path).sections['hand']['created_utc']})"]
    assert len(json.loads(captured.out)["fingers"]) == 4
    # and 'none' turns it off without a warning
    assert main(["--port", URL, "--json", "status", "--calibration", "none"]) == 0
    assert capsys.readouterr().err.strip() == ("calibration: none (accelerometers on their "
                                               "nominal mounting)")


def test_another_robots_file_is_a_warning_and_not_used(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "other.json"
    cf.save_section(path, "0badc0de", "hand", _a_calibration())
    assert main(["--port", URL, "home", "--finger", "3", "--calibration", str(path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any("0badc0de" in line and "not used" in line for line in err)
    assert "calibration: none" in err[-1]


def test_an_older_firmwares_file_is_used_with_a_warning(serial: str, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    path = tmp_path / "old.json"
    cf.save_section(path, serial, "hand", _a_calibration("0.0.1"))
    assert main(["--port", URL, "status", "--calibration", str(path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any("firmware 0.0.1" in line for line in err) and str(path) in err[-1]


@pytest.mark.parametrize("text", ["{ not json", json.dumps({"format": "lowcost-calibration",
                                                            "version": 99})])
def test_a_bad_file_is_a_one_line_error_and_exit_2(tmp_path: Path, text: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text, encoding="utf-8")
    assert main(["--port", URL, "status", "--calibration", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "Traceback" not in err[0]


@pytest.mark.slow
def test_calibrate_writes_the_file_the_next_command_uses(serial: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    out = tmp_path / "cal.json"
    assert main(["--port", URL, "calibrate", "--fingers", "3", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "calibrating finger 3: pose 27/27" in captured.err
    assert f"wrote {out}" in captured.out and "not observable" in captured.out
    written = cf.load(out)
    assert written.robot_serial == serial
    hand = written.sections["hand"]
    assert set(hand["boards"]) == {board_key(3, b) for b in ("fmcb", "f2", "f3")}
    assert hand["fits"]["3"]["poses"] == 27 and "f2.rotation[y]" in hand["fits"]["3"][
        "unobservable"]
    assert main(["--port", URL, "status", "--calibration", str(out)]) == 0
    assert capsys.readouterr().err.strip().endswith(f"(hand, 3 boards, made "
                                                    f"{hand['created_utc']})")


def test_a_hand_section_with_a_broken_board_is_a_one_line_error(
        serial: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "broken.json"
    section = _a_calibration()
    section["boards"][board_key(3, "f2")]["bias_counts"] = ["x", 1, 2]
    cf.save_section(path, serial, "hand", section)
    assert main(["--port", URL, "status", "--calibration", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "finger3.f2" in err[0]
