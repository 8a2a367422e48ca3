"""The emulated robot behind its host ports, served on one clock.

:class:`Emulator` is an :class:`~hil_emulator.robot.EmulatedRobot` (one of
:data:`~hil_emulator.robot.CONFIGS`: ``full``, ``hand``, ``arm``, ``loose-finger``) with the
ports a host opens:

``full``          palm port, arm port, CAN (SLCAN pty);
``hand``          palm port, CAN;
``arm``           arm port;
``loose-finger``  the finger's pogo bus on a 2 Mbaud port (``finger0``).

:meth:`Emulator.run` serves the ports with its :class:`~hil_emulator.pacing.Pacer`, either
paced to the wall clock (``realtime=True``: programs with wall-clock timeouts work) or as
fast as the CPU allows; in-process users call :meth:`Emulator.step` and share the clock
(:mod:`hil_emulator.inprocess`: a host transport on it, and the hand's bring-up).  A
``seed`` makes a run repeatable: same seed, same inputs → same frames, same physics.  Faults
are applied from outside by whoever runs a plan (:mod:`hil_emulator.faults`); the emulator
offers them its parts, its ports and each host link's :class:`~hil_emulator.ports.link_tap.LinkTap`.
"""

from __future__ import annotations

import gc
import os
import threading
from collections.abc import Callable
from typing import TypedDict

from hil_emulator.errors import EmulatorConfigError
from hil_emulator.imperfections import DEFAULT_SENSORS
from hil_emulator.pacing import Pacer
from hil_emulator.ports.host_links import HostLink, Port, SerialLink, SlcanLink, VirtualCanLink
from hil_emulator.ports.link_dir import LinkDirLock
from hil_emulator.ports.link_tap import LinkTap
from hil_emulator.profile import RobotProfile
from hil_emulator.robot import EmulatedRobot

CanMode = str  # "slcan" (a pty), "virtual:<channel>" (python-can, same process), "none"
#: The most USB–RS-485 adapters the arm's bus takes (each a port).
MAX_ARM_ADAPTERS = 8


def arm_adapter_name(k: int) -> str:
    """The port of the arm bus's adapter ``k`` (1: ``arm``, the host's; then ``arm2``, …)."""
    return "arm" if k == 1 else f"arm{k}"


class PortsDescription(TypedDict, total=False):
    """The ports as the ``hil-emulator`` command prints them (:meth:`Emulator.describe`):
    always ``config``, ``palm``, ``arm``, ``fingers`` (paths, or None / empty where the
    configuration has none), ``seed`` and ``sensors``; ``arm_adapters`` with an arm (the
    paths of its bus's adapters, ``arm`` first); ``can`` and ``can_interface`` with a CAN link,
    ``scene`` with a scene, ``hand_layout`` with a hand, ``links`` with a link directory,
    ``profile`` (its file) with a robot profile read from one."""

    config: str
    palm: str | None
    arm: str | None
    arm_adapters: list[str | None]
    fingers: list[str | None]
    can: str | None
    can_interface: str
    seed: int
    sensors: str
    scene: str
    hand_layout: str
    links: dict[str, str]
    profile: str


