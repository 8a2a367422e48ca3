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

import ctypes
import gc
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
from hil_emulator.faults.host_link import LinkTap
from hil_emulator.hand_rig import HandRig, LooseFinger
from hil_emulator.host_links import PtyBacked, SerialLink, SlcanLink, VirtualCanLink
from hil_emulator.link_dir import LinkDirLock
from hil_emulator.plant import Plant, PlantPart, new_spec
from hil_emulator.scheduling import RT_BUSY_LIMIT_S, RT_YIELD_S, Scheduling, request_priority
from protocol.robot import HAND_ON_FLANGE_POSITION_M, HAND_ON_FLANGE_QUAT

#: The configurations :class:`Emulator` can build.
CONFIGS: Final = ("full", "hand", "arm", "loose-finger")
#: Longest the real-time loop sleeps without looking at its stop flag (s); host input and
#: signals wake it earlier.
MAX_SLEEP_S: Final = 0.02
#: The real-time loop sleeps until this long before the next event and spins from there
#: (s): with :data:`TIMER_SLACK_NS` a sleeper wakes within tens of µs of its deadline.
SPIN_S: Final = 0.00005
#: While it is not asleep, the real-time loop reads its ports at least this often (s); asleep,
#: host input wakes it at once.
POLL_S: Final = 0.0002
#: Timer slack (ns) the real-time loop asks of Linux for its own sleeps: the default 50 µs
#: would wake it up to that late.
TIMER_SLACK_NS: Final = 10_000
_PR_SET_TIMERSLACK: Final = 29
#: Events run between looks at the wall clock, the stop flag and the ports while catching
#: up (the full configuration runs about 35 events per ms of CPU: a look every ~0.6 ms).
CATCH_UP_EVENTS: Final = 20
#: Longest the real-time loop runs events before it serves the ports again (s).
CATCH_UP_BUDGET_S: Final = 0.005
#: Lateness (ms) from which the runner says it cannot keep up (once per episode).
LATE_WARN_MS: Final = 5.0
#: An episode of lateness ends after this long (s) with every event on time (within 1 ms).
LATE_EPISODE_END_S: Final = 1.0
#: Further behind than this (s), the simulation clock slips instead of replaying the lost
#: wall time in a burst: the simulation runs slower than the wall clock, replies stay prompt.
MAX_BEHIND_S: Final = 0.02
#: Height of the hand's stand in the ``hand`` configuration (m); the palm faces up.
STAND_Z_M: Final = 0.4
#: Lateness samples kept for :meth:`Emulator.lateness_stats`.
LATENESS_SAMPLES: Final = 200_000

CanMode = str  # "slcan" (a pty), "virtual:<channel>" (python-can, same process), "none"


