"""The emulator in the host's own process: a :class:`host.transports.base.Transport` on its clock,
and the hand brought up through it.

Host code opened on ``emu://CONFIG/LINK`` (or given ``EmulatorTransport(emulator, "palm")``)
talks to an :class:`~hil_emulator.emulator.Emulator` in fast lockstep: :meth:`EmulatorTransport.send`
puts bytes on the host adapter's wire at the current simulation time, and waiting in
:meth:`EmulatorTransport.recv` advances the simulation event by event until bytes arrive or
the timeout (simulation seconds) passes.  Timing is therefore exact and independent of how
busy the machine is: a reply arrives when its last bit would on the real wire.

URLs: ``emu://full/palm``, ``emu://full/arm``, ``emu://hand/palm``, ``emu://arm/arm``,
``emu://loose-finger/finger0``, options
``?seed=N&ready=1&physics=0&scene=mug&sensors=ideal&profile=PATH&name=X`` (``scene``:
:data:`hil_emulator.scene_model.SCENES`; ``sensors``: ``realistic``, the default, or
``ideal``, :mod:`hil_emulator.imperfections`; ``profile``: a robot profile file,
:mod:`hil_emulator.profile`).  Transports
opened with the same configuration, seed, options and ``name`` share one emulator, so a
program can open ``emu://full/palm`` and ``emu://full/arm`` and drive one robot.
``ready=1`` (the default) brings the hand up first, as ``hil-emulator --ready`` does.

:func:`bring_up` starts from a robot whose thirteen hand microcontrollers run their
applications (``hil-emulator --ready``, ``ready=1``, benchmarks, tests).  The host library
does it, through this transport: a :class:`~host.hand.facade.Hand` on the palm's link waits out the
palm's bootloader window (``AUTOBOOT_WINDOW_US``), powers the fingers (``palm.finger_power``), waits for each
fmcb to boot, powers the phalanges over the tendons (``fmcb.phalange_power``) and, after
their boot, switches on every fmcb's 100 Hz autopoll of its phalanges; a
:class:`~host.hand.session.HandSession` on a loose finger's cable does the same for its one
module.  Every reply is checked (route statuses), then the emulator checks that each node
runs its application.  The arm is left as it powers up: torque off, hanging, until the host
enables it.  The requests go without the ``txn`` envelope (``txn=False``) and each starts a
fixed slot of simulation time, so the frames and their times are those of the original
hand's host and a recorded run (``tools/traffic_record.py``) does not depend on the
envelope's format.  Bytes a listener already had on the link (a recorder) keep reaching it
(``tee``).
"""

from __future__ import annotations

import math
import weakref
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Final

from firmware_py.mcu import Mcu
from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError, EmulatorError
from hil_emulator.imperfections import DEFAULT_SENSORS
from hil_emulator.profile import RobotProfile
from host.errors import HostError, TransportError, UsageError
from host.hand.facade import Hand, Node
from host.hand.session import LINK_NODE, HandSession, Timeouts
from host.transports.base import LinkKind, Transport, url_options
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.messages.palm import ALL_FINGERS, FingerPower
from protocol.topology import FINGERS

#: The link names each configuration offers.
LINKS: Final = {"full": ("palm", "arm"), "hand": ("palm",), "arm": ("arm",),
                "loose-finger": ("finger0",)}

#: Time a hand node needs from power-up to its application (µs): the autoboot window and
#: 0.3 s for the application to start.
BOOT_US: Final = AUTOBOOT_WINDOW_US + 300_000
#: Stagger between fingers when the palm switches them all on (ms).
STAGGER_MS: Final = 5
#: How long the palm waits for an fmcb's reply to a routed bring-up request (ms).
ROUTE_MS: Final = 20
#: Simulation time each routed request is given before the next is sent (µs).
ROUTED_SLOT_US: Final = 30_000

_shared: dict[tuple[str, ...], Emulator] = {}
#: Host sends kept per emulator link for :meth:`EmulatorTransport.sent_before` (beyond, a
#: later transport is told the link's past is unknown).
SENT_LOG_LIMIT: Final = 20_000


