"""A live view of the robot in a browser, served on this machine with no internet.

:class:`RobotView` serves rerun's web viewer (from the ``rerun-sdk`` package, the optional
``view`` extra) on this machine and streams the robot's state to it while a session runs::

    view = RobotView()                 # prints nothing; view.address is the page to open
    arm = Arm.open("./robot/arm", view=view)
    hand = Hand.open("./robot/palm", view=view)   # one view: the hand drawn on the arm

What it draws is :mod:`host.view.render`'s: the arm and hand in 3D from the kinematics,
joint angles and goals, deflections and torques, tactile pads, currents and temperatures,
bus counters and alarms, as time series.

**Cheap enough to leave on.**  The page and its data are served by a child process
(:mod:`host.view.server`: rerun's own server, started with the view, ended with it or with
this process); this process only encodes and sends.  The robot's loop only hands a state
over: each attached object's tap offers at most ``max_rate_hz`` states a second per topic
(by the link's clock; the rest cost one comparison) to a bounded queue (``queue_size``;
an append, waking nothing), and when the queue is full the state is dropped and counted
(:attr:`dropped`), never waited for.  One daemon thread looks at the queue every
:data:`POLL_S`; once it holds about :data:`SEND_INTERVAL_S` of the robot's states (at the
rate limit), or :data:`MAX_WAIT_S` have passed, it turns them into the recorders' dicts,
draws them and sends them as one batch (:attr:`draw_cpu_s`: its CPU time).

rerun is imported when a view is made, never by ``import host``; without the package
:class:`ViewUnavailable` says how to install it.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

from host.errors import UsageError, ViewUnavailable

# Topics (the MCAP recorders' names; host.view.render draws them), importable from here too.
from host.recording.topics import ARM_BUS_STATS, ARM_STATE, HAND_EVENTS, HAND_LINK_STATS, HAND_STATE
from host.view.server import ViewServer, free_port
from protocol.robot import DEFAULT_HAND_LAYOUT

if TYPE_CHECKING:
    from host.arm.interface import WatchedArm
    from host.hand.interface import WatchedHand

__all__ = ["ARM_BUS_STATS", "ARM_STATE", "HAND_EVENTS", "HAND_LINK_STATS", "HAND_STATE",
           "MessageSink", "RobotView", "ViewSpec", "ViewUnavailable", "as_message",
           "open_view"]
#: Default port of the web page; the data it reads is served on the next port up.
WEB_PORT: Final = 9090
DEFAULT_RATE_HZ: Final = 10.0
DEFAULT_QUEUE: Final = 64
#: The bus and link counters are drawn once a second (s, the link's clock).
STATS_INTERVAL_S: Final = 1.0
#: How much of the robot's time the drawing thread gathers before it sends (s: the states
#: the rate limit lets through in that time): the page lags the robot by about this; each
#: send costs about the same for one state or many.
SEND_INTERVAL_S: Final = 0.5
#: ... but never longer than this (s, wall clock: a robot slower than real time, a hand's
#: events).
MAX_WAIT_S: Final = 2.0
#: How often the drawing thread looks at the queue (s, wall clock).
POLL_S: Final = 0.1
#: The series the page does not show (:data:`host.view.render.BACKGROUND`) go with every
#: this many sends (and with every :meth:`RobotView.drain` and the last).
BACKGROUND_EVERY: Final = 4
INSTALL_HINT: Final = "pip install 'lowcost-hand-stack[view]' (or: pip install rerun-sdk)"
#: What the view's queue holds: (topic, t (s), payload).
_Item = tuple[str, float, Any]


class MessageSink(Protocol):
    """What a telemetry consumer takes: one message on ``topic`` at ``t`` (s, the link's
    clock).  ``payload`` is the recorders' JSON-ready dict, or an object whose
    ``as_dict()``/``to_dict()`` gives it (turned into the dict only if it is used)."""

    def message(self, topic: str, t: float, payload: Any) -> None: ...


def as_message(payload: Any) -> Mapping[str, Any]:
    """The JSON-ready dict of ``payload`` (a dict, a state with ``as_dict``/``to_dict``, or a
    dataclass)."""
    if isinstance(payload, Mapping):
        return payload
    for name in ("as_dict", "to_dict"):
        method = getattr(payload, name, None)
        if method is not None:
            return dict(method())
    if dataclasses.is_dataclass(payload) and not isinstance(payload, type):
        return dataclasses.asdict(payload)
    raise TypeError(f"cannot turn {type(payload).__name__} into a message")


def _remove(taps: list[Any], tap: Any) -> None:
    if tap in taps:
        taps.remove(tap)


class RobotView:
    """Serves a view (``serve``: the web page on ``web_port`` and its data on
    ``grpc_port``, by default ``web_port + 1``; 0 picks free ports) and/or writes it to the
    rerun file ``save`` (.rrd);
    ``layout`` is the hand's.  A context manager; :meth:`close` stops the thread (after
    drawing what was queued), flushes and ends the server."""

    def __init__(self, *, serve: bool = True, web_port: int = WEB_PORT,
                 grpc_port: int | None = None, save: str | Path | None = None,
                 layout: str = DEFAULT_HAND_LAYOUT, max_rate_hz: float = DEFAULT_RATE_HZ,
                 queue_size: int = DEFAULT_QUEUE, application: str = "lowcost-hand") -> None:
        if max_rate_hz <= 0 or queue_size < 1:
            raise UsageError("a view needs a positive rate and a queue of at least 1")
        try:
            import rerun as rr

            from host.view.render import Renderer, blueprint
        except ImportError as exc:
            raise ViewUnavailable(f"the live view needs rerun-sdk: {INSTALL_HINT}") from exc
        self.address: str | None = None
        #: The child process serving the page (None when not serving).
        self.server: ViewServer | None = None
        sinks: list[Any] = []
        if serve:
            if grpc_port is None:
                grpc_port = web_port + 1 if web_port else 0
            self.server = ViewServer(web_port or free_port(), grpc_port or free_port())
            self.address = self.server.address
            sinks.append(rr.GrpcSink(self.server.url))
        try:
            if save is not None:
                sinks.append(rr.FileSink(str(save)))
            self.rec = rr.RecordingStream(application)
            if sinks:
                self.rec.set_sinks(*sinks, default_blueprint=blueprint())
            self.renderer = Renderer(self.rec, layout)
        except BaseException:
            if self.server is not None:
                self.server.close()
            raise
        self.min_interval = 1.0 / max_rate_hz
        self.queue_size = queue_size
        self.max_rate_hz = max_rate_hz
        #: States that make a batch: :data:`SEND_INTERVAL_S` of each attached object's.
        self.batch = 1
        self._queue: deque[_Item] = deque()
        self._wake = threading.Event()
        self._rounds = threading.Condition()
        self._asked = self._served = 0  # drain() requests, and the last one a round served
        self._detach: list[Callable[[], None]] = []
        self._samplers: dict[tuple[str, float | None], Callable[[float, Any], bool]] = {}
        self._streams = 0  # objects attached
        #: States handed over, drawn, and dropped because the queue was full.
        self.offered = 0
        self.drawn = 0
        self.dropped = 0
        #: CPU time the drawing thread has spent (s): turning states into dicts and
        #: rerun's logging calls (rerun's own threads and the server are not in it).
        self.draw_cpu_s = 0.0
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="robot-view", daemon=True)
        self._thread.start()

    # --- feeding ---------------------------------------------------------------------------
    def message(self, topic: str, t: float, payload: Any) -> None:
        """Queue one message (never blocks, wakes nothing: dropped when the queue is full)."""
        if self._closed:
            return
        self.offered += 1
        if len(self._queue) >= self.queue_size:
            self.dropped += 1
        else:
            self._queue.append((topic, t, payload))

    def sampler(self, topic: str, interval: float | None = None
                ) -> Callable[[float, Any], bool]:
        """A function ``offer(t, payload)`` that queues ``payload`` on ``topic`` at most
        ``max_rate_hz`` times a second (or one every ``interval`` s) by ``t`` (s, the link's
        clock), True if it did; a ``t`` before the last one offered (a clock restarted)
        starts afresh.  A state not offered costs one comparison."""
        period = interval or self.min_interval
        last, due = float("inf"), -float("inf")

        def offer(t: float, payload: Any) -> bool:
            nonlocal last, due
            if due > t >= last:
                return False
            last, due = t, t + period
            self.message(topic, t, payload)
            return True

        return offer

    def sample(self, topic: str, t: float, payload: Any, interval: float | None = None
               ) -> bool:
        """Queue a state at most ``max_rate_hz`` times a second per topic (or one every
        ``interval`` s; by ``t``); True if it was offered (:meth:`sampler`'s, per topic)."""
        offer = self._samplers.get((topic, interval))
        if offer is None:
            offer = self._samplers[(topic, interval)] = self.sampler(topic, interval)
        return offer(t, payload)

    def _attach(self, taps: list[Callable[[Any], None]], state_topic: str, stats_topic: str,
                counters: Any) -> None:
        """Draw every state the object's ``taps`` see on ``state_topic``, and its link
        ``counters`` (requests, retries, timeouts) once a second on ``stats_topic``."""
        state = self.sampler(state_topic)
        stats = self.sampler(stats_topic, STATS_INTERVAL_S)

        def tap(s: Any) -> None:
            if state(s.t, s):
                stats(s.t, {"requests": counters.requests, "retries": counters.retries,
                            "timeouts": counters.timeouts})

        taps.append(tap)
        self._detach.append(lambda: _remove(taps, tap))
        self._streams += 1
        self.batch = max(1, min(self.queue_size // 2,
                                round(self._streams * self.max_rate_hz * SEND_INTERVAL_S)))

    def attach_arm(self, arm: WatchedArm) -> None:
        """Draw every cycle's state of ``arm`` (and its bus counters) from now on."""
        self._attach(arm.state_taps, ARM_STATE, ARM_BUS_STATS, arm.bus.stats)

    def attach_hand(self, hand: WatchedHand) -> None:
        """Draw every state ``hand`` reads (its link counters) and every finger event."""
        self._attach(hand.state_taps, HAND_STATE, HAND_LINK_STATS, hand.session.counters)
        self._detach.append(
            hand.subscribe(lambda event: self.message(HAND_EVENTS, event.t, event)))

    # --- drawing ---------------------------------------------------------------------------
    def _run(self) -> None:
        """Every :data:`POLL_S` (at once when :meth:`drain` or :meth:`close` asks): when a
        batch is queued, or :data:`MAX_WAIT_S` have passed with something queued, draw it
        and send it.  The robot's loop never wakes this thread, and drawn together the
        states cost less than drawn one at a time between the robot's cycles."""
        sends = 0
        since = time.monotonic()
        while True:
            self._wake.wait(POLL_S)
            self._wake.clear()
            with self._rounds:
                serving = self._asked
            closing = self._closed
            asked = closing or serving > self._served
            waited = time.monotonic() - since
            if not (asked or len(self._queue) >= self.batch
                    or (self._queue and waited >= MAX_WAIT_S)):
                continue
            start = time.thread_time()
            for _ in range(len(self._queue)):
                self._draw(*self._queue.popleft())
            sends += 1
            self._send(asked or sends % BACKGROUND_EVERY == 0)
            since = time.monotonic()
            self.draw_cpu_s += time.thread_time() - start
            with self._rounds:
                self._served = serving
                self._rounds.notify_all()
            if closing:
                return

    def _draw(self, topic: str, t: float, payload: Any) -> None:
        try:
            self.renderer.message(topic, t, as_message(payload))
            self.drawn += 1
        except Exception as exc:  # a view never takes the robot's session down
            print(f"view: could not draw {topic}: {exc}", file=sys.stderr)

    def _send(self, everything: bool) -> None:
        try:
            self.renderer.flush(everything)
        except Exception as exc:  # a view never takes the robot's session down
            print(f"view: could not send: {exc}", file=sys.stderr)

    def drain(self) -> None:
        """Wait until every message queued so far is drawn and sent."""
        if self._closed:  # close() drew and sent everything
            return
        with self._rounds:
            self._asked += 1
            ask = self._asked
            self._wake.set()
            self._rounds.wait_for(lambda: self._served >= ask or not self._thread.is_alive())

    def server_cpu_s(self) -> float | None:
        """CPU time the serving child process has used (s; None: not serving, or not
        known on this system)."""
        return None if self.server is None else self.server.cpu_seconds()

    def close(self) -> None:
        """Detach, draw what is queued, stop the thread, flush and end the server
        (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for detach in self._detach:
            detach()
        self._wake.set()
        self._thread.join()
        try:
            self.rec.flush(timeout_sec=10.0)
            self.rec.disconnect()  # a file's footer is written, the server let go
        finally:
            if self.server is not None:
                self.server.close()

    def __enter__(self) -> RobotView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: What ``view=`` takes: None/False (no view), True (a view on the default ports), an int
#: (the web page's port), or a :class:`RobotView` to share (e.g. between a hand and an arm).
ViewSpec = RobotView | bool | int | None


def open_view(spec: ViewSpec, **options: Any) -> RobotView | None:
    """The view ``spec`` asks for (None for none); a new one's address is printed on stderr."""
    if spec is None or spec is False:
        return None
    if isinstance(spec, RobotView):
        return spec
    view = RobotView(web_port=WEB_PORT if spec is True else int(spec), **options)
    print(f"view: {view.address}", file=sys.stderr, flush=True)
    return view
