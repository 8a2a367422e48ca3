"""The loop that serves the emulator's ports and paces its simulation, with its statistics.

A :class:`Pacer` runs one :class:`~firmware_py.scheduler.Scheduler` and serves a set of
:class:`~hil_emulator.ports.host_links.Port` s (the host links, the fault control channel) until
told to stop, either paced to the wall clock (real time: programs with wall-clock timeouts
work) or as fast as the CPU allows.  In real time it also decides when host input enters
the simulation (:meth:`Pacer.input_time_us`), measures how late each delivery to the host
was (:attr:`Pacer.lateness_s`, :meth:`Pacer.lateness_stats`) and tells when it cannot keep
up (:attr:`Pacer.on_late`).  It knows nothing of what the scheduler runs.
"""

from __future__ import annotations

import ctypes
import select
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Final

import numpy as np

from firmware_py.scheduler import Scheduler
from hil_emulator.ports.host_links import HostLink, Port, PtyBacked
from host.scheduling import Scheduling, priority_for

#: Longest the real-time loop sleeps without looking at its stop flag (s); host input and
#: signals wake it earlier.
MAX_SLEEP_S: Final = 0.02
#: The real-time loop sleeps until this long before the next event and spins from there
#: (s): with :data:`TIMER_SLACK_NS` a sleeper wakes within tens of µs of its deadline.
SPIN_S: Final = 0.00005
#: While it is not asleep, the real-time loop looks at its ports' descriptors at least this
#: often (s) and reads those that have something; asleep, host input wakes it at once.
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
#: Lateness samples kept for :meth:`Pacer.lateness_stats`.
LATENESS_SAMPLES: Final = 200_000
#: A real-time loop busy this long (s) without sleeping (the simulation cannot keep up)
#: sleeps :data:`RT_YIELD_S` before it goes on: at least a tenth of its core stays free.
RT_BUSY_LIMIT_S: Final = 0.05
#: How long (s) such a loop gives the CPU away.
RT_YIELD_S: Final = 0.005


