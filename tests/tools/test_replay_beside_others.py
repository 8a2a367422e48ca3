"""A recording replays exactly though another program used the link while it recorded (a
flasher beside the hand's own link, as in ``make demo``), and though the host read a link's
replies late because it was busy with another link: the recorders keep what the others sent
(``/…/tx/others``) and stamp each reply with its arrival on the emulator's clock."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_emulator.inprocess import EmulatorTransport, forget_shared_emulators
from host.arm.facade import Arm
from host.arm.recording import OTHERS_TOPIC, ArmRecorder
from host.arm.state import JOINT_IDS, JOINT_NAMES
from host.hand.facade import Hand
from host.hand.recording import FRAMES_OTHERS, HandRecorder
from host.recording.writer import SOURCE_METADATA
from protocol.control_tables import RX64_TABLE
from protocol.dynamixel import make_write
from tools.cli.mcap_capture import read_recording
from tools.hil_bench.cli import main
from tools.hil_bench.replay.session import replay

HAND_URL = "emu://hand/palm?seed=3&name=test-replay-others"
ARM_URL = "emu://arm/arm?seed=3&name=test-replay-others"


def _replay_code(capsys: pytest.CaptureFixture[str], *paths: Path) -> tuple[int, dict]:
    code = main(["replay", *map(str, paths), "--json"])
    return code, json.loads(capsys.readouterr().out)


def _spread(path: Path, channel: str) -> float:
    values = replay(path).channels[channel].recorded
    return max(values) - min(values)


def test_a_second_program_moving_a_finger_while_the_hand_records_replays_exactly(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "hand.mcap"
    forget_shared_emulators()
    try:
        with Hand.open(HAND_URL) as hand, HandRecorder(hand, path) as recorder:
            recorder.record(0.1, 20.0)
            # another program takes the link for a while (the link's bytes go to it) and
            # moves finger 2, which the recorded program never commands
            with Hand.open(HAND_URL) as other:
                other.fingers[2].move([0.0, 0.6, 0.5], effort=200, timeout=1.0, unhomed=True)
            recorder.record(0.3, 20.0)
    finally:
        forget_shared_emulators()
    contents = read_recording(path)
    assert contents.metadata[SOURCE_METADATA]["others"] == "kept"
    assert sum(m.channel == FRAMES_OTHERS.name for m in contents.messages) > 0
    # finger 2 moved in the recorded readings only because of the other program's frames:
    # a replay that left them out could not agree
    assert _spread(path, "hand.finger2.fmcb.status.hall_pos[1]") > 20
    code, data = _replay_code(capsys, path)
    assert code == 0, data["failing"]


def test_a_second_program_writing_to_a_servo_while_the_arm_records_replays_exactly(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "arm.mcap"
    servo_id, servo_name = JOINT_IDS[-1], JOINT_NAMES[-1]
    goal = RX64_TABLE["goal_position"]
    torque = RX64_TABLE["torque_enable"]
    forget_shared_emulators()
    try:
        with Arm.open(ARM_URL) as arm, ArmRecorder(arm, path):
            arm.cycle()
            other = EmulatorTransport.from_url(ARM_URL)
            try:  # a plain SDK-style program: torque on and a goal 60° away, no reads
                other.send(make_write(servo_id, torque.address, b"\x01").encode())
                other.sleep(0.01)
                other.send(make_write(servo_id, goal.address,
                                      (512 + 205).to_bytes(2, "little")).encode())
                other.sleep(0.01)
            finally:
                other.close()
            for _ in range(60):
                arm.cycle()
                arm.transport.sleep(0.01)
    finally:
        forget_shared_emulators()
    contents = read_recording(path)
    assert contents.metadata[SOURCE_METADATA]["others"] == "kept"
    assert sum(m.channel == OTHERS_TOPIC for m in contents.messages) == 2
    assert _spread(path, f"arm.{servo_name}.present_position") > 0.2
    code, data = _replay_code(capsys, path)
    assert code == 0, data["failing"]


def test_a_reply_read_late_is_stamped_when_it_arrived() -> None:
    """The host asks the palm, then waits on another link for 25 ms (within the reply's
    budget): the reply, read at the end of the wait, carries the time it arrived (what a
    replay reproduces), not the time it was read."""
    forget_shared_emulators()
    try:
        with Hand.open(HAND_URL) as hand:
            seen: list[tuple[str, float]] = []
            hand.session.taps.append(lambda direction, t, _frame: seen.append((direction, t)))
            pending = hand.session.start("palm.hand_status")
            sent_at = hand.session.now()
            transport = hand.session.transport
            assert isinstance(transport, EmulatorTransport)
            transport.emulator.step(25_000)  # the host busy elsewhere: nothing read
            hand.session.wait(pending)
            read_at = hand.session.now()
    finally:
        forget_shared_emulators()
    replies = [t for direction, t in seen if direction == "rx"]
    assert len(replies) == 1
    assert read_at - sent_at >= 0.025
    assert sent_at < replies[0] < read_at - 0.01  # its arrival, not the read


def test_a_reply_waiting_unread_past_its_deadline_is_taken_not_retried() -> None:
    """The host asks the palm, then is busy elsewhere for longer than the reply's budget:
    the reply came in time and waits unread, so the session takes it instead of timing
    the request out and sending it again."""
    forget_shared_emulators()
    try:
        with Hand.open(HAND_URL) as hand:
            sent: list[float] = []
            hand.session.taps.append(
                lambda direction, t, _frame: sent.append(t) if direction == "tx" else None)
            pending = hand.session.start("palm.hand_status")
            transport = hand.session.transport
            assert isinstance(transport, EmulatorTransport)
            transport.emulator.step(200_000)  # well past the budget
            reply = hand.session.wait(pending)
    finally:
        forget_shared_emulators()
    assert reply
    assert len(sent) == 1 and hand.session.counters.retries == 0
