"""Recordings written as they go, read back up to a cut, and understood by a viewer."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil_emulator.inprocess import forget_shared_emulators
from host.errors import RecordingError
from host.hand.facade import Hand
from host.hand.recording import HandRecorder
from host.recording import writer as recording
from host.recording.writer import FLUSH_INTERVAL_S
from host.scheduling import HOST_RT_PRIORITY, Scheduling, priority_for, rtprio_limit
from tests.tools.mcap_check import check_recording
from tools.cli import armctl, handbus, handctl
from tools.cli.mcap_capture import read_recording

ROOT = Path(__file__).resolve().parents[2]
#: A hand without physics (quick to bring up) in this process, simulated time.
HAND_URL = "emu://hand/palm?physics=0&name=test-recordings"
ARM_URL = "emu://arm/arm?name=test-recordings"


@pytest.fixture(scope="module")
def hand_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 s of the hand, with chunks written every 50 ms of wall time instead of 0.5 s: the
    in-process emulator without physics runs 3 simulated seconds in well under 1.5 s of wall
    time, and the cut tests need several chunks to cut between."""
    path = tmp_path_factory.mktemp("rec") / "hand.mcap"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(recording, "FLUSH_INTERVAL_S", FLUSH_INTERVAL_S / 10)
        try:
            assert handctl.main(["--port", HAND_URL, "record", str(path), "--seconds", "3"]) == 0
        finally:
            forget_shared_emulators()
    return path


@pytest.fixture(scope="module")
def arm_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "arm.mcap"
    try:
        assert armctl.main(["--port", ARM_URL, "record", str(path), "--seconds", "1"],
                           out=io.StringIO()) == 0
    finally:
        forget_shared_emulators()
    return path


# ---------------------------------------------------------------- what a viewer reads


def test_a_hand_recording_is_valid_with_schemas_units_and_wall_clock_times(
        hand_recording: Path) -> None:
    counts = check_recording(hand_recording)
    # 3 s at 50 Hz on the link's clock: every state read, each with its frames
    assert counts["/hand/state"] == 151
    assert counts["/hand/frames/tx"] == counts["/hand/frames/rx"] > counts["/hand/state"]
    with hand_recording.open("rb") as stream:
        states = [(m.log_time, m.publish_time, json.loads(m.data)) for _s, c, m
                  in make_reader(stream).iter_messages(topics=["/hand/state"])]
    # the link's clock (simulated) is the publish time and the field t
    assert all(abs(pub / 1e9 - s["t"]) < 1e-6 for _log, pub, s in states)
    assert states[-1][1] - states[0][1] == pytest.approx(3e9, abs=1e6)


def test_an_arm_recording_is_valid_with_schemas_units_and_wall_clock_times(
        arm_recording: Path) -> None:
    counts = check_recording(arm_recording)
    assert counts["/arm/state"] == 100 and counts["/arm/bus/tx"] >= 100


def test_the_hand_tour_example_recording_is_valid(tmp_path: Path) -> None:
    from tools.examples import hand_tour

    path = tmp_path / "tour.mcap"
    hand_tour.main("emu://hand/palm?name=test-recordings-tour", str(path))
    assert check_recording(path)["/hand/state"] >= 5


def test_finger_events_and_finger_readings_are_recorded_as_they_come(tmp_path: Path) -> None:
    path = tmp_path / "events.mcap"
    with Hand.open(HAND_URL) as hand, HandRecorder(hand, path):
        hand.power(3, "off")
        hand.power(3, "full")
        hand.session.sleep(0.2)
        hand.finger_states([0, 1])
    forget_shared_emulators()
    counts = check_recording(path)
    assert counts["/hand/events"] >= 2 and counts["/hand/fingers"] == 1
    with path.open("rb") as stream:
        events = [json.loads(m.data)["event"] for _s, _c, m
                  in make_reader(stream).iter_messages(topics=["/hand/events"])]
    assert "unpowered" in events and "powered" in events


def test_a_recorder_follows_a_link_opened_again_in_the_same_file(tmp_path: Path) -> None:
    path = tmp_path / "reopened.mcap"
    first = Hand.open(HAND_URL)
    with HandRecorder(first, path) as recorder:
        first.status()
        first.close()
        with Hand.open(HAND_URL) as second:
            recorder.attach(second)
            second.status()
            second.status()
            assert not first.state_taps and recorder.states == 3
    forget_shared_emulators()
    assert check_recording(path)["/hand/state"] == 3


# ---------------------------------------------------------------- written as it goes


