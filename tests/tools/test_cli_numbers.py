"""The one argparse type every tool uses for a number above a bound."""

from __future__ import annotations

import argparse

import pytest

from tools.cli.numeric import (
    NEGATIVE_NUMBER,
    finite,
    number_above,
    number_in,
    read_negative_numbers,
)


@pytest.mark.parametrize(("text", "value"), [("0.5", 0.5), ("3", 3.0), ("1e-3", 0.001)])
def test_a_number_above_zero_is_taken(text: str, value: float) -> None:
    assert number_above(0)(text) == value


@pytest.mark.parametrize(("text", "says"), [
    ("0", "0: give a time > 0"), ("-2", "-2: give a time > 0"), ("inf", "inf: give a time"),
    ("nan", "nan: give a time"), ("soon", "'soon' is not a number")])
def test_a_time_that_is_not_above_zero_is_refused(text: str, says: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=says):
        number_above(0, what="a time")(text)


def test_an_inclusive_integer_bound_and_its_note() -> None:
    seed = number_above(0, int, inclusive=True, what="a seed")
    assert seed("0") == 0 and isinstance(seed("7"), int)
    with pytest.raises(argparse.ArgumentTypeError, match="'1.5' is not an integer"):
        seed("1.5")
    runs = number_above(1, int, inclusive=True, what="a number of runs", note=" (forever)")
    with pytest.raises(argparse.ArgumentTypeError, match=r"^0: give a number of runs >= 1 "
                                                         r"\(forever\)$"):
        runs("0")


@pytest.mark.parametrize("word", ["-1e-3", "-1E+2", "-.5", "-1_000", "-2.", "-inf", "-nan",
                                  "-0.1,0.2,0", "-1e-3,-2,3e4"])
def test_every_negative_number_python_reads_is_a_value_not_an_option(word: str) -> None:
    parser = argparse.ArgumentParser(prog="t")
    sub = parser.add_subparsers(dest="command", required=True)
    move = sub.add_parser("move")
    move.add_argument("--joints", nargs="+")
    move.add_argument("--duration")
    read_negative_numbers(parser)
    args = parser.parse_args(["move", "--joints", "0", word, "--duration", word])
    assert args.joints == ["0", word] and args.duration == word


@pytest.mark.parametrize("word", ["-x", "--joints", "-1e", "-e3", "-1,x"])
def test_an_option_is_still_an_option(word: str) -> None:
    assert not NEGATIVE_NUMBER.match(word)


def test_a_bounded_number_refuses_what_is_absurd_or_not_finite() -> None:
    speed = number_in(0, 170, what="a speed (rad/s)")
    assert speed("170") == 170 and speed("1e-3") == 0.001
    for text in ("1e6", "0", "-1", "nan", "inf", "1e400"):
        with pytest.raises(argparse.ArgumentTypeError, match="give a speed"):
            speed(text)
    position = finite("a position (m)")
    assert position("-1e-3") == -0.001
    for text in ("nan", "-inf", "1e400"):
        with pytest.raises(argparse.ArgumentTypeError, match=f"^{text}: give a position"):
            position(text)
