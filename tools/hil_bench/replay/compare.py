"""Per channel, the replayed robot's error against the recorded one's, over time.

A channel is one field of the replies to one kind of request (``arm.J2.present_position``,
``hand.finger1.fmcb.status.joints_hall[0]``, ``arm.J5.reply_us``, ``….replied``).  The
recorded and the replayed exchanges are paired by request (:mod:`.exchanges`): the n-th
request of a kind in the recording with the n-th of the same kind in the replay.  The error
is replayed − recorded, at the recorded request's time; a channel keeps its error series,
its RMS and maximum (of the absolute error) and the first time it exceeds its tolerance.

Tolerances (:func:`tolerances_for`) are given per channel as ``CHANNEL=VALUE``: CHANNEL is a
channel's full name, a pattern with ``*`` (``arm.J?.present_position``), or a field's name
alone (``present_position``, ``reply_us``: that field on every node).  The last one given
that matches a channel is its tolerance; a channel nothing matches has
:data:`DEFAULT_TOLERANCE` (0: exact agreement, what a replay against the emulator that
made the recording must show).
"""

from __future__ import annotations

import fnmatch
import math
from collections import defaultdict
from collections.abc import Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

from tools.errors import ReplayRefused
from tools.hil_bench.replay.exchanges import REPLY_US, Exchange

#: A channel's tolerance when none is given (its unit's: counts, rad, µs …).
DEFAULT_TOLERANCE: Final = 0.0
#: The hand boards' clocks in their status (µs since the board's power-up,
#: :mod:`protocol.messages.fmcb`): over a port only their increments compare.
BOARD_CLOCKS: Final = ("fmcb_time", "pp_time", "dp_time")
#: Relative slack on a tolerance, for numbers that went through decimal text (times).
_SLACK: Final = 1e-9


@dataclass
class Channel:
    """One channel's errors: ``t`` (s, the recording's clock), ``recorded`` and ``replayed``
    values, and the ``tolerance`` it was held to."""

    name: str
    tolerance: float = DEFAULT_TOLERANCE
    t: list[float] = field(default_factory=list)
    recorded: list[float] = field(default_factory=list)
    replayed: list[float] = field(default_factory=list)

    @property
    def errors(self) -> list[float]:
        """replayed − recorded, sample by sample."""
        return [b - a for a, b in zip(self.recorded, self.replayed, strict=True)]

    @property
    def rms(self) -> float:
        """RMS of the error (the channel's unit)."""
        errors = self.errors
        return math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else 0.0

    @property
    def max_abs(self) -> float:
        """Largest absolute error (the channel's unit)."""
        return max((abs(e) for e in self.errors), default=0.0)

    @property
    def first_exceeded_t(self) -> float | None:
        """The first time (s) the error exceeds the tolerance, or None."""
        bound = self.tolerance
        for t, a, b in zip(self.t, self.recorded, self.replayed, strict=True):
            if abs(b - a) > bound + _SLACK * max(1.0, abs(a)):
                return t
        return None

    @property
    def within(self) -> bool:
        """True when the error never exceeds the tolerance."""
        return self.first_exceeded_t is None


def _occurrences(exchanges: Iterable[Exchange]) -> dict[tuple[Hashable, int], Exchange]:
    seen: dict[Hashable, int] = defaultdict(int)
    out: dict[tuple[Hashable, int], Exchange] = {}
    for ex in exchanges:
        n = seen[ex.key]
        seen[ex.key] = n + 1
        out[(ex.key, n)] = ex
    return out


def channel_names(exchanges: Iterable[Exchange]) -> set[str]:
    """The channels ``exchanges`` have (what a tolerance may name)."""
    return {f"{ex.prefix}.{name}" for ex in exchanges for name in ex.values()}


def matches(name: str, pattern: str) -> bool:
    """Whether a tolerance's CHANNEL ``pattern`` names channel ``name`` (module doc)."""
    return name == pattern or fnmatch.fnmatchcase(name, pattern) or name.endswith("." + pattern)


def tolerances_for(names: Iterable[str], given: Sequence[tuple[str, float]]) -> dict[str, float]:
    """Each channel's tolerance from ``given`` (CHANNEL, VALUE) pairs (module doc);
    :class:`ReplayRefused` naming a CHANNEL that matches none of ``names``."""
    names = sorted(names)
    out = dict.fromkeys(names, DEFAULT_TOLERANCE)
    for pattern, value in given:
        matched = [n for n in names if matches(n, pattern)]
        if not matched:
            raise ReplayRefused(f"unknown channel {pattern!r}: the recording has none of "
                                f"that name (e.g. {', '.join(names[:3])})")
        for n in matched:
            out[n] = value
    return out


def compare(recorded: Iterable[Exchange], replayed: Iterable[Exchange],
            tolerances: Mapping[str, float] | None = None) -> dict[str, Channel]:
    """Every channel of the recorded exchanges, replay against recording, by name."""
    tolerances = tolerances or {}
    theirs = _occurrences(replayed)
    channels: dict[str, Channel] = {}
    for occurrence, ex in _occurrences(recorded).items():
        mine = ex.values()
        other = theirs.get(occurrence)
        others = other.values() if other is not None else {"replied": 0.0}
        for name, value in mine.items():
            if name not in others:
                continue
            full = f"{ex.prefix}.{name}"
            channel = channels.get(full)
            if channel is None:
                channel = channels[full] = Channel(
                    full, tolerances.get(full, DEFAULT_TOLERANCE))
            channel.t.append(ex.t)
            channel.recorded.append(value)
            channel.replayed.append(others[name])
    return channels


def over_a_port(channels: Mapping[str, Channel], given: Sequence[tuple[str, float]]
                ) -> tuple[dict[str, Channel], list[str]]:
    """The channels of a recording made over a port as they can be compared, and a note
    for each change: ``reply_us`` left out unless a tolerance in ``given`` names it (the
    adapter's and the operating system's latency, not the robot's), and each board clock
    (:data:`BOARD_CLOCKS`) compared from its first sample (the recorded robot had been on
    for an unknown time)."""
    out: dict[str, Channel] = {}
    notes: list[str] = []
    dropped = 0
    for name, channel in channels.items():
        field_name = name.rsplit(".", 1)[-1]
        if field_name == REPLY_US and not any(matches(name, p) for p, _ in given):
            dropped += 1
            continue
        if field_name in BOARD_CLOCKS and channel.recorded:
            r0, p0 = channel.recorded[0], channel.replayed[0]
            channel = Channel(name, channel.tolerance, channel.t,
                              [v - r0 for v in channel.recorded],
                              [v - p0 for v in channel.replayed])
        out[name] = channel
    if dropped:
        notes.append(f"{dropped} reply_us channels not compared: over a port a reply's time is "
                     "the adapter's and the operating system's as much as the robot's (give "
                     "--tolerance reply_us=… to compare them)")
    if any(n.rsplit(".", 1)[-1] in BOARD_CLOCKS for n in out):
        notes.append("the boards' clocks (" + ", ".join(BOARD_CLOCKS) + ") compared from their "
                     "first sample: the recorded robot had been on for a while")
    return out, notes