class Emulator(EmulatedRobot):
    """One emulated robot and its host ports.  Build it, :meth:`open_ports`, then
    :meth:`run` or :meth:`step`.

    ``can`` is ``"slcan"`` (default), ``"virtual:<channel>"`` or ``"none"``;
    ``arm_adapters`` the USB–RS-485 adapters on the arm's bus, each a port (``arm``,
    ``arm2``, …: :data:`MAX_ARM_ADAPTERS` at most); the other arguments build the robot
    (:class:`~hil_emulator.robot.EmulatedRobot`).
    """

    def __init__(self, config: str = "full", *, seed: int = 0, layout: str | None = None,
                 physics: bool = True, can: CanMode = "slcan", scene: str = "none",
                 sensors: str = DEFAULT_SENSORS,
                 profile: RobotProfile | str | None = None, arm_adapters: int = 1) -> None:
        if not 1 <= arm_adapters <= MAX_ARM_ADAPTERS:
            raise EmulatorConfigError(f"the arm's bus takes 1 to {MAX_ARM_ADAPTERS} adapters, "
                                      f"not {arm_adapters}")
        if arm_adapters > 1 and config not in ("full", "arm"):
            raise EmulatorConfigError(f"the {config!r} configuration has no arm to put "
                                      f"{arm_adapters} adapters on")
        super().__init__(config, seed=seed, layout=layout, physics=physics, scene=scene,
                         sensors=sensors, profile=profile)
        self.can_mode = can
        self.arm_adapters = arm_adapters
        #: What :meth:`run` serves: the host links by name, and any :meth:`add_port`.
        self.links: dict[str, Port] = {}
        #: Where the links' symlinks are (:meth:`open_ports` with a link directory).
        self.link_paths: dict[str, str] = {}
        #: The loop serving :attr:`links` and its lateness statistics (:mod:`.pacing`).
        self.pacer = Pacer(self.scheduler, self.links)
        self._closed = False
        #: The hold on ``--link-dir`` while the links are there (:mod:`.link_dir`).
        self._link_dir_lock: LinkDirLock | None = None
        #: Each host link's fault stages, made on first use (:meth:`link_tap`).
        self.taps: dict[str, LinkTap] = {}

    # ------------------------------------------------------------------ ports
    def open_ports(self, link_dir: str | None = None) -> PortsDescription:
        """Create the host ports (and ``link_dir`` symlinks); returns :meth:`describe`."""
        if self.hand is not None:
            palm = SerialLink.to_uart("palm", self.hand.host_uart)
            self.hand.host_uart.sink = self.hand._to_host  # through the link's fault tap
            self.hand.on_host_bytes = palm.emit
            self.links["palm"] = palm
            palm_can = self.hand.palm_can
            if self.can_mode == "slcan":
                self.links["can"] = SlcanLink("can", palm_can)
            elif self.can_mode.startswith("virtual:"):
                self.links["can"] = VirtualCanLink("can", palm_can,
                                                   self.can_mode.partition(":")[2])
            elif self.can_mode != "none":
                raise EmulatorConfigError(f"unknown CAN mode {self.can_mode!r}")
        if self.arm is not None:
            arm = SerialLink("arm", self.arm.bus.baud, self.arm.send_from_host,
                             self.scheduler.now_us)
            self.arm.on_host_bytes = arm.emit
            self.links["arm"] = arm
            for k in range(2, self.arm_adapters + 1):
                uart = self.arm.add_adapter()
                adapter = SerialLink(arm_adapter_name(k), self.arm.bus.baud, uart.send,
                                     self.scheduler.now_us)
                uart.set_receiver(adapter.emit)
                self.links[adapter.name] = adapter
        if self.loose is not None:
            finger = SerialLink.to_uart("finger0", self.loose.host_uart)
            self.loose.host_uart.sink = self.loose._to_host  # through the link's fault tap
            self.loose.on_host_bytes = finger.emit
            self.links["finger0"] = finger
        for name, tap in self.taps.items():
            port = self.links.get(name)
            if isinstance(port, SerialLink):
                port.tap = tap
        for link in self.links.values():
            if isinstance(link, HostLink):
                self.pacer.attach(link)
        if link_dir is not None:
            self._link_dir_lock = LinkDirLock(link_dir)
            self._link_dir_lock.acquire()  # another live emulator's directory is refused
            for name, link in self.links.items():
                if isinstance(link, SerialLink | SlcanLink):
                    self.link_paths[name] = link.link(link_dir)
        # Everything built so far lives as long as the emulator: take it out of the cyclic
        # collector's sight now, before anyone is told the ports are ready, so neither this
        # pass nor later full passes stall a reply by tens of milliseconds.
        gc.collect()
        gc.freeze()
        return self.describe()

    def describe(self) -> PortsDescription:
        """The ports as the ``hil-emulator`` command prints them (one JSON object)."""
        def path(name: str) -> str | None:
            link = self.links.get(name)
            return link.path if isinstance(link, HostLink) else None

        out: PortsDescription = {"config": self.config, "palm": path("palm"),
                                 "arm": path("arm"),
                                 "fingers": [path("finger0")] if "finger0" in self.links else []}
        if self.arm is not None:
            out["arm_adapters"] = [path(arm_adapter_name(k))
                                   for k in range(1, self.arm_adapters + 1)]
        if "can" in self.links:
            out["can"] = path("can")
            out["can_interface"] = "slcan" if self.can_mode == "slcan" else "virtual"
        out["seed"] = self.seed
        out["sensors"] = self.sensors
        if self.scene != "none":
            out["scene"] = self.scene
        if self.hand is not None:
            out["hand_layout"] = self.layout
        if self.link_paths:
            out["links"] = dict(self.link_paths)
        if self.profile is not None and self.profile.source:
            out["profile"] = self.profile.source
        return out

    def add_port(self, port: Port) -> None:
        """Serve ``port`` too (the fault control channel), under its name; it is closed
        with the emulator."""
        self.links[port.name] = port

    def link_tap(self, link: str) -> LinkTap:
        """The fault stages of host link ``link`` (made and wired on first use: the rig's
        output toward the host, the in-process transport and the pty's input)."""
        tap = self.taps.get(link)
        if tap is None:
            rig = self.rig(link)
            tap = self.taps[link] = LinkTap(link, self.scheduler)
            rig.link_tap = tap
            port = self.links.get(link)
            if isinstance(port, SerialLink):
                port.tap = tap
        return tap

    # ------------------------------------------------------------------ running
    def step(self, duration_us: int) -> None:
        """Advance simulation time by ``duration_us`` µs, serving the ports at its start."""
        self.pacer.step(duration_us)

    def run(self, stop: threading.Event, realtime: bool = True,
            on_idle: Callable[[], None] | None = None, fast_chunk_us: int = 1_000,
            priority: str = "normal") -> None:
        """Serve the ports until ``stop`` is set, in real time or fast
        (:meth:`hil_emulator.pacing.Pacer.run`)."""
        self.pacer.run(stop, realtime, on_idle, fast_chunk_us, priority)

    def lateness_stats(self) -> dict[str, int | float | None]:
        """Real-time delivery lateness (:meth:`hil_emulator.pacing.Pacer.lateness_stats`)."""
        return self.pacer.lateness_stats()

    def link_stats(self) -> dict[str, dict[str, int]]:
        """Per port: bytes in and out, host input lost to overrun, output the host did not
        read, the longest input queue (µs)."""
        return {name: link.stats() for name, link in self.links.items()}

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        """Close every port and remove the symlinks (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for link in self.links.values():
            link.close()
        if self._link_dir_lock is not None:
            self._link_dir_lock.release()

    def __enter__(self) -> Emulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def has_display() -> bool:
    """True when a viewer window could open (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
