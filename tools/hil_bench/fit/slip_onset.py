"""A stepper's holding torque from the moment its rotor let go: a bracketing search over its
torque constant.

A holding probe (:mod:`host.arm.holding_probe`) lowers a loaded stepper's holding current
until the node latches SLIP, and stops.  Below the load's torque nothing depends on the
holding torque: the rotor holds.  So the replayed robot's channels do not change smoothly
with the torque constant — a robot stronger than the recorded one never slips at all in the
recorded ramp (the host put the current back when the recorded one slipped), one weaker slips
earlier — and least squares, whose finite differences see a step or nothing, cannot use them.
What does change monotonically is *when* the replayed node first reports SLIP
(``cycle_status_flags``): later for a larger torque constant, never for one large enough.

:func:`search` therefore brackets the values whose replay slips at the very sample the
recording did: each round replays a few values (one per worker) inside the bracket, each
either *early* (it slipped before the recording), *late* (after, or never) or a *match*, and
narrows the bracket to the values between the largest early and the smallest late one.
Where to look next: the probe ramps the current down linearly in time, and a rotor lets go
where the current has fallen to ``load / (G · k_T)``, so the slip time is linear in
``1 / k_T``; two early replays (their slip times) give that line, and the next values are
where it meets the recorded slip, and just beside it (regula falsi).  Without two, the
bracket is split evenly (in the logarithm).  The
estimate is the bracket's middle; its uncertainty that of a value anywhere in it
(``width / √12``), the resolution the probe's current steps give (one cycle of the ramp).
A recording in which the joint never slipped says nothing of its holding torque: the
parameter is unobservable there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

from hil_emulator.profile import Parameter
from protocol.control_tables import StepperFlag
from tools.hil_bench.fit.evaluate import Replayed, Replayer
from tools.hil_bench.replay.compare import Channel

_SLIP: Final = int(StepperFlag.SLIP)
#: Rounds of the search at most, and the bracket's width (share of the value) it stops at.
MAX_ROUNDS: Final = 12
RESOLUTION: Final = 0.01


def flags_channel(parameter: Parameter) -> str:
    """The channel whose SLIP bit shows ``parameter``'s joint letting go."""
    return f"arm.J{parameter.index + 1}.cycle_status_flags"


def first_slip(channel: Channel | None, replayed: bool) -> float:
    """The first time (s) ``channel`` (the recorded or the ``replayed`` values) has SLIP,
    or infinity."""
    if channel is None:
        return math.inf
    values = channel.replayed if replayed else channel.recorded
    return next((t for t, v in zip(channel.t, values, strict=True) if int(v) & _SLIP),
                math.inf)


@dataclass(frozen=True)
class SlipFit:
    """The search's outcome for one parameter: the ``low``–``high`` bracket (its unit) of
    the values whose replays slip when the recording did, the replays' rounds, and whether
    the recordings showed a slip at all (``observable``)."""

    low: float
    high: float
    rounds: int
    observable: bool

    @property
    def value(self) -> float:
        """The estimate: the bracket's middle."""
        return 0.5 * (self.low + self.high)

    @property
    def uncertainty(self) -> float:
        """1σ of a value anywhere in the bracket (its unit): width / √12."""
        return (self.high - self.low) / math.sqrt(12.0)


def _side(recorded: Sequence[float], replayed: Replayed, name: str) -> int:
    """−1 early, +1 late, 0 a match: the replay's first slips against the recorded ones
    (over every recording that has one; a disagreement between them counts as a match)."""
    signs = set()
    for t_rec, channels in zip(recorded, replayed, strict=True):
        if math.isfinite(t_rec):
            t = first_slip(channels.get(name), replayed=True)
            signs.add(0 if t == t_rec else (-1 if t < t_rec else 1))
    return signs.pop() if len(signs) == 1 else 0


def _secant(early: Mapping[float, float], target: float, low: float, high: float
            ) -> float | None:
    """Where the line of slip time over ``1 / value`` through the two largest early values
    meets ``target`` (s), inside ``low``..``high``; None without two or outside."""
    if len(early) < 2:
        return None
    (k1, t1), (k2, t2) = sorted(early.items())[-2:]
    if t1 == t2:
        return None
    slope = (t2 - t1) / (1.0 / k2 - 1.0 / k1)
    inverse = 1.0 / k2 + (target - t2) / slope
    if inverse <= 0:
        return None
    guess = 1.0 / inverse
    return guess if low < guess < high else None


def search(replayer: Replayer, parameter: Parameter, fixed: Mapping[str, float],
           recorded_cases: Sequence[Mapping[str, Channel]], workers: int,
           progress: Callable[[str], None] | None = None,
           start: tuple[float, float] | None = None) -> SlipFit:
    """Bracket ``parameter`` (a ``torque_constant``) from the recordings' slips (module
    doc); every other parameter at ``fixed`` (or nominal).  ``recorded_cases``: each
    recording's channels as a first replay gave them (their recorded values).  ``start``:
    the bracket to start from (default: the parameter's bounds)."""
    name = flags_channel(parameter)
    recorded = [first_slip(channels.get(name), replayed=False) for channels in recorded_cases]
    low, high = start or (parameter.low, parameter.high)
    if not any(math.isfinite(t) for t in recorded):
        return SlipFit(parameter.nominal, parameter.nominal, 0, False)
    matches: list[float] = []
    early: dict[float, float] = {}  # value → its replay's first slip (s)
    target = min(t for t in recorded if math.isfinite(t))
    n = max(2, workers)
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):
        guess = _secant(early, target, low, high)
        if guess is not None and not matches:
            spread = [guess * (1.0 + 0.5 * RESOLUTION * (k - (n - 1) / 2)) for k in range(n)]
            points = [v for v in spread if low < v < high] or [guess]
        elif matches:
            gaps = [(low, min(matches)), (max(matches), high)]
            gaps = [(a, b) for a, b in gaps if b - a > RESOLUTION * b]
            if not gaps:
                break
            per = max(1, n // len(gaps))
            points = [a * (b / a) ** (k / (per + 1)) for a, b in gaps
                      for k in range(1, per + 1)]
        else:
            if high - low <= RESOLUTION * high:
                break
            points = [low * (high / low) ** (k / (n + 1)) for k in range(1, n + 1)]
        replayed = replayer.run([{**fixed, parameter.name: v} for v in points])
        for value, result in zip(points, replayed, strict=True):
            side = _side(recorded, result, name)
            if side < 0:
                early[value] = min(first_slip(c.get(name), replayed=True) for c in result)
                low = max(low, value)
            elif side > 0:
                high = min(high, value)
            else:
                matches.append(value)
        matches = [m for m in matches if low <= m <= high]
        if progress is not None:
            progress(f"fit: {parameter.name}: slip onset bracketed in {low:.4g}..{high:.4g} "
                     f"{parameter.unit} (round {rounds})")
    return SlipFit(low, high, rounds, True)
