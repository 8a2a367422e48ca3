"""The emulated robot: firmware nodes, buses, MuJoCo plant and host ports on one clock.

:class:`Emulator` builds one of the :data:`CONFIGS`:

``full``          the hand on the arm's wrist: palm port, arm port, CAN (SLCAN pty);
``hand``          the hand on a fixed stand with an object to grasp: palm port, CAN;
``arm``           the arm alone: arm port;
``loose-finger``  one finger module on a bench, its pogo bus on a 2 Mbaud port (the
                  original's 'loose finger' cable): ``fingers[0]``.

Every node runs its real ``firmware_py`` program on a :class:`~firmware_py.sim.virtual_hal.VirtualHal`
driven by one :class:`~firmware_py.scheduler.Scheduler` (integer µs); the plant
(:mod:`hil_emulator.plant`) ticks on the same clock.  :meth:`Emulator.run` serves the ports
either paced to the wall clock (``realtime=True``: programs with wall-clock timeouts work) or
as fast as the CPU allows; in-process users call :meth:`Emulator.step` and share the clock.
A ``seed`` makes a run repeatable: same seed, same inputs → same frames, same physics.
"""

from __future__ import annotations

import gc
import math
import os
import select
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Final

import numpy as np

from firmware_py.scheduler import Scheduler
from hil_emulator.arm_rig import ArmRig
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand_rig import HandRig, LooseFinger
from hil_emulator.host_links import SerialLink, SlcanLink, VirtualCanLink
from hil_emulator.plant import Plant, PlantPart, new_spec

#: The configurations :class:`Emulator` can build.
CONFIGS: Final = ("full", "hand", "arm", "loose-finger")
#: Longest the real-time loop sleeps without looking at its ports (s).
MAX_SLEEP_S: Final = 0.002
#: Height of the hand's stand in the ``hand`` configuration (m); the palm faces up.
STAND_Z_M: Final = 0.4
#: Lateness samples kept for :meth:`Emulator.lateness_stats`.
LATENESS_SAMPLES: Final = 200_000

CanMode = str  # "slcan" (a pty), "virtual:<channel>" (python-can, same process), "none"