def test_a_recording_reaches_the_disk_while_it_runs_with_no_further_message(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    with Hand.open(HAND_URL) as hand, HandRecorder(hand, path) as recorder:
        for _ in range(5):
            hand.status()
        # the states are in the file before it is closed, within the flush interval
        deadline = time.monotonic() + 30  # a busy machine may starve the flushing thread
        while time.monotonic() < deadline:
            contents = read_recording(path)
            if sum(m.channel == "/hand/state" for m in contents.messages) == 5:
                break
            time.sleep(FLUSH_INTERVAL_S / 5)
        assert sum(m.channel == "/hand/state" for m in contents.messages) == 5
        assert contents.stopped and recorder.error is None  # no summary yet
    forget_shared_emulators()


@pytest.mark.skipif(not (os.geteuid() == 0 or rtprio_limit() > 0),
                    reason="real-time scheduling is not allowed here")
def test_the_flushing_thread_of_a_file_opened_by_a_real_time_loop_runs_real_time_too(
        tmp_path: Path) -> None:
    """It holds the file's lock while it writes: left at normal priority, a CPU-bound process
    could preempt it there and the real-time loop logging through the same lock would wait
    behind it (Linux does not pass SCHED_RR on to new threads)."""
    def open_and_wait(name: str) -> Scheduling | None:
        sink = recording.McapFile(tmp_path / name, library="test")
        deadline = time.monotonic() + 30
        while sink.flusher_scheduling is None and time.monotonic() < deadline:
            time.sleep(0.001)
        sink.close()
        return sink.flusher_scheduling

    got: list[Scheduling | None] = []

    def real_time() -> None:
        with priority_for("realtime", HOST_RT_PRIORITY) as asked:
            assert asked.realtime
            got.append(open_and_wait("rt.mcap"))

    thread = threading.Thread(target=real_time)
    thread.start()
    thread.join()
    assert got[0] is not None and got[0].realtime and got[0].priority == HOST_RT_PRIORITY
    normal = open_and_wait("normal.mcap")  # opened by a normally scheduled thread
    assert normal is not None and not normal.realtime


def test_an_output_that_cannot_be_written_is_refused_before_the_port_is_opened(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "no-such-dir" / "run.mcap"
    for main in (handctl.main, armctl.main):
        code = main(["--port", "/dev/no-such-port", "record", str(missing), "--seconds", "1"])
        err = capsys.readouterr().err
        assert code == 2, err
        assert f"cannot write the recording to {missing}" in err and "no-such-port" not in err


def test_a_recording_that_cannot_be_created_is_a_recording_error(tmp_path: Path) -> None:
    with Hand.open(HAND_URL) as hand, pytest.raises(RecordingError, match="cannot write"):
        HandRecorder(hand, tmp_path)  # a directory
    forget_shared_emulators()


def _run(argv: list[str], **options: object) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", *argv], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, **options)  # type: ignore[call-overload]


def test_a_full_disk_stops_the_recording_with_one_line() -> None:
    proc = _run(["tools.cli.handctl", "--port", HAND_URL, "record", "/dev/full", "--seconds", "6"])
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err
    assert err.strip().splitlines() == [
        "handctl: cannot write the recording to /dev/full: No space left on device; it "
        "stopped there, keeping the 0 messages written before"]


def test_a_full_disk_stops_an_arm_recording_with_one_line(
        capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = armctl.main(["--port", ARM_URL, "record", "/dev/full", "--seconds", "6"],
                           out=io.StringIO())
    finally:
        forget_shared_emulators()
    err = capsys.readouterr().err
    assert code == 1, err
    assert err.strip().splitlines() == [
        "armctl: cannot write the recording to /dev/full: No space left on device; it "
        "stopped there, keeping the 0 messages written before"]


def _limit_file_size(limit: int) -> None:
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.slow
def test_a_disk_that_fills_mid_run_keeps_what_was_written(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    proc = _run(["tools.cli.handctl", "--port", HAND_URL, "record", str(path), "--seconds", "30"],
                preexec_fn=lambda: _limit_file_size(60_000))
    _out, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err
    assert len(err.strip().splitlines()) == 1 and "it stopped there, keeping the " in err
    kept = int(err.split("keeping the ")[1].split()[0])
    contents = read_recording(path)
    assert contents.stopped and 0 < kept <= len(contents.messages)
    assert path.stat().st_size <= 60_000


@pytest.mark.slow
def test_kill_9_leaves_a_file_that_decodes_up_to_shortly_before_the_kill(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    proc = _run(["tools.cli.handctl", "--port", HAND_URL, "record", str(path), "--seconds", "60"])
    try:
        deadline = time.monotonic() + 300
        span = 0.0
        while span < 2.0 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if path.exists() and path.stat().st_size > 0:
                states = [m for m in read_recording(path).messages if m.channel == "/hand/state"]
                span = (states[-1].publish_time_ns - states[0].publish_time_ns) / 1e9 \
                    if states else 0.0
        time.sleep(1.0)
        killed_at = time.time_ns()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert span >= 2.0
    contents = read_recording(path)
    frames = [m for m in contents.messages if m.channel.startswith("/hand/frames/")]
    assert frames and contents.stopped
    # what the process logged until about a second before it was killed is there (a busy
    # machine may have paused it for a while before the kill, hence the margin)
    assert frames[-1].log_time_ns >= killed_at - (1.0 + FLUSH_INTERVAL_S + 1.0) * 1e9
    out = subprocess.run([sys.executable, "-m", "tools.cli.handbus", "decode", str(path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == handbus.EXIT_CUT, out.stderr
    assert json.loads(out.stdout.splitlines()[-1])["summary"]["frames"] == len(frames)


# ---------------------------------------------------------------- read up to a cut


def _frames(capsys: pytest.CaptureFixture[str], path: Path, *argv: str
            ) -> tuple[int, list[dict], str]:
    code = handbus.main(["decode", *argv, str(path)])
    out, err = capsys.readouterr()
    lines = [json.loads(line) for line in out.splitlines()]
    return code, lines, err


def _reference_frames_before_the_cut(data: bytes) -> int:
    """Hand frames the reference streaming reader gives before it stops at the cut."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics: dict[int, str] = {}
    frames = 0
    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message) and topics[record.channel_id].startswith(
                    "/hand/frames/"):
                frames += 1
    except Exception:  # noqa: BLE001 - where it stops is the cut
        pass
    return frames


@pytest.mark.parametrize("cut", [100, 1000, 20_000, "mid-chunk"])
def test_a_cut_recording_decodes_every_whole_message_before_the_cut(
        hand_recording: Path, tmp_path: Path, cut: int | str,
        capsys: pytest.CaptureFixture[str]) -> None:
    data = hand_recording.read_bytes()
    with hand_recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 3  # written as it went: a chunk at least every flush interval
    if cut == "mid-chunk":
        middle = chunks[len(chunks) // 2]
        size = middle.chunk_start_offset + middle.chunk_length // 2
    else:
        size = len(data) - int(cut)
    short = tmp_path / "cut.mcap"
    short.write_bytes(data[:size])
    whole = _reference_frames_before_the_cut(data[:size])
    code, lines, err = _frames(capsys, short)
    assert code == handbus.EXIT_CUT == 3
    *records, last = lines
    assert len(records) == last["summary"]["frames"] >= whole > 0
    assert all(r["crc_ok"] for r in records)
    unread = len(data[:size]) - read_recording(short).end
    assert err.startswith(f"handbus: warning: {short} is cut short: the last {unread} of its "
                          f"{size} bytes")
    assert err.count("\n") == 1 and "--dynamixel" not in err
    # each channel's frames decoded are the whole recording's first ones, in order
    _, full, _ = _frames(capsys, hand_recording)
    for topic in ("/hand/frames/tx", "/hand/frames/rx"):
        mine = [r for r in records if r["channel"] == topic]
        assert mine and mine == [r for r in full if r.get("channel") == topic][:len(mine)]


def test_an_empty_file_is_an_error_not_an_empty_success(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("empty.mcap", "empty.bin"):
        path = tmp_path / name
        path.write_bytes(b"")
        code, lines, err = _frames(capsys, path)
        assert code == 2 and lines == []
        assert err == f"handbus: error: {path} is empty (0 bytes): nothing to decode\n"


def test_a_file_named_mcap_that_is_not_one_says_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "plot.mcap"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    code, lines, err = _frames(capsys, path)
    assert code == 2 and lines == []
    assert err == f"handbus: error: {path} is not an MCAP recording: it is a PNG image\n"


def test_an_mcap_cut_inside_its_first_record_says_so(
        hand_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "stub.mcap"
    path.write_bytes(hand_recording.read_bytes()[:12])
    code, lines, err = _frames(capsys, path)
    assert code == 2 and lines == []
    assert "is an MCAP file with no channel before its cut at byte 8" in err


def test_hints_name_only_what_applies(hand_recording: Path, arm_recording: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _frames(capsys, hand_recording, "--dynamixel")
    assert code == 2
    assert "has no arm bus bytes" in err and "decode without --dynamixel" in err
    code, _, err = _frames(capsys, arm_recording)
    assert code == 2
    assert "has no hand frames" in err and "decode with --dynamixel" in err
    assert "without" not in err
