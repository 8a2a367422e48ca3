"""The calibration file: round trip, sections kept, atomic replace, refusals, warnings."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host.errors import CalibrationFileError, UsageError
from host.estimation import calibration_file as cf

SERIAL = "00001000"

_json_leaf = (st.none() | st.booleans() | st.integers(-(2**53), 2**53)
              | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8))
_json = st.recursive(_json_leaf, lambda kids: st.lists(kids, max_size=4)
                     | st.dictionaries(st.text(max_size=6), kids, max_size=4), max_leaves=12)
_sections = st.dictionaries(st.text(max_size=6), _json, max_size=5)


@settings(deadline=None, max_examples=60,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(extra=_sections, serial=st.from_regex(r"\A[0-9a-f]{8}\Z"))
def test_load_of_save_is_what_was_saved(tmp_path: Path, extra: dict, serial: str) -> None:
    path = tmp_path / f"{serial}.json"
    path.unlink(missing_ok=True)
    data = {**extra, "method": "m", "created_utc": "2026-01-01T00:00:00Z"}
    written = cf.save_section(path, serial, "hand", data)
    again = cf.load(path)
    assert again == written
    assert again.section("hand") == data and again.robot_serial == serial


def test_a_second_section_keeps_the_first_and_the_files_creation_time(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    first = cf.save_section(path, SERIAL, "hand", {"method": "a", "bias": [1.0, 2.0, 3.0]})
    second = cf.save_section(path, SERIAL, "arm", {"method": "b", "links": [0.1]})
    assert second.created_utc == first.created_utc
    assert set(cf.load(path).sections) == {"hand", "arm"}
    assert cf.load(path).sections["hand"]["bias"] == [1.0, 2.0, 3.0]
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]  # no temporary file left


def test_numpy_values_are_stored_as_lists(tmp_path: Path) -> None:
    import numpy as np

    path = tmp_path / "cal.json"
    cf.save_section(path, SERIAL, "hand", {"method": "m", "rot": np.eye(3), "rms": np.float64(2)})
    hand = cf.load(path).sections["hand"]
    assert hand["rot"] == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] and hand["rms"] == 2


def test_another_robots_file_is_not_overwritten_unless_told(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    cf.save_section(path, "aaaa0001", "hand", {"method": "m"})
    with pytest.raises(CalibrationFileError, match="aaaa0001"):
        cf.save_section(path, SERIAL, "hand", {"method": "m"})
    assert cf.load(path).robot_serial == "aaaa0001"
    cf.save_section(path, SERIAL, "hand", {"method": "m"}, replace_other_robot=True)
    assert cf.load(path).robot_serial == SERIAL


@pytest.mark.parametrize(("text", "says"), [
    ("{not json", "not JSON"),
    ("[]", "format"),
    (json.dumps({"format": "other"}), "format"),
    (json.dumps({"format": cf.FORMAT, "version": "1"}), "version"),
    (json.dumps({"format": cf.FORMAT, "version": 1, "robot_serial": "../x",
                 "created_utc": "t", "sections": {}}), "robot_serial"),
    (json.dumps({"format": cf.FORMAT, "version": 1, "robot_serial": SERIAL,
                 "created_utc": "t", "sections": {"hand": {"method": "m"}}}), "created_utc"),
    (json.dumps({"format": cf.FORMAT, "version": cf.VERSION + 1, "robot_serial": SERIAL,
                 "created_utc": "t", "sections": {}}), "newer"),
])
def test_a_bad_file_is_a_one_line_error_naming_it(tmp_path: Path, text: str, says: str) -> None:
    path = tmp_path / "cal.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(CalibrationFileError) as info:
        cf.load(path)
    message = str(info.value)
    assert says in message and str(path) in message and "\n" not in message
    with pytest.raises(CalibrationFileError):  # never overwritten either
        cf.save_section(path, SERIAL, "hand", {"method": "m"})
    assert path.read_text(encoding="utf-8") == text


def test_a_value_json_cannot_hold_is_refused(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="not finite"):
        cf.save_section(tmp_path / "c.json", SERIAL, "hand", {"method": "m", "x": float("nan")})
    with pytest.raises(UsageError, match="method"):
        cf.save_section(tmp_path / "c.json", SERIAL, "hand", {"bias": 1})
    assert not (tmp_path / "c.json").exists()


def test_default_path_follows_the_environment(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(cf.DIR_ENV, str(tmp_path / "cals"))
    assert cf.default_path(SERIAL) == tmp_path / "cals" / f"{SERIAL}.json"
    monkeypatch.delenv(cf.DIR_ENV)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    assert cf.default_path(SERIAL) == tmp_path / "cfg" / "lowcost-hand" / "calibration" / (
        f"{SERIAL}.json")
    with pytest.raises(UsageError):
        cf.default_path("../../etc/passwd")


def test_find_warns_of_a_missing_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(cf.DIR_ENV, str(tmp_path))
    cal, warnings = cf.find(SERIAL)
    assert cal is None and len(warnings) == 1 and "no calibration file" in warnings[0]
    cf.save_section(cf.default_path(SERIAL), SERIAL, "hand", {"method": "m"})
    cal, warnings = cf.find(SERIAL, section="hand")
    assert cal is not None and warnings == []


def test_find_never_uses_another_robots_file(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    cf.save_section(path, "aaaa0001", "hand", {"method": "m"})
    cal, warnings = cf.find(SERIAL, path)
    assert cal is None and len(warnings) == 1
    assert "aaaa0001" in warnings[0] and SERIAL in warnings[0] and "not used" in warnings[0]


def test_find_warns_of_older_firmware_and_a_missing_section(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    cf.save_section(path, SERIAL, "hand", {"method": "m", "firmware": "1.2.3"})
    assert cf.find(SERIAL, path, section="hand", firmware="1.2.3")[1] == []
    cal, warnings = cf.find(SERIAL, path, section="hand", firmware="1.10.0")
    assert cal is not None and len(warnings) == 1 and "1.2.3" in warnings[0]
    cal, warnings = cf.find(SERIAL, path, section="arm")
    assert cal is not None and len(warnings) == 1 and "no 'arm' section" in warnings[0]


def test_find_warns_of_an_older_format_version(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cal.json"
    cf.save_section(path, SERIAL, "hand", {"method": "m"})
    monkeypatch.setattr(cf, "VERSION", cf.VERSION + 1)  # this library moved on a version
    cal, warnings = cf.find(SERIAL, path)
    assert cal is not None and len(warnings) == 1 and "format version" in warnings[0]


def test_find_raises_for_a_malformed_file(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    path.write_text("{}", encoding="utf-8")
    with pytest.raises(CalibrationFileError):
        cf.find(SERIAL, path)


def test_the_write_is_atomic_a_failed_write_leaves_the_old_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cal.json"
    cf.save_section(path, SERIAL, "hand", {"method": "old"})
    before = path.read_bytes()

    def fail(*_: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError):
        cf.save_section(path, SERIAL, "hand", {"method": "new"})
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


def test_serial_of_uid_is_eight_hex_digits() -> None:
    assert cf.serial_of_uid(0x1000) == "00001000"
    assert cf.serial_of_uid(0xDEADBEEF) == "deadbeef"
