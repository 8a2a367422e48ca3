"""One replay: build the emulator a recording needs, drive it with the host's bytes, pair
and compare (:func:`replay`).  A fitter calls :func:`replay_channels` many times with
emulators of other parameters: in process, on the simulated clock, no ptys."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorError
from host.errors import UsageError
from protocol.dynamixel import InstructionPacket
from tools.errors import ReplayRefused
from tools.hil_bench.replay.compare import (
    Channel,
    channel_names,
    compare,
    over_a_port,
    tolerances_for,
)
from tools.hil_bench.replay.drive import answers
from tools.hil_bench.replay.exchanges import PAIRING, Exchange
from tools.hil_bench.replay.prelude import SETTLE_S, held_by, rebuild, start_values, writes
from tools.hil_bench.replay.source import Recorded, load, merge


@dataclass
class ReplayResult:
    """What a replay found: the ``recording`` replayed, every ``channel`` by name, the
    simulated seconds run (``sim_s``) and the CPU seconds it took (``cpu_s``, this process)."""

    recording: Recorded
    channels: dict[str, Channel]
    sim_s: float = 0.0
    cpu_s: float = 0.0
    exchanges: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def failing(self) -> list[str]:
        """The channels outside their tolerance, by the time they first parted."""
        bad = [c for c in self.channels.values() if not c.within]
        return [c.name for c in sorted(bad, key=lambda c: (c.first_exceeded_t or 0.0, c.name))]

    @property
    def within(self) -> bool:
        """True when every channel stayed within its tolerance."""
        return not self.failing


def build_emulator(recording: Recorded) -> Emulator:
    """The emulator ``recording`` names (brought up when it was); :class:`ReplayRefused`
    when it cannot be built."""
    try:
        return recording.spec.build()
    except (UsageError, EmulatorError) as exc:
        raise ReplayRefused(f"cannot build its emulator: {exc}") from exc


def recorded_exchanges(recording: Recorded) -> list[Exchange]:
    """The recorded requests paired with the recorded replies, every link.  In a file cut
    short, the last request answered and those after it are left out: their replies may
    be what the cut lost."""
    out = [ex for traffic in recording.links.values()
           for ex in PAIRING[traffic.kind](traffic.tx, traffic.rx)]
    if recording.truncated:
        answered = [ex.t for ex in out if ex.fields is not None]
        last = max(answered, default=-math.inf)
        # the last answered request's other replies (a BULK_READ's later nodes) may be
        # what the cut lost: it goes too
        out = [ex for ex in out if ex.t < last]
    return out


def start_writes(recording: Recorded, recorded: Sequence[Exchange], emulator: Emulator
                 ) -> list[tuple[str, InstructionPacket]]:
    """For a recording made over a port, the writes that give ``emulator``'s arm nodes the
    registers the recording found them with (:mod:`.prelude`); none for an ``emu://`` one
    (its link's earlier use is in it) or without an arm link."""
    traffic = next((t for t in recording.links.values() if t.kind == "arm"), None)
    if recording.emulated or traffic is None:
        return []
    arm = [ex for ex in recorded if ex.prefix.startswith("arm.")]
    return writes(start_values(arm, traffic.tx), held_by(emulator, traffic.link))


def replay_channels(recording: Recorded, emulator: Emulator,
                    tolerances: Mapping[str, float] | None = None,
                    recorded: Sequence[Exchange] | None = None
                    ) -> tuple[dict[str, Channel], float]:
    """Drive ``emulator`` (fresh, as the recording's started) with ``recording``'s host bytes
    and compare its answers; returns the channels and the simulated seconds run.
    ``recorded`` (:func:`recorded_exchanges`) may be passed in by a caller that replays one
    recording many times."""
    if recorded is None:
        recorded = recorded_exchanges(recording)
    start_us = emulator.scheduler.now_us()
    if not recording.emulated:  # the robot as the recording found it (prelude)
        for traffic in recording.links.values():
            if traffic.kind == "arm":
                rebuild(emulator, traffic.link, start_writes(recording, recorded, emulator))
                break
        else:
            emulator.step(int(SETTLE_S * 1e6))
    sent = {traffic.link: traffic.sent() for traffic in recording.links.values()}
    first = min(m.t for messages in sent.values() for m in messages)
    shift = 0.0 if recording.emulated else emulator.scheduler.now_us() / 1e6 - first
    got = answers(emulator, sent, shift_s=shift)
    replayed = [ex for traffic in recording.links.values()
                for ex in PAIRING[traffic.kind](traffic.tx, got[traffic.link])]
    sim_s = (emulator.scheduler.now_us() - start_us) / 1e6
    return compare(recorded, replayed, tolerances), sim_s


def replay(path: str | Path | Sequence[str | Path], *,
           tolerances: Sequence[tuple[str, float]] = (),
           seed: int | None = None, sensors: str | None = None, profile: str | None = None,
           emulator_factory: Callable[[Recorded], Emulator] = build_emulator) -> ReplayResult:
    """Replay the recording at ``path`` (or one session's recordings, one per link: every
    link on one emulator, :func:`~tools.hil_bench.replay.source.merge`) against a new
    emulator of its configuration (``seed``, ``sensors`` and ``profile``, a robot profile's
    file or "" for the nominal robot, override the recording's; ``emulator_factory`` builds
    another); :class:`ReplayRefused` for a recording it cannot replay or a tolerance naming
    no channel."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    recording = merge([load(p, seed=seed, sensors=sensors) for p in paths])
    if profile is not None:
        recording = replace(recording, spec=replace(recording.spec, profile=profile))
    recorded = recorded_exchanges(recording)
    limits = tolerances_for(channel_names(recorded), tolerances)
    cpu0 = time.process_time()
    emulator = emulator_factory(recording)
    try:
        restored = start_writes(recording, recorded, emulator)
        channels, sim_s = replay_channels(recording, emulator, limits, recorded)
    finally:
        emulator.close()
    notes: list[str] = []
    if not recording.emulated and recording.links:
        notes.append(f"the recording's clock is not the emulator's: its times were shifted so "
                     f"its first host message went out {SETTLE_S:g} s after the emulator was "
                     f"ready")
        if restored:
            notes.append("the robot as the recording found it, written before the replay (its "
                         "replies showed it): " + ", ".join(what for what, _ in restored))
        channels, more = over_a_port(channels, tolerances)
        notes += more
    return ReplayResult(recording, channels, sim_s, time.process_time() - cpu0,
                        len(recorded), notes)