class _SentLog:
    """One emulator link's host sends, in order, up to :data:`SENT_LOG_LIMIT`."""

    def __init__(self) -> None:
        self.sends: list[tuple[float, bytes]] = []
        self.complete = True
        #: The open transports on the link that keep what the others send
        #: (:meth:`EmulatorTransport.watch_others`).
        self.watchers: weakref.WeakSet[EmulatorTransport] = weakref.WeakSet()

    def add(self, t: float, data: bytes, sender: EmulatorTransport) -> None:
        if len(self.sends) < SENT_LOG_LIMIT:
            self.sends.append((t, data))
        else:
            self.complete = False
        for watcher in self.watchers:
            if watcher is not sender:
                watcher.others.append((t, data))


_sent: weakref.WeakKeyDictionary[Emulator, dict[str, _SentLog]] = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class EmulatorSpec:
    """What an ``emu://`` URL asks for: the emulator (``config``, ``seed``, ``ready``,
    ``physics``, ``scene``, ``sensors``, ``profile`` (a file's path, empty: none), its
    sharing ``name``) and the ``link`` opened."""

    config: str
    link: str
    seed: int = 0
    ready: bool = True
    physics: bool = True
    scene: str = "none"
    sensors: str = DEFAULT_SENSORS
    name: str = ""
    profile: str = ""

    def key(self) -> tuple[str, ...]:
        """What transports sharing one emulator have in common (all but the link)."""
        return (self.config, str(self.seed), str(self.ready), str(self.physics), self.scene,
                self.sensors, self.profile, self.name)  # the name last: merge() drops it

    def build(self, url: str = "", profile: RobotProfile | None = None) -> Emulator:
        """A new emulator of this spec (``profile`` instead of the spec's, when given),
        brought up (:func:`bring_up`) when ``ready``; :class:`UsageError` (naming ``url``)
        for a configuration or profile it cannot build."""
        try:
            emulator = Emulator(self.config, seed=self.seed, physics=self.physics, can="none",
                                scene=self.scene, sensors=self.sensors,
                                profile=profile or self.profile or None)
        except EmulatorConfigError as exc:
            raise UsageError(f"{url or self.config}: {exc}") from exc
        if self.ready:
            bring_up(emulator)
        return emulator


def parse_url(url: str, **options: object) -> EmulatorSpec:
    """The :class:`EmulatorSpec` of ``emu://CONFIG/LINK?…`` (``options`` override the
    URL's); :class:`UsageError` for an unknown configuration, link option or seed."""
    rest = url.split("://", 1)[1].split("?", 1)[0] if "://" in url else url
    config, _, link = rest.partition("/")
    if config not in LINKS:
        raise UsageError(f"{url}: unknown emulator configuration {config!r}; "
                         f"choose one of {', '.join(LINKS)}")
    link = link or LINKS[config][0]
    merged = {**url_options(url), **{k: str(v) for k, v in options.items()}}
    seed_text = merged.pop("seed", "0")
    try:
        seed = int(seed_text)
    except ValueError:
        raise UsageError(f"{url}: seed={seed_text!r} is not an integer") from None
    spec = EmulatorSpec(
        config, link, seed,
        ready=merged.pop("ready", "1") not in ("0", "false", "no"),
        physics=merged.pop("physics", "1") not in ("0", "false", "no"),
        scene=merged.pop("scene", "none"), sensors=merged.pop("sensors", DEFAULT_SENSORS),
        name=merged.pop("name", ""), profile=merged.pop("profile", ""))
    if merged:
        raise UsageError(f"{url}: unknown emulator options {sorted(merged)}; it takes "
                         "seed, ready, physics, scene, sensors, profile and name")
    return spec