def tighten_timer_slack(slack_ns: int = TIMER_SLACK_NS) -> bool:
    """Ask Linux to wake this thread's timed sleeps within ``slack_ns`` ns of their deadline
    (``prctl(PR_SET_TIMERSLACK)``; no privilege needed).  False where it cannot be set."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


class Pacer:
    """Runs ``scheduler`` and serves ``ports`` (read live: ports added later are served).

    Host links are :meth:`attach` ed so that their input enters at the time the pacer
    chooses and their deliveries are measured; outside a real-time :meth:`run` input enters
    at once and nothing is measured.
    """

    def __init__(self, scheduler: Scheduler, ports: Mapping[str, Port]) -> None:
        self.scheduler = scheduler
        self.ports = ports
        #: Delivery lateness samples (s) of real-time runs, newest last.
        self.lateness_s: deque[float] = deque(maxlen=LATENESS_SAMPLES)
        #: Real time: how long before an event the loop stops sleeping and polls (s).
        self.spin_s = SPIN_S
        #: Told (one line of text) when the real-time loop starts to fall behind and when
        #: it has caught up; the ``hil-emulator`` command prints it on standard error.
        self.on_late: Callable[[str], None] | None = None
        #: Told (one line of text) when the real-time loop starts: the scheduling it got
        #: (:mod:`host.scheduling`); the ``hil-emulator`` command prints it.
        self.on_notice: Callable[[str], None] | None = None
        #: The pacing thread's scheduling during the last real-time :meth:`run`.
        self.scheduling: Scheduling | None = None
        self.late_episodes = 0  #: episodes of lateness beyond :data:`LATE_WARN_MS`
        self.slipped_s = 0.0  #: wall time (s) the simulation clock gave up to keep up
        self._wall0 = 0.0
        self._sim0 = 0
        self._last_input_us = 0
        self._realtime = False
        self._episode_worst_ms = 0.0
        self._episode_last_late = 0.0
        self._in_episode = False

    # ------------------------------------------------------------------ the host links
    def attach(self, link: HostLink) -> None:
        """Host input of ``link`` enters when this pacer says; its deliveries are measured."""
        link.on_emit = self._record_lateness
        link.schedule_input = self._schedule_input
        link.input_clock = self.input_time_us
        if isinstance(link, PtyBacked):
            link.on_notice = self._tell

    def _tell(self, text: str) -> None:
        """Pass one line to :attr:`on_notice` (if set)."""
        if self.on_notice is not None:
            self.on_notice(text)

    def poll(self) -> int:
        """Take what arrived on every port; returns how much."""
        return sum(port.poll() for port in self.ports.values())

    def step(self, duration_us: int) -> None:
        """Serve the ports, then advance simulation time by ``duration_us`` µs."""
        self.poll()
        self.scheduler.run_for(duration_us)

    def _wall_us(self, wall_s: float) -> int:
        """The simulation time (µs) matching monotonic wall time ``wall_s`` (real time)."""
        return self._sim0 + int((wall_s - self._wall0) * 1e6)

    def input_time_us(self, arrived: float | None = None) -> int:
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
        """Host input enters the simulation at ``t_us`` (from :meth:`input_time_us`; in
        fast mode and in-process: at once)."""
        if self._realtime:
            self.scheduler.call_at(t_us, apply)
        else:
            apply()

    # ------------------------------------------------------------------ lateness
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

    # ------------------------------------------------------------------ running
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
        calling thread for the run (:func:`~host.scheduling.priority_for`; real
        time only), told to :attr:`on_notice` and kept in :attr:`scheduling`; the thread
        gets its own scheduling back when the run ends."""
        self._realtime = realtime
        if not realtime:
            self._run_loop(stop, False, on_idle, fast_chunk_us)
            return
        tighten_timer_slack()
        with priority_for(priority) as got:
            self.scheduling = got
            if self.on_notice is not None:
                self.on_notice(got.describe())
            ported = [port for port in self.ports.values() if isinstance(port, PtyBacked)]
            try:
                for link in ported:  # on this thread: the readers adopt its scheduling
                    link.start_reader()
                self._run_loop(stop, True, on_idle, fast_chunk_us)
            finally:
                for link in ported:
                    link.stop_reader()

    def _descriptors(self) -> tuple[list[int], bool]:
        """The ports' descriptors to wait on, and whether they tell of everything that
        arrives: true when every port is a host link with a descriptor (its reader's
        wake-up pipe or its pty), so that a port whose descriptor is not readable has
        nothing to read; false with any other port (the fault control channel's listening
        socket does not tell of its clients' requests; an in-process CAN channel has no
        descriptor), which is then read on every pass."""
        fds = [fd for port in self.ports.values() if (fd := port.fileno()) >= 0]
        exact = bool(fds) and len(fds) == len(self.ports) and all(
            isinstance(port, PtyBacked) for port in self.ports.values())
        return fds, exact

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
        exact = False
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
                # Descriptors each time: a port that vanished and came back has a new one.
                fds, exact = self._descriptors()
                # Host links are read only when their descriptors say something arrived
                # (one select instead of a read per port); with any other port, every time.
                if readable or not exact or select.select(fds, [], [], 0)[0]:
                    self.poll()  # input is scheduled at the simulation time of "now"
                    fds, exact = self._descriptors()
                    now = time.monotonic()
                next_poll = now + POLL_S
                readable = False
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
            behind_us = _behind_us(due, now_us)
            if rt_policy and now - slept_at > RT_BUSY_LIMIT_S:
                time.sleep(RT_YIELD_S)  # real-time and busy for long: leave the CPU a while
                slept_at = now = time.monotonic()
                now_us = self._wall_us(now)
                behind_us = _behind_us(due, now_us)
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
            if not readable and exact:
                next_poll = slept_at + POLL_S  # the sleep was a look at every port
        if realtime:  # how far behind it was when told to stop counts too
            now = time.monotonic()
            behind_us = _behind_us(scheduler.next_due_us(), self._wall_us(now))
            if behind_us:
                self._note_lateness(behind_us / 1e3, now)


def _behind_us(due_us: int | None, now_us: int) -> int:
    """How long (µs) the next event, due at ``due_us``, is overdue at ``now_us``; 0 if it is
    not (or there is none)."""
    return now_us - due_us if due_us is not None and due_us < now_us else 0
