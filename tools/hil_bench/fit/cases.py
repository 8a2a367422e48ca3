"""The recordings a fit reproduces and the residuals of one set of parameters.

A :class:`FitCase` is one recording (:func:`~tools.hil_bench.replay.source.load`), its
recorded exchanges, read once, and the channels the fit holds it to: those with a tolerance
> 0.  Unless told otherwise (``--tolerance CHANNEL=VALUE``, as ``hil-bench replay``) those
are :data:`FIT_TOLERANCES`, the arm's joint positions and the elastic elements' deflections,
and :data:`HAND_FIT_TOLERANCES`, the finger motors' hall counts and the accelerometers' axes,
which the parameters move smoothly; velocities (counted in steps of 100), status flags and
reply times are left out.  :func:`residuals` replays every case against a new emulator of
the recording's configuration with the parameters given (a
:class:`~hil_emulator.profile.RobotProfile` of them: every other parameter nominal, the
bearings' friction the seed's draw) and returns each sample's error over its tolerance, in
a layout fixed by the first replay (:class:`Layout`), so that every evaluation's vector has
the same length.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Final

import numpy as np

from hil_emulator.errors import EmulatorError
from hil_emulator.hand_profile import sensor_names
from hil_emulator.profile import PARAMETERS, RobotProfile
from host.errors import UsageError
from protocol.control_tables import StepperFlag
from tools.errors import ReplayRefused
from tools.hil_bench.replay.compare import Channel, channel_names, tolerances_for
from tools.hil_bench.replay.exchanges import Exchange
from tools.hil_bench.replay.session import recorded_exchanges, replay_channels
from tools.hil_bench.replay.source import Recorded, load, merge

_SLIP: Final = int(StepperFlag.SLIP)
#: The channels a fit is held to by default (a field on every node) and their tolerances:
#: encoder counts of the stepper joints' positions and their elements' deflections, RX-64
#: position units (0.29°).
FIT_TOLERANCES: Final = (("cycle_present_position", 2.0), ("cycle_deflection", 2.0),
                         ("present_position", 2.0))
#: The hand's: each finger motor's hall count, and each accelerometer's three axes (mg: the
#: fmcb's, f2's and f3's in ``fmcb.status``, the palm's ``accel`` in its state), 8 mg being
#: five times the chip's noise (1.5 mg rms).
HAND_FIT_TOLERANCES: Final = (
    *((f"hall_pos[{i}]", 2.0) for i in range(3)),
    *((f"{imu}[{i}]", 8.0) for imu in ("fmcb_imu", "pp_imu", "dp_imu", "accel")
      for i in range(3)))
#: Joins the recordings of one session (one emulator, one recorder per link) in a fit's
#: argument: ``arm.mcap+hand.mcap``.
SESSION_JOIN: Final = "+"


@dataclass
class FitCase:
    """One recording to reproduce: ``recording``, its ``recorded`` exchanges and the
    ``tolerances`` of the channels fitted (> 0), by name."""

    recording: Recorded
    recorded: list[Exchange]
    tolerances: dict[str, float]
    #: The profile the recording's emulator had (left out: the fit starts from nominal).
    recorded_profile: str = ""

    @property
    def fitted(self) -> list[str]:
        """The channels the fit is held to, sorted."""
        return sorted(n for n, v in self.tolerances.items() if v > 0)


def load_case(path: str | Path, tolerances: Sequence[tuple[str, float]] = ()) -> FitCase:
    """The case of the recording at ``path`` (or of one session's recordings joined by
    :data:`SESSION_JOIN`, replayed together on one emulator as ``hil-bench replay`` does);
    :class:`ReplayRefused` for a recording that cannot be replayed, a tolerance naming no
    channel, or one with no channel to fit."""
    recording = merge([load(p) for p in str(path).split(SESSION_JOIN)])
    profile = recording.spec.profile
    if profile:  # the fit starts from the nominal robot, not the recording's
        recording = replace(recording, spec=replace(recording.spec, profile=""))
    recorded = recorded_exchanges(recording)
    names = channel_names(recorded)
    given = [(n, v) for n, v in (*FIT_TOLERANCES, *HAND_FIT_TOLERANCES)
             if any(c.endswith("." + n) for c in names)] + list(tolerances)
    limits = tolerances_for(names, given)
    case = FitCase(recording, recorded, limits, profile)
    if not case.fitted:
        raise ReplayRefused("it has no channel to fit (no joint positions or deflections; "
                            "give one with --tolerance CHANNEL=VALUE)")
    return case


def check_parameters(case: FitCase, names: Sequence[str]) -> None:
    """:class:`ReplayRefused` when ``case``'s robot has none of what ``names`` are of."""
    spec = case.recording.spec
    arm = [n for n in names if PARAMETERS[n].part == "arm"]
    if arm and spec.config not in ("arm", "full"):
        raise ReplayRefused(f"its {spec.config!r} robot has no arm: {', '.join(arm)} cannot "
                            "be seen in it")
    absent = [n for n in names if PARAMETERS[n].part == "hand"
              and not _has_part(spec.config, PARAMETERS[n].element)]
    if absent:
        raise ReplayRefused(f"its {spec.config!r} robot has none of {', '.join(absent)}")
    if spec.sensors != "realistic" and (named := sensor_names(dict.fromkeys(names, 0.0))):
        raise ReplayRefused(f"it was recorded with {spec.sensors!r} sensors: "
                            f"{', '.join(named)} cannot be seen in it")