class EmulatorTransport(Transport):
    """One host link of an in-process emulator (``link``: ``palm``, ``arm`` or
    ``finger0``), on the simulation clock.

    The transport takes the link's bytes from whatever listened before (a port, a
    recorder); ``tee`` keeps passing them to that listener too, and :meth:`close` gives
    the link back to it."""

    #: The simulation clock: wire times exact, so the palm's own budget (30 ms) is all.
    schemes: ClassVar[Mapping[str, LinkKind]] = {
        "emu": LinkKind("in-process", budget_s=0.030, exact_timing=True)}

    def __init__(self, emulator: Emulator, link: str, url: str | None = None, *,
                 tee: bool = False, logged: bool = True) -> None:
        super().__init__(url or f"emu://{emulator.config}/{link}")
        rig = {"palm": emulator.hand, "arm": emulator.arm, "finger0": emulator.loose}.get(link)
        if rig is None:
            raise UsageError(f"the {emulator.config!r} emulator has no {link!r} link; "
                                 f"it has {', '.join(LINKS[emulator.config])}")
        self.emulator = emulator
        self.link = link
        self._rig = rig
        self._inbox: deque[tuple[int, bytes]] = deque()  # (arrival µs, bytes)
        self._displaced: Callable[[bytes, int], None] | None = rig.on_host_bytes
        self._tee = tee
        #: Every host transport's sends on this emulator's link, shared by them (those of
        #: the bring-up, ``logged=False``, left out: a replay's emulator does it itself).
        self._log: _SentLog | None = (
            _sent.setdefault(emulator, {}).setdefault(link, _SentLog()) if logged else None)
        self._before = len(self._log.sends) if self._log is not None else 0
        #: What other transports sent on the link since :meth:`watch_others`.
        self.others: list[tuple[float, bytes]] = []
        self._known = self._log is not None and self._log.complete
        rig.on_host_bytes = self._arrived

    @classmethod
    def from_url(cls, url: str, **options: object) -> EmulatorTransport:
        """``emu://CONFIG/LINK?seed=N&ready=1&physics=1&scene=S&sensors=M&name=X``."""
        spec = parse_url(url, **options)
        key = spec.key()
        emulator = _shared.get(key)
        if emulator is None:
            emulator = spec.build(url)
            _shared[key] = emulator
        return cls(emulator, spec.link, url)

    def _arrived(self, data: bytes, t_us: int) -> None:
        self._inbox.append((t_us, data))
        if self._tee and self._displaced is not None:
            self._displaced(data, t_us)

    def now(self) -> float:
        """Simulation time (s)."""
        return self.emulator.scheduler.now_us() / 1e6

    def sleep(self, seconds: float) -> None:
        """Advance the simulation by ``seconds``."""
        if seconds > 0:
            self.emulator.step(int(round(seconds * 1e6)))

    def sent_before(self) -> list[tuple[float, bytes]] | None:
        """What earlier transports sent on this link of the emulator before this one
        opened (``(t, bytes)``, simulation s); the bring-up's requests are not in it."""
        if self._log is None or not self._known:
            return None
        return list(self._log.sends[:self._before])

    def watch_others(self) -> bool:
        """Keep what other logged transports send on this link from now on, until this one
        closes (the bring-up's sends are not kept: a replay's emulator does it itself)."""
        if self._log is None:
            return False
        self._log.watchers.add(self)
        return True

    def take_others(self) -> list[tuple[float, bytes]]:
        taken, self.others = self.others, []
        return taken

    def _send(self, data: bytes) -> None:
        if self._log is not None:
            self._log.add(self.now(), bytes(data), self)
        tap = self._rig.link_tap
        if tap is not None:
            if tap.vanished:
                raise TransportError(f"{self.url}: the port has vanished (fault injected)")
            data = tap.down(data)
            if not data:
                return
        self._rig.send_from_host(data)

    def _recv(self, timeout: float | None) -> bytes:
        return b"".join(data for _t, data in self._recv_timed(timeout))

    def _recv_timed(self, timeout: float | None) -> list[tuple[float, bytes]]:
        scheduler = self.emulator.scheduler
        if not self._inbox and timeout != 0.0:
            # At least 1 µs: a positive timeout must advance the clock, or a caller waiting
            # for a deadline a fraction of a µs away would spin for ever.
            deadline = None if timeout is None else scheduler.now_us() + max(
                1, math.ceil(timeout * 1e6))
            while not self._inbox:
                due = scheduler.next_due_us()
                if due is None:
                    if deadline is not None:
                        scheduler.run_until(deadline)
                    break
                if deadline is not None and due > deadline:
                    scheduler.run_until(deadline)
                    break
                scheduler.run_until(due)
        out = [(t_us / 1e6, data) for t_us, data in self._inbox]
        self._inbox.clear()
        return out

    def _close(self) -> None:
        if self._rig.on_host_bytes == self._arrived:
            self._rig.on_host_bytes = self._displaced
        if self._log is not None:  # what comes after is the next transport's to keep
            self._log.watchers.discard(self)

    def _reopen(self) -> None:
        self._rig.on_host_bytes = self._arrived


