"""Every installed command and every one of its subcommands answers ``--help`` (exit 0),
as the first thing a user types; argparse builds help text lazily, so a bad ``metavar`` only
shows there."""

from __future__ import annotations

import importlib
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS: dict[str, str] = tomllib.loads(
    (ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]


def _help(entry: str, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    module, _, func = entry.partition(":")
    main = getattr(importlib.import_module(module), func)
    try:
        code = main([*argv, "--help"])  # some mains turn argparse's exit into a status
    except SystemExit as stop:
        code = stop.code
    out = capsys.readouterr().out
    assert code in (0, None), f"{argv} --help exited {code}"
    assert "usage:" in out
    return out


@pytest.mark.parametrize("command", sorted(SCRIPTS))
def test_every_command_and_subcommand_answers_help(
        command: str, capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(SCRIPTS[command], [], capsys)
    # the subcommands' choices: the first {a,b,...} that is not an option's (--priority {..})
    choices = [m.group(2) for m in re.finditer(r"(--[\w-]+ )?\{([a-z0-9_,-]+)\}", text)
               if m.group(1) is None]
    subcommands = choices[0].split(",") if choices else []
    for sub in subcommands:
        if command == "hil-bench" and sub == "experiments":
            continue  # hands its words to tools.experiments.dissertation, tested with hil-bench
        _help(SCRIPTS[command], [sub], capsys)