def _has_part(config: str, element: str) -> bool:
    """Whether a robot of ``config`` has the finger module or board ``element``
    (``finger1``, ``finger1.f2``, ``palm``)."""
    if config in ("hand", "full"):
        return True
    return config == "loose-finger" and element.split(".")[0] == "finger0"


def replay_case(case: FitCase, values: Mapping[str, float]) -> dict[str, Channel]:
    """``case`` replayed against its emulator with the parameters ``values``."""
    try:
        emulator = case.recording.spec.build(profile=RobotProfile(dict(values)))
    except (UsageError, EmulatorError) as exc:
        raise ReplayRefused(f"cannot build its emulator: {exc}") from exc
    try:
        channels, _sim_s = replay_channels(case.recording, emulator, case.tolerances,
                                           case.recorded)
    finally:
        emulator.close()
    return channels


def first_recorded_slip(channels: Mapping[str, Channel]) -> float:
    """The first time (s) a stepper node of the recording reported SLIP (its
    ``cycle_status_flags``), or infinity."""
    return min((t for name, c in channels.items() if name.endswith(".cycle_status_flags")
                for t, v in zip(c.t, c.recorded, strict=True) if int(v) & _SLIP),
               default=math.inf)


@dataclass
class Layout:
    """Where each sample's residual sits: per case, per fitted channel, the recorded times
    (s) of its samples, taken from a first replay: every sample before the recording's
    first SLIP (:func:`first_recorded_slip`).  After a slip a rotor re-locks a random 0–2
    electrical periods on (15–60 counts), which no parameter reproduces: the samples after
    it would only pull the other parameters off; the slip itself is the holding torque's
    (:mod:`.slip_onset`)."""

    times: list[dict[str, list[float]]] = field(default_factory=list)

    @classmethod
    def of(cls, cases: Sequence[FitCase], replayed: Sequence[Mapping[str, Channel]]
           ) -> Layout:
        """The layout of ``replayed`` (one replay per case)."""
        out = []
        for case, channels in zip(cases, replayed, strict=True):
            cut = first_recorded_slip(channels)
            out.append({name: [t for t in channels[name].t if t < cut]
                        if name in channels else [] for name in case.fitted})
        return cls(out)

    def vector(self, cases: Sequence[FitCase], replayed: Sequence[Mapping[str, Channel]]
               ) -> np.ndarray:
        """Each sample's error over its channel's tolerance, in this layout (0 where a
        replay lacks a sample the first one had)."""
        out: list[float] = []
        for case, times, channels in zip(cases, self.times, replayed, strict=True):
            for name in case.fitted:
                channel = channels.get(name)
                errors = dict(zip(channel.t, channel.errors, strict=True)) if channel else {}
                scale = case.tolerances[name]
                out.extend(errors.get(t, 0.0) / scale for t in times[name])
        return np.asarray(out, dtype=float)

    def segments(self, cases: Sequence[FitCase]) -> tuple[list[int], list[float]]:
        """Each fitted channel's number of samples and tolerance, in the residuals' order."""
        counts: list[int] = []
        tolerances: list[float] = []
        for case, times in zip(cases, self.times, strict=True):
            for name in case.fitted:
                counts.append(len(times[name]))
                tolerances.append(case.tolerances[name])
        return counts, tolerances

    def channel_rms(self, cases: Sequence[FitCase], vector: np.ndarray) -> dict[str, float]:
        """Each fitted channel's RMS error (its unit) from a residual ``vector``; a channel
        of several recordings over all of them."""
        sums: dict[str, list[float]] = {}
        at = 0
        for case, times in zip(cases, self.times, strict=True):
            for name in case.fitted:
                n = len(times[name])
                part = vector[at:at + n] * case.tolerances[name]
                at += n
                acc = sums.setdefault(name, [0.0, 0.0])
                acc[0] += float(np.sum(part * part))
                acc[1] += n
        return {name: math.sqrt(s / n) if n else 0.0 for name, (s, n) in sorted(sums.items())}