def bring_up(emulator: Emulator, autopoll: bool = True) -> None:
    """Power and boot every hand node of ``emulator`` (its hand, or its loose finger) with
    the host library, on the simulation clock; call before :meth:`Emulator.open_ports
    <hil_emulator.emulator.Emulator.open_ports>`.  The arm is left as it powers up, torque
    off.  Raise :class:`EmulatorError` if a request fails or a node is not
    running its application afterwards."""
    try:
        if emulator.hand is not None:
            with _session(emulator, "palm") as session:
                _bring_up_hand(emulator, Hand(session), autopoll)
            _check_running(emulator.hand.mcus)
        if emulator.loose is not None:
            with _session(emulator, "finger0") as session:
                fmcb = Node(session, LINK_NODE, "fmcb")
                _bring_up_finger(emulator, fmcb, BOOT_US, autopoll)
            finger = emulator.loose.finger
            _check_running([finger.fmcb, finger.f2, finger.f3])
    except HostError as exc:
        raise EmulatorError(f"bring-up: {exc}") from exc


def _session(emulator: Emulator, link: str) -> HandSession:
    transport = EmulatorTransport(emulator, link, tee=True, logged=False)
    return HandSession(transport, link="palm" if link == "palm" else "finger",
                       timeouts=Timeouts(fmcb_ms=ROUTE_MS), retries=0)


def _in_slot(emulator: Emulator, slot_us: int, node: Node, name: str,
             fields: dict[str, Any]) -> dict[str, Any]:
    """Request ``name`` of ``node`` un-enveloped, take its reply, and let the rest of
    ``slot_us`` (µs from the moment it was sent) pass."""
    sent_us = emulator.scheduler.now_us()
    reply = node.request(name, fields, txn=False)
    emulator.step(max(0, sent_us + slot_us - emulator.scheduler.now_us()))
    node.session.pump()
    return reply


def _bring_up_hand(emulator: Emulator, hand: Hand, autopoll: bool) -> None:
    emulator.step(BOOT_US)
    # The reply shows the first finger on; the others follow STAGGER_MS apart.
    _in_slot(emulator, BOOT_US + FINGERS * STAGGER_MS * 1000, hand.palm, "palm.finger_power",
             {"finger": ALL_FINGERS, "state": FingerPower.FULL, "stagger_ms": STAGGER_MS})
    for finger in hand.fingers:
        _in_slot(emulator, ROUTED_SLOT_US, finger.motor, "fmcb.phalange_power", {"on": 1})
    emulator.step(BOOT_US)
    if autopoll:
        for finger in hand.fingers:
            _in_slot(emulator, ROUTED_SLOT_US, finger.motor, "fmcb.autopoll", {"on": 1})


def _bring_up_finger(emulator: Emulator, fmcb: Node, boot_us: int, autopoll: bool) -> None:
    emulator.step(boot_us)
    _in_slot(emulator, boot_us, fmcb, "fmcb.phalange_power", {"on": 1})
    if autopoll:
        _in_slot(emulator, ROUTED_SLOT_US, fmcb, "fmcb.autopoll", {"on": 1})


def _check_running(mcus: list[Mcu]) -> None:
    stuck = [f"board {m.identity.board} uid {m.identity.uid:#x}" for m in mcus
             if not m.powered or m.program_name in (None, "bootloader")]
    if stuck:
        raise EmulatorError(f"bring-up: not running their application: {', '.join(stuck)}")


def forget_shared_emulators() -> None:
    """Drop the emulators URL-opened transports share (tests start from a fresh robot)."""
    _shared.clear()

