"""Every tool's standard output or output file that cannot be written: one line on stderr,
a non-zero exit, never a traceback (tools.cli.output)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "tools" / "samples" / "hand_session.hex"

#: (tool, arguments): each prints enough to fill a buffer, or flushes on exit.
COMMANDS = [
    ("cli.handbus", ["list"]),
    ("cli.handbus", ["decode", "--hex", str(SAMPLE)]),
    ("cli.fwimage", ["--help"]),
    ("hil_bench.cli", ["list-faults"]),
    ("cli.armctl", ["--port", "emu://arm/arm", "ping"]),
]


def run_into_full_disk(tool: str, args: list[str], buffered: bool) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env.pop("PYTHONUNBUFFERED", None)
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    with open("/dev/full", "w") as full:
        return subprocess.run([sys.executable, "-m", f"tools.{tool}", *args], cwd=ROOT,
                              stdout=full, stderr=subprocess.PIPE, text=True, env=env,
                              timeout=120)


#: argparse's --help swallows the failed write where standard output is unbuffered.
CASES = [(tool, args, True) for tool, args in COMMANDS] + [
    ("cli.fwimage", ["--help"], False), ("cli.handbus", ["list"], False)]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize(("tool", "args", "buffered"), CASES,
                         ids=[" ".join([t, *a[:1], "buffered" if b else "unbuffered"])
                              for t, a, b in CASES])
def test_a_full_disk_on_standard_output_is_one_line_and_exit_1(tool: str, args: list[str],
                                                               buffered: bool) -> None:
    result = run_into_full_disk(tool, args, buffered)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.endswith("cannot write standard output: No space left on device\n")
    assert result.stderr.count("\n") == 1, result.stderr


def test_an_output_directory_that_cannot_be_made_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    result = subprocess.run([sys.executable, "-m", "tools.demo", "--out",
                             str(tmp_path / "file" / "out")], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr == f"demo: {tmp_path / 'file' / 'out'}: Not a directory\n"
