"""Emulator.run in real time, in process: it sleeps, it stops at once however far behind it
is, it says when it is late, and its stats are strict JSON."""

from __future__ import annotations

import json
import socket
import time
from functools import partial
from pathlib import Path

import serial

from firmware_py.scheduler import Scheduler
from hil_emulator.emulator import Emulator
from hil_emulator.pacing import CATCH_UP_EVENTS, LATE_WARN_MS, MAX_BEHIND_S
from hil_emulator.ports.host_links import SerialLink
from protocol.dynamixel import make_ping
from tests.hil_emulator.emulator_thread import serving
from tests.hil_emulator.faults.probes import FaultyEmulator


def _ping_node_5(path: str) -> bytes:
    """Ping node 5 over the pty at ``path``; what came back (up to its 6-byte status)."""
    with serial.Serial(path, 1_000_000, timeout=0) as port:
        port.write(make_ping(5).encode())
        got = b""
        deadline = time.monotonic() + 10.0  # a hang guard, not a timing bound
        while len(got) < 6 and time.monotonic() < deadline:
            got += port.read(64)
            time.sleep(0.001)
    return got

def test_stop_takes_effect_at_once_when_far_behind() -> None:
    """Every simulated 100 µs costs 1 ms of wall time: the loop can never catch up.  Once
    ``stop`` is set it runs at most one more batch of :data:`CATCH_UP_EVENTS` events (each
    costs 1 ms here: well within 100 ms however busy the machine); the wall clock only
    guards against a hang (2 s)."""
    emulator = Emulator("arm", physics=False)
    ran = [0]

    def costly() -> None:
        ran[0] += 1
        time.sleep(0.001)

    emulator.scheduler.call_every(100, costly)
    said: list[str] = []
    emulator.pacer.on_late = said.append
    with serving(emulator, ports=False) as run:
        time.sleep(0.5)
        t0 = time.monotonic()
        run.stop.set()
        ran_at_stop = ran[0]
        run.thread.join(2.0)
        assert not run.thread.is_alive()
    stop_s = time.monotonic() - t0
    assert ran[0] - ran_at_stop <= CATCH_UP_EVENTS + 1, (ran[0] - ran_at_stop, stop_s)
    # It said so, once, with the figure; and gave up wall time instead of bursting.
    assert len(said) == 1 and "ms late" in said[0], said
    assert float(said[0].split(" ms late")[0].rsplit(" ", 1)[1]) > LATE_WARN_MS
    assert emulator.pacer.late_episodes == 1
    assert emulator.pacer.slipped_s > 0.0


def test_host_input_skips_the_backlog_of_a_run_that_is_behind() -> None:
    """Far behind (every simulated 100 µs costs 1 ms of wall time), a ping written to the
    arm's pty enters the simulation at its present time, not at the wall clock's time
    behind a backlog of events: the reply costs only its own simulated time."""
    emulator = Emulator("arm", physics=False)
    emulator.scheduler.call_every(100, lambda: time.sleep(0.001))
    emulator.open_ports()
    link = emulator.links["arm"]
    assert isinstance(link, SerialLink)
    entered: list[tuple[int, int]] = []  # (input time, simulation time when read), µs
    clock = link.input_clock

    def recording_clock(arrived: float | None = None) -> int:
        now_us = emulator.scheduler.now_us()
        t_us = clock(arrived)
        entered.append((t_us, now_us))
        return t_us

    link.input_clock = recording_clock
    replies: list[int] = []
    emitted = link.on_emit
    assert emitted is not None  # the pacer attached at open_ports measures deliveries

    def on_emit(t_us: int) -> None:
        replies.append(t_us)
        emitted(t_us)

    link.on_emit = on_emit
    with serving(emulator, ports=False):
        time.sleep(0.3)  # far behind by now: the clock has slipped
        got = _ping_node_5(link.path)
    assert got[:3] == b"\xff\xff\x05", got
    t_in, sim_at_read = entered[0]
    assert t_in == sim_at_read  # at the present simulation time, not ahead of a backlog
    # The reply is one event chain away on the simulation clock: the ping's and the reply's
    # wire time and the servo's return delay, far less than the backlog (MAX_BEHIND_S).
    assert 0 < replies[0] - t_in < 2_000 < MAX_BEHIND_S * 1e6
    assert emulator.pacer.slipped_s > 0.0


