"""``handbus decode RUN.mcap``: the raw-frame channels of handctl/armctl recordings."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil_emulator.inprocess import forget_shared_emulators
from tools.cli import armctl, handbus, handctl
from tools.cli.mcap_capture import MCAP_MAGIC, is_mcap, raw_chunks, read_recording


def _decode(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[list[dict], dict]:
    assert handbus.main(["decode", *argv]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    return lines[:-1], lines[-1]["summary"]


@pytest.fixture(scope="module")
def hand_mcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mcap") / "hand.mcap"
    url = "emu://hand/palm?name=test_handbus_mcap"
    assert handctl.main(["--port", url, "--json", "record", str(path), "--seconds", "0.1"]) == 0
    forget_shared_emulators()
    return path


def test_a_hand_recording_decodes_frame_by_frame(hand_mcap: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert is_mcap(hand_mcap) and hand_mcap.read_bytes().startswith(MCAP_MAGIC)
    records, summary = _decode(capsys, str(hand_mcap))
    with hand_mcap.open("rb") as stream:
        frames = [(ch.topic, msg.log_time, msg.data) for _, ch, msg
                  in make_reader(stream).iter_messages(log_time_order=False)
                  if ch.topic.startswith("/hand/frames/")]
    assert len(records) == len(frames) == summary["frames"] > 10
    assert all(r["crc_ok"] for r in records)
    for topic in ("/hand/frames/tx", "/hand/frames/rx"):
        mine = [r for r in records if r["channel"] == topic]
        theirs = [(t, d) for c, t, d in frames if c == topic]  # in the order written
        # one record per recorded frame, at its log time, with its length and type
        assert [r["t"] for r in mine] == [t / 1e9 for t, _ in theirs]  # wall clock
        assert [r["length"] + 7 for r in mine] == [len(d) for _, d in theirs]
        assert [r["type"] for r in mine] == [d[4] for _, d in theirs]
    names = {r["name"] for r in records}
    assert "txn" in names
    # the same JSON as decoding the channel's bytes as a raw capture, plus channel and t
    tx = b"".join(c.data for c in raw_chunks(hand_mcap, "hand-frame")
                  if c.channel == "/hand/frames/tx")
    raw_path = hand_mcap.with_suffix(".bin")
    raw_path.write_bytes(tx)
    raw, _ = _decode(capsys, str(raw_path))
    assert raw == [{k: v for k, v in r.items() if k not in ("channel", "t", "t_link")}
                   for r in records if r["channel"] == "/hand/frames/tx"]


def test_a_hand_recording_without_arm_channels_says_so(
        hand_mcap: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert handbus.main(["decode", "--dynamixel", str(hand_mcap)]) == 2
    assert "application/octet-stream" in capsys.readouterr().err


def test_an_arm_recording_decodes_with_dynamixel(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "arm.mcap"
    url = "emu://arm/arm?name=test_handbus_mcap"
    try:
        assert armctl.main(["--port", url, "record", str(path), "--seconds", "0.1"],
                           out=io.StringIO()) == 0
    finally:
        forget_shared_emulators()
    capsys.readouterr()
    records, summary = _decode(capsys, "--dynamixel", str(path))
    # the recording opens with what the arm sent before the recorder attached (its prologue:
    # the Arm's opening); then the 10 cycles
    start = float(read_recording(path).metadata["source"]["start_t"])
    assert any(r["t_link"] < start for r in records)
    # (a reply comes strictly after its request; the last prologue reply may end at start)
    rx = [r for r in records if r["channel"] == "/arm/bus/rx" and r["t_link"] > start]
    tx = [r for r in records if r["channel"] == "/arm/bus/tx" and r["t_link"] >= start]
    # 10 cycles at 100 Hz: each a BULK_READ of the 7 joints (commands only when given)
    assert sum(1 for r in tx if r["name"] == "BULK_READ") == 10
    assert [r["id"] for r in rx] == list(range(1, 8)) * 10
    times = [r["t_link"] for r in rx]  # the link's clock (simulated); "t" is the wall clock
    assert times == sorted(times) and times[-1] - times[0] == pytest.approx(0.09, abs=0.005)
    assert all(r["checksum_ok"] for r in records) and summary



def test_a_file_with_the_mcap_magic_but_no_recording_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "short.mcap"
    path.write_bytes(MCAP_MAGIC)
    assert handbus.main(["decode", str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "is an MCAP file with no channel before its cut at byte 8" in err
    assert "Traceback" not in err
