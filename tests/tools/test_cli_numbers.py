"""The one argparse type every tool uses for a number above a bound."""

from __future__ import annotations

import argparse

import pytest

from tools.cli_numbers import number_above


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
