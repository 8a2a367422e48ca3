"""A live view of the robot in a browser, served from this process with no internet.

:class:`RobotView` serves rerun's web viewer (from the ``rerun-sdk`` package, the optional
``view`` extra) on this machine and streams the robot's state to it while a session runs::

    view = RobotView()                 # prints nothing; view.address is the page to open
    arm = Arm.open("./robot/arm", view=view)
    hand = Hand.open("./robot/palm", view=view)   # one view: the hand drawn on the arm

What it draws is :mod:`host.view_render`'s: the arm and hand in 3D from the kinematics,
joint angles and goals, deflections and torques, tactile pads, currents and temperatures,
bus counters and alarms, as time series.

**Cheap enough to leave on.**  The robot's loop only hands a state over: each attached
object's tap puts ``(topic, t, state)`` on a bounded queue (``queue_size``) and returns;
states come at most ``max_rate_hz`` per topic (by the link's clock; the rest are not
queued), and when the queue is full the state is dropped and counted (:attr:`dropped`),
never waited for.  One daemon thread turns states into the recorders' dicts and draws them.

rerun is imported when a view is made, never by ``import host``; without the package
:class:`ViewUnavailable` says how to install it.
"""

from __future__ import annotations

import dataclasses
import queue
import socket
import sys
import threading
import urllib.parse
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

from host.errors import UsageError, ViewUnavailable

# Topics (the MCAP recorders' names; host.view_render draws them), importable from here too.
from host.topics import ARM_BUS_STATS, ARM_STATE, HAND_EVENTS, HAND_LINK_STATS, HAND_STATE
from protocol.robot import DEFAULT_HAND_LAYOUT

if TYPE_CHECKING:
    from host.arm_interface import WatchedArm
    from host.hand_interface import WatchedHand

#: Default port of the web page; the data it reads is served on the next port up.
WEB_PORT: Final = 9090
DEFAULT_RATE_HZ: Final = 10.0
DEFAULT_QUEUE: Final = 64
#: The bus and link counters are drawn once a second (s, the link's clock).
STATS_INTERVAL_S: Final = 1.0
INSTALL_HINT: Final = "pip install 'lowcost-hand-stack[view]' (or: pip install rerun-sdk)"


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


