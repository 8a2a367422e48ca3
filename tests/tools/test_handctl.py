"""handctl on the emulated hand: in process (emu://) and through the emulator's pty."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import bring_up
from protocol.framing import parse_frame
from tests.hil_emulator.emulator_thread import serving
from tools.cli.handctl import main

URL = "emu://hand/palm?name=host-tests"


def _json(capsys: pytest.CaptureFixture[str]) -> dict:
    return json.loads(capsys.readouterr().out)


def test_json_status_gives_four_fingers_with_joints_taxels_and_currents(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "--json", "status"]) == 0
    fingers = _json(capsys)["fingers"]
    assert len(fingers) == 4
    f0 = fingers[0]
    assert set(f0) >= {"joints", "joints_hall", "tactile", "currents", "present", "power"}
    assert f0["present"] and f0["power"] == "full" and len(f0["joints"]) == 3
    assert len(f0["tactile"]["proximal"]) == 6 and len(f0["tactile"]["distal"]) == 12
    assert f0["currents"]["phalange_bus"] is not None
    # The wire carries raw ADC counts; the host shows engineering units: the emulated fmcb
    # runs on 24 V with motors at the plant's ambient (about 25 °C).
    assert f0["supply_v"] == pytest.approx(24.0, abs=0.05)
    assert all(15 < t < 60 for t in f0["temperatures_c"])


def test_move_waits_until_the_finger_settles(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "--json", "move", "--finger", "0", "--joints",
                 "0.2,0.4,0.3", "--effort", "200", "--unhomed"]) == 0
    out = _json(capsys)
    assert out["settled"]
    assert out["fingers"]["0"]["joints"] == pytest.approx([0.2, 0.4, 0.3], abs=0.15)


def test_a_target_beyond_the_joint_limit_is_refused_without_a_traceback(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "move", "--finger", "0", "--joints", "0,2.5,0"]) == 2
    err = capsys.readouterr().err
    assert "joint limit" in err and "Traceback" not in err


def test_a_wrong_port_says_what_to_check(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", "/dev/no-such-hand", "status"]) == 1
    err = capsys.readouterr().err
    assert "/dev/no-such-hand" in err and "Check the path" in err and "Traceback" not in err


def test_record_writes_frames_and_states_to_mcap(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    assert main(["--port", URL, "--json", "record", str(path), "--seconds", "0.1"]) == 0
    summary = _json(capsys)
    topics: dict[str, int] = {}
    with path.open("rb") as stream:
        for _schema, channel, message in make_reader(stream).iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            if channel.topic.startswith("/hand/frames/"):
                parse_frame(message.data)  # raw frames, whole and CRC-valid
            elif channel.topic == "/hand/state":
                assert len(json.loads(message.data)["fingers"]) == 4
    assert topics["/hand/state"] == summary["states"] >= 5
    assert topics["/hand/frames/tx"] + topics["/hand/frames/rx"] == summary["frames"]


@pytest.fixture(scope="module")
def palm_pty() -> Iterator[str]:
    """An emulated hand (firmware only, no physics) serving its palm pty in real time."""
    emulator = Emulator("hand", physics=False, can="none")
    bring_up(emulator)
    with serving(emulator) as run:
        yield run.ports["palm"]


def test_ping_through_the_emulators_pty_finds_every_node(
        palm_pty: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", palm_pty, "--json", "ping"]) == 0
    nodes = _json(capsys)["nodes"]
    assert len(nodes) == 13 and all(n["running"] == "application" for n in nodes)


def test_power_and_status_through_the_emulators_pty(
        palm_pty: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", palm_pty, "--json", "power", "2", "off"]) == 0
    assert _json(capsys)["power"] == ["full", "full", "off", "full"]
    assert main(["--port", palm_pty, "--json", "status"]) == 0
    fingers = _json(capsys)["fingers"]
    assert [f["present"] for f in fingers] == [True, True, False, True]


def test_status_exits_1_naming_a_powered_finger_that_does_not_answer(
        capsys: pytest.CaptureFixture[str]) -> None:
    from hil_emulator.inprocess import EmulatorTransport

    url = "emu://hand/palm?physics=0&name=status-silent"
    probe = EmulatorTransport.from_url(url)
    probe.emulator.break_away(1)  # off its pogo pins: the palm still powers its slot
    probe.close()
    assert main(["--port", url, "status"]) == 1
    captured = capsys.readouterr()
    assert "finger 1: power full, not answering (no_reply" in captured.out
    # before it: which calibration the estimates use (tests/tools/test_handctl_calibration.py)
    assert captured.err.splitlines()[-1] == "handctl: finger(s) 1 powered but not answering"


@pytest.mark.parametrize(("seen", "says"), [
    ({"bytes_discarded": 4096, "crc_failures": 3, "stale_replies": 0}, "garbage on the line"),
    ({"bytes_discarded": 0, "crc_failures": 0, "stale_replies": 2}, "try --timeout 0.5"),
    ({"bytes_discarded": 0, "crc_failures": 0, "stale_replies": 0}, "nothing came back"),
])
def test_the_advice_for_a_finger_that_did_not_reply_fits_what_the_link_carried(
        seen: dict[str, int], says: str) -> None:
    from tools.cli.handctl import _no_reply_advice

    advice = _no_reply_advice(seen)
    assert says in advice
    assert ("--timeout" in advice) == (says == "try --timeout 0.5")  # never a guess