def tighten_timer_slack(slack_ns: int = TIMER_SLACK_NS) -> bool:
    """Ask Linux to wake this thread's timed sleeps within ``slack_ns`` ns of their deadline
    (``prctl(PR_SET_TIMERSLACK)``; no privilege needed).  False where it cannot be set."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


class Emulator:
    """One emulated robot.  Build it, :meth:`open_ports`, then :meth:`run` or :meth:`step`.

    ``layout`` names the hand layout (:data:`hil_emulator.hand_model.LAYOUTS`); ``physics``
    False leaves the MuJoCo plant out (firmware and buses only); ``can`` is ``"slcan"``
    (default), ``"virtual:<channel>"`` or ``"none"``; ``scene`` adds things to the world
    (:data:`hil_emulator.scene_model.SCENES`: ``"none"``, ``"mug"`` — a table and a coffee
    mug in front of the arm; configurations with the arm only).
    """

    def __init__(self, config: str = "full", *, seed: int = 0, layout: str | None = None,
                 physics: bool = True, can: CanMode = "slcan", scene: str = "none") -> None:
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
        from hil_emulator.scene_model import SCENES

        if scene not in SCENES:
            raise EmulatorConfigError(f"unknown scene {scene!r}; choose one of "
                                      f"{', '.join(SCENES)}")
        if scene != "none" and config not in ("full", "arm"):
            raise EmulatorConfigError(f"the {scene!r} scene stands in front of the arm: use it "
                                      f"with the full or arm configuration, not {config!r}")
        self.config = config
        self.scene = scene  #: the scene's name (:data:`hil_emulator.scene_model.SCENES`)
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
        #: The scene's object trackers (:class:`hil_emulator.scene_model.MugTracker`).
        self.scene_parts: list[Any] = []
        if physics:
            self.plant = self._build_plant(layout, seeds)
            self.plant.attach(self.scheduler)
        self.links: dict[str, Any] = {}
        self.lateness_s: deque[float] = deque(maxlen=LATENESS_SAMPLES)
        self._wall0 = 0.0
        self._sim0 = 0
        self._last_input_us = 0
        self._realtime = False
        self._closed = False
        #: The hold on ``--link-dir`` while the links are there (:mod:`.link_dir`).
        self._link_dir_lock: LinkDirLock | None = None
        #: Real time: how long before an event the loop stops sleeping and polls (s).
        self.spin_s = SPIN_S
        #: Told (one line of text) when the real-time loop starts to fall behind and when
        #: it has caught up; the ``hil-emulator`` command prints it on standard error.
        self.on_late: Callable[[str], None] | None = None
        #: Told (one line of text) when the real-time loop starts: the scheduling it got
        #: (:mod:`hil_emulator.scheduling`); the ``hil-emulator`` command prints it.
        self.on_notice: Callable[[str], None] | None = None
        #: The pacing thread's scheduling during the last real-time :meth:`run`.
        self.scheduling: Scheduling | None = None
        self.late_episodes = 0  #: episodes of lateness beyond :data:`LATE_WARN_MS`
        self.slipped_s = 0.0  #: wall time (s) the simulation clock gave up to keep up
        self._episode_worst_ms = 0.0
        self._episode_last_late = 0.0
        self._in_episode = False
        # Supplies on: the palm and the loose finger start their bootloaders; arm nodes run.
        if self.hand is not None:
            self.hand.power_on()
        if self.loose is not None:
            self.loose.power_on()
        from hil_emulator.faults import FaultInjector

        #: The fault registry's injector: plans, in-process injection, the timeline.
        self.faults = FaultInjector(self)
        self._taps: dict[str, LinkTap] = {}

    # ------------------------------------------------------------------ building
    def _build_plant(self, layout: str, seeds: Any) -> Plant:
        from hil_emulator import arm_model, hand_model, scene_model
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
            if self.arm is not None:  # on the wrist flange, the palm facing away from it
                hand_model.add_hand(spec, hand_parent, layout=layout, prefix="hand/",
                                    pos=HAND_ON_FLANGE_POSITION_M, quat=HAND_ON_FLANGE_QUAT)
            else:
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
        self.scene_parts = scene_model.add_scene(spec, self.scene)
        parts.extend(self.scene_parts)
        return Plant(spec, parts)

    # ------------------------------------------------------------------ ports
    def open_ports(self, link_dir: str | None = None) -> dict[str, Any]:
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
        if self.loose is not None:
            finger = SerialLink.to_uart("finger0", self.loose.host_uart)
            self.loose.host_uart.sink = self.loose._to_host  # through the link's fault tap
            self.loose.on_host_bytes = finger.emit
            self.links["finger0"] = finger
        for name, tap in self._taps.items():
            if isinstance(self.links.get(name), SerialLink):
                self.links[name].tap = tap
        for link in self.links.values():
            link.on_emit = self._record_lateness
            link.schedule_input = self._schedule_input
            if isinstance(link, SerialLink | SlcanLink | VirtualCanLink):
                link.input_clock = self._input_time_us
        self.link_paths: dict[str, str] = {}
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
        if self.scene != "none":
            out["scene"] = self.scene
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

    def rig(self, link: str) -> HandRig | ArmRig | LooseFinger:
        """The rig behind host link ``link`` (``palm``, ``arm``, ``finger0``)."""
        rig = {"palm": self.hand, "arm": self.arm, "finger0": self.loose}.get(link)
        if rig is None:
            raise EmulatorConfigError(f"the {self.config!r} configuration has no host link "
                                      f"{link!r}")
        return rig

    def link_tap(self, link: str) -> LinkTap:
        """The fault stages of host link ``link`` (made and wired on first use: the rig's
        output toward the host, the in-process transport and the pty's input)."""
        tap = self._taps.get(link)
        if tap is None:
            rig = self.rig(link)
            tap = self._taps[link] = LinkTap(link, self.scheduler)
            rig.link_tap = tap
            port = self.links.get(link)
            if isinstance(port, SerialLink):
                port.tap = tap
        return tap

    def open_control(self, path: str) -> str:
        """Listen for fault requests of another process on the unix socket ``path``
        (:mod:`hil_emulator.faults.control`); served by :meth:`run` like a port."""
        from hil_emulator.faults.control import ControlChannel

        self.links["control"] = ControlChannel(self, path)
        return path

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

    def _wall_us(self, wall_s: float) -> int:
        """The simulation time (µs) matching monotonic wall time ``wall_s`` (real time)."""
        return self._sim0 + int((wall_s - self._wall0) * 1e6)

    def _input_time_us(self, arrived: float | None = None) -> int:
        """When host input that arrived at ``arrived`` (monotonic s; None: now) enters the
        simulation (µs): the time matching the wall clock then (real time, never before
        earlier input nor the simulation's present), or the current time (fast).

        Real time and behind (events due before the wall clock's time have not run): the
        input does not queue behind that backlog.  The simulation clock slips to its
        present time (:attr:`slipped_s`) and the input enters there, so a reply costs only
        its own simulated time (the request's and reply's wire time, the device's
        turnaround) however far behind a busy machine has left the simulation."""
        if not self._realtime:
            return self.scheduler.now_us()
        scheduler = self.scheduler
        wall_us = self._wall_us(time.monotonic() if arrived is None else arrived)
        due = scheduler.next_due_us()
        if due is not None and due < wall_us:
            present = max(scheduler.now_us(), self._last_input_us)
            if wall_us > present:
                self._wall0 += (wall_us - present) / 1e6
                self.slipped_s += (wall_us - present) / 1e6
                wall_us = present
        t = max(wall_us, self._last_input_us, scheduler.now_us())
        self._last_input_us = t
        return t

    def _schedule_input(self, apply: Callable[[], None], t_us: int) -> None:
        """Host input enters the simulation at ``t_us`` (from :meth:`_input_time_us`; in
        fast mode and in-process: at once)."""
        if self._realtime:
            self.scheduler.call_at(t_us, apply)
        else:
            apply()

    def _record_lateness(self, t_us: int) -> None:
        if self._realtime:
            now = time.monotonic()
            late_s = now - (self._wall0 + (t_us - self._sim0) / 1e6)
            self.lateness_s.append(late_s)
            self._note_lateness(late_s * 1e3, now)

    def _note_lateness(self, late_ms: float, now: float) -> None:
        """Track episodes of lateness; tell :attr:`on_late` when one starts and ends."""
        if late_ms > 1.0:
            self._episode_last_late = now
        if late_ms > LATE_WARN_MS and not self._in_episode:
            self._in_episode = True
            self._episode_worst_ms = late_ms
            self.late_episodes += 1
            if self.on_late is not None:
                self.on_late(f"cannot keep up with the wall clock: {late_ms:.1f} ms late "
                             "(is the machine busy?); replies arrive late, and beyond "
                             f"{MAX_BEHIND_S * 1e3:g} ms the robot runs slower than the wall "
                             "clock, which a host's closed loop (armctl moveto) may not "
                             "settle under: `make compiled` or a smaller --config helps")
        elif self._in_episode:
            self._episode_worst_ms = max(self._episode_worst_ms, late_ms)
            if now - self._episode_last_late > LATE_EPISODE_END_S:
                self._in_episode = False
                if self.on_late is not None:
                    self.on_late(f"on time again; at worst {self._episode_worst_ms:.1f} ms "
                                 f"late, {self.slipped_s:.3f} s given up in all")

    def run(self, stop: threading.Event, realtime: bool = True,
            on_idle: Callable[[], None] | None = None, fast_chunk_us: int = 1_000,
            priority: str = "normal") -> None:
        """Serve the ports until ``stop`` is set.

        Real time: simulation time follows the wall clock.  Between events the loop sleeps
        on the ports' descriptors until :attr:`spin_s` before the next event (host input
        wakes it), then polls.  Catching up, it runs at most :data:`CATCH_UP_BUDGET_S` of
        events before serving the ports and looking at ``stop`` again, and serves the ports
        as soon as host input is waiting (a look every :data:`CATCH_UP_EVENTS` events); more than
        :data:`MAX_BEHIND_S` behind, the simulation clock slips (:attr:`slipped_s`).  How far
        behind it was when ``stop`` was set is recorded as lateness too (a process stopped
        and resumed, then told to stop, may never have run an event in between).
        Fast: the simulation runs ``fast_chunk_us`` at a time as fast as it can, polling the
        ports between chunks.  ``on_idle`` is called about every 16 ms of wall time (the
        viewer's sync).  ``priority`` ``"realtime"`` asks for real-time scheduling of the
        calling thread for the run (:func:`~hil_emulator.scheduling.request_priority`; real
        time only), told to :attr:`on_notice` and kept in :attr:`scheduling`; the thread
        gets its own scheduling back when the run ends."""
        self._realtime = realtime
        if not realtime:
            self._run_loop(stop, False, on_idle, fast_chunk_us)
            return
        tighten_timer_slack()
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        self.scheduling = got = request_priority(priority)
        if self.on_notice is not None:
            self.on_notice(got.describe())
        ported = [link for link in self.links.values() if isinstance(link, PtyBacked)]
        try:
            for link in ported:  # on this thread: the readers share its scheduling
                link.start_reader()
            self._run_loop(stop, True, on_idle, fast_chunk_us)
        finally:
            for link in ported:
                link.stop_reader()
            if (os.sched_getscheduler(0), os.sched_getparam(0)) != before:
                try:
                    os.sched_setscheduler(0, *before)
                except OSError:
                    pass

    def _run_loop(self, stop: threading.Event, realtime: bool,
                  on_idle: Callable[[], None] | None, fast_chunk_us: int) -> None:
        """The loop of :meth:`run`."""
        self._wall0 = time.monotonic()
        self._sim0 = self.scheduler.now_us()
        self._last_input_us = self._sim0
        rt_policy = self.scheduling is not None and self.scheduling.realtime and realtime
        slept_at = self._wall0  # when the loop last gave the CPU away
        next_idle = self._wall0
        next_poll = 0.0
        readable = True  # look at the ports first
        fds: list[int] = []
        scheduler = self.scheduler
        while not stop.is_set():
            now = time.monotonic()
            if on_idle is not None and now >= next_idle:
                on_idle()
                next_idle = now + 0.016
            if not realtime:
                self.step(fast_chunk_us)
                continue
            if readable or now >= next_poll:
                self._poll_links()  # input is scheduled at the simulation time of "now"
                # Descriptors each time: a port that vanished and came back has a new one.
                fds = [fd for link in self.links.values() if (fd := link.fileno()) >= 0]
                next_poll = now + POLL_S
                readable = False
                now = time.monotonic()
            target = self._wall_us(now)
            deadline = now + CATCH_UP_BUDGET_S
            while scheduler.run_some(target, CATCH_UP_EVENTS) == CATCH_UP_EVENTS:
                if stop.is_set() or time.monotonic() >= deadline:
                    break
                if fds and select.select(fds, [], [], 0)[0]:
                    readable = True
                    break  # host input is served before the rest of the backlog
            now = time.monotonic()
            now_us = self._wall_us(now)
            due = scheduler.next_due_us()
            behind_us = self._behind_us(due, now_us)
            if rt_policy and now - slept_at > RT_BUSY_LIMIT_S:
                time.sleep(RT_YIELD_S)  # real-time and busy for long: leave the CPU a while
                slept_at = now = time.monotonic()
                now_us = self._wall_us(now)
                behind_us = self._behind_us(due, now_us)
            if behind_us:  # behind: serve the ports, then go on
                self._note_lateness(behind_us / 1e3, now)
                if behind_us > MAX_BEHIND_S * 1e6:
                    self._wall0 += behind_us / 1e6
                    self.slipped_s += behind_us / 1e6
                continue
            self._note_lateness(0.0, now)
            wait = MAX_SLEEP_S if due is None else min((due - now_us) / 1e6, MAX_SLEEP_S)
            if wait <= self.spin_s:
                continue  # the next event is close: poll for it
            if fds:
                readable = bool(select.select(fds, [], [], wait - self.spin_s)[0])
            else:
                time.sleep(wait - self.spin_s)
            slept_at = time.monotonic()
        if realtime:  # how far behind it was when told to stop counts too
            now = time.monotonic()
            behind_us = self._behind_us(scheduler.next_due_us(), self._wall_us(now))
            if behind_us:
                self._note_lateness(behind_us / 1e3, now)

    @staticmethod
    def _behind_us(due_us: int | None, now_us: int) -> int:
        """How long (µs) the next event, due at ``due_us``, is overdue at ``now_us``; 0 if
        it is not (or there is none)."""
        return now_us - due_us if due_us is not None and due_us < now_us else 0

    def lateness_stats(self) -> dict[str, int | float | None]:
        """Real-time delivery lateness (ms): count, median, p99, max (None before any
        delivery), with the episodes of lateness and the wall time the clock gave up
        (``count`` and ``late_episodes`` are integers)."""
        out: dict[str, int | float | None] = {"count": len(self.lateness_s), "p50_ms": None,
                                              "p99_ms": None, "max_ms": None}
        if self.lateness_s:
            values = np.asarray(self.lateness_s) * 1e3
            out.update(p50_ms=float(np.percentile(values, 50)),
                       p99_ms=float(np.percentile(values, 99)), max_ms=float(values.max()))
        out["late_episodes"] = self.late_episodes
        out["slipped_s"] = self.slipped_s
        return out

    def scene_stats(self) -> dict[str, dict[str, float]]:
        """Ground truth of the scene's objects (``{"mug": MugTracker.summary()}``), empty
        without a scene or physics."""
        return {part.name: part.summary() for part in self.scene_parts}

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
