"""``make demo``'s own recordings, ``arm.mcap`` and ``hand.mcap`` given together, replay
exactly against the emulator that made them: the flash that ran beside the demo's hand on
the palm's link is in the hand's file (``/hand/frames/tx/others``), and every reply carries
its arrival time.  About 100 CPU s (the demo with ideal sensors, then its replay), so in the
long set; tests/tools/test_replay_beside_others.py checks both mechanisms in make test."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.hand.recording import FRAMES_OTHERS
from tools.cli.mcap_capture import read_recording
from tools.demo import command
from tools.hil_bench.cli import main

pytestmark = [pytest.mark.long, pytest.mark.timeout(1800)]


def test_the_demos_recordings_replay_exactly(capsys: pytest.CaptureFixture[str],
                                             tmp_path: Path) -> None:
    forget_shared_emulators()
    try:
        status = command.main(["--out", str(tmp_path), "--sensors", "ideal"])
    finally:
        forget_shared_emulators()
    out = capsys.readouterr().out
    assert status == 0, out
    hand = read_recording(tmp_path / "hand.mcap")
    assert sum(m.channel == FRAMES_OTHERS.name for m in hand.messages) > 100  # the flash
    code = main(["replay", str(tmp_path / "arm.mcap"), str(tmp_path / "hand.mcap"),
                 "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0, data["failing"]
    assert data["links"] == ["arm", "palm"] and data["exchanges"] > 10_000
    assert not data["assumed"]