class Emulator:
    """One emulated robot.  Build it, :meth:`open_ports`, then :meth:`run` or :meth:`step`.

    ``layout`` names the hand layout (:data:`hil_emulator.hand_model.LAYOUTS`); ``physics``
    False leaves the MuJoCo plant out (firmware and buses only); ``can`` is ``"slcan"``
    (default), ``"virtual:<channel>"`` or ``"none"``.
    """

    def __init__(self, config: str = "full", *, seed: int = 0, layout: str | None = None,
                 physics: bool = True, can: CanMode = "slcan") -> None:
        if config not in CONFIGS:
            raise EmulatorConfigError(
                f"unknown configuration {config!r}; choose one of {', '.join(CONFIGS)}")
        if seed < 0:
            raise EmulatorConfigError(f"the seed must be >= 0, got {seed}")
        from hil_emulator import hand_model

        layout = layout or hand_model.DEFAULT_LAYOUT
        if layout not in hand_model.LAYOUTS:
            raise EmulatorConfigError(f"unknown hand layout {layout!r}; choose one of "
                                      f"{', '.join(hand_model.LAYOUTS)}")
        self.config = config
        self.seed = seed
        self.can_mode = can
        self.scheduler = Scheduler()
        seeds = iter(np.random.SeedSequence(seed).generate_state(16))
        self.hand: HandRig | None = None
        self.arm: ArmRig | None = None
        self.loose: LooseFinger | None = None
        if config in ("full", "arm"):
            self.arm = ArmRig(self.scheduler, seed=int(next(seeds)))
        if config in ("full", "hand"):
            self.hand = HandRig(self.scheduler, line_model=True, seed=int(next(seeds)),
                                record=False)
        if config == "loose-finger":
            self.loose = LooseFinger(self.scheduler, line_model=True, seed=int(next(seeds)),
                                     record=False)
        self.layout = layout  #: the hand layout's name
        self.plant: Plant | None = None
        self.finger_plants: list[Any] = []
        self.arm_plant: Any = None
        if physics:
            self.plant = self._build_plant(layout, seeds)
            self.plant.attach(self.scheduler)
        self.links: dict[str, Any] = {}
        self.lateness_s: deque[float] = deque(maxlen=LATENESS_SAMPLES)
        self._wall0 = 0.0
        self._sim0 = 0
        self._realtime = False
        self._closed = False
        #: Real time: poll instead of sleeping between events.  Sleeping costs no CPU, but
        #: a woken process is often a millisecond or more late; polling keeps delivery
        #: lateness well under a millisecond at the price of one busy core.
        self.spin = True
        # Supplies on: the palm and the loose finger start their bootloaders; arm nodes run.
        if self.hand is not None:
            self.hand.power_on()
        if self.loose is not None:
            self.loose.power_on()

    # ------------------------------------------------------------------ building
    def _build_plant(self, layout: str, seeds: Any) -> Plant:
        from hil_emulator import arm_model, hand_model
        from hil_emulator.arm_plant import ArmPlant
        from hil_emulator.finger_plant import FingerPlant, PalmPlant

        def rng() -> np.random.Generator:
            return np.random.default_rng(int(next(seeds)))

        spec = new_spec(f"hil-{self.config}")
        parts: list[PlantPart] = []
        hand_parent = None
        if self.arm is not None:
            base = spec.worldbody.add_body(name="arm_base",
                                           pos=[0.0, 0.0, arm_model.MOUNT_HEIGHT_M])
            hand_parent = arm_model.add_arm(spec, base, prefix="arm/")
            self.arm_plant = ArmPlant("arm/", self.arm.stepper_hals, self.arm.servo_hals,
                                      rng())
            parts.append(self.arm_plant)
        if self.hand is not None:
            if hand_parent is None:
                hand_parent = spec.worldbody.add_body(name="stand", pos=[0.0, 0.0, STAND_Z_M])
                # An object resting on the palm, ready to be grasped.
                hand_model.add_grasp_object(spec, spec.worldbody,
                                            pos=(0.0, 0.012, STAND_Z_M + 0.036))
            hand_model.add_hand(spec, hand_parent, layout=layout, prefix="hand/")
            parts.append(PalmPlant("hand/", self.hand.palm, rng()))
            for finger in self.hand.fingers:
                fp = FingerPlant(f"hand/finger{finger.index}/", finger.fmcb, finger.f2,
                                 finger.f3, rng())
                self.finger_plants.append(fp)
                parts.append(fp)
        if self.loose is not None:
            bench = spec.worldbody.add_body(name="bench_clamp", pos=[0.0, 0.0, 0.3])
            hand_model.add_finger(spec, bench, "finger0/")
            f = self.loose.finger
            fp = FingerPlant("finger0/", f.fmcb, f.f2, f.f3, rng())
            self.finger_plants.append(fp)
            parts.append(fp)
        return Plant(spec, parts)

    # ------------------------------------------------------------------ ports
    def open_ports(self, link_dir: str | None = None) -> dict[str, Any]:
        """Create the host ports (and ``link_dir`` symlinks); returns :meth:`describe`."""
        if self.hand is not None:
            palm = SerialLink.to_uart("palm", self.hand.host_uart)
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
            arm = SerialLink("arm", self.arm.bus.baud, self.arm.send_from_host)
            self.arm.on_host_bytes = arm.emit
            self.links["arm"] = arm
        if self.loose is not None:
            finger = SerialLink.to_uart("finger0", self.loose.host_uart)
            self.loose.on_host_bytes = finger.emit
            self.links["finger0"] = finger
        for link in self.links.values():
            link.on_emit = self._record_lateness
            link.schedule_input = self._schedule_input
        self.link_paths: dict[str, str] = {}
        if link_dir is not None:
            for name, link in self.links.items():
                if isinstance(link, SerialLink | SlcanLink):
                    self.link_paths[name] = link.link(link_dir)
        # Everything built so far lives as long as the emulator: take it out of the cyclic
        # collector's sight now, before anyone is told the ports are ready, so neither this
        # pass nor later full passes stall a reply by tens of milliseconds.
        gc.collect()
        gc.freeze()
        return self.describe()

    def describe(self) -> dict[str, Any]:
        """The ports as the ``hil-emulator`` command prints them (one JSON object)."""
        def path(name: str) -> str | None:
            link = self.links.get(name)
            return None if link is None else str(link.path)

        out: dict[str, Any] = {
            "config": self.config,
            "palm": path("palm"),
            "arm": path("arm"),
            "fingers": [path("finger0")] if "finger0" in self.links else [],
        }
        if "can" in self.links:
            out["can"] = path("can")
            out["can_interface"] = "slcan" if self.can_mode == "slcan" else "virtual"
        out["seed"] = self.seed
        if self.hand is not None:
            out["hand_layout"] = self.layout
        if getattr(self, "link_paths", None):
            out["links"] = dict(self.link_paths)
        return out

    def bring_up(self, autopoll: bool = True) -> None:
        """Power and boot every hand node as a host would (palm, fingers, phalanges; fmcb
        autopoll on), on the simulation clock; call before :meth:`open_ports`.  The arm is
        left as it powers up, torque off.  The host library does it on the in-process
        transport (see :mod:`hil_emulator.bring_up`)."""
        from hil_emulator.bring_up import bring_up

        bring_up(self, autopoll)

    def transport(self, link: str) -> Any:
        """A :class:`host.transport.Transport` for host code in this process on link
        ``link`` (``palm``, ``arm``, ``finger0``), on the simulation clock (fast lockstep);
        see :mod:`hil_emulator.inprocess`."""
        from hil_emulator.inprocess import EmulatorTransport

        return EmulatorTransport(self, link)

    # ------------------------------------------------------------------ faults
    def break_away(self, finger: int) -> None:
        """Finger ``finger`` leaves its pogo pins (overload): no link, no power, motors
        coast in the plant."""
        hand = self._require_hand()
        hand.break_away(finger)
        if self.finger_plants:
            self.finger_plants[finger].attached = False

    def reattach(self, finger: int, bounce: bool = True) -> None:
        """Finger ``finger`` is pushed back on, with contact bounce unless ``bounce`` is
        False; it gets the palm's power state once the contacts settle."""
        hand = self._require_hand()
        hand.reattach(finger, bounce=bounce)
        if self.finger_plants:
            self.finger_plants[finger].attached = True

    def tendon_glitch(self, finger: int, duration_us: int) -> None:
        """Finger ``finger``'s tendon contact opens for ``duration_us`` µs."""
        self._require_hand().tendon_glitch(finger, duration_us)

    def _require_hand(self) -> HandRig:
        if self.hand is None:
            raise EmulatorConfigError(f"the {self.config!r} configuration has no hand")
        return self.hand

    # ------------------------------------------------------------------ running
    def step(self, duration_us: int) -> None:
        """Advance simulation time by ``duration_us`` µs, serving the ports at its start."""
        self._poll_links()
        self.scheduler.run_for(duration_us)

    def _poll_links(self) -> int:
        return sum(link.poll() for link in self.links.values())

    def _schedule_input(self, apply: Callable[[], None]) -> None:
        """Host input enters the simulation at the time matching the wall clock now (real
        time), or at the simulation's current time (fast, in-process)."""
        if self._realtime:
            now_us = self._sim0 + int((time.monotonic() - self._wall0) * 1e6)
            self.scheduler.call_at(now_us, apply)
        else:
            apply()

    def _record_lateness(self, t_us: int) -> None:
        if self._realtime:
            due = self._wall0 + (t_us - self._sim0) / 1e6
            self.lateness_s.append(time.monotonic() - due)

    def run(self, stop: threading.Event, realtime: bool = True,
            on_idle: Callable[[], None] | None = None, fast_chunk_us: int = 1_000) -> None:
        """Serve the ports until ``stop`` is set.

        Real time: simulation time follows the wall clock; between events the loop sleeps
        on the ports' descriptors.  Fast: the simulation runs ``fast_chunk_us`` at a time
        as fast as it can, polling the ports between chunks.  ``on_idle`` is called about
        every 16 ms of wall time (the viewer's sync)."""
        self._realtime = realtime
        self._wall0 = time.monotonic()
        self._sim0 = self.scheduler.now_us()
        fds = [fd for link in self.links.values() if (fd := link.fileno()) >= 0]
        next_idle = self._wall0
        while not stop.is_set():
            now = time.monotonic()
            if on_idle is not None and now >= next_idle:
                on_idle()
                next_idle = now + 0.016
            if not realtime:
                self.step(fast_chunk_us)
                continue
            self._poll_links()  # input is scheduled at the simulation time of "now"
            target = self._sim0 + int((time.monotonic() - self._wall0) * 1e6)
            self.scheduler.run_until(target)
            due = self.scheduler.next_due_us()
            wait = MAX_SLEEP_S if due is None else (due - self._sim0) / 1e6 - (
                time.monotonic() - self._wall0)
            wait = min(max(wait, 0.0), MAX_SLEEP_S)
            if self.spin:
                continue  # the OS wakes sleepers milliseconds late: keep the core instead
            if wait > 0.0 and fds:
                select.select(fds, [], [], wait)
            elif wait > 0.0:
                time.sleep(wait)

    def lateness_stats(self) -> dict[str, float]:
        """Real-time delivery lateness (ms): count, median, p99, max."""
        if not self.lateness_s:
            return {"count": 0, "p50_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}
        values = np.asarray(self.lateness_s) * 1e3
        return {"count": float(values.size), "p50_ms": float(np.percentile(values, 50)),
                "p99_ms": float(np.percentile(values, 99)), "max_ms": float(values.max())}

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        """Close every port and remove the symlinks (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for link in self.links.values():
            link.close()

    def __enter__(self) -> Emulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def has_display() -> bool:
    """True when a viewer window could open (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
