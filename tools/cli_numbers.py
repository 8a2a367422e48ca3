"""Numbers on the command line: one argparse type for every "a number above a bound".

Used by every tool (``--timeout``, ``--duration``, ``--seed``, ``--workers`` …), so each
option refuses the same way: ``'x' is not a number: give a time > 0``, ``-1: give a time > 0``.  Standard
library only: the in-process fuzzers import it too.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def number_above(low: float, kind: type[int] | type[float] = float, *, inclusive: bool = False,
                 what: str = "a number", note: str = "") -> Callable[[str], int | float]:
    """An argparse type: a finite number of ``kind`` above ``low`` (at ``low`` too with
    ``inclusive``); the error says ``what`` it should be, then ``note``."""
    sign = ">=" if inclusive else ">"

    def parse(text: str) -> int | float:
        wanted = f"give {what} {sign} {low:g}{note}"
        try:
            value = kind(text)
        except ValueError:
            noun = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {noun}: {wanted}") from None
        if not math.isfinite(value) or value < low or (value == low and not inclusive):
            raise argparse.ArgumentTypeError(f"{text}: {wanted}")
        return value

    return parse
