"""docs/HOST.md's examples run: each program in tools/examples/ on ``emu://``, and every
Python block of the guide is a fragment of one of them (so the guide cannot drift)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from firmware_py.fmcb_params import FMCB_PARAMS
from tools.examples import arm_tour, hand_tour, session_tour

#: The fmcb's deadband at power-up (hall counts), as its firmware declares it.
FMCB_DEFAULT_DEADBAND = next(p.default for p in FMCB_PARAMS if p.name == "deadband")

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "HOST.md"
EXAMPLES = sorted((ROOT / "tools" / "examples").glob("*.py"))
#: The hand examples' emulators (session_tour power-cycles finger 0, whose phalanges then
#: stay off until the fmcb powers them: it gets an emulator of its own).
HAND_URL = "emu://hand/palm?name=host-examples"
SESSION_URL = "emu://hand/palm?name=host-examples-session"


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def _is_fragment(block: list[str], lines: list[str]) -> bool:
    """``block`` appears in ``lines`` as consecutive lines, all shifted by one indent."""
    first = block[0]
    for i, line in enumerate(lines):
        indent = len(line) - len(first)
        if indent < 0 or line[indent:] != first or line[:indent].strip():
            continue
        window = lines[i:i + len(block)]
        if len(window) == len(block) and all(
                (want == "" and got.strip() == "") or (got[:indent].strip() == ""
                                                       and got[indent:] == want)
                for want, got in zip(block, window, strict=True)):
            return True
    return False


def test_every_python_block_of_the_guide_is_part_of_a_tested_example() -> None:
    sources = {p.name: p.read_text().splitlines() for p in EXAMPLES}
    blocks = _blocks(GUIDE.read_text(), "python")
    assert len(blocks) >= 6
    for block in blocks:
        lines = block.rstrip("\n").splitlines()
        assert any(_is_fragment(lines, src) for src in sources.values()), \
            f"not in tools/examples/: {lines[0]!r}"


def test_the_guide_names_commands_that_exist() -> None:
    text = GUIDE.read_text()
    for command in ("handctl", "armctl", "handbus decode", "flash-all-fingers"):
        assert command in text
    readme = (ROOT / "README.md").read_text()
    assert "docs/HOST.md" in readme and "Driving the robot from Python" in readme


@pytest.mark.slow
def test_session_tour(capsys: pytest.CaptureFixture[str]) -> None:
    seen = session_tour.main(SESSION_URL)
    assert seen["palm"]["board"].name == "PALM"
    assert seen["f3"]["board"].name == "F3" and seen["f3"]["address"] == 2
    assert len(seen["halls"]) == 4
    assert "route unpowered" in seen["refused"] and "handctl power 0 full" in seen["refused"]
    assert "route unpowered" in capsys.readouterr().out


@pytest.mark.slow
def test_hand_tour(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    path = tmp_path / "tour.mcap"
    seen = hand_tour.main(HAND_URL, str(path))
    assert seen["nodes"] == seen["answered"] == 13
    assert (3, "unpowered") in seen["events"] and (3, "powered") in seen["events"]
    assert seen["deadband"] == FMCB_DEFAULT_DEADBAND and seen["settled"]
    assert seen["joints"] == pytest.approx([0.0, 0.4, 0.3], abs=0.1)
    stream = seen["stream"]
    assert len(stream) == 5
    assert [b - a for a, b in zip(stream, stream[1:], strict=False)] == pytest.approx(
        [0.05] * 4, abs=0.01)  # 20 Hz on the simulation clock
    with path.open("rb") as f:
        topics = {channel.topic for _s, channel, _m in make_reader(f).iter_messages()}
    assert {"/hand/frames/tx", "/hand/frames/rx", "/hand/state"} <= topics
    assert seen["frames"] > 0 and seen["states"] >= 5


@pytest.mark.slow
def test_arm_tour() -> None:
    seen = arm_tour.main("emu://arm/arm?name=host-examples")
    assert seen["joints"] == ["J1", "J2", "J3", "J4", "J5", "J6", "J7"]
    assert seen["homed"] and seen["settled"] and seen["reached"]
    # settled means within the move's tolerance; the elastic joints sag a little under load
    assert seen["angles"] == pytest.approx([0.0, 0.3, 0.0, 0.4], abs=0.05)
    assert seen["moveto_error_m"] < 0.005
