"""Sub-commands declared once each (tools.cli.commands): the parser a program builds and the
handler it runs come from the same declaration, in the order declared."""

from __future__ import annotations

import argparse
import io
from typing import TextIO

import pytest

from tools.cli import armctl, handctl
from tools.cli.commands import Commands


def _sub_names(parser: argparse.ArgumentParser) -> list[str]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return list(sub.choices)


def test_handctl_and_armctl_parse_exactly_the_commands_they_declare() -> None:
    assert _sub_names(handctl._parser()) == list(handctl.COMMANDS) == [
        "watch", "ping", "status", "up", "power", "move", "home", "calibrate", "grasp", "record",
        "excite"]
    assert _sub_names(armctl.make_parser()) == list(armctl.COMMANDS) == [
        "watch", "ping", "scan", "status", "torque", "clear", "move", "home", "moveto",
        "waypoints", "record", "excite", "calibrate"]
    assert not armctl.COMMANDS["scan"].opens and armctl.COMMANDS["move"].opens


def _demo() -> tuple[Commands[list[str], [str]], list[str]]:
    commands: Commands[list[str], [str]] = Commands()
    log: list[str] = []

    def checked(args: argparse.Namespace) -> None:
        log.append(f"check {args.n}")

    @commands.command("b", "declared first, listed first", lambda p: p.add_argument("n"),
                      check=checked)
    def _b(target: list[str], args: argparse.Namespace, extra: str) -> int:
        target.append(f"b {args.n} {extra}")
        return 3

    @commands.alone("a", "opens nothing")
    def _a(args: argparse.Namespace, extra: str) -> int:
        log.append(f"a {extra}")
        return 4

    return commands, log


def test_declared_commands_parse_check_and_run_in_declaration_order() -> None:
    commands, log = _demo()
    parser = argparse.ArgumentParser(prog="demo")
    commands.add_parsers(parser.add_subparsers(dest="command", required=True))
    assert _sub_names(parser) == ["b", "a"]
    args = parser.parse_args(["b", "7"])
    commands.check(args)
    assert commands.run(log, args, "x") == 3
    assert log == ["check 7", "b 7 x"]
    alone = parser.parse_args(["a"])
    commands.check(alone)
    assert commands.run_alone(alone, "y") == 4 and log[-1] == "a y"


def test_a_name_declared_twice_is_refused() -> None:
    commands, _ = _demo()
    with pytest.raises(ValueError, match="'b' is declared twice"):
        @commands.alone("b", "again")
        def _again(args: argparse.Namespace, extra: str) -> int:
            return 0


def test_the_extra_argument_reaches_the_handler() -> None:
    """armctl's handlers get the stream its caller chose (``main(out=)``)."""
    seen: list[TextIO] = []
    commands: Commands[None, [TextIO]] = Commands()

    @commands.command("x", "x")
    def _x(target: None, args: argparse.Namespace, out: TextIO) -> int:
        seen.append(out)
        return 0

    stream = io.StringIO()
    assert commands.run(None, argparse.Namespace(command="x"), stream) == 0
    assert seen == [stream]
