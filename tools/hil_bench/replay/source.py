"""A recording as replay sees it: each host link's bytes with their times, and the emulator
that should answer them.

The recorders (:mod:`host.arm.recording`, :mod:`host.hand.recording`) write the host's
bytes (``/arm/bus/tx``, ``/hand/frames/tx``), what came back (``/arm/bus/rx``,
``/hand/frames/rx``), each with the link's clock as its publish time, and a ``source``
metadata record (:func:`host.recording.writer.source_metadata`): the link, its URL and the
link's clock when the recorder attached.  An ``emu://`` URL names the emulator (its
configuration, seed, sensors, scene: :func:`hil_emulator.inprocess.parse_url`); any other
URL (a serial port, a pty) does not, and replay assumes the defaults and says so.  A file cut
short (a killed recorder) is read up to its cut (:func:`tools.cli.mcap_capture.read_recording`)
and replayed as far as it goes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Final

from hil_emulator.inprocess import EmulatorSpec, parse_url
from host.arm.recording import EARLIER_TOPIC, OTHERS_TOPIC
from host.errors import UsageError
from host.hand.recording import FRAMES_EARLIER, FRAMES_OTHERS
from host.recording.writer import SOURCE_METADATA
from tools.cli.mcap_capture import read_recording
from tools.errors import McapCaptureError, ReplayRefused

#: Each host link's (sent, received) topics.
LINK_TOPICS: Final = {"arm": ("/arm/bus/tx", "/arm/bus/rx"),
                      "hand": ("/hand/frames/tx", "/hand/frames/rx")}
#: Each link's topic of what other programs sent on it before the recorded one: replayed
#: (the robot as the recording found it), not compared.
EARLIER_TOPICS: Final = {"arm": EARLIER_TOPIC, "hand": FRAMES_EARLIER.name}
#: Each link's topic of what other programs sent on it while the recorded one was open
#: (a flasher beside the hand's own link): replayed, not compared.
OTHERS_TOPICS: Final = {"arm": OTHERS_TOPIC, "hand": FRAMES_OTHERS.name}
#: The emulator's link name of a hand session's ``link`` (:class:`host.hand.session.HandSession`).
HAND_LINKS: Final = {"palm": "palm", "finger": "finger0", "finger0": "finger0"}


@dataclass(frozen=True)
class Timed:
    """Bytes on a link at ``t`` (s, the link's clock)."""

    t: float
    data: bytes


@dataclass
class LinkTraffic:
    """One host link of a recording: ``kind`` (``arm`` or ``hand``), the emulator's ``link``
    name (``arm``, ``palm``, ``finger0``), what the host sent (``tx``) and received (``rx``)."""

    kind: str
    link: str
    tx: list[Timed] = field(default_factory=list)
    rx: list[Timed] = field(default_factory=list)
    #: What other programs sent on the link before the recorded one (sent, not compared).
    earlier: list[Timed] = field(default_factory=list)
    #: What other programs sent on the link while the recorded one was open (the same).
    others: list[Timed] = field(default_factory=list)

    def sent(self) -> list[Timed]:
        """Every host message to send on the link, the recorded program's and the others'."""
        return self.earlier + self.others + self.tx


@dataclass
class Recorded:
    """What replay needs of a recording: its ``links`` with traffic, the emulator ``spec``,
    whether its times are the emulator's own clock (``emulated``: an ``emu://`` recording;
    otherwise replay shifts them onto the emulator's), what it ``assumed`` (one sentence each),
    and ``truncated``: why the file stopped before its end (None when whole)."""

    path: str
    links: dict[str, LinkTraffic]
    spec: EmulatorSpec
    emulated: bool
    assumed: list[str] = field(default_factory=list)
    truncated: str | None = None

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last host message (s)."""
        times = [m.t for traffic in self.links.values() for m in traffic.tx]
        return max(times) - min(times) if times else 0.0


def load(path: str | Path, *, seed: int | None = None, sensors: str | None = None) -> Recorded:
    """Read the recording ``path``; ``seed`` and ``sensors`` override what it says.
    :class:`ReplayRefused` when it cannot be read, holds no host bytes or names an emulator
    that does not exist."""
    try:
        contents = read_recording(path)
    except McapCaptureError as exc:
        raise ReplayRefused(f"cannot read it: {exc}") from exc
    source = contents.metadata.get(SOURCE_METADATA, {})
    links: dict[str, LinkTraffic] = {}
    by_topic: dict[str, tuple[LinkTraffic, str]] = {}
    for kind, (tx, rx) in LINK_TOPICS.items():
        if tx in contents.encodings:
            link = "arm" if kind == "arm" else HAND_LINKS.get(source.get("link", ""), "palm")
            traffic = links[kind] = LinkTraffic(kind, link)
            by_topic[tx] = (traffic, "tx")
            by_topic[rx] = (traffic, "rx")
            by_topic[EARLIER_TOPICS[kind]] = (traffic, "earlier")
            by_topic[OTHERS_TOPICS[kind]] = (traffic, "others")
    for message in contents.messages:
        found = by_topic.get(message.channel)
        if found is not None:
            traffic, which = found
            getattr(traffic, which).append(Timed(message.publish_time_ns / 1e9, message.data))
    links = {k: v for k, v in links.items() if v.tx}
    if not links:
        cut = f" (the file is {contents.stopped} after {len(contents.messages)} messages)" \
            if contents.stopped else ""
        raise ReplayRefused(f"no host bytes in it: no messages on "
                            f"{', '.join(t for t, _ in LINK_TOPICS.values())}{cut}")
    assumed: list[str] = []
    url = source.get("url", "")
    if url.startswith("emu://"):
        try:
            spec = parse_url(url)
        except UsageError as exc:
            raise ReplayRefused(f"its emulator cannot be built: {exc}") from exc
        emulated = True
    else:
        config = "full" if len(links) == 2 else ("arm" if "arm" in links else "hand")
        if "hand" in links and links["hand"].link == "finger0":
            config = "loose-finger"
        spec = EmulatorSpec(config, links[next(iter(links))].link)
        emulated = False
        what = f"recorded on {url}" if url else "with no source record"
        assumed.append(f"{what}: assumed the {config!r} emulator, seed {spec.seed}, "
                       f"sensors {spec.sensors!r}, no scene, brought up (ready)")
    if seed is not None and seed != spec.seed:
        assumed.append(f"used seed {seed} instead of the recording's {spec.seed}")
        spec = replace(spec, seed=seed)
    if sensors is not None and sensors != spec.sensors:
        assumed.append(f"used sensors {sensors!r} instead of the recording's "
                       f"{spec.sensors!r}")
        spec = replace(spec, sensors=sensors)
    missing = [kind for kind in links if not _offers(spec.config, links[kind].link)]
    if missing:
        raise ReplayRefused(f"the {spec.config!r} emulator it names has no "
                            f"{' or '.join(links[k].link for k in missing)} link")
    if source and source.get("earlier", "unknown") == "unknown" and url.startswith("emu://"):
        assumed.append("the link's use before the recording is unknown: assumed none")
    if source.get("prologue") == "partial":
        assumed.append("the link's opening is only partly in the file: assumed the rest "
                       "changed nothing")
    truncated = None
    if contents.stopped:
        truncated = (f"the file is {contents.stopped} ({contents.unread} bytes unread); "
                     f"replayed the {sum(len(t.tx) for t in links.values())} host messages "
                     f"before the cut")
    return Recorded(str(path), links, spec, emulated, assumed, truncated)


def merge(recordings: list[Recorded]) -> Recorded:
    """One session recorded by several recorders (``make demo``'s ``arm.mcap`` and
    ``hand.mcap``: one emulator, one recorder per link) as one recording, so every link is
    driven on one emulator, as it was; :class:`ReplayRefused` when they name different
    emulators, repeat a link, or mix an emulator's clock with a serial port's."""
    first = recordings[0]
    if len(recordings) == 1:
        return first
    links: dict[str, LinkTraffic] = {}
    for rec in recordings:
        if rec.spec.key()[:-1] != first.spec.key()[:-1]:
            raise ReplayRefused(f"{rec.path} was recorded on another emulator than "
                                f"{first.path} ({rec.spec.config}, seed {rec.spec.seed}, "
                                f"sensors {rec.spec.sensors}, scene {rec.spec.scene} against "
                                f"{first.spec.config}, seed {first.spec.seed}, sensors "
                                f"{first.spec.sensors}, scene {first.spec.scene})")
        if rec.emulated != first.emulated:
            raise ReplayRefused(f"{rec.path} and {first.path} do not share a clock (one is an "
                                f"emu:// recording, the other not)")
        for kind, traffic in rec.links.items():
            if kind in links:
                raise ReplayRefused(f"{rec.path} repeats the {kind} link of another file: "
                                    f"give each link's recording once")
            links[kind] = traffic
    assumed = [a for rec in recordings for a in rec.assumed]
    cuts = [f"{rec.path}: {rec.truncated}" for rec in recordings if rec.truncated]
    return Recorded(" + ".join(rec.path for rec in recordings), links, first.spec,
                    first.emulated, assumed, "; ".join(cuts) or None)


def _offers(config: str, link: str) -> bool:
    from hil_emulator.inprocess import LINKS

    return link in LINKS.get(config, ())
