"""``hil-bench replay``: a recording replayed against the emulator that made it agrees
exactly; against another seed, other sensors or a perturbed plant it names the channels that
part; recordings it cannot replay are refused with one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from host.recording.writer import SOURCE_METADATA, Recording, Topic
from tools.cli.mcap_capture import read_recording
from tools.hil_bench.cli import main
from tools.hil_bench.replay.session import build_emulator, replay
from tools.hil_bench.replay.source import Recorded

ARM_URL = "emu://arm/arm?seed=5&name=test-replay"
HAND_URL = "emu://hand/palm?seed=5&name=test-replay"
#: The arm's move: J2 and J4 bend, J6 turns (rad).
GOAL = [0.0, 0.3, 0.0, 0.4, 0.0, 0.2, 0.0]


@pytest.fixture(scope="module")
def arm_move(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The arm enabled and moved on ``emu://``, recorded from after the link opened."""
    path = tmp_path_factory.mktemp("replay") / "arm-move.mcap"
    forget_shared_emulators()
    try:
        with Arm.open(ARM_URL) as arm:
            arm.cycle()  # the setup before the recorder: in the file's prologue
            with ArmRecorder(arm, path):
                arm.cycle([arm.make_torque(j, True) for j in range(7)])
                _state, _settled = arm.move(GOAL, duration=0.6, timeout=2.0)
                arm.torque(False)
    finally:
        forget_shared_emulators()
    return path