def free_port() -> int:
    """A TCP port free on this machine now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _remove(taps: list[Any], tap: Any) -> None:
    if tap in taps:
        taps.remove(tap)


def page_address(web_port: int, grpc_url: str, host: str = "127.0.0.1") -> str:
    """The address of the web page that shows the data served at ``grpc_url``."""
    return f"http://{host}:{web_port}/?url={urllib.parse.quote(grpc_url, safe='')}"


class RobotView:
    """Serves a view (``serve``: the web page on ``web_port`` and its data on
    ``grpc_port``, by default ``web_port + 1``; 0 picks free ports) and/or writes it to the
    rerun file ``save`` (.rrd);
    ``layout`` is the hand's.  A context manager; :meth:`close` stops the thread (after
    drawing what was queued) and flushes."""

    def __init__(self, *, serve: bool = True, web_port: int = WEB_PORT,
                 grpc_port: int | None = None, save: str | Path | None = None,
                 layout: str = DEFAULT_HAND_LAYOUT, max_rate_hz: float = DEFAULT_RATE_HZ,
                 queue_size: int = DEFAULT_QUEUE, application: str = "lowcost-hand") -> None:
        if max_rate_hz <= 0 or queue_size < 1:
            raise UsageError("a view needs a positive rate and a queue of at least 1")
        try:
            import rerun as rr

            from host.view_render import Renderer, blueprint
        except ImportError as exc:
            raise ViewUnavailable(f"the live view needs rerun-sdk: {INSTALL_HINT}") from exc
        self.rec = rr.RecordingStream(application)
        self.address: str | None = None
        sinks: list[Any] = []
        if serve:
            if grpc_port is None:
                grpc_port = web_port + 1 if web_port else 0
            web_port = web_port or free_port()
            grpc_port = grpc_port or free_port()
            for port in (web_port, grpc_port):
                if not _port_free(port):
                    raise ViewUnavailable(f"port {port} is taken (another view?): "
                                          "choose other ports (--view-port N: N and N+1)")
            sinks.append(rr.GrpcServerSink("127.0.0.1", grpc_port,
                                             server_memory_limit="512MiB"))
        if save is not None:
            sinks.append(rr.FileSink(str(save)))
        self._saving = save is not None
        if sinks:
            self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        if serve:
            grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
            rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=grpc_url)
            self.address = page_address(web_port, grpc_url)
        self.renderer = Renderer(self.rec, layout)
        self.min_interval = 1.0 / max_rate_hz
        self._queue: queue.Queue[tuple[str, float, Any] | None] = queue.Queue(queue_size)
        self._last: dict[str, float] = {}
        self._detach: list[Callable[[], None]] = []
        #: States handed over, drawn, and dropped because the queue was full.
        self.offered = 0
        self.drawn = 0
        self.dropped = 0
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="robot-view", daemon=True)
        self._thread.start()

    # --- feeding ---------------------------------------------------------------------------
    def message(self, topic: str, t: float, payload: Any) -> None:
        """Queue one message (never blocks: dropped when the queue is full)."""
        if self._closed:
            return
        self.offered += 1
        try:
            self._queue.put_nowait((topic, t, payload))
        except queue.Full:
            self.dropped += 1

    def sample(self, topic: str, t: float, payload: Any, interval: float | None = None
               ) -> bool:
        """Queue a state at most ``max_rate_hz`` times a second per topic (or one every
        ``interval`` s; by ``t``); True if it was offered."""
        last = self._last.get(topic)
        if last is not None and last <= t < last + (interval or self.min_interval):
            return False
        self._last[topic] = t
        self.message(topic, t, payload)
        return True

    def attach_arm(self, arm: WatchedArm) -> None:
        """Draw every cycle's state of ``arm`` (and its bus counters) from now on."""
        stats = arm.bus.stats

        def tap(state: Any) -> None:
            if self.sample(ARM_STATE, state.t, state):
                self.sample(ARM_BUS_STATS, state.t, {"requests": stats.requests,
                                                     "retries": stats.retries,
                                                     "timeouts": stats.timeouts},
                            STATS_INTERVAL_S)

        arm.state_taps.append(tap)
        self._detach.append(lambda: _remove(arm.state_taps, tap))

    def attach_hand(self, hand: WatchedHand) -> None:
        """Draw every state ``hand`` reads (its link counters) and every finger event."""
        counters = hand.session.counters

        def tap(state: Any) -> None:
            if self.sample(HAND_STATE, state.t, state):
                self.sample(HAND_LINK_STATS, state.t, {"requests": counters.requests,
                                                       "retries": counters.retries,
                                                       "timeouts": counters.timeouts},
                            STATS_INTERVAL_S)

        hand.state_taps.append(tap)
        unsubscribe = hand.subscribe(lambda event: self.message(HAND_EVENTS, event.t, event))
        self._detach.append(lambda: _remove(hand.state_taps, tap))
        self._detach.append(unsubscribe)

    # --- drawing ---------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            topic, t, payload = item
            try:
                self.renderer.message(topic, t, as_message(payload))
                self.drawn += 1
            except Exception as exc:  # a view never takes the robot's session down
                print(f"view: could not draw {topic}: {exc}", file=sys.stderr)
            finally:
                self._queue.task_done()

    def drain(self) -> None:
        """Wait until every message queued so far is drawn."""
        self._queue.join()

    def close(self) -> None:
        """Detach, draw what is queued, stop the thread and flush (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for detach in self._detach:
            detach()
        self._queue.put(None)
        self._thread.join()
        self.rec.flush()
        if self._saving:  # the file's footer is written when its sink goes
            self.rec.disconnect()

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
