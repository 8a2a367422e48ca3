"""hil-fuzz end to end on the emulator in process: a planted defect is found, shrunk to the
one frame, saved and replayed; the project's own firmware survives a short campaign."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from firmware_py.sim import boards
from protocol.messages import CATALOGUE
from protocol.strategies import mutate_frame
from tests.tools.fuzz_planted import HANGING_INDEX, PROGRAM
from tools import hil_fuzz
from tools.fuzz.campaign import replay, run_campaign
from tools.fuzz.steps import Reproducer, Step
from tools.fuzz.targets import TARGETS, TargetLink, is_motion_frame


@pytest.fixture
def planted_fmcb(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every fmcb the emulator builds from now on runs the planted program."""
    monkeypatch.setitem(boards.APP_PROGRAMS, "fmcb", PROGRAM)


def test_planted_hang_is_found_shrunk_saved_and_replayed(
        planted_fmcb: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Focused on the parameter messages so the default run stays short; bench_fuzz.py
    # measures how fast it is found (over seeds).
    code = hil_fuzz.main(["--target", "fmcb", "--examples", "300", "--seed", "2",
                          "--steps", "10", "--messages", "fmcb.param_*",
                          "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 1, out
    assert "no longer answers a ping" in out
    files = list(tmp_path.glob("fmcb-seed*.json"))
    assert len(files) == 1
    saved = json.loads(files[0].read_text())
    assert saved["target"] == "fmcb"
    assert len(saved["steps"]) == 1, saved["steps"]  # shrunk to the one frame
    rep = Reproducer.load(files[0])
    param_set = CATALOGUE["fmcb.param_set"]
    data = rep.steps[0].data
    assert data[4] == param_set.type_id
    assert param_set.parse_request(data[5:-2])["index"] == HANGING_INDEX
    assert hil_fuzz.main(["replay", str(files[0])]) == 1
    assert "reproduced" in capsys.readouterr().out


def test_replay_of_the_planted_frame_does_not_reproduce_on_the_real_firmware(
        tmp_path: Path) -> None:
    frame = CATALOGUE["fmcb.param_set"].request_frame(10, index=HANGING_INDEX, value=bytes(4))
    rep = Reproducer("fmcb", 0, [Step("fmcb.param_set", ((frame, 0),))], "hang")
    path = rep.save(tmp_path)
    assert replay(Reproducer.load(path)) is None
    assert hil_fuzz.main(["replay", str(path)]) == 0


def test_silent_frames_stay_silent_and_ping_answers() -> None:
    link = TargetLink.open(TARGETS["fmcb"], TARGETS["fmcb"].url)
    try:
        assert link.alive()
        ping = CATALOGUE["identify"].request_frame(10)
        for how in ("bad_crc", "foreign_address"):
            link.write(((mutate_frame(ping, how, 3), 0),))
            assert link.answers(link.listen(0.02)) == []
        link.write(((ping, 0),))
        assert [f.type for f in link.answers(link.listen(0.02))] == [0x60]
    finally:
        link.close()


def test_motion_commands_are_recognised() -> None:
    control = CATALOGUE["fmcb.control"]
    assert is_motion_frame(control.request_frame(10, mode=1, args={"hall_target": [1, 2, 3]}),
                           "fmcb")
    assert not is_motion_frame(control.request_frame(10, mode=0, args={}), "fmcb")
    inner = control.request_frame(10, mode=2, args={"target": [0.1, 0.2, 0.3]})
    routed = CATALOGUE["palm.route"].request_frame(10, finger=1, hop=0, timeout_ms=0,
                                                   frame=inner)
    assert is_motion_frame(routed, "palm")
    txn = CATALOGUE["txn"].request_frame(10, seq=1, inner_type=control.type_id,
                                         inner=inner[5:-2])
    assert is_motion_frame(txn, "fmcb")
    assert not is_motion_frame(mutate_frame(inner, "bad_crc", 0), "fmcb")


@pytest.mark.parametrize("target", ["fmcb", "f2", "f3", "bootloader", "arm"])
def test_short_campaign_finds_nothing_in_our_firmware(target: str) -> None:
    result = run_campaign(target, examples=4, seed=2, steps=6)
    assert result.reproducer is None, (result.reproducer.failure,
                                       [str(s) for s in result.reproducer.steps])
    assert result.examples >= 4


@pytest.mark.slow
@pytest.mark.parametrize("target", sorted(TARGETS))
def test_longer_campaign_finds_nothing_in_our_firmware(target: str) -> None:
    result = run_campaign(target, examples=40, seed=5, steps=15)
    assert result.reproducer is None, (result.reproducer.failure,
                                       [str(s) for s in result.reproducer.steps])
