"""The emulator in the host's own process: a :class:`host.transport.Transport` on its clock.

Host code opened on ``emu://CONFIG/LINK`` (or given ``emulator.transport("palm")``) talks to
an :class:`~hil_emulator.emulator.Emulator` in fast lockstep: :meth:`EmulatorTransport.send`
puts bytes on the host adapter's wire at the current simulation time, and waiting in
:meth:`EmulatorTransport.recv` advances the simulation event by event until bytes arrive or
the timeout (simulation seconds) passes.  Timing is therefore exact and independent of how
busy the machine is: a reply arrives when its last bit would on the real wire.

URLs: ``emu://full/palm``, ``emu://full/arm``, ``emu://hand/palm``, ``emu://arm/arm``,
``emu://loose-finger/finger0``, options ``?seed=N&ready=1&physics=0&scene=mug&name=X``
(``scene``: :data:`hil_emulator.scene_model.SCENES`).  Transports
opened with the same configuration, seed, options and ``name`` share one emulator, so a
program can open ``emu://full/palm`` and ``emu://full/arm`` and drive one robot.
``ready=1`` (the default) brings the hand up first, as ``hil-emulator --ready`` does.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Final

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from host.errors import TransportError, UsageError
from host.transport import LinkKind, Transport, url_options

#: The link names each configuration offers.
LINKS: Final = {"full": ("palm", "arm"), "hand": ("palm",), "arm": ("arm",),
                "loose-finger": ("finger0",)}

_shared: dict[tuple[str, ...], Emulator] = {}


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
                 tee: bool = False) -> None:
        super().__init__(url or f"emu://{emulator.config}/{link}")
        rig = {"palm": emulator.hand, "arm": emulator.arm, "finger0": emulator.loose}.get(link)
        if rig is None:
            raise UsageError(f"the {emulator.config!r} emulator has no {link!r} link; "
                                 f"it has {', '.join(LINKS[emulator.config])}")
        self.emulator = emulator
        self.link = link
        self._rig = rig
        self._inbox: deque[bytes] = deque()
        self._displaced: Callable[[bytes, int], None] | None = rig.on_host_bytes
        self._tee = tee
        rig.on_host_bytes = self._arrived

    @classmethod
    def from_url(cls, url: str, **options: Any) -> EmulatorTransport:
        """``emu://CONFIG/LINK?seed=N&ready=1&physics=1&scene=S&name=X``."""
        rest = url.split("://", 1)[1].split("?", 1)[0]
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
        ready = merged.pop("ready", "1") not in ("0", "false", "no")
        physics = merged.pop("physics", "1") not in ("0", "false", "no")
        scene = merged.pop("scene", "none")
        name = merged.pop("name", "")
        if merged:
            raise UsageError(f"{url}: unknown emulator options {sorted(merged)}; it takes "
                             "seed, ready, physics, scene and name")
        key = (config, str(seed), str(ready), str(physics), scene, name)
        emulator = _shared.get(key)
        if emulator is None:
            try:
                emulator = Emulator(config, seed=seed, physics=physics, can="none",
                                    scene=scene)
            except EmulatorConfigError as exc:
                raise UsageError(f"{url}: {exc}") from exc
            if ready:
                emulator.bring_up()
            _shared[key] = emulator
        return cls(emulator, link, url)

    def _arrived(self, data: bytes, t_us: int) -> None:
        self._inbox.append(data)
        if self._tee and self._displaced is not None:
            self._displaced(data, t_us)

    def now(self) -> float:
        """Simulation time (s)."""
        return self.emulator.scheduler.now_us() / 1e6

    def sleep(self, seconds: float) -> None:
        """Advance the simulation by ``seconds``."""
        if seconds > 0:
            self.emulator.step(int(round(seconds * 1e6)))

    def _send(self, data: bytes) -> None:
        tap = self._rig.link_tap
        if tap is not None:
            if tap.vanished:
                raise TransportError(f"{self.url}: the port has vanished (fault injected)")
            data = tap.down(data)
            if not data:
                return
        self._rig.send_from_host(data)

    def _recv(self, timeout: float | None) -> bytes:
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
        out = b"".join(self._inbox)
        self._inbox.clear()
        return out

    def _close(self) -> None:
        if self._rig.on_host_bytes == self._arrived:
            self._rig.on_host_bytes = self._displaced

    def _reopen(self) -> None:
        self._rig.on_host_bytes = self._arrived


def forget_shared_emulators() -> None:
    """Drop the emulators URL-opened transports share (tests start from a fresh robot)."""
    _shared.clear()

