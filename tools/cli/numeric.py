"""Numbers on the command line: one argparse type for every number option, and negative
numbers in every form Python reads.

:func:`number_above` (``--timeout``, ``--duration``, ``--seed``, ``--workers`` …) and
:func:`number_in` (a value with both bounds: ``grasp --speed``) refuse the same way:
``'x' is not a number: give a time > 0``, ``-1: give a time > 0``; NaN and infinities are
refused by both.  :func:`finite` is any finite number (a coordinate).

argparse takes a word that starts with ``-`` for an option unless it looks like a negative
number to it, and it knows only ``-1`` and ``-0.5``: ``--joints 0 -1e-3`` was "unrecognized
arguments".  :func:`read_negative_numbers` teaches a parser (and its sub-commands) every
form Python's ``float`` reads (``-1e-3``, ``-1_000``, ``-.5``, ``-inf``) and comma lists of
them (``-0.1,0.2,0``), so the number's own type says what is wrong with it.  Standard
library only: the in-process fuzzers import it too.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from typing import Final

_NUMBER: Final = r"(?:(?:\d[\d_]*\.?[\d_]*|\.\d[\d_]*)(?:e[-+]?\d[\d_]*)?|inf(?:inity)?|nan)"
#: A word argparse must take as a (negative) number, not as an option.
NEGATIVE_NUMBER: Final = re.compile(rf"^-{_NUMBER}(?:,\s*[-+]?{_NUMBER})*,?$", re.IGNORECASE)


def read_negative_numbers(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Make ``parser`` and its sub-parsers take every negative number Python reads as a
    value (see the module's doc); returns ``parser``."""
    parser._negative_number_matcher = NEGATIVE_NUMBER  # noqa: SLF001 - argparse has no API
    for action in parser._actions:  # noqa: SLF001
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                read_negative_numbers(sub)
    return parser


def number_above(low: float, kind: type[int] | type[float] = float, *, inclusive: bool = False,
                 what: str = "a number", note: str = "") -> Callable[[str], int | float]:
    """An argparse type: a finite number of ``kind`` above ``low`` (at ``low`` too with
    ``inclusive``); the error says ``what`` it should be, then ``note``."""
    sign = ">=" if inclusive else ">"
    return _number(kind, f"give {what} {sign} {low:g}{note}",
                   lambda v: v > low or (inclusive and v == low))


def number_in(low: float, high: float, kind: type[int] | type[float] = float, *,
              what: str = "a number", note: str = "") -> Callable[[str], int | float]:
    """An argparse type: a finite number of ``kind`` above ``low`` and at most ``high``."""
    return _number(kind, f"give {what} > {low:g} and <= {high:g}{note}",
                   lambda v: low < v <= high)


def finite(what: str = "a number") -> Callable[[str], float]:
    """An argparse type: any finite float (NaN and infinities refused)."""
    parse = _number(float, f"give {what}", lambda v: True)
    return lambda text: float(parse(text))


def _number(kind: type[int] | type[float], wanted: str,
            ok: Callable[[float], bool]) -> Callable[[str], int | float]:
    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            noun = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {noun}: {wanted}") from None
        if not math.isfinite(value) or not ok(value):
            raise argparse.ArgumentTypeError(f"{text}: {wanted}")
        return value

    return parse