@pytest.fixture(scope="module")
def hand_move(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finger closed on ``emu://`` and the hand's state read, recorded."""
    path = tmp_path_factory.mktemp("replay") / "hand-move.mcap"
    forget_shared_emulators()
    try:
        with Hand.open(HAND_URL) as hand, HandRecorder(hand, path) as recorder:
            hand.status()
            hand.fingers[1].move([0.0, 0.5, 0.4], effort=200, timeout=1.0, unhomed=True)
            recorder.record(0.2, 20.0)
    finally:
        forget_shared_emulators()
    return path


def _replay_json(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code = main(["replay", *args, "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


def _moved(data: dict, name: str) -> bool:
    """The recording's values of channel ``name`` changed (the test replays a motion)."""
    result = replay(data["recording"])
    values = result.channels[name].recorded
    return max(values) - min(values) > 0


# ------------------------------------------------------------------------- agreement

def test_the_recording_says_where_it_came_from_and_keeps_the_setup_before_it(
        arm_move: Path) -> None:
    contents = read_recording(arm_move)
    source = contents.metadata[SOURCE_METADATA]
    assert source["url"] == ARM_URL and source["link"] == "arm"
    assert source["prologue"] == "complete"
    start = float(source["start_t"])
    before = [m for m in contents.messages if m.channel == "/arm/bus/tx"
              and m.publish_time_ns / 1e9 < start]
    assert before  # the Arm's opening and its first cycle


def test_an_arm_move_replays_exactly_against_the_emulator_that_made_it(
        arm_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, data, _err = _replay_json(capsys, str(arm_move))
    assert code == 0, data["failing"]
    assert data["within"] and data["failing"] == []
    assert data["emulator"]["seed"] == 5 and data["from_recording"]
    channels = data["channels"]
    assert all(c["max"] == 0 for c in channels.values())
    # it compared the motion itself: the joints' positions and deflections, the timing
    for name in ("arm.J2.cycle_present_position", "arm.J4.cycle_deflection",
                 "arm.J6.present_position", "arm.J2.reply_us", "arm.J1.error"):
        assert channels[name]["samples"] > 10, name
    assert _moved(data, "arm.J2.cycle_present_position")


def test_a_differently_seeded_arm_disagrees_naming_the_channels(
        arm_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, data, err = _replay_json(capsys, str(arm_move), "--seed", "6")
    assert code == 1
    assert not data["within"] and data["failing"]
    first = data["failing"][0]
    assert first.startswith("arm.J") and first in err
    bad = data["channels"][first]
    assert bad["max"] > bad["tolerance"] and bad["first_exceeded_t"] is not None
    assert len(bad["t"]) == len(bad["recorded"]) == len(bad["replayed"]) == bad["samples"]


def test_a_softer_spring_in_the_emulator_shows_in_that_joint(arm_move: Path) -> None:
    def softer_j2(recording: Recorded) -> Emulator:
        emulator = build_emulator(recording)
        plant = emulator.require_arm_plant()
        plant.set_stiffness(1, plant.stiffness[1] * 0.7)
        return emulator

    result = replay(arm_move, emulator_factory=softer_j2)
    assert not result.within
    assert any(n.startswith("arm.J2.") and "deflection" in n for n in result.failing)


def test_a_tolerance_wider_than_the_error_passes_the_channel(
        arm_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _code, data, _err = _replay_json(capsys, str(arm_move), "--seed", "6")
    widened = [f"--tolerance={name}={data['channels'][name]['max']}"
               for name in data["failing"]]
    code, again, _err = _replay_json(capsys, str(arm_move), "--seed", "6", *widened)
    assert code == 0 and again["within"]


def test_a_hand_move_replays_exactly_and_other_sensors_disagree(
        hand_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, data, _err = _replay_json(capsys, str(hand_move))
    assert code == 0, data["failing"]
    names = data["channels"]
    assert any(n.startswith("hand.finger1.fmcb.status.") for n in names)
    assert any(".tactile" in n or "tactile" in n for n in names)
    assert _moved(data, "hand.finger1.fmcb.status.hall_pos[1]")
    code, ideal, err = _replay_json(capsys, str(hand_move), "--sensors", "ideal")
    assert code == 1
    assert ideal["failing"] and all(n.startswith("hand.") for n in ideal["failing"])
    assert ideal["failing"][0] in err
    assert any("sensors 'ideal'" in a for a in ideal["assumed"])


def test_the_report_has_the_table_the_plots_and_the_json(
        arm_move: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(arm_move), "--seed", "6", "--report", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "replay disagrees" in out
    text = (tmp_path / "replay.md").read_text()
    data = json.loads((tmp_path / "replay.json").read_text())
    first = data["failing"][0]
    assert f"`{first}`" in text
    plots = sorted(tmp_path.glob("*.png"))
    assert plots and all(p.stat().st_size > 1000 for p in plots)
    assert any(p.name.startswith(first) for p in plots)
    assert all(f"]({p.name})" in text for p in plots)


# ------------------------------------------------------------------------- refusals

def _refused(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    assert main(["replay", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("hil-bench replay: ")
    return err


def test_a_recording_without_host_bytes_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "states-only.mcap"
    topic = Topic("/arm/state", "json")
    recording = Recording(path, [topic], library="test")
    recording.log(topic, 0.1, b"{}")
    recording.close_sinks()
    assert "no host bytes" in _refused(capsys, str(path))


def test_an_unknown_channel_is_refused(arm_move: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    err = _refused(capsys, str(arm_move), "--tolerance", "arm.J9.nothing=1")
    assert "unknown channel 'arm.J9.nothing'" in err


def test_an_emulator_that_cannot_be_built_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "elsewhere.mcap"
    tx = Topic("/arm/bus/tx", "application/octet-stream")
    recording = Recording(path, [tx], library="test", metadata={SOURCE_METADATA: {
        "link": "arm", "url": "emu://hand/palm?seed=1", "start_t": "0.0",
        "prologue": "complete"}})
    recording.log(tx, 0.1, bytes.fromhex("ffff0102010000fb"))
    recording.close_sinks()
    assert "has no arm link" in _refused(capsys, str(path))
    path.write_bytes(path.read_bytes().replace(b"emu://hand/palm", b"emu://left/palm"))
    assert "unknown emulator configuration" in _refused(capsys, str(path))


def test_a_file_that_is_no_recording_is_refused(
        tmp_path: Path, arm_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert "cannot read it" in _refused(capsys, str(junk))
    head = tmp_path / "head.mcap"
    head.write_bytes(arm_move.read_bytes()[:40])  # the magic and part of the header
    assert "no host bytes" in _refused(capsys, str(head))
    assert "cannot read it" in _refused(capsys, str(tmp_path / "missing.mcap"))


def test_a_recording_cut_short_replays_what_it_has_and_says_so(
        arm_move: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    whole = arm_move.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    code, data, _err = _replay_json(capsys, str(cut))
    assert code == 0, data["failing"]
    assert "cut short" in data["truncated"]
    full = replay(arm_move)
    assert 0 < data["exchanges"] < full.exchanges



def test_a_recording_of_a_serial_port_replays_on_an_assumed_emulator_and_says_so(
        arm_move: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A serial port names no emulator: the default one for the recorded link is assumed,
    the times are shifted onto its clock, and the output says both."""
    path = tmp_path / "serial.mcap"
    topics = {name: Topic(name, "application/octet-stream")
              for name in ("/arm/bus/tx", "/arm/bus/rx")}
    recording = Recording(path, list(topics.values()), library="test", metadata={
        SOURCE_METADATA: {"link": "arm", "url": "/dev/ttyUSB0", "start_t": "1000.0",
                          "prologue": "complete", "earlier": "unknown"}})
    for m in read_recording(arm_move).messages:
        if m.channel in topics:  # the same bytes, on a clock 1000 s later
            recording.log(topics[m.channel], 1000.0 + m.publish_time_ns / 1e9, m.data)
    recording.close_sinks()
    code, data, _err = _replay_json(capsys, str(path))
    assert code in (0, 1)
    assert not data["from_recording"] and data["emulator"]["config"] == "arm"
    assert any("/dev/ttyUSB0" in a and "assumed" in a for a in data["assumed"])
    assert any("shifted" in n for n in data["notes"])
    # on the right clock: the replies came, the nodes answered as the arm's do
    assert data["channels"]["arm.J2.replied"]["max"] == 0


def test_one_sessions_arm_and_hand_recordings_replay_together_on_one_emulator(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``make demo``'s shape: the hand on the arm, one emulator, a recorder per link; the
    two files given together drive both links of one emulator, as the session did."""
    url = "emu://full/{link}?seed=5&name=test-replay-full"
    arm_path, hand_path = tmp_path / "arm.mcap", tmp_path / "hand.mcap"
    forget_shared_emulators()
    try:
        with Arm.open(url.format(link="arm")) as arm, \
                Hand.open(url.format(link="palm")) as hand, \
                ArmRecorder(arm, arm_path), HandRecorder(hand, hand_path):
            arm.cycle([arm.make_torque(j, True) for j in range(7)])
            arm.move(GOAL, duration=0.6, timeout=2.0)
            hand.fingers[1].move([0.0, 0.5, 0.4], effort=200, timeout=1.0, unhomed=True)
            hand.status()
            arm.torque(False)
    finally:
        forget_shared_emulators()
    code, data, _err = _replay_json(capsys, str(arm_path), str(hand_path))
    assert code == 0, data["failing"]
    assert data["links"] == ["arm", "palm"] and data["emulator"]["config"] == "full"
    names = data["channels"]
    assert any(n.startswith("arm.J2.") for n in names)
    assert any(n.startswith("hand.finger1.") for n in names)


def test_recordings_of_two_emulators_are_refused_together(
        arm_move: Path, hand_move: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(arm_move), str(hand_move)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another emulator" in err[0]
    assert main(["replay", str(arm_move), str(arm_move)]) == 2
    assert "repeats the arm link" in capsys.readouterr().err