def test_an_idle_run_sleeps_and_keeps_time() -> None:
    emulator = Emulator("arm", physics=False)
    cpu0 = time.process_time()
    wall0 = time.monotonic()
    sim0 = emulator.scheduler.now_us()
    with serving(emulator, ports=False) as run:
        time.sleep(1.0)
        run.end(2.0)
    wall = time.monotonic() - wall0
    sim = (emulator.scheduler.now_us() - sim0) / 1e6
    assert sim <= wall  # never ahead of the wall clock
    assert sim >= wall - 0.1 - emulator.pacer.slipped_s
    # The arm's firmware alone needs a small fraction of a core; polling would take it all.
    assert time.process_time() - cpu0 < 0.8 * wall


def test_stats_are_strict_json_with_null_before_any_delivery() -> None:
    stats = Emulator("arm", physics=False).lateness_stats()
    text = json.dumps(stats, allow_nan=False)
    assert json.loads(text)["p99_ms"] is None


def test_run_some_stops_after_max_events_and_carries_on() -> None:
    scheduler = Scheduler()
    seen: list[int] = []
    for t in (10, 20, 30, 40):
        scheduler.call_at(t, partial(seen.append, t))
    assert scheduler.run_some(100, 2) == 2
    assert seen == [10, 20] and scheduler.now_us() == 20  # time stays at the last event
    assert scheduler.run_some(100, 5) == 2
    assert seen == [10, 20, 30, 40] and scheduler.now_us() == 100


def test_a_real_time_run_reads_a_port_only_when_something_arrived() -> None:
    """Between events the loop sleeps on the ports' descriptors; a sleep that ends with none
    readable was a look at every port, so it does not read them again (the arm's firmware
    wakes the loop about a thousand times a simulated second: a read of every port per wake
    was most of the loop's own work).  Host input is still read, and answered."""
    emulator = Emulator("arm", physics=False)
    with serving(emulator) as run:
        link = run.emulator.links["arm"]
        polls = [0]
        poll = link.poll

        def counting_poll() -> int:
            polls[0] += 1
            return poll()

        link.poll = counting_poll  # type: ignore[method-assign]
        sim0 = emulator.scheduler.now_us()
        time.sleep(0.5)
        idle_polls, sim_us = polls[0], emulator.scheduler.now_us() - sim0
        got = _ping_node_5(run.ports["arm"])
    assert sim_us > 100_000  # it ran: hundreds of wake-ups for the arm's 1 ms ticks
    assert idle_polls <= 5, idle_polls  # no host input: (almost) never read
    assert got[:3] == b"\xff\xff\x05", got
    assert polls[0] > idle_polls


def test_a_real_time_run_answers_a_connected_control_client(tmp_path: Path) -> None:
    """The control channel's descriptor is its listening socket, which does not become
    readable when a connected client sends a request: with such a port the loop reads every
    port on every pass, so a second request on the same connection is answered too."""
    emulator = FaultyEmulator("arm", physics=False)
    path = emulator.open_control(str(tmp_path / "control"))
    with serving(emulator), socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(10.0)  # a hang guard, not a timing bound
        client.connect(path)
        answers = []
        for _ in range(3):
            client.sendall(b'{"op": "status"}\n')
            answers.append(json.loads(client.recv(65536)))
    assert [a["ok"] for a in answers] == [True, True, True]
    assert answers[0]["t_us"] < answers[2]["t_us"]  # read while the simulation ran
